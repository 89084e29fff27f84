"""Poisson ``position_weight: auto``: lambda chosen on held-out example poses, then refitted on all."""

import numpy as np
import pytest
from pydantic import ValidationError
from support.synthetic import tube_asset

from rigslim.errors import StepError
from rigslim.plugin import StepContext
from rigslim.plugins.selection.k_largest import k_largest
from rigslim.plugins.solvers.auto_lambda import choose_position_weight, held_out_errors
from rigslim.plugins.solvers.methods import PoissonParams, PoissonSolver, reduce_weights
from rigslim.poses import FrameSplit


def asset_with_examples(count=7):
    asset = tube_asset(poses=count + 2)
    asset.influences = k_largest(asset.weights, 2)
    return asset


def test_auto_picks_the_least_score_and_refits_on_all_examples():
    asset = asset_with_examples()
    params = PoissonParams(position_weight="auto", position_weight_grid=[0.0, 0.01, 1.0, 100.0])
    ctx = StepContext()
    reduced = PoissonSolver().solve(asset, params, ctx)
    search = ctx.report["position_weight_auto"]
    assert search["held_out_frames"] == asset.split.examples[1::3]
    assert set(search["fit_frames"]) | set(search["held_out_frames"]) == set(asset.split.examples)
    assert [r["position_weight"] for r in search["grid"]] == [0.0, 0.01, 1.0, 100.0]
    scores = [r["score"] for r in search["grid"]]
    assert search["chosen"] == search["grid"][int(np.argmin(scores))]["position_weight"]
    assert ctx.report["position_weight"] == search["chosen"]
    assert min(scores) >= 2.0 - 1e-12   # each term is relative to its best value over the grid
    # the returned weights are the fit with the chosen lambda on ALL example poses
    direct, _ = reduce_weights(asset, "poisson", PoissonParams(position_weight=search["chosen"]))
    np.testing.assert_allclose(reduced.values, direct.values, atol=1e-10)


def test_held_out_errors_match_a_direct_computation():
    asset = asset_with_examples()
    params = PoissonParams(position_weight_grid=[0.1])
    lam, search = choose_position_weight(asset, params, [0.1])
    held = search["held_out_frames"]
    sub = FrameSplit(search["fit_frames"], held, [])
    import dataclasses
    reduced, _ = reduce_weights(dataclasses.replace(asset, split=sub), "poisson", PoissonParams(position_weight=0.1))
    p, n = held_out_errors(asset, reduced, held)
    assert lam == 0.1
    assert search["grid"][0]["position_rms_pct"] == pytest.approx(p)
    assert search["grid"][0]["normal_rms_rad"] == pytest.approx(n)


def test_too_few_examples():
    asset = tube_asset(poses=4)   # 2 example poses
    asset.influences = k_largest(asset.weights, 2)
    with pytest.raises(StepError, match="only 2"):
        PoissonSolver().solve(asset, PoissonParams(position_weight="auto"), StepContext())


def test_params():
    assert PoissonParams(position_weight="auto").position_weight == "auto"
    assert PoissonParams(position_weight=0.5).position_weight == 0.5
    for bad in (-1.0, "often"):
        with pytest.raises(ValidationError):
            PoissonParams(position_weight=bad)
    with pytest.raises(ValidationError):
        PoissonParams(position_weight_grid=[-1.0])
