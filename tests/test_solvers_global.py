"""Global solver: the exact equality-constrained optimum."""

import numpy as np
import pytest

from rigslim.plugins.selection.k_largest import k_largest
from rigslim.plugins.solvers.global_solver import assemble_hessian, global_solve, linear_term
from rigslim.plugins.solvers.problem import build_problem
from rigslim.plugins.solvers.synthetic import cage_asset, tube_asset


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
    e = lambda a: a.ravel() @ H @ a.ravel() + 2 * f @ a.ravel()
    assert prob.energy(a1) - prob.energy(ref) == pytest.approx(e(a1) - e(ref), rel=1e-8)


def test_cage_linear_precision_is_exact():
    asset = cage_asset()
    asset.influences = k_largest(asset.weights, 5)
    prob = build_problem(asset, "smooth", nonnegative=False, linear_precision=True)
    alpha, _ = global_solve(prob)
    rest = np.einsum("mqk,mk->mq", prob.C, alpha)
    np.testing.assert_allclose(rest, prob.d, atol=1e-9)
