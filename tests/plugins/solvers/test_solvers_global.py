"""Global solver: the exact equality-constrained optimum."""

import numpy as np
import pytest
import scipy.sparse as sp
from support.synthetic import cage_asset, tube_asset

from rigslim.numerics.largest_entries import k_largest
from rigslim.plugins.solvers.global_solver import assemble_hessian, global_solve, linear_term
from rigslim.plugins.solvers.problem import build_problem


@pytest.mark.parametrize("method", ["geometric", "smooth", "poisson"])
def test_matches_dense_kkt(method):
    asset = tube_asset(rings=8, segments=6)
    asset.influences = k_largest(asset.weights, 2)
    prob = build_problem(asset, method, nonnegative=False)
    alpha, rep = global_solve(prob)
    m, k = prob.m, prob.k
    H = assemble_hessian(prob).toarray()
    f = linear_term(prob)
    C = np.zeros((m, m * k))
    for v in range(m):
        C[v, v * k:(v + 1) * k] = prob.C[v, 0]
    K = np.block([[H, C.T], [C, np.zeros((m, m))]])
    ref = np.linalg.solve(K, np.r_[-f, prob.d[:, 0]])[:m * k].reshape(m, k)
    np.testing.assert_allclose(alpha, ref, atol=1e-8)
    assert rep["kkt_residual"] < 1e-9
    # The Hessian form agrees with the energy: E(a) = a^T H a + 2 f^T a + const.
    a1 = ref + 0.01 * np.random.default_rng(0).normal(size=ref.shape)
    a1 = np.where(prob.valid, a1, 0)
    def e(a):
        return a.ravel() @ H @ a.ravel() + 2 * f @ a.ravel()
    assert prob.energy(a1) - prob.energy(ref) == pytest.approx(e(a1) - e(ref), rel=1e-8)


def test_cage_linear_precision_is_exact():
    asset = cage_asset()
    asset.influences = k_largest(asset.weights, 5)
    prob = build_problem(asset, "smooth", nonnegative=False, linear_precision=True)
    alpha, _ = global_solve(prob)
    rest = np.einsum("mqk,mk->mq", prob.C, alpha)
    np.testing.assert_allclose(rest, prob.d, atol=1e-9)


def test_spd_solve_backends_agree():
    """MKL PARDISO (upper triangle, SPD mode) and SuperLU give the same solution of a reduction system."""
    from rigslim.plugins.solvers.global_solver import spd_solve

    rng = np.random.default_rng(3)
    n = 400
    R = sp.random(n, n, density=0.01, random_state=4, format="csr")
    A = (R @ R.T + sp.identity(n) * 0.5).tocsr()
    b = rng.normal(size=n)
    x_p, used_p = spd_solve(A, b, "pardiso")
    x_s, used_s = spd_solve(A, b, "superlu")
    assert (used_p, used_s) == ("pardiso", "superlu")
    assert np.linalg.norm(A @ x_p - b) <= 1e-10 * np.linalg.norm(b)
    np.testing.assert_allclose(x_p, x_s, rtol=0, atol=1e-9 * np.abs(x_s).max())


def test_direct_global_solve_reports_factorisation():
    """The exact global solve names its back end, and both back ends reach the same optimum."""
    import rigslim.plugins.solvers.global_solver as gs

    asset = tube_asset()
    asset.influences = k_largest(asset.weights, 3)
    prob = build_problem(asset, "poisson", nonnegative=False)
    a1, r1 = gs.global_solve(prob, method="direct")
    assert r1["factorisation"] == "pardiso"
    orig = gs.pardiso_available
    try:
        gs.pardiso_available = lambda: False
        a2, r2 = gs.global_solve(prob, method="direct")
    finally:
        gs.pardiso_available = orig
    assert r2["factorisation"] == "superlu"
    assert abs(r1["energy"] - r2["energy"]) <= 1e-10 * abs(r2["energy"])
    np.testing.assert_allclose(a1, a2, atol=1e-8)


