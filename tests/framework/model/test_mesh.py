import numpy as np
import pytest

from rigslim.errors import InputError
from rigslim.model.mesh import Mesh

TET_V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
TET_F = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])


def test_derived_quantities():
    m = Mesh(TET_V, TET_F)
    assert m.edges.shape == (6, 2)
    assert m.adjacency.sum() == 12
    assert m.bbox_diagonal == pytest.approx(np.sqrt(3))
    L, M = m.cotmatrix, m.massmatrix
    np.testing.assert_allclose(L @ np.ones(4), 0, atol=1e-12)  # constants in the kernel
    assert M.diagonal().sum() == pytest.approx(1.5 + np.sqrt(3) / 2)  # total surface area


def test_immutable_and_validated():
    m = Mesh(TET_V, TET_F)
    with pytest.raises(ValueError):
        m.V[0, 0] = 1
    with pytest.raises(InputError):
        Mesh(TET_V, TET_F + 1)
    with pytest.raises(InputError):
        Mesh(TET_V[:, :2], TET_F)
