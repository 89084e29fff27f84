"""Area-weighted vertex normals through a precomputed face->vertex operator (compiled, all cores).

The recomputed normal of vertex v is

.. math:: n_v = \\operatorname{normalize}\\Big(\\sum_{f \\ni v} (x_{f,1} - x_{f,0}) \\times (x_{f,2} - x_{f,0})\\Big),

the sum of its faces' unit normals weighted by twice their areas (libigl's
``per_vertex_normals`` with ``AREA`` weighting, to rounding). The operator
(:class:`VertexNormalOperator`) is the vertex->face incidence of ``F`` in
CSR form, built once per face array by a counting sort; applying it is two
``prange`` passes: face normals into a buffer the operator owns, then one
gather and normalisation per vertex (no scatter, no atomics, no per-call
allocation with ``out=``). Vertices in no face get zero normals.
"""

from __future__ import annotations

import weakref

import numpy as np
from numba import njit, prange

from rigslim.errors import InputError


@njit(cache=True)
def _incidence(F, m):  # pragma: no cover - numba
    """Vertex-major CSR of the faces around each vertex (counting sort; faces in increasing order)."""
    f = F.shape[0]
    indptr = np.zeros(m + 1, dtype=np.int64)
    for i in range(f):
        for c in range(3):
            indptr[F[i, c] + 1] += 1
    for v in range(m):
        indptr[v + 1] += indptr[v]
    fill = indptr[:-1].copy()
    faces = np.empty(3 * f, dtype=np.int32)
    for i in range(f):
        for c in range(3):
            v = F[i, c]
            faces[fill[v]] = i
            fill[v] += 1
    return indptr, faces


@njit(parallel=True, cache=True)
def _face_normals(V, F, FN):  # pragma: no cover - numba
    for i in prange(F.shape[0]):
        a, b, c = F[i, 0], F[i, 1], F[i, 2]
        ux = V[b, 0] - V[a, 0]
        uy = V[b, 1] - V[a, 1]
        uz = V[b, 2] - V[a, 2]
        wx = V[c, 0] - V[a, 0]
        wy = V[c, 1] - V[a, 1]
        wz = V[c, 2] - V[a, 2]
        FN[i, 0] = uy * wz - uz * wy
        FN[i, 1] = uz * wx - ux * wz
        FN[i, 2] = ux * wy - uy * wx


@njit(parallel=True, cache=True)
def _gather_normalize(indptr, faces, FN, out):  # pragma: no cover - numba
    for v in prange(out.shape[0]):
        x = y = z = 0.0
        for j in range(indptr[v], indptr[v + 1]):
            f = faces[j]
            x += FN[f, 0]
            y += FN[f, 1]
            z += FN[f, 2]
        ln = np.sqrt(x * x + y * y + z * z)
        s = 1.0 / ln if ln > 0 else 0.0
        out[v, 0] = x * s
        out[v, 1] = y * s
        out[v, 2] = z * s


class VertexNormalOperator:
    """The face->vertex operator of one triangle array: ``op(V)`` gives area-weighted unit vertex normals.

    Parameters
    ----------
    F : (f, 3) int array
    n_vertices : int
        Rows of the positions it will be applied to (at least ``F.max() + 1``).

    Attributes
    ----------
    indptr : (m + 1,) int64, faces : (3f,) int32
        The faces around vertex v are ``faces[indptr[v]:indptr[v + 1]]``.
    """

    def __init__(self, F: np.ndarray, n_vertices: int):
        F = np.ascontiguousarray(F, dtype=np.int64)
        if F.ndim != 2 or F.shape[1] != 3:
            raise InputError(f"face array has shape {F.shape}, expected (f, 3)", source="vertex normals",
                             field="faces", fix="triangulate the mesh")
        if F.size and (F.min() < 0 or F.max() >= n_vertices):
            raise InputError(f"face indices outside 0..{n_vertices - 1}", source="vertex normals", field="faces",
                             fix="pass the positions of the mesh these faces belong to")
        self.F = F
        self.n_vertices = int(n_vertices)
        self.indptr, self.faces = _incidence(F, self.n_vertices)
        self._FN = np.empty((len(F), 3))

    def __call__(self, V: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """(m, 3) float64 unit normals of positions V (written into ``out`` when given)."""
        V = np.ascontiguousarray(V, dtype=np.float64)
        if V.shape != (self.n_vertices, 3):
            raise InputError(f"positions have shape {V.shape}, expected ({self.n_vertices}, 3)",
                             source="vertex normals", field="V", fix="pass one pose's positions of this mesh")
        if out is None:
            out = np.empty((self.n_vertices, 3))
        _face_normals(V, self.F, self._FN)
        _gather_normalize(self.indptr, self.faces, self._FN, out)
        return out


_operators: dict[int, tuple] = {}
#: Operators kept for face arrays that are still alive (oldest dropped first).
CACHE_SIZE = 8


def operator_for(F: np.ndarray, n_vertices: int) -> VertexNormalOperator:
    """The operator of this face array, cached while the array lives (a Mesh's read-only ``F``)."""
    key = id(F)
    entry = _operators.get(key)
    if entry is not None and entry[0]() is F and entry[1].n_vertices == n_vertices:
        return entry[1]
    op = VertexNormalOperator(F, n_vertices)
    try:
        ref = weakref.ref(F)
    except TypeError:          # not weak-referenceable (a list): no caching
        return op
    for dead in [k for k, (r, _) in _operators.items() if r() is None]:
        del _operators[dead]
    while len(_operators) >= CACHE_SIZE:
        del _operators[next(iter(_operators))]
    _operators[key] = (ref, op)
    return op


def area_weighted_normals(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Area-weighted unit vertex normals of positions V (m, 3) on triangles F (f, 3), float64."""
    V = np.asarray(V)
    return operator_for(F, len(V))(V)
