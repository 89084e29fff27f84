"""Levels of detail of a UsdSkel character: each level's meshes with their primvars, subsets and blend shapes.

A level taken from a :class:`rigslim.model.hierarchy.ProgressiveHierarchy` of the
merged mesh (:func:`rigslim.io.usd.read.read_usd_skin`) keeps the source
triangles whose three corners stand for three distinct level vertices
(:func:`rigslim.io.gltf.lod.level_representatives`); each stays in its mesh,
so every level face has a *source triangle* ``s`` and its corner ``c`` is the
source corner ``c`` moved to the level vertex ``u``. Everything a USD mesh
carries per point, per face corner or per face is carried by barycentric
coordinates in the source triangle:

- ``beta_{c} = e_c`` when ``u`` is the source corner's own point (the level kept it),
  else the closest point of triangle ``s`` to ``u``'s rest position
  (:func:`rigslim.io.gltf.lod.closest_point_barycentric`);
- a ``faceVarying`` primvar (UVs) at the level corner is ``sum_j beta_{cj} x(s, j)``, with ``x(s, j)``
  the value at the source triangle's corner j: each face keeps its own UV chart, so seams stay seams;
- a ``vertex``/``varying`` primvar (and normals, blend-shape offsets) at level vertex ``u`` is the mean
  of ``sum_j beta_{cj} x(point(s, j))`` over the corners at ``u`` (exactly its value where the level
  kept the point);
- a ``uniform`` primvar and ``GeomSubset`` membership (materials) follow the source polygon;
- ``constant`` primvars, material bindings, the skeleton binding and every other property are copied.

Normals are renormalised. Integer primvars take the value of the corner with
the largest ``beta``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from rigslim.errors import StepError

if TYPE_CHECKING:
    from rigslim.io.usd.read import MeshPart


@dataclass(eq=False)
class LevelPart:
    """One mesh of one level.

    Attributes
    ----------
    part : MeshPart
        The source mesh.
    V : (v, 3) array
        Rest positions in the skeleton's space (the writer applies ``geomBindTransform^{-1}``).
    faces : (t, 3) int64 array
        Triangles in the level mesh's own numbering.
    source : (t,) int64 array
        The source triangle (index into the part's triangles) of each level face.
    bary : (t, 3, 3) array
        ``bary[f, c]``: the level corner c in barycentric coordinates of its source triangle.
    rows : (v,) int64 array
        Rows of the level (``level.mesh`` / ``level.weights``) holding the vertices.
    """

    part: MeshPart
    V: np.ndarray
    faces: np.ndarray
    source: np.ndarray
    bary: np.ndarray
    rows: np.ndarray

    def point_values(self, X: np.ndarray, points: np.ndarray) -> np.ndarray:
        """(v, C) per-vertex values from per-point source values ``X`` (points: (T, 3) source triangles' points)."""
        C = np.einsum("tcj,tjk->tck", self.bary, X[points[self.source]])
        return self._vertex_mean(C)

    def corner_values(self, X: np.ndarray) -> np.ndarray:
        """(t, 3, C) per-corner values from per-corner (faceVertexIndices position) source values ``X``."""
        return np.einsum("tcj,tjk->tck", self.bary, X[self.part.corners[self.source]])

    def face_values(self, X: np.ndarray) -> np.ndarray:
        """(t, C) per-face values from per-polygon source values ``X``."""
        return X[self.part.polygon[self.source]]

    def nearest_corner(self) -> np.ndarray:
        """(t, 3) which source corner (0..2) weighs most at each level corner (for integer data)."""
        return np.argmax(self.bary, axis=2)

    def _vertex_mean(self, C: np.ndarray) -> np.ndarray:
        v = len(self.V)
        S = np.zeros((v,) + C.shape[2:])
        np.add.at(S, self.faces.ravel(), C.reshape((-1,) + C.shape[2:]))
        n = np.bincount(self.faces.ravel(), minlength=v).astype(float)
        return S / np.maximum(n, 1.0).reshape((-1,) + (1,) * (S.ndim - 1))


def level_parts(skin, hier, level) -> list[LevelPart]:
    """One :class:`LevelPart` per source mesh for a level taken from ``hier`` (module docstring).

    A mesh every face of which collapsed away gets a part with no faces.
    """
    from rigslim.io.gltf.lod import closest_point_barycentric, level_representatives

    if level.vertex_ids is None:
        raise StepError(f"level '{level.label}' was not taken from a progressive hierarchy", field="levels",
                        fix="use a hierarchy decimator (quartic, mohr-gleicher, decoro-rusinkiewicz) for USD LODs")
    if hier is None or hier.n_original != skin.mesh.n_vertices:
        raise StepError(f"level '{level.label}' does not come from this file's mesh", field="levels",
                        fix="write levels of the hierarchy the decimate step built on the USD input")
    m = hier.n_original
    ids = np.asarray(level.vertex_ids, np.int64)
    rep = level_representatives(hier, ids)
    pos = np.searchsorted(ids, np.maximum(rep, 0))
    rows_of = np.where(rep >= 0, pos, -1)
    Fsrc = np.asarray(skin.mesh.F, np.int64)
    R = rows_of[Fsrc]
    keep = (R >= 0).all(axis=1) & (R[:, 0] != R[:, 1]) & (R[:, 1] != R[:, 2]) & (R[:, 2] != R[:, 0])
    level_keys = set(map(tuple, np.sort(np.asarray(level.mesh.F), axis=1).tolist()))
    if keep.any():
        inlevel = np.array([tuple(r) in level_keys for r in np.sort(R[keep], axis=1).tolist()], bool)
        keep[np.flatnonzero(keep)[~inlevel]] = False
    Vs = hier.V[:m]
    LV = np.asarray(level.mesh.V, np.float64)
    out = []
    for part in skin.parts:
        tri = np.arange(part.face_start, part.face_start + part.n_triangles)
        tri = tri[keep[tri]]
        Rt = R[tri]
        rows, faces = np.unique(Rt.ravel(), return_inverse=True)
        faces = faces.reshape(-1, 3).astype(np.int64)
        bary = np.zeros((len(tri), 3, 3))
        src = Fsrc[tri]
        for c in range(3):
            kept = ids[Rt[:, c]] == src[:, c]
            bary[kept, c, c] = 1.0
            moved = ~kept
            if moved.any():
                bary[moved, c] = closest_point_barycentric(LV[Rt[moved, c]], Vs[src[moved, 0]], Vs[src[moved, 1]],
                                                           Vs[src[moved, 2]])
        out.append(LevelPart(part, LV[rows], faces, tri - part.face_start, bary, rows))
    return out