@pytest.mark.parametrize("linear_precision", [False, True])
def test_upper_triangle_equals_triu_of_the_block_matrix(linear_precision):
    """The scalar upper triangle PARDISO reads, written from the blocks, is scipy's triu of the matrix
    (dummy rows of vertices with fewer null directions included)."""
    from rigslim.plugins.solvers.nullspace import nullspace_system

    asset = cage_asset()
    asset.influences = k_largest(asset.weights, 5)
    prob = build_problem(asset, "poisson", nonnegative=False, linear_precision=linear_precision)
    system = nullspace_system(prob)
    U = system.upper_triangle()
    ref = sp.triu(system.matrix().tocsr(), format="csr")
    ref.sort_indices()
    assert U.has_sorted_indices and U.indptr.dtype == np.int32
    np.testing.assert_array_equal(U.indptr, ref.indptr)
    np.testing.assert_array_equal(U.indices, ref.indices)
    np.testing.assert_array_equal(U.data, ref.data)


@pytest.mark.parametrize("linear_precision", [False, True])
def test_upper_blocks_solve_equals_a_dense_solve(linear_precision):
    """The upper block triangle PARDISO reads as block sparse rows holds the upper blocks of the matrix,
    each column by column, and PARDISO's block solve agrees with a dense solve of the whole system
    (dummy rows of vertices with fewer null directions included)."""
    from rigslim.plugins.solvers.global_solver import pardiso_block_solve
    from rigslim.plugins.solvers.nullspace import nullspace_system

    asset = cage_asset()
    asset.influences = k_largest(asset.weights, 5)
    prob = build_problem(asset, "poisson", nonnegative=False, linear_precision=linear_precision)
    system = nullspace_system(prob)
    r = system.N.shape[1]
    ptr, idx, vals = system.upper_blocks()
    blocks = vals.reshape(-1, r, r).transpose(0, 2, 1)
    upper = sp.bsr_matrix((blocks, idx, ptr), shape=(system.unknowns,) * 2).toarray()
    A = system.matrix().toarray()
    rows = np.repeat(np.arange(len(ptr) - 1), np.diff(ptr))
    assert (idx >= rows).all() and ptr.dtype == np.int32 and idx.dtype == np.int32
    np.testing.assert_array_equal(upper, np.where(np.kron(np.triu(np.ones((len(ptr) - 1,) * 2)),
                                                          np.ones((r, r))) > 0, A, 0.0))
    x = pardiso_block_solve(ptr, idx, vals, r, system.rhs)
    ref = np.linalg.solve(A, system.rhs)
    np.testing.assert_allclose(x, ref, rtol=0, atol=1e-9 * np.abs(ref).max())


@pytest.mark.parametrize("position_weight", [0.0, 0.1])
def test_poisson_optimum_equals_a_general_purpose_solve(position_weight):
    """The direct Poisson solve (PARDISO on the upper triangle) reaches the optimum scipy's dense solver
    finds for the same null-space system: weights within 1e-6, energy gap below 1e-6."""
    import scipy.linalg

    from rigslim.plugins.solvers.nullspace import nullspace_system

    asset = tube_asset(rings=10, segments=8)
    asset.influences = k_largest(asset.weights, 3)
    prob = build_problem(asset, "poisson", nonnegative=False, position_weight=position_weight)
    alpha, rep = global_solve(prob, method="direct")
    assert rep["factorisation"] == "pardiso"
    system = nullspace_system(prob)
    z = scipy.linalg.solve(system.matrix().toarray(), system.rhs, assume_a="pos")
    ref = np.where(prob.valid, system.weights(z), 0.0)
    np.testing.assert_allclose(alpha, ref, rtol=0, atol=1e-6)
    assert (rep["energy"] - prob.energy(ref)) <= 1e-6 * abs(prob.energy(ref))
