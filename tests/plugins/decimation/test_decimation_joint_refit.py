"""Weights of a level without some joints (plugins/decimation/joint_refit.py): re-fit against parent reassignment."""

from __future__ import annotations

import numpy as np
import pytest
from support.synthetic import tube_asset

from rigslim.model.hierarchy import SimplifiedLevel
from rigslim.model.weights import ReducedWeights
from rigslim.plugins.decimation.joint_budget import default_solver, level_target
from rigslim.plugins.decimation.joint_refit import parent_rows, proxy_matrix, refit_rows, row_errors


def _level(asset, k):
    W = asset.weights.toarray()
    order = np.argsort(-W, axis=1)[:, :k]
    vals = np.take_along_axis(W, order, 1)
    vals /= vals.sum(axis=1, keepdims=True)
    return SimplifiedLevel(asset.mesh, ReducedWeights(order, vals, W.shape[1]), "full")


def test_proxies_are_the_nearest_kept_ancestor_and_descendants():
    parents = np.array([-1, 0, 1, 2, 1])           # 0 - 1 - 2 - 3, and 4 under 1
    kept = np.array([True, False, False, True, True])
    P = proxy_matrix(kept, parents)
    assert P[1].nonzero()[0].tolist() == [0, 3, 4]      # up to 0, down through 2 to 3, and 4
    assert P[2].nonzero()[0].tolist() == [0, 3]
    assert P[3].nonzero()[0].tolist() == [3]
    up = proxy_matrix(kept, parents, descendants=False)
    assert up[1].nonzero()[0].tolist() == [0] and up[2].nonzero()[0].tolist() == [0]
    root_dropped = proxy_matrix(np.array([False, True, True, True, True]), parents, descendants=False)
    assert root_dropped[0].nonzero()[0].tolist() == [1]  # a dropped root goes down


def test_middle_joint_dropped_refit_beats_parent_reassignment():
    asset = tube_asset(rings=24, segments=8, bones=3, poses=10, seed=3)
    target = level_target(asset, _level(asset, 3), 2)
    kept = np.array([True, False, True])
    rows = np.flatnonzero(target.support[:, 1])
    ri, rv = refit_rows(target, rows, kept, default_solver(), asset.handles)
    pi, pv = parent_rows(target, rows, kept)
    assert not ((ri == 1) & (rv > 0)).any() and not ((pi == 1) & (pv > 0)).any()
    np.testing.assert_allclose(rv.sum(axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(pv.sum(axis=1), 1.0, atol=1e-12)
    e_refit = (target.area[rows] * row_errors(target, rows, ri, rv)).sum()
    e_parent = (target.area[rows] * row_errors(target, rows, pi, pv)).sum()
    assert e_refit < 0.25 * e_parent, (e_refit, e_parent)


def test_refit_equals_the_exact_least_squares_solve():
    """Candidates {0, 2}: min_t sum_p ||t b0 + (1 - t) b2 - y||^2 over t in [0, 1] in closed form."""
    asset = tube_asset(rings=12, segments=6, bones=3, poses=8, seed=5)
    target = level_target(asset, _level(asset, 3), 2)
    kept = np.array([True, False, True])
    rows = np.arange(len(target.V))
    solver = default_solver()
    solver = (solver[0], solver[0].parse_params({"nonnegative": True, "ridge": 0.0}))
    idx, val = refit_rows(target, rows, kept, solver, asset.handles)
    vh = np.c_[target.V, np.ones(len(target.V))]
    b0 = np.einsum("pij,vj->vpi", target.T[:, 0], vh).reshape(len(rows), -1)
    b2 = np.einsum("pij,vj->vpi", target.T[:, 2], vh).reshape(len(rows), -1)
    y = target.Y.transpose(1, 0, 2).reshape(len(rows), -1)
    d = b0 - b2
    t = np.clip(((y - b2) * d).sum(axis=1) / (d * d).sum(axis=1), 0.0, 1.0)
    w0 = np.where(idx == 0, val, 0.0).sum(axis=1)
    w2 = np.where(idx == 2, val, 0.0).sum(axis=1)
    np.testing.assert_allclose(w0, t, atol=1e-7)
    np.testing.assert_allclose(w2, 1 - t, atol=1e-7)


def test_bone_limit_holds_and_rows_outside_the_kept_joints_never_appear():
    asset = tube_asset(rings=20, segments=8, bones=5, poses=8, seed=1)
    target = level_target(asset, _level(asset, 4), 2)
    kept = np.array([True, False, True, False, True])
    rows = np.arange(len(target.V))
    idx, val = refit_rows(target, rows, kept, default_solver(), asset.handles)
    assert idx.shape[1] == 2 and ((val > 0).sum(axis=1) <= 2).all()
    assert kept[idx[val > 0]].all()


@pytest.mark.parametrize("method", ["refit", "parent"])
def test_row_masks_row_by_row_equal_one_mask_at_a_time(method):
    """Several candidate choices in one solve give what each gives alone (the batched greedy relies on it)."""
    asset = tube_asset(rings=12, segments=6, bones=4, poses=8, seed=2)
    target = level_target(asset, _level(asset, 4), 3)
    rows = np.arange(len(target.V))
    a, b = np.array([True, False, True, True]), np.array([True, True, False, True])
    fn = (lambda r, k: refit_rows(target, r, k, default_solver(), asset.handles)) if method == "refit" else \
        (lambda r, k: parent_rows(target, r, k))
    both = fn(np.r_[rows, rows], np.r_[np.tile(a, (len(rows), 1)), np.tile(b, (len(rows), 1))])
    for i, mask in enumerate((a, b)):
        alone = fn(rows, mask)
        sl = slice(i * len(rows), (i + 1) * len(rows))
        np.testing.assert_allclose(row_errors(target, rows, both[0][sl], both[1][sl]),
                                   row_errors(target, rows, *alone), rtol=1e-9, atol=1e-14)
