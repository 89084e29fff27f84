"""The solvers' safeguards: the guard against k-largest on held-out frames of every clip, and the pass-through
of vertices with at most k influences (plugins/solvers/safeguards.py)."""

import json

import numpy as np
import pytest
import scipy.sparse as sp

import rigslim
from rigslim.model.weights import ReducedWeights
from rigslim.numerics.blend import linear_blend
from rigslim.plugins.solvers.safeguards import k_largest_weights, pass_through


def _rotation_z(angle):
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def two_clip_rig(frames=30):
    """Joints 0 (static), 1 (bends), 2, 3; vertices of two kinds, weights (0.5, 0.3, 0.2).

    Kind "over" (joints 0, 1, 2): joint 2 moves like joint 1 in clip A and on clip B's frames 0, 3, 6, ...
    (the example frames sampled there), and stays at rest on B's other frames: the examples say that
    joint 1 can stand in for joint 2, the held-out frames of B say otherwise (the fit over-fits).
    Kind "right" (joints 0, 1, 3): joint 3 moves like joint 1 everywhere; the fit is exact everywhere.
    """
    rng = np.random.default_rng(3)
    m = 40
    V = rng.normal(size=(m, 3)) + np.array([2.0, 0.0, 0.0])
    F = np.array([[i, i + 1, i + 2] for i in range(m - 2)])
    W = np.zeros((m, 4))
    over = np.arange(m) < m // 2
    W[over, :3] = (0.5, 0.3, 0.2)
    W[~over] = (0.5, 0.3, 0.0, 0.2)

    def clip(angles, rest2):
        T = np.tile(np.eye(3, 4), (len(angles), 4, 1, 1))
        for p, a in enumerate(angles):
            T[p, 1, :, :3] = T[p, 3, :, :3] = _rotation_z(a)
            if not rest2[p]:
                T[p, 2, :, :3] = _rotation_z(a)
        return T

    t = np.linspace(0.0, 1.0, frames)
    A = clip(0.9 * np.sin(2 * np.pi * t), np.zeros(frames, bool))
    B = clip(0.7 * np.cos(3 * np.pi * t), np.arange(frames) % 3 != 0)
    return (V, F), W, A, B, over


def _rms(mesh, W, reduced, T, rows=slice(None)):
    full = np.stack([linear_blend(mesh[0], sp.csr_matrix(W), T[j])[rows] for j in range(len(T))])
    red = np.stack([linear_blend(mesh[0], reduced, T[j])[rows] for j in range(len(T))])
    return float(np.sqrt(np.mean(np.sum((full - red) ** 2, axis=-1))))


def test_guard_never_worse_than_k_largest_on_any_clip_and_better_where_the_fit_is_right():
    mesh, W, A, B, over = two_clip_rig()
    kl = k_largest_weights(sp.csr_matrix(W), 2)
    unguarded = rigslim.reduce_weights(mesh, W, [A, B], k=2, guard="off")
    # the held-out (test) frames of each clip, as the sampling keeps them: 2, 5, 8, ... here
    held = np.arange(30) % 3 == 2
    # without the guard the fit loses to k-largest on clip B (the over-fitted vertices), in total too
    assert _rms(mesh, W, unguarded, B[held], over) > 1.5 * _rms(mesh, W, kl, B[held], over)
    assert _rms(mesh, W, unguarded, B[held]) > _rms(mesh, W, kl, B[held])
    for guard in ("k-largest", "k-largest-per-vertex"):
        report = {}
        default = rigslim.reduce_weights(mesh, W, [A, B], k=2, report=report,
                                         **({} if guard == "k-largest" else {"guard": guard}))
        assert report["select"] == "best-fit" and report["guard"] == guard
        assert report["validation_frames"] == 20 and 0 < report["fallback_vertices"] <= int(over.sum())
        # with it: never worse than k-largest on either clip, and better on both
        for clip in (A, B):
            assert _rms(mesh, W, default, clip[held]) < _rms(mesh, W, kl, clip[held])
        for c in report["validation_clips"]:
            assert c["rms_pct"] <= c["rms_pct_k_largest"]
        # where the fit is right it is kept, exact on every clip where k-largest is not
        for clip in (A, B):
            assert _rms(mesh, W, default, clip[held], ~over) < 1e-6 < _rms(mesh, W, kl, clip[held], ~over)
    # per vertex: every over-fitted vertex falls back to k-largest's weights
    assert report["fallback_vertices"] == int(over.sum())
    np.testing.assert_array_equal(default.to_sparse()[over].toarray(), kl.to_sparse()[over].toarray())


