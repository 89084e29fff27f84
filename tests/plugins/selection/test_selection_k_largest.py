import numpy as np
import pytest
import scipy.sparse as sp

from rigslim.errors import StepError
from rigslim.numerics.largest_entries import check_k, k_largest


def test_picks_largest_sorted_with_padding():
    A = sp.csr_matrix(np.array([[0.1, 0.5, 0.0, 0.4], [0.0, 0.0, 1.0, 0.0]]))
    inf = k_largest(A, 2)
    assert inf.indices.tolist() == [[1, 3], [2, 0]]
    assert inf.valid.tolist() == [[True, True], [True, False]]


def test_matches_dense_argsort(rng):
    W = rng.random((200, 12)) * (rng.random((200, 12)) < 0.6)
    inf = k_largest(sp.csr_matrix(W), 4)
    for v in range(200):
        nz = np.flatnonzero(W[v])
        expect = nz[np.argsort(-W[v, nz], kind="stable")][:4]
        assert inf.indices[v, :len(expect)].tolist() == expect.tolist()
        assert inf.valid[v].sum() == len(expect)


def test_key_abs():
    A = sp.csr_matrix(np.array([[0.9, -0.6, 0.7]]))
    assert k_largest(A, 2, key=np.abs).indices.tolist() == [[0, 2]]
    assert k_largest(A, 2).indices.tolist() == [[0, 2]]
    assert k_largest(sp.csr_matrix([[0.2, -0.9, 1.7]]), 2, key=np.abs).indices.tolist() == [[2, 1]]


def test_k_must_reduce():
    with pytest.raises(StepError, match="not smaller"):
        check_k(4, 4)
