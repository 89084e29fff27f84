"""Poisson ``position_weight: auto``: lambda chosen on held-out example poses, then refitted on all."""

import numpy as np
import pytest
from pydantic import ValidationError
from support.synthetic import tube_asset

from rigslim.errors import StepError
from rigslim.model.poses import FrameSplit
from rigslim.numerics.largest_entries import k_largest
from rigslim.plugin import StepContext
from rigslim.plugins.solvers.auto_lambda import choose_position_weight, held_out_errors, kfold_splits
from rigslim.plugins.solvers.methods import PoissonParams, PoissonSolver
from rigslim.plugins.solvers.reduction import solve_weights


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
    assert search["fold_count"] == len(asset.split.examples)   # leave-one-out for <= 8 examples
    assert [f["held_out_frames"] for f in search["folds"]] == [[e] for e in asset.split.examples]
    assert all(len(r["folds"]) == search["fold_count"] for r in search["grid"])
    assert [r["position_weight"] for r in search["grid"]] == [0.0, 0.01, 1.0, 100.0]
    scores = [r["score"] for r in search["grid"]]
    assert search["chosen"] == search["grid"][int(np.argmin(scores))]["position_weight"]
    assert ctx.report["position_weight"] == search["chosen"]
    assert min(scores) >= 2.0 - 1e-12   # each term is relative to its best value over the grid
    # the returned weights are the fit with the chosen lambda on ALL example poses
    direct, _ = solve_weights(asset, "poisson", PoissonParams(position_weight=search["chosen"]))
    np.testing.assert_allclose(reduced.values, direct.values, atol=1e-10)


def test_held_out_errors_match_a_direct_computation():
    import dataclasses
    asset = asset_with_examples(4)
    params = PoissonParams(position_weight_grid=[0.1])
    lam, search = choose_position_weight(asset, params, [0.1])
    assert lam == 0.1
    p2 = n2 = 0.0
    for fold, got in zip(search["folds"], search["grid"][0]["folds"], strict=False):
        held = fold["held_out_frames"]
        sub = FrameSplit(fold["fit_frames"], held, [])
        reduced, _ = solve_weights(dataclasses.replace(asset, split=sub), "poisson",
                                    PoissonParams(position_weight=0.1))
        p, n = held_out_errors(asset, reduced, held)
        assert got["position_rms_pct"] == pytest.approx(p)
        assert got["normal_rms_rad"] == pytest.approx(n)
        p2 += len(held) * p * p
        n2 += len(held) * n * n
    # pooled over every held-out pose of every fold
    m = len(asset.split.examples)
    assert search["grid"][0]["position_rms_pct"] == pytest.approx(np.sqrt(p2 / m))
    assert search["grid"][0]["normal_rms_rad"] == pytest.approx(np.sqrt(n2 / m))


@pytest.mark.parametrize("m, folds, expect", [(3, None, 3), (6, None, 6), (8, None, 8), (9, None, 4),
                                              (23, None, 4), (10, 3, 3), (5, 2, 2)])
def test_kfold_holds_out_every_example_exactly_once(m, folds, expect):
    examples = list(range(0, 3 * m, 3))   # frame numbers, not 0..m-1
    splits = kfold_splits(examples, folds)
    assert len(splits) == expect
    held_all = [f for _, held in splits for f in held]
    assert sorted(held_all) == examples          # each example held out exactly once
    for fit, held in splits:
        assert held and fit
        assert set(fit) | set(held) == set(examples) and not set(fit) & set(held)
        assert fit == [e for e in examples if e in set(fit)]   # order kept
    sizes = [len(h) for _, h in splits]
    assert max(sizes) - min(sizes) <= 1


def test_kfold_bad_fold_count():
    with pytest.raises(ValueError):
        kfold_splits([0, 1, 2], 4)
    with pytest.raises(ValueError):
        kfold_splits([0, 1, 2], 1)


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
