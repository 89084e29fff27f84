"""The guard on a short clip: few validation frames, one of them flattering the fit (plugins/solvers/safeguards.py).

Joints 0 (static), 1 and 2; every vertex has weights (0.5, 0.3, 0.2); k = 2. Joint 2 follows joint 1 on
the long clip A and on the example frames of the short clip B, so the fit lets joint 1 stand in for joint 2
(weights 0.5, 0.5: exact on the examples). On B's other frames joint 2 rests and joint 1 turns a little,
except validation frame 1, where both turn far: there the fit is much better than k-largest, on the other
validation frames and on the test frames it is worse. The sum over B's three validation frames favours the
fit (the old guard's per-clip bound passes every vertex); its margin from B's own sampling uncertainty
(mean plus two standard errors of the per-frame excess) does not, and the test frames agree.
"""

import numpy as np
import scipy.sparse as sp

import rigslim
from rigslim.model.poses import sample_clip_frames
from rigslim.numerics.blend import linear_blend
from rigslim.plugins.solvers.safeguards import MARGIN_Z, clip_bound, fallback_set, k_largest_weights

#: Every example frame weighted alike in the selection and the solve (the default balances the clips).
FRAMES = {"select_params": {"balance": "frames"}, "balance": "frames"}


def _turn(angle):
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _clip(angles, follows):
    T = np.tile(np.eye(3, 4), (len(angles), 3, 1, 1))
    for p, (a, f) in enumerate(zip(angles, follows, strict=True)):
        T[p, 1, :, :3] = _turn(a)
        if f:
            T[p, 2, :, :3] = _turn(a)
    return T


def short_clip_rig():
    rng = np.random.default_rng(5)
    m = 30
    V = rng.normal(size=(m, 3)) + np.array([2.0, 0.0, 0.0])
    F = np.array([[i, i + 1, i + 2] for i in range(m - 2)])
    W = np.tile([0.5, 0.3, 0.2], (m, 1))
    t = np.linspace(0.0, 1.0, 60)
    A = _clip(0.9 * np.sin(2 * np.pi * t), np.ones(60, bool))
    ex_b, val_b, test_b = sample_clip_frames([60, 8], 24)[1]
    angles = np.full(8, 0.3)
    angles[ex_b] = 0.8
    angles[val_b[0]] = 1.2
    follows = np.zeros(8, bool)
    follows[ex_b] = follows[val_b[0]] = True
    return (V, F), W, A, _clip(angles, follows), (ex_b, val_b, test_b)


def _errors(V, W, reduced, T):
    """(m, p) squared position error against the input weights."""
    out = []
    for Tj in T:
        d = linear_blend(V, reduced, Tj) - linear_blend(V, sp.csr_matrix(W), Tj)
        out.append(np.einsum("vc,vc->v", d, d))
    return np.stack(out, axis=1)


def test_short_clip_split_has_few_validation_frames():
    ex, val, test = sample_clip_frames([60, 8], 24)[1]
    assert (ex, val, test) == ([0, 3, 6], [1, 4, 7], [2, 5])


def test_margin_falls_back_the_vertices_the_clip_sum_passes():
    (V, F), W, A, B, (ex_b, val_b, test_b) = short_clip_rig()
    # Joints 1 and 2 are alike on every example frame, so which one the fit keeps is decided by round-off;
    # the frames weighted alike (balance: frames) keep the tie where this rig's premise puts it.
    fit = rigslim.reduce_weights((V, F), W, [A, B], k=2, guard="off", **FRAMES)
    kl = k_largest_weights(sp.csr_matrix(W), 2)
    # the fit lets joint 1 stand in for joint 2: exact on the examples of both clips
    np.testing.assert_allclose(fit.to_sparse().toarray(), np.tile([0.5, 0.5, 0.0], (len(V), 1)), atol=1e-6)
    assert _errors(V, W, fit, B[ex_b]).max() < 1e-12
    # on B's validation frames: far better on frame 1, worse on the others, better in sum
    D = _errors(V, W, fit, B[val_b]) - _errors(V, W, kl, B[val_b])
    assert (D[:, 0] < 0).all() and (D[:, 1:] > 0).all() and (D.sum(axis=1) < 0).all()
    # ... and worse on every test frame of B, for every vertex
    assert (_errors(V, W, fit, B[test_b]) > _errors(V, W, kl, B[test_b])).all()
    val_a = sample_clip_frames([60, 8], 24)[0][1]
    DA = _errors(V, W, fit, A[val_a]) - _errors(V, W, kl, A[val_a])
    excess = DA.sum(axis=1) + D.sum(axis=1)       # fit's minus k-largest's error over every validation frame
    passes, zero = np.zeros(len(V), bool), np.zeros(len(V))
    # the old rule (the clip's sum, z = 0) keeps every over-fitted vertex; the margin keeps none
    assert not fallback_set([DA, D], excess, zero, passes, z=0.0).any()
    assert clip_bound(D.sum(axis=0), z=0.0) < 0.0 < clip_bound(D.sum(axis=0), z=MARGIN_Z)
    assert fallback_set([DA, D], excess, zero, passes).all()


def test_default_is_not_worse_than_k_largest_on_the_short_clips_test_frames():
    (V, F), W, A, B, (_, _, test_b) = short_clip_rig()
    report = {}
    out = rigslim.reduce_weights((V, F), W, [A, B], k=2, report=report, **FRAMES)
    kl = k_largest_weights(sp.csr_matrix(W), 2)
    assert report["guard"] == "k-largest" and report["fallback_vertices"] == len(V)
    assert _errors(V, W, out, B[test_b]).sum() <= _errors(V, W, kl, B[test_b]).sum() * (1 + 1e-12)
