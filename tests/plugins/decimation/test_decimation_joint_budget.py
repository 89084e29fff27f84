"""Joint budgets per level (plugins/decimation/joint_budget.py): the greedy choices, what stays, the step."""

from __future__ import annotations

import numpy as np
import pytest
from support.synthetic import tube_asset

from rigslim.errors import StepError
from rigslim.model.hierarchy import SimplifiedLevel
from rigslim.model.weights import ReducedWeights
from rigslim.plugins.decimation.joint_budget import (
    apply_joint_budgets,
    budget_counts,
    choose_joints,
    default_solver,
    level_target,
)


def _level(asset, k=4):
    W = asset.weights.toarray()
    order = np.argsort(-W, axis=1)[:, :k]
    vals = np.take_along_axis(W, order, 1)
    vals /= vals.sum(axis=1, keepdims=True)
    return SimplifiedLevel(asset.mesh, ReducedWeights(order, vals, W.shape[1]), "full")


def _used(choice):
    return set(np.unique(choice.indices[choice.values > 0]).tolist())


def test_budget_counts():
    assert budget_counts(None, 2, 10) == [None, None]
    assert budget_counts(4, 3, 10) == [4, 4, 4]
    assert budget_counts(0.5, 2, 54) == [27, 27]
    assert budget_counts([40, 24, 0.25], 3, 54) == [40, 24, 14]
    for bad in ([1, 2], 0, -3, 2.5):
        with pytest.raises(StepError):
            budget_counts(bad, 3, 10)


@pytest.mark.parametrize("strategy", ["leaf-first", "global", "best"])
def test_a_level_keeps_at_most_its_budget_and_never_a_required_joint_is_dropped(strategy):
    asset = tube_asset(rings=30, segments=8, bones=6, poses=10, seed=4)
    target = level_target(asset, _level(asset), 4)
    required = np.zeros(6, bool)
    required[2] = True
    choice = choose_joints(target, 3, required, strategy=strategy, solver=default_solver(), handles=asset.handles)
    assert choice.met and len(_used(choice)) <= 3 and 2 in _used(choice)
    assert 2 not in choice.dropped
    np.testing.assert_allclose(choice.values.sum(axis=1), 1.0, atol=1e-9)
    assert choice.indices.shape[1] == 4


def test_leaf_first_drops_only_leaves_and_global_can_drop_a_middle_joint():
    """With the chain's tip required, leaf-first has no leaf to drop; global drops the middle ones."""
    asset = tube_asset(rings=30, segments=8, bones=5, poses=10, seed=6)
    target = level_target(asset, _level(asset), 4)
    required = np.zeros(5, bool)
    required[4] = True
    solver = default_solver()
    leaf = choose_joints(target, 3, required, strategy="leaf-first", solver=solver, handles=asset.handles)
    assert not leaf.met and leaf.dropped == []
    glob = choose_joints(target, 3, required, strategy="global", solver=solver, handles=asset.handles)
    assert glob.met and 4 in _used(glob) and len(glob.dropped) >= 2
    free = choose_joints(target, 3, np.zeros(5, bool), strategy="leaf-first", solver=solver, handles=asset.handles)
    parents = asset.handles.parents
    gone = set()
    for j in free.dropped:                      # when dropped, no joint below it was still there
        below = [c for c in range(5) if c not in gone and c != j and _is_below(c, j, parents)]
        assert not below, (j, below)
        gone.add(j)


def _is_below(c, j, parents):
    a = int(parents[c])
    while a >= 0:
        if a == j:
            return True
        a = int(parents[a])
    return False


def test_refit_choice_beats_parent_reassignment_of_its_own_choice():
    """Each method choosing its own joints; and the re-fit on the joints parent reassignment kept."""
    from rigslim.plugins.decimation.joint_refit import refit_rows, row_errors

    asset = tube_asset(rings=30, segments=8, bones=6, poses=12, seed=7)
    target = level_target(asset, _level(asset), 4)
    none = np.zeros(6, bool)
    refit = choose_joints(target, 3, none, strategy="global", solver=default_solver(), handles=asset.handles)
    parent = choose_joints(target, 3, none, strategy="global", method="parent")
    assert refit.energy < 0.8 * parent.energy, (refit.energy, parent.energy)
    rows = np.arange(len(target.V))
    idx, val = refit_rows(target, rows, parent.used, default_solver(), asset.handles)
    same = float((target.area * row_errors(target, rows, idx, val)).sum())
    assert same < 0.8 * parent.energy, (same, parent.energy)


