import numpy as np
import pytest
import scipy.sparse as sp

from rigslim.errors import InputError
from rigslim.model.weights import InfluenceSets, ReducedWeights, influence_counts, validate_weights


def test_roundoff_becomes_zero():
    W = np.array([[1.0 + 5e-10, -5e-10], [0.5, 0.5]])
    A = validate_weights(W, 2)
    assert A.nnz == 3 and (A.data > 0).all()


@pytest.mark.parametrize("W,match", [
    (np.ones((3, 1)), "3 rows but the mesh has 2"),
    (np.array([[np.nan], [1.0]]), "NaN"),
    (np.array([[0.5, 0.4], [0.5, 0.5]]), "do not sum to 1"),
])
def test_rejects(W, match):
    with pytest.raises(InputError, match=match) as e:
        validate_weights(W, 2, source="w.dmat")
    assert "w.dmat" in str(e.value) and "fix:" in str(e.value)


def test_transposed_hint():
    with pytest.raises(InputError, match="transposed"):
        validate_weights(np.ones((1, 4)), 4)


def test_normalize():
    A = validate_weights(np.array([[1.0, 3.0], [2.0, 2.0]]), 2, normalize=True)
    np.testing.assert_allclose(A.toarray(), [[0.25, 0.75], [0.5, 0.5]])
    with pytest.raises(InputError, match="no weight"):
        validate_weights(np.array([[0.0, 0.0], [1.0, 0.0]]), 2, normalize=True)


def test_column_count():
    with pytest.raises(InputError, match="columns"):
        validate_weights(np.eye(2), 2, n_handles=3)


def test_reduced_to_sparse_drops_padding():
    r = ReducedWeights(np.array([[2, 0], [1, 0]]), np.array([[1.0, 0.0], [0.25, 0.75]]), n_handles=3)
    np.testing.assert_allclose(r.to_sparse().toarray(), [[0, 0, 1], [0.75, 0.25, 0]])
    assert list(r.influence_counts()) == [1, 2]
    assert list(influence_counts(sp.csr_matrix(r.to_sparse()))) == [1, 2]


def test_from_influences_pads_with_zero():
    inf = InfluenceSets(np.array([[3, 5]], dtype=np.int32), np.array([[True, False]]))
    r = ReducedWeights.from_influences(inf, np.array([[1.0, 0.3]]), 6)
    assert r.indices.tolist() == [[3, 0]] and r.values.tolist() == [[1.0, 0.0]]
