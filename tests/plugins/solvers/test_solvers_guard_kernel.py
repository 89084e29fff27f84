"""The guard's compiled per-frame errors (plugins/solvers/guard_kernel.py) agree with the numpy reference."""

from types import SimpleNamespace

import numpy as np
import pytest
import scipy.sparse as sp

from rigslim.model.weights import ReducedWeights
from rigslim.plugins.solvers.guard_kernel import frame_errors
from rigslim.plugins.solvers.safeguards import _frame_excess_reference, k_largest_weights


def random_rig(m, n, p, k, seed):
    """Sparse input weights (2..n per row), random affine frames, and a random k-slot weighting."""
    rng = np.random.default_rng(seed)
    V = rng.normal(size=(m, 3))
    W = np.zeros((m, n))
    for v in range(m):
        cols = rng.choice(n, size=int(rng.integers(2, n + 1)), replace=False)
        W[v, cols] = rng.uniform(0.05, 1.0, size=len(cols))
    A = sp.csr_matrix(W / W.sum(axis=1, keepdims=True))
    T = np.tile(np.eye(3, 4), (p, n, 1, 1)) + 0.3 * rng.normal(size=(p, n, 3, 4))
    idx = np.stack([rng.choice(n, size=k, replace=False) for _ in range(m)])
    val = rng.uniform(-0.2, 1.0, size=(m, k))
    return V, A, T, ReducedWeights(idx, val / val.sum(axis=1, keepdims=True), n)


@pytest.mark.parametrize("m", [7, 700])          # one thread, and two (over_rows uses threads from 2 x 256 rows)
def test_frame_errors_match_three_blends_per_frame(m):
    V, A, T, fit = random_rig(m, 9, 5, 3, seed=m)
    base = k_largest_weights(A, 3)
    poses = SimpleNamespace(select=lambda frames: SimpleNamespace(T=T[list(frames)]))
    asset = SimpleNamespace(mesh=SimpleNamespace(V=V), weights=A, poses=poses)
    D_ref, ea_ref, eb_ref = _frame_excess_reference(asset, fit, base, range(len(T)))
    D, ea, eb = frame_errors(V, A, T, fit, base)
    assert D.dtype == np.float32 and D.shape == (m, len(T))
    np.testing.assert_allclose(ea, ea_ref, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(eb, eb_ref, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(D, D_ref, rtol=1e-6, atol=1e-7)
    assert (ea > 0).all() and (eb >= 0).all()
    exact = np.diff(A.indptr) <= 3                  # k-largest keeps these rows' weights: no error
    assert exact.any() and eb[exact].max() < 1e-20 and (eb[~exact] > 0).all()


def test_the_input_weights_themselves_have_zero_error():
    """A weighting equal to the input (k = the row width, padded with zero weights) has e = 0 on every frame."""
    V, A, T, _ = random_rig(20, 4, 3, 2, seed=1)
    dense = A.toarray()
    same = ReducedWeights(np.tile(np.arange(4), (20, 1)), dense, 4)
    D, ea, eb = frame_errors(V, A, T, same, same)
    assert np.abs(ea).max() < 1e-24 and np.abs(D).max() == 0.0
