"""Area-weighted vertex normals through the precomputed face->vertex operator, against libigl."""

from __future__ import annotations

import igl
import numpy as np
import pytest

from rigslim.errors import InputError
from rigslim.numerics.area_weighted_normals import VertexNormalOperator, area_weighted_normals, operator_for
from rigslim.numerics.blend import linear_blend, per_vertex_normals


def igl_normals(V, F):
    return igl.per_vertex_normals(V, F, igl.PER_VERTEX_NORMALS_WEIGHTING_TYPE_AREA)


def test_matches_libigl_on_posed_elephant(elephant):
    mesh = elephant.mesh
    for frame in (0, 40, 229):
        P = linear_blend(mesh.V, elephant.weights, elephant.poses.T[frame])
        np.testing.assert_allclose(area_weighted_normals(P, mesh.F), igl_normals(P, mesh.F), atol=1e-12)
    assert per_vertex_normals(mesh.V, mesh.F) is not None


def test_incidence_lists_every_face_of_every_vertex(elephant):
    mesh = elephant.mesh
    op = VertexNormalOperator(mesh.F, mesh.n_vertices)
    assert op.indptr[-1] == 3 * mesh.n_faces
    for v in (0, 17, mesh.n_vertices - 1):
        expected = np.flatnonzero((mesh.F == v).any(axis=1))
        np.testing.assert_array_equal(np.sort(op.faces[op.indptr[v]:op.indptr[v + 1]]), expected)


def test_operator_is_cached_per_face_array_and_writes_into_out(elephant):
    mesh = elephant.mesh
    assert operator_for(mesh.F, mesh.n_vertices) is operator_for(mesh.F, mesh.n_vertices)
    op = operator_for(mesh.F, mesh.n_vertices)
    out = np.empty((mesh.n_vertices, 3))
    assert op(mesh.V, out=out) is out
    np.testing.assert_allclose(out, igl_normals(mesh.V, mesh.F), atol=1e-12)


def test_isolated_vertex_and_degenerate_face_give_zero_or_neighbour_normals():
    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [5, 5, 5], [2, 0, 0]], dtype=float)
    F = np.array([[0, 1, 2], [0, 1, 4]])          # the second face is degenerate (collinear)
    N = area_weighted_normals(V, F)
    np.testing.assert_allclose(N[:3], [[0, 0, 1]] * 3)
    np.testing.assert_array_equal(N[3], 0.0)       # in no face
    np.testing.assert_array_equal(N[4], 0.0)       # only in a zero-area face


def test_bad_faces_and_positions_are_input_errors():
    with pytest.raises(InputError, match="face indices"):
        VertexNormalOperator(np.array([[0, 1, 3]]), 3)
    op = VertexNormalOperator(np.array([[0, 1, 2]]), 3)
    with pytest.raises(InputError, match="positions have shape"):
        op(np.zeros((4, 3)))