def test_guard_is_off_without_validation_frames():
    mesh, W, A, B, _ = two_clip_rig()
    report = {}
    rigslim.reduce_weights(mesh, W, A, k=2, report=report)
    assert report["guard"] == "no validation frames" and report["fallback_vertices"] == 0


def test_validation_poses_of_the_api_drive_the_guard():
    mesh, W, A, B, over = two_clip_rig()
    report = {}
    examples = np.concatenate([A, B[::3]])
    out = rigslim.reduce_weights(mesh, W, examples, k=2, validation=B[1::3], report=report)
    assert report["validation_frames"] == 10 and report["fallback_vertices"] > 0
    assert _rms(mesh, W, out, B[2::3]) <= _rms(mesh, W, k_largest_weights(sp.csr_matrix(W), 2), B[2::3])


def test_pass_through_keeps_small_rows_bit_for_bit():
    A = sp.csr_matrix(np.array([[0.1 + 1e-17, 0.9, 0.0, 0.0], [0.25, 0.25, 0.25, 0.25], [0.3, 0.0, 0.0, 0.7]]))
    reduced = ReducedWeights(np.array([[1, 0], [0, 1], [3, 0]]), np.array([[0.8, 0.2], [0.5, 0.5], [1.0, 0.0]]), 4)
    out, count = pass_through(A, reduced)
    assert count == 2
    assert out.to_sparse()[[0, 2]].toarray().tobytes() == A[[0, 2]].toarray().tobytes()
    np.testing.assert_array_equal(out.values[1], reduced.values[1])


def test_pass_through_only_where_the_influence_set_holds_the_row():
    """A joint budget re-fits a row onto kept joints with a set that leaves out a dropped joint: such a row is
    fitted, never passed through with the dropped joint's weight (wuson at half the joints: max error 0.222 m
    passed through against 0.054 m fitted)."""
    from rigslim.model.weights import InfluenceSets

    A = sp.csr_matrix(np.array([[0.5, 0.5, 0.0], [0.3, 0.0, 0.7]]))
    fitted = ReducedWeights(np.array([[0, 2], [0, 2]]), np.array([[0.9, 0.1], [0.2, 0.8]]), 3)
    sets = InfluenceSets(np.array([[0, 2], [0, 2]]), np.ones((2, 2), bool))   # joint 1 dropped
    out, n = pass_through(A, fitted, sets)
    assert n == 1                                                   # row 1 (joints 0, 2) passes through
    np.testing.assert_array_equal(out.values[0], [0.9, 0.1])       # row 0 keeps its fit on joints 0 and 2
    np.testing.assert_array_equal(out.to_sparse().toarray()[1], [0.3, 0.0, 0.7])
    assert pass_through(A, fitted)[1] == 2                          # without sets: both rows, as before


def test_k_at_least_the_joint_count_passes_through_in_the_api():
    mesh, W, A, B, _ = two_clip_rig()
    for k in (4, 6):
        report = {}
        out = rigslim.reduce_weights(mesh, W, [A, B], k=k, report=report)
        assert out.to_sparse().toarray().tobytes() == W.tobytes()
        assert "not smaller than the 4 handles" in report["select_report"]["pass_through"]
        assert report["passed_through"] == len(W) and report["fallback_vertices"] == 0


