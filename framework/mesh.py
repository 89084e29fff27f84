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
    def cotmatrix(self) -> sp.csr_matrix:
        """Cotangent Laplacian ``L`` (``igl.cotmatrix``; negative semi-definite)."""
        import igl

        return sp.csr_matrix(igl.cotmatrix(self.V, self.F))

    @cached_property
    def massmatrix(self) -> sp.csr_matrix:
        """Voronoi mass matrix ``M`` (``igl.massmatrix``, diagonal)."""
        import igl

        return sp.csr_matrix(igl.massmatrix(self.V, self.F, igl.MASSMATRIX_TYPE_VORONOI))