def test_apply_reports_each_level_and_leaves_unbudgeted_levels_alone():
    asset = tube_asset(rings=24, segments=8, bones=6, poses=10, seed=8)
    lv = _level(asset)
    out, records = apply_joint_budgets(asset, [lv, lv], [None, 2], {0: "named"}, max_bones=4)
    assert out[0] is lv and records[0]["dropped"] == []
    assert records[1]["joints"] <= 2 and records[1]["met"] and "bone0" not in records[1]["dropped"]
    assert records[1]["joints_before"] == 6 and len(records[1]["dropped"]) >= 4
    assert out[1].mesh is lv.mesh and out[1].label == lv.label
    used = np.unique(out[1].weights.indices[out[1].weights.values > 0])
    assert 0 in used and len(used) <= 2


def _displacement(asset, level, weights) -> float:
    """Largest per-vertex RMS example-pose displacement of ``weights`` from ``level``'s own deformation."""
    from rigslim.numerics.blend import linear_blend

    T = asset.example_poses().T
    d2 = sum(((linear_blend(level.mesh.V, weights.to_sparse(), Tp)
               - linear_blend(level.mesh.V, level.weights.to_sparse(), Tp)) ** 2).sum(axis=1) for Tp in T)
    return float(np.sqrt(d2.max() / len(T)))


def test_the_error_bound_stops_joint_removals_before_the_budget():
    """Unbounded, two joints of six displace the tube by d; under a bound of half of d (less the faces' error)
    the removals stop inside it: more joints than the budget, met false, stopped max_error, and the error the
    next removal would reach (above the bound) recorded; the weights written displace it within the bound."""
    asset = tube_asset(rings=24, segments=8, bones=6, poses=10, seed=8)
    lv = _level(asset)
    (free,), (rec,) = apply_joint_budgets(asset, [lv], [2], {}, max_bones=4)
    d = _displacement(asset, lv, free.weights)
    assert rec["met"] and rec["joints"] == 2 and rec["stopped"] is None and rec["max_error"] is None
    assert rec["displacement"] == pytest.approx(d, rel=1e-6) and rec["error"] == rec["displacement"]
    bound, face = 0.5 * d, 0.1 * d
    (held,), (rec,) = apply_joint_budgets(asset, [lv], [2], {}, max_bones=4, bound=bound, face_errors=[face])
    assert not rec["met"] and rec["stopped"] == "max_error" and rec["joints"] > 2
    assert rec["max_error"] == bound and rec["face_error"] == face
    assert rec["error"] == pytest.approx(face + _displacement(asset, lv, held.weights), rel=1e-6)
    assert rec["error"] <= bound < rec["next_error"]
    assert len(np.unique(held.weights.indices[held.weights.values > 0])) == rec["joints"]
    (same,), (rec2,) = apply_joint_budgets(asset, [lv], [2], {}, max_bones=4, bound=2 * d)
    assert rec2["met"] and rec2["stopped"] is None and rec2["error"] <= 2 * d      # room enough: the budget met


def test_best_prefers_the_fewer_joints_when_neither_choice_meets_the_budget():
    asset = tube_asset(rings=24, segments=8, bones=6, poses=10, seed=8)
    target = level_target(asset, _level(asset), 4)
    none = np.zeros(6, bool)
    solver = default_solver()
    free = choose_joints(target, 2, none, strategy="global", solver=solver, handles=asset.handles)
    limit = 0.5 * free.displacement(target)
    tries = [choose_joints(target, 2, none, strategy=s, solver=solver, handles=asset.handles, limit=limit)
             for s in ("leaf-first", "global", "best")]
    assert all(c.stopped == "max_error" and c.displacement(target) <= limit < c.next_error for c in tries)
    assert int(tries[2].used.sum()) == min(int(c.used.sum()) for c in tries[:2])


def test_a_cage_has_no_joints_to_budget():
    from support.synthetic import cage_asset

    asset = cage_asset()
    lv = SimplifiedLevel(asset.mesh, ReducedWeights(np.zeros((asset.mesh.n_vertices, 1), int),
                                                    np.ones((asset.mesh.n_vertices, 1)), asset.handles.n), "l")
    with pytest.raises(StepError, match="skeleton"):
        apply_joint_budgets(asset, [lv], [2], {}, max_bones=4)