def test_k_at_least_the_joint_count_passes_through_in_a_pipeline(write_pipeline):
    from rigslim.runtime.run import run_pipeline

    for select, solve in (("best-fit\n    by: error", "geometric"), ("k-largest", "k-largest")):
        path = write_pipeline(f"""
inputs:
  mesh: data/elephant.obj
  skeleton: data/elephant.tgf
  weights: data/elephant-weights.dmat
  animation: data/elephant-anim.dmat
poses: {{examples: "0:457:45", test: "5:457:45"}}
steps:
  - select: {select}
    k: 24
  - solve: {solve}
  - evaluate: [position-rms]
""")
        result = run_pipeline(path)
        reduced = result.asset.reduced.to_sparse()
        reduced.sort_indices()
        weights = result.asset.weights.tocsr()
        weights.sort_indices()
        assert (reduced != weights).nnz == 0
        assert result.document["evaluations"][0]["metrics"]["position_rms_pct"]["max"] == 0.0
        select_step = next(s for s in result.document["steps"] if s["stage"] == "select")
        assert "24 handles" in json.dumps(select_step)


def test_twins_take_the_input_weights_choice_and_change_nothing_on_the_seen_poses():
    """Joints 1 and 2 move alike on every seen pose (twins): the fit cannot tell them apart, and the slot goes
    to the one of larger input weight; on a pose where they part, that is closer to the input."""
    from rigslim.plugins.solvers.safeguards import canonical_twins, twin_handles

    rng = np.random.default_rng(7)
    V = rng.normal(size=(6, 3)) + np.array([2.0, 0.0, 0.0])
    seen = np.tile(np.eye(3, 4), (5, 4, 1, 1))
    for p, a in enumerate(np.linspace(0.2, 1.0, 5)):
        seen[p, 1, :, :3] = seen[p, 2, :, :3] = _rotation_z(a)
        seen[p, 3, :, :3] = _rotation_z(-a)
    label = twin_handles(seen, 3.0)
    assert label.tolist() == [0, 1, 1, 3]
    A = sp.csr_matrix(np.tile([0.4, 0.35, 0.05, 0.2], (6, 1)))
    # the fit put joint 2 (input weight 0.05) where joint 1 (0.35) moves the same
    fit = ReducedWeights(np.tile([0, 2, 3], (6, 1)), np.tile([0.4, 0.4, 0.2], (6, 1)), 4)
    out, moved = canonical_twins(A, fit, label)
    assert moved == 6 and (out.indices == [0, 1, 3]).all() and (out.values == fit.values).all()
    for T in seen:
        np.testing.assert_allclose(linear_blend(V, out, T), linear_blend(V, fit, T), atol=1e-12)
    parted = seen[-1].copy()
    parted[2, :, :3] = np.eye(3)
    full = linear_blend(V, A, parted)
    assert np.linalg.norm(linear_blend(V, out, parted) - full) < np.linalg.norm(linear_blend(V, fit, parted) - full)
    # already on the larger: nothing moves
    assert canonical_twins(A, out, label)[1] == 0


def conflicting_clips_rig():
    """Joints 0 (static), 1 (turns), 2; every vertex (0.5, 0.3, 0.2), k = 2 on joints 0 and 1 (k-largest sets).

    The set's one free weight a (on joint 0) reproduces clip A exactly at a = 0.7 (joint 2 rests) and clip B
    exactly at a = 0.64 (joint 2 = 0.7 I + 0.3 joint 1); k-largest's a is 0.625. A is long and moves far, B is
    short and moves little, so the fit of both (a = 0.67) is far better than k-largest on A and twice as bad on
    B: the guard gives every vertex back to k-largest. Any a in (0.625, 0.655) beats k-largest on both.
    """
    rng = np.random.default_rng(1)
    m = 30
    V = rng.normal(size=(m, 3)) + np.array([2.0, 0.0, 0.0])
    F = np.array([[i, i + 1, i + 2] for i in range(m - 2)])
    W = np.tile([0.5, 0.3, 0.2], (m, 1))

    def clip(n, amplitude, mix):
        T = np.tile(np.eye(3, 4), (n, 3, 1, 1))
        for p, t in enumerate(np.linspace(0.0, 1.0, n)):
            T[p, 1, :, :3] = _rotation_z(amplitude * np.sin(2 * np.pi * t))
            T[p, 2] = (1.0 - mix) * np.eye(3, 4) + mix * T[p, 1]
        return T

    return (V, F), W, clip(60, 1.2, 0.0), clip(30, 0.25, 0.3)


