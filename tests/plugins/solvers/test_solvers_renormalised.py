import numpy as np
import scipy.sparse as sp

from rigslim.numerics.largest_entries import k_largest
from rigslim.plugins.solvers.problem import gather
from rigslim.plugins.solvers.renormalised import renormalised_weights


def test_renormalised_k_largest(elephant):
    inf = k_largest(elephant.weights, 4)
    r = renormalised_weights(elephant.weights, inf)
    assert r.k == 4 and (r.influence_counts() <= 4).all()
    np.testing.assert_allclose(r.values.sum(axis=1), 1.0, atol=1e-12)
    assert (r.values >= 0).all()
    raw = gather(elephant.weights, inf)
    np.testing.assert_allclose(r.values, raw / raw.sum(axis=1, keepdims=True))


def test_k_equal_n_returns_input(rng):
    W = rng.random((30, 5))
    W /= W.sum(axis=1, keepdims=True)
    A = sp.csr_matrix(W)
    r = renormalised_weights(A, k_largest(A, 5))
    np.testing.assert_allclose(r.to_sparse().toarray(), W, atol=1e-15)
