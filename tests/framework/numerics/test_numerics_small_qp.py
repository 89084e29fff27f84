"""Batched small QPs against exact KKT solves and a general QP solver (Clarabel)."""

import numpy as np
import pytest

from rigslim.numerics.small_qp import solve_small_qps


def _random_batch(rng, nb, k, q, rank=3):
    A = rng.normal(size=(nb, k, rank))
    H = A @ A.transpose(0, 2, 1) + 0.05 * np.eye(k)
    g = rng.normal(size=(nb, k)) * 3
    C = np.concatenate([np.ones((nb, 1, k)), rng.normal(size=(nb, q - 1, k))], axis=1)
    x_feas = rng.dirichlet(np.ones(k), size=nb)
    d = np.einsum("bqk,bk->bq", C, x_feas)
    return H, g, C, d, x_feas


def _clarabel(H, g, C, d, nonneg):
    clarabel = pytest.importorskip("clarabel")
    import scipy.sparse as sp

    k, q = len(g), len(d)
    rows = [C] + ([-np.eye(k)] if nonneg else [])
    cones = [clarabel.ZeroConeT(q)] + ([clarabel.NonnegativeConeT(k)] if nonneg else [])
    settings = clarabel.DefaultSettings()
    settings.verbose = False
    settings.tol_gap_abs = settings.tol_gap_rel = settings.tol_feas = 1e-12
    s = clarabel.DefaultSolver(sp.csc_matrix(np.triu(H)), g, sp.csc_matrix(np.vstack(rows)),
                               np.r_[d, np.zeros(k if nonneg else 0)], cones, settings)
    return np.array(s.solve().x)


def _objective(H, g, x):
    return 0.5 * np.einsum("bk,bkl,bl->b", x, H, x) + np.einsum("bk,bk->b", g, x)


def test_equality_only_matches_kkt(rng):
    H, g, C, d, _ = _random_batch(rng, 50, 5, 2)
    x = solve_small_qps(H, g, C, d).x
    for b in range(50):
        K = np.block([[H[b], C[b].T], [C[b], np.zeros((2, 2))]])
        ref = np.linalg.solve(K, np.r_[-g[b], d[b]])[:5]
        np.testing.assert_allclose(x[b], ref, atol=1e-9)
    np.testing.assert_allclose(np.einsum("bqk,bk->bq", C, x), d, atol=1e-12)


@pytest.mark.parametrize("k,q", [(4, 1), (6, 1), (6, 4)])
def test_nonnegative_matches_clarabel(rng, k, q):
    nb = 40
    H, g, C, d, x0 = _random_batch(rng, nb, k, q)
    res = solve_small_qps(H, g, C, d, nonneg=True, x0=x0)
    assert res.converged.all()
    assert (res.x >= 0).all()
    np.testing.assert_allclose(np.einsum("bqk,bk->bq", C, res.x), d, atol=1e-10)
    ref = np.array([_clarabel(H[b], g[b], C[b], d[b], True) for b in range(nb)])
    f, fref = _objective(H, g, res.x), _objective(H, g, ref)
    # Exact active set: never worse than the interior-point reference, and equal to it.
    assert (f <= fref + 1e-8 * (1 + np.abs(fref))).all()
    np.testing.assert_allclose(f, fref, atol=1e-7 * (1 + np.abs(fref).max()))
    np.testing.assert_allclose(res.x, ref, atol=1e-5)


def test_mixed_batch_and_padding(rng):
    # Problem 0 non-negative, problem 1 free; slot 3 is padding (identity row, no constraint).
    H = np.tile(np.eye(4), (2, 1, 1))
    g = np.array([[-3.0, 1.0, 1.0, 0.0], [-3.0, 1.0, 1.0, 0.0]])
    C = np.array([[[1.0, 1.0, 1.0, 0.0]]] * 2)
    d = np.ones((2, 1))
    x0 = np.array([[1 / 3, 1 / 3, 1 / 3, 0.0]] * 2)
    res = solve_small_qps(H, g, C, d, nonneg=np.array([True, False]), x0=x0)
    np.testing.assert_allclose(res.x[0], [1.0, 0.0, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(res.x[1], [3.0, -1.0, -1.0, 0.0], atol=1e-12)  # -g already sums to 1


def test_start_must_be_given_with_bounds(rng):
    H, g, C, d, _ = _random_batch(rng, 3, 4, 1)
    with pytest.raises(ValueError):
        solve_small_qps(H, g, C, d, nonneg=True)


@pytest.mark.parametrize("k,q,nonneg", [(4, 1, True), (6, 4, True), (5, 2, False)])
@pytest.mark.opencl
def test_opencl_kernel_matches_numpy(rng, k, q, nonneg):
    pytest.importorskip("pyopencl")
    from rigslim.device.opencl import OpenCLUnavailable, get_runtime
    from rigslim.plugins.solvers.opencl_qp import solve_small_qps_opencl

    try:
        get_runtime("cpu")
    except OpenCLUnavailable:
        pytest.skip("no OpenCL CPU device")
    H, g, C, d, x0 = _random_batch(rng, 200, k, q)
    ref = solve_small_qps(H, g, C, d, nonneg=nonneg, x0=x0).x
    x = solve_small_qps_opencl(H, g, C, d, nonneg, x0, device="cpu")
    np.testing.assert_allclose(x, ref, atol=1e-10)
