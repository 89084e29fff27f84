import numpy as np
import scipy.sparse as sp

from rigslim.model.handles import cage_transforms
from rigslim.numerics.blend import basis_positions, blended_matrices, linear_blend
from rigslim.numerics.largest_entries import k_largest
from rigslim.plugins.solvers.renormalised import renormalised_weights


def random_rigid(rng, n):
    Q, _ = np.linalg.qr(rng.standard_normal((n, 3, 3)))
    T = np.concatenate([Q, rng.standard_normal((n, 3, 1))], axis=2)
    return T


def test_sparse_and_fixed_k_agree_when_nothing_is_dropped(rng):
    V = rng.standard_normal((50, 3))
    W = rng.random((50, 6)) * (rng.random((50, 6)) < 0.5)
    W[:, 0] += 0.1
    W /= W.sum(axis=1, keepdims=True)
    A = sp.csr_matrix(W)
    reduced = renormalised_weights(A, k_largest(A, 6))
    T = random_rigid(rng, 6)
    np.testing.assert_allclose(linear_blend(V, A, T), linear_blend(V, reduced, T), atol=1e-12)
    np.testing.assert_allclose(blended_matrices(A, T), blended_matrices(reduced, T), atol=1e-12)


def test_cage_form_is_barycentric_combination(rng):
    C = rng.standard_normal((2, 5, 3))
    W = rng.random((7, 5))
    W /= W.sum(axis=1, keepdims=True)
    T = cage_transforms(C)
    V = rng.standard_normal((7, 3))  # ignored by the cage form: only c_i^j matter
    np.testing.assert_allclose(linear_blend(V, sp.csr_matrix(W), T[1]), W @ C[1], atol=1e-12)


def test_basis_positions(rng):
    V = rng.standard_normal((4, 3))
    T = rng.standard_normal((3, 5, 3, 4))
    idx = np.array([[0, 4], [1, 1], [2, 3], [4, 0]])
    B = basis_positions(V, T, idx)
    assert B.shape == (3, 4, 2, 3)
    np.testing.assert_allclose(B[2, 3, 0], T[2, 4] @ np.r_[V[3], 1])
