"""Triangle meshes with cached derived quantities.

A :class:`Mesh` is immutable: its vertex and face arrays are read-only, so
derived data (edges, vertex adjacency, cotangent Laplacian, mass matrix,
bounding-box diagonal) is computed once and cached.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np
import scipy.sparse as sp

from rigslim.errors import InputError

#: Largest absolute coordinate accepted: squared lengths and areas of larger meshes overflow float64.
MAX_COORDINATE = 1e150
#: A face whose area is below this fraction of the squared bounding-box diagonal is degenerate.
DEGENERATE_AREA = 1e-14


@dataclass(frozen=True, eq=False)
class Mesh:
    """A triangle mesh.

    Parameters
    ----------
    V : (m, 3) float64 array
        Rest vertex positions.
    F : (f, 3) int64 array
        Triangles, indices into ``V`` (int64 because libigl's bindings take it).
    source : str, optional
        Where the mesh came from (for messages).

    Example
    -------
    >>> import numpy as np
    >>> tet = Mesh(np.eye(4, 3), np.array([[0, 1, 2], [0, 3, 1], [0, 2, 3], [1, 3, 2]]))
    >>> tet.edges.shape
    (6, 2)
    """

    V: np.ndarray
    F: np.ndarray
    source: str | None = field(default=None, compare=False)

    def __post_init__(self):
        V = np.ascontiguousarray(self.V, dtype=np.float64)
        F = np.ascontiguousarray(self.F, dtype=np.int64)
        where = self.source or "mesh"
        if V.ndim != 2 or V.shape[1] != 3:
            raise InputError(f"vertex array has shape {V.shape}, expected (m, 3)", source=where,
                             field="vertices", fix="give 3D vertex positions")
        if F.ndim != 2 or F.shape[1] != 3:
            raise InputError(f"face array has shape {F.shape}, expected (f, 3)", source=where,
                             field="faces", fix="triangulate the mesh")
        if not np.isfinite(V).all():
            raise InputError("vertex positions contain NaN or inf", source=where, field="vertices",
                             fix="repair or re-export the mesh")
        if V.size and np.abs(V).max() > MAX_COORDINATE:
            raise InputError(f"coordinates up to {np.abs(V).max():.3g} exceed {MAX_COORDINATE:g} (squared lengths "
                             "overflow)", source=where, field="vertices", fix="rescale the mesh")
        if F.size and (F.min() < 0 or F.max() >= len(V)):
            raise InputError(f"face indices outside 0..{len(V) - 1}", source=where, field="faces",
                             fix="re-export the mesh")
        V.setflags(write=False)
        F.setflags(write=False)
        object.__setattr__(self, "V", V)
        object.__setattr__(self, "F", F)

    @property
    def n_vertices(self) -> int:
        return len(self.V)

    @property
    def n_faces(self) -> int:
        return len(self.F)

    @cached_property
    def bbox_diagonal(self) -> float:
        """Length of the diagonal of the axis-aligned bounding box."""
        return float(np.linalg.norm(self.V.max(axis=0) - self.V.min(axis=0)))

    @cached_property
    def edges(self) -> np.ndarray:
        """(e, 2) unique undirected edges, ``edges[:, 0] < edges[:, 1]``."""
        E = np.concatenate([self.F[:, [0, 1]], self.F[:, [1, 2]], self.F[:, [2, 0]]])
        E.sort(axis=1)
        E = np.unique(E, axis=0)
        E.setflags(write=False)
        return E

    @cached_property
    def adjacency(self) -> sp.csr_matrix:
        """(m, m) symmetric 0/1 vertex adjacency matrix (one ring)."""
        E = self.edges
        m = self.n_vertices
        A = sp.coo_matrix((np.ones(2 * len(E)), (np.r_[E[:, 0], E[:, 1]], np.r_[E[:, 1], E[:, 0]])),
                          shape=(m, m)).tocsr()
        A.data[:] = 1.0
        return A

    @cached_property
    def face_areas(self) -> np.ndarray:
        """(f,) triangle areas ``|(b - a) x (c - a)| / 2``."""
        a, b, c = (self.V[self.F[:, i]] for i in range(3))
        return 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)

    @cached_property
    def laplacian_faces(self) -> np.ndarray:
        """Faces the Laplacian is built from: those with area (see :attr:`cotmatrix`).

        Raises
        ------
        InputError
            When the mesh has no faces, or no face has area (a flat-to-a-line,
            collinear or single-point mesh): no Laplacian exists, naming the faces.
        """
        if not len(self.F):
            raise InputError("the mesh has no faces; the Laplacian (smooth, poisson, bone heat...) needs triangles",
                             source=self.source or "mesh", field="faces",
                             fix="give a triangle mesh, or a method that needs no faces (geometric, k-largest)")
        areas = self.face_areas
        tol = DEGENERATE_AREA * max(self.bbox_diagonal, np.finfo(float).tiny) ** 2
        good = areas > tol
        if not good.any():
            listed = ", ".join(map(str, range(min(len(self.F), 6)))) + (" ..." if len(self.F) > 6 else "")
            raise InputError(f"all {len(self.F)} faces ({listed}) have zero area (bounding-box diagonal "
                             f"{self.bbox_diagonal:.3g}); the Laplacian needs triangles with area",
                             source=self.source or "mesh", field="faces",
                             fix="give a surface mesh whose triangles are not collinear or coincident")
        return self.F[good]

    @cached_property
    def cotmatrix(self) -> sp.csr_matrix:
        """Cotangent Laplacian ``L`` (``igl.cotmatrix``; negative semi-definite), (m, m).

        Built robustly: degenerate (zero-area) faces, whose cotangents are
        infinite, are left out (they span no area, so no Dirichlet energy),
        and vertices no face uses get zero rows and columns (libigl sizes
        its matrix by the largest index used).
        """
        import igl

        return self._pad(igl.cotmatrix(self.V, self.laplacian_faces))

    @cached_property
    def massmatrix(self) -> sp.csr_matrix:
        """Voronoi mass matrix ``M`` (``igl.massmatrix``, diagonal), (m, m), over :attr:`laplacian_faces`.

        Vertices without area (unused, or only in degenerate faces) get a
        mass of ``1e-8`` times the mean, so ``M`` stays invertible.
        """
        import igl

        M = self._pad(igl.massmatrix(self.V, self.laplacian_faces, igl.MASSMATRIX_TYPE_VORONOI))
        d = M.diagonal()
        if (d <= 0).any():
            d = np.where(d > 0, d, 1e-8 * d[d > 0].mean())
            M = sp.diags(d).tocsr()
        return M

    def _pad(self, A) -> sp.csr_matrix:
        """A libigl per-vertex matrix as (m, m), zero rows/columns for vertices past the last used."""
        A = sp.csr_matrix(A)
        m = self.n_vertices
        if A.shape != (m, m):
            A = sp.csr_matrix((A.data, A.indices, np.r_[A.indptr, np.full(m - A.shape[0], A.indptr[-1])]),
                              shape=(m, m))
        return A
