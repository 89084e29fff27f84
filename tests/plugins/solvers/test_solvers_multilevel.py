"""Multilevel-preconditioned CG on block-sparse SPD systems (rigslim.plugins.solvers.multilevel)."""

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from rigslim.plugins.solvers.coloring import color_classes, color_graph
from rigslim.plugins.solvers.multilevel import ColoredBlockSmoother, MultilevelSystem


def _grid_bilaplacian(n=40, r=2, seed=0):
    """Block system ``kron(L^2 + 1e-3 I, S)`` on an n x n grid (S random SPD r x r), as block CSR."""
    rng = np.random.default_rng(seed)
    one = sp.diags([-1.0, 2.0, -1.0], [-1, 0, 1], shape=(n, n))
    L = (sp.kron(one, sp.identity(n)) + sp.kron(sp.identity(n), one)).tocsr()
    K = (L @ L + 1e-3 * sp.identity(n * n)).tocsr()
    K.sort_indices()
    G = rng.normal(size=(r, r))
    S = G @ G.T + r * np.eye(r)
    blocks = K.data[:, None, None] * S[None]
    classes = color_classes(color_graph(K))
    A = sp.kron(K, S).tocsr()
    return K.indptr, K.indices, blocks, classes, A


def test_smoother_is_block_gauss_seidel():
    indptr, indices, blocks, classes, A = _grid_bilaplacian(n=12)
    sm = ColoredBlockSmoother(indptr, indices, blocks, classes)
    b = np.random.default_rng(1).normal(size=A.shape[0])
    x = np.zeros_like(b)
    sm.sweep(x, b)
    # Reference: vertex by vertex in colour order, exact r x r block solves.
    r = blocks.shape[1]
    ref = np.zeros_like(b)
    Ad = A.toarray()
    for S in classes:
        new = ref.copy()
        for v in S:
            sl = slice(v * r, (v + 1) * r)
            new[sl] = ref[sl] + np.linalg.solve(Ad[sl, sl], b[sl] - Ad[sl] @ ref)
        ref = new
    np.testing.assert_allclose(x, ref, rtol=1e-12, atol=1e-12)


def test_vcycle_is_symmetric_positive_definite():
    indptr, indices, blocks, classes, A = _grid_bilaplacian(n=30)
    ml = MultilevelSystem(indptr, indices, blocks, classes, max_coarse=100)
    assert len(ml.levels) >= 2
    rng = np.random.default_rng(2)
    u, v = rng.normal(size=(2, A.shape[0]))
    uv, vu = u @ ml.vcycle(v), v @ ml.vcycle(u)
    assert abs(uv - vu) <= 1e-9 * abs(uv)
    assert u @ ml.vcycle(u) > 0


def test_pcg_matches_direct_solve_in_few_iterations():
    indptr, indices, blocks, classes, A = _grid_bilaplacian(n=40)
    ml = MultilevelSystem(indptr, indices, blocks, classes, max_coarse=200)
    b = np.random.default_rng(3).normal(size=A.shape[0])
    x, info = ml.solve(b, tol=1e-10, maxiter=300)
    ref = spla.spsolve(A.tocsc(), b)
    assert info["converged"] and info["residual"] <= 1e-10
    np.testing.assert_allclose(x, ref, rtol=1e-7, atol=1e-7 * np.abs(ref).max())
    # Plain CG for comparison: the multilevel preconditioner must cut iterations by a large factor.
    count = [0]
    spla.cg(A, b, rtol=1e-10, maxiter=20000, callback=lambda _: count.__setitem__(0, count[0] + 1))
    assert info["iterations"] * 5 < count[0]