def test_reweighting_finds_weights_that_beat_k_largest_on_both_clips():
    mesh, W, A, B = conflicting_clips_rig()
    kl = k_largest_weights(sp.csr_matrix(W), 2)
    unguarded = rigslim.reduce_weights(mesh, W, [A, B], k=2, select="k-largest", guard="off")
    assert _rms(mesh, W, unguarded, A) < 0.5 * _rms(mesh, W, kl, A)
    assert _rms(mesh, W, unguarded, B) > 1.5 * _rms(mesh, W, kl, B)
    # without reweighting the guard can only fall back: k-largest's weights everywhere
    plain: dict = {}
    out = rigslim.reduce_weights(mesh, W, [A, B], k=2, select="k-largest", reweight_rounds=0, report=plain)
    assert plain["fallback_vertices"] == len(W) and "reweight_rounds" not in plain
    np.testing.assert_allclose(out.values, kl.values)
    # with it (the default), B's frames count more until B passes; A still passes
    report: dict = {}
    out = rigslim.reduce_weights(mesh, W, [A, B], k=2, select="k-largest", report=report)
    assert report["reweight_rounds"] >= 1 and report["clip_scale"][0] == 1.0 and report["clip_scale"][1] > 1.0
    assert report["fallback_vertices"] == 0
    assert _rms(mesh, W, out, A) < 0.8 * _rms(mesh, W, kl, A)
    assert _rms(mesh, W, out, B) < 0.9 * _rms(mesh, W, kl, B)
    assert np.all((out.values[:, 0] > 0.625) & (out.values[:, 0] < 0.655))


def test_failing_clips_names_the_clip_the_fit_is_worse_on():
    from rigslim.api import _asset
    from rigslim.plugins.solvers.safeguards import failing_clips

    mesh, W, A, B = conflicting_clips_rig()
    asset = _asset(mesh, W, [A, B], None, None, None)
    kl = k_largest_weights(sp.csr_matrix(W), 2)
    fit = rigslim.reduce_weights(mesh, W, [A, B], k=2, select="k-largest", guard="off")
    assert failing_clips(asset, fit) == [1]          # clip B
    assert failing_clips(asset, kl) == []            # k-largest is its own bound: excess 0 on every frame
    assert failing_clips(_asset(mesh, W, A, None, None, None), fit) == []   # one clip, no validation frames


def test_roundoff_on_a_clip_at_rest_is_not_a_failure():
    """A clip in which the vertices do not move gives the fit and k-largest errors of about 1e-12 that differ in
    their last bits (the zebra's idle); an excess below the round-off tolerance must not make them fall back."""
    from rigslim.api import _asset
    from rigslim.plugins.solvers.safeguards import ROUNDOFF, fallback_set, roundoff_tolerance

    rng = np.random.default_rng(0)
    m = 12
    moving = -rng.uniform(1e-3, 2e-3, size=(m, 8))          # the fit far better on the moving clip
    rest = np.full((m, 6), 5e-16) * rng.uniform(0.5, 1.5, size=(m, 6))   # last bits against it at rest
    e_fit = 1e-3 + 2e-12 + rest.sum(axis=1)
    e_kl = e_fit - moving.sum(axis=1) - rest.sum(axis=1)
    passes = np.zeros(m, bool)
    mesh, W, A, _ = conflicting_clips_rig()
    asset = _asset(mesh, W, A, None, None, None)
    tol = roundoff_tolerance(asset, m)
    assert tol == pytest.approx(m * (ROUNDOFF * asset.mesh.bbox_diagonal) ** 2)
    assert fallback_set([moving, rest], e_fit, e_kl, passes).all()          # no tolerance: every vertex falls back
    assert not fallback_set([moving, rest], e_fit, e_kl, passes, tol=tol).any()
    # a real excess on the clip at rest (each vertex 1e-4 of the diagonal off) still fails
    real = rest + (1e-4 * asset.mesh.bbox_diagonal) ** 2
    assert fallback_set([moving, real], e_fit, e_kl + 0.0, passes, tol=tol).any()
