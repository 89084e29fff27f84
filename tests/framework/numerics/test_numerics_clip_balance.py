"""Clip-balanced example frames (framework/numerics/clip_balance.py): the weights' formula, the cases where they
are all 1, and the fit they give against the pooled fit on held-out frames of two clips."""

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.spatial.transform import Rotation

import rigslim
from rigslim.model.poses import FrameSplit, sample_clip_frames
from rigslim.numerics.blend import linear_blend
from rigslim.numerics.clip_balance import FLOOR, clip_balance_weights, example_clips, fit_transforms, k_largest_matrix


def _clip(rng, n, frames, amplitude):
    """Joints 1.. turning about random axes with random phases and frequencies (joint 0 rests)."""
    axes = rng.normal(size=(n, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    phase, freq = rng.uniform(0, 2 * np.pi, n), rng.uniform(0.5, 2, n)
    t = np.linspace(0, 1, frames)
    T = np.tile(np.eye(3, 4), (frames, n, 1, 1))
    for j in range(1, n):
        angle = amplitude * np.sin(2 * np.pi * freq[j] * t + phase[j])
        T[:, j, :, :3] = Rotation.from_rotvec(angle[:, None] * axes[j]).as_matrix()
    return T


def two_clip_rig(seed, m=60, n=5):
    """Random weights over n joints; a long clip of large turns and a short one of small turns."""
    rng = np.random.default_rng(seed)
    V = rng.normal(size=(m, 3))
    F = np.array([[i, i + 1, i + 2] for i in range(m - 2)])
    W = rng.dirichlet(np.full(n, 0.7), size=m)
    return (V, F), W, _clip(rng, n, 60, 1.0), _clip(rng, n, 20, 0.15)


def _sq_error(V, W, R, T):
    return np.array([np.sum((linear_blend(V, sp.csr_matrix(W), t) - linear_blend(V, R, t)) ** 2) for t in T])


def test_weights_are_one_over_root_of_clip_frames_times_clip_error():
    (V, _), W, A, B = two_clip_rig(0)
    T = np.concatenate([A[::10], B[::5]])
    clip = np.array([0] * len(A[::10]) + [1] * len(B[::5]))
    w = clip_balance_weights(V, sp.csr_matrix(W), T, clip, 2)
    K = k_largest_matrix(sp.csr_matrix(W), 2)
    e = _sq_error(V, W, K, T)
    E = np.array([e[clip == c].sum() for c in (0, 1)])
    n = np.bincount(clip)
    expect = 1.0 / np.sqrt(n * E)[clip]
    np.testing.assert_allclose(w, expect / expect.mean(), rtol=1e-10)
    assert w.mean() == pytest.approx(1.0)
    assert w[clip == 1][0] > w[clip == 0][0]          # the quiet clip's frames count more


def test_k_largest_matrix_keeps_and_renormalises_the_k_largest():
    A = sp.csr_matrix(np.array([[0.5, 0.3, 0.2], [0.0, 0.6, 0.4]]))
    np.testing.assert_allclose(k_largest_matrix(A, 2).toarray(), [[0.625, 0.375, 0.0], [0.0, 0.6, 0.4]])


def test_weights_are_one_for_one_clip_or_when_k_largest_is_exact():
    (V, _), W, A, B = two_clip_rig(1, n=3)
    T = np.concatenate([A[::10], B[::5]])
    clip = np.array([0] * len(A[::10]) + [1] * len(B[::5]))
    np.testing.assert_array_equal(clip_balance_weights(V, sp.csr_matrix(W), T, np.zeros(len(T)), 2), 1.0)
    np.testing.assert_array_equal(clip_balance_weights(V, sp.csr_matrix(W), T, clip, 3), 1.0)


def test_a_clip_k_largest_already_fits_counts_at_the_floor():
    (V, _), W, A, _ = two_clip_rig(2)
    rest = np.tile(np.eye(3, 4), (4, W.shape[1], 1, 1))           # k-largest is exact on a clip at rest
    T = np.concatenate([A[::10], rest])
    clip = np.array([0] * len(A[::10]) + [1] * 4)
    w = clip_balance_weights(V, sp.csr_matrix(W), T, clip, 2)
    e = _sq_error(V, W, k_largest_matrix(sp.csr_matrix(W), 2), A[::10])
    n0 = len(A[::10])
    ratio = np.sqrt(n0 * e.sum()) / np.sqrt(4 * FLOOR * e.sum())  # w_rest / w_moving
    assert w[-1] / w[0] == pytest.approx(ratio, rel=1e-10)


def test_example_clips_from_the_split_segments():
    segments = [{"clip": "a", "start": 0, "frames": 10}, {"clip": "b", "start": 10, "frames": 5}]
    split = FrameSplit([0, 4, 8, 10, 13], [1, 11], [], segments=segments)
    np.testing.assert_array_equal(example_clips(split), [0, 0, 0, 1, 1])
    assert example_clips(FrameSplit([0, 4, 8], [1], [], segments=segments)) is None   # one clip
    assert example_clips(FrameSplit([0, 4], [1], [])) is None                          # no clips


def test_clip_scale_multiplies_each_clips_frame_weights():
    from rigslim.api import _asset

    mesh, W, A, B = two_clip_rig(3)
    asset = _asset(mesh, W, [A, B], None, None, None)
    clip = example_clips(asset.split)
    T0 = asset.example_poses().T
    T, w = fit_transforms(asset, 2, "clips")
    np.testing.assert_allclose(w, clip_balance_weights(mesh[0], sp.csr_matrix(W), T0, clip, 2), rtol=1e-12)
    np.testing.assert_allclose(T, T0 * np.sqrt(w)[:, None, None, None], rtol=1e-12)
    scale = np.array([1.0, 4.0])
    _, ws = fit_transforms(asset, 2, "clips", scale)
    expect = w * scale[clip]
    np.testing.assert_allclose(ws, expect / expect.mean(), rtol=1e-12)
    # every frame alike, then the scale alone; a scale of ones changes nothing
    _, wf = fit_transforms(asset, 2, "frames", scale)
    np.testing.assert_allclose(wf, scale[clip] / scale[clip].mean(), rtol=1e-12)
    assert fit_transforms(asset, 2, "frames", np.ones(2))[1] is None
    assert fit_transforms(asset, 2, "frames")[1] is None


@pytest.mark.parametrize("seed", range(6))
def test_balanced_fit_beats_the_pooled_fit_over_the_clips_held_out_frames(seed):
    """Mean over the two clips of the position error on their test frames, relative to k-largest's: the
    clip-balanced fit (the default) lowers it against every frame weighted alike, on every rig (the solvers'
    validated reweighting off, so that the two weightings alone are compared)."""
    (V, F), W, A, B = two_clip_rig(seed)
    (_, _, test_a), (_, _, test_b) = sample_clip_frames([len(A), len(B)], 24)
    kl = k_largest_matrix(sp.csr_matrix(W), 2)
    ratios = {}
    for balance in ("frames", "clips"):
        report: dict = {}
        R = rigslim.reduce_weights((V, F), W, [A, B], k=2, select_params={"balance": balance}, balance=balance,
                                   reweight_rounds=0, report=report)
        assert report["select_report"]["balance"] == balance and report["balance"] == balance
        ratios[balance] = np.mean([np.sqrt(_sq_error(V, W, R, T[t]).sum() / _sq_error(V, W, kl, T[t]).sum())
                                   for T, t in ((A, test_a), (B, test_b))])
    assert ratios["clips"] < ratios["frames"] < 1.0
