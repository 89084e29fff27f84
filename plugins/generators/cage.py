"""Cages for meshes that have none, and cage poses driven by a skeleton.

- :func:`build_cage`: an enclosing coarse triangle cage (offset surface,
  decimated, then inflated until every mesh vertex is inside).
- :func:`enclosure`: winding numbers and clearances that certify it.
- :func:`transfer_weights`: a mesh's skin weights at other points (the cage
  vertices), by barycentric interpolation at the closest surface point.
- :func:`skinned_cage_poses`: the cage deformed by linear blend skinning in
  every pose of a skeleton animation, as cage :class:`rigslim.model.poses.Poses`
  (``T_i^j = [0 | c_i^j]``, :func:`rigslim.model.handles.cage_transforms`).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from rigslim.errors import StepError
from rigslim.model.handles import cage_transforms
from rigslim.model.mesh import Mesh
from rigslim.model.poses import Poses
from rigslim.numerics.blend import linear_blend


@dataclass(frozen=True)
class Enclosure:
    """How well a cage encloses a mesh.

    Attributes
    ----------
    winding : (m,) array
        Generalised winding number of the cage at each mesh vertex (1 inside).
    clearance : (m,) array
        Distance from each mesh vertex to the cage surface.
    outside : (m,) bool array
        Vertices with winding number below 0.5 or clearance below the minimum.
    """

    winding: np.ndarray
    clearance: np.ndarray
    outside: np.ndarray

    @property
    def ok(self) -> bool:
        return not self.outside.any()


def enclosure(cage: Mesh, points: np.ndarray, min_clearance: float = 0.0) -> Enclosure:
    """Winding numbers and clearances of points with respect to a closed cage.

    Notes
    -----
    The generalised winding number ``w(x) = (1 / 4 pi) sum_f Omega_f(x)``
    (signed solid angles of the faces, ``igl.winding_number``) is 1 inside a
    closed, outward-oriented cage and 0 outside; a point counts as inside
    when ``w > 0.5`` and its distance to the cage is at least
    ``min_clearance``.
    """
    import igl

    P = np.ascontiguousarray(points, dtype=np.float64)
    w = igl.winding_number(cage.V, cage.F, P)
    d2, _, _ = igl.point_mesh_squared_distance(P, cage.V, cage.F)
    clearance = np.sqrt(d2)
    return Enclosure(w, clearance, (w < 0.5) | (clearance < min_clearance))


def _largest_component(V, F):
    n = len(V)
    E = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    A = sp.coo_matrix((np.ones(len(E)), (E[:, 0], E[:, 1])), shape=(n, n))
    _, labels = connected_components(A, directed=False)
    face_label = labels[F[:, 0]]
    keep = face_label == np.bincount(face_label).argmax()
    F = F[keep]
    used = np.unique(F)
    remap = np.full(n, -1)
    remap[used] = np.arange(len(used))
    return V[used], remap[F]


def _euler_characteristic(V, F) -> int:
    E = np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1)
    return len(V) - len(np.unique(E, axis=0)) + len(F)


def build_cage(mesh: Mesh, n_vertices: int = 100, *, offset: float = 0.03, resolution: int = 64,
               clearance: float = 0.002, max_iterations: int = 40, progress=None) -> Mesh:
    """An enclosing coarse cage of a closed mesh.

    Parameters
    ----------
    mesh : Mesh
        A closed (watertight) triangle mesh.
    n_vertices : int
        Target number of cage vertices (the result is within a few of it).
    offset : float
        Outward offset of the cage surface, as a fraction of the mesh's
        bounding-box diagonal.
    resolution : int
        Grid cells along the longest side for the offset surface.
    clearance : float
        Minimum distance of every mesh vertex to the cage, as a fraction of
        the bounding-box diagonal.
    max_iterations : int
        Inflation rounds before giving up.

    Returns
    -------
    Mesh
        A closed, outward-oriented triangle cage with every mesh vertex
        inside (winding number > 0.5), and at least ``clearance`` away where
        the inflation achieves it (otherwise the state with the fewest
        vertices closer than that: check with :func:`enclosure`).

    Notes
    -----
    1. Offset surface: the level set ``s(x) = offset * diag`` of the signed
       distance ``s`` to the mesh (``igl.signed_distance`` on a grid,
       ``igl.marching_cubes``), largest component.
    2. Decimation to ``F = 2 (n_vertices - chi)`` faces (Euler:
       ``V - E + F = chi``) by quadric error edge collapses (``igl.qslim``).
    3. Inflation: while some mesh vertex ``v`` is outside (winding number
       ``w(v) <= 0.5``) or closer than the clearance, the three vertices of
       the cage face nearest to ``v`` move along their vertex normals by
       ``|v - c(v)| + clearance`` (``c(v)`` the closest cage point).

    Raises
    ------
    StepError
        If the mesh is degenerate or the cage still leaves vertices outside
        after ``max_iterations`` rounds.
    """
    import igl

    V, F = mesh.V, mesh.F
    diag = mesh.bbox_diagonal
    if diag <= 0 or n_vertices < 4:
        raise StepError(f"cannot build a cage of {n_vertices} vertices for this mesh", field="cage_vertices",
                        fix="give a non-degenerate mesh and at least 4 cage vertices")
    SV, SF = _offset_surface(V, F, offset * diag, resolution)
    CV, CF = _decimated_cage(SV, SF, n_vertices)
    # orient outward: the winding number at a mesh vertex must be positive
    if igl.winding_number(CV, CF, V[:1]).item() < 0:
        CF = CF[:, ::-1].copy()
    best = _inflated_cage(CV, CF, V, clearance * diag, max_iterations, progress)
    # every vertex is inside; where the clearance could not be met everywhere, keep the closest state
    return Mesh(best, CF, source=f"cage of {mesh.source or 'mesh'}")


def _offset_surface(V: np.ndarray, F: np.ndarray, off: float, resolution: int) -> tuple[np.ndarray, np.ndarray]:
    """Step 1 of :func:`build_cage`: the largest component of the level set ``s(x) = off`` of the signed
    distance to the mesh, by marching cubes on a grid of ``resolution`` cells along the longest side."""
    import igl

    h = (V.max(0) - V.min(0)).max() / resolution
    lo = V.min(0) - off - 3 * h
    hi = V.max(0) + off + 3 * h
    counts = np.ceil((hi - lo) / h).astype(int) + 1
    axes = [lo[i] + h * np.arange(counts[i]) for i in range(3)]
    Z, Y, X = np.meshgrid(axes[2], axes[1], axes[0], indexing="ij")
    GV = np.column_stack([X.ravel(), Y.ravel(), Z.ravel()])          # x fastest
    S = igl.signed_distance(GV, V, F, igl.SIGNED_DISTANCE_TYPE_FAST_WINDING_NUMBER)[0]
    SV, SF = igl.marching_cubes(S - off, GV, int(counts[0]), int(counts[1]), int(counts[2]))[:2]
    if len(SF) == 0:
        raise StepError("the offset surface is empty", field="cage", fix="check that the mesh is closed")
    return _largest_component(SV, SF)


def _decimated_cage(SV: np.ndarray, SF: np.ndarray, n_vertices: int) -> tuple[np.ndarray, np.ndarray]:
    """Step 2 of :func:`build_cage`: the offset surface decimated to ``2 (n_vertices - chi)`` faces
    (``igl.qslim``), as float64 vertices and int64 faces."""
    import igl

    chi = _euler_characteristic(SV, SF)
    target_faces = max(4, 2 * (n_vertices - chi))
    if len(SF) > target_faces:
        out = igl.qslim(np.asfortranarray(SV), np.asfortranarray(SF.astype(np.int32)), target_faces)
        CV, CF = out[-4], out[-3]
        CV, CF = igl.remove_unreferenced(np.asarray(CV, dtype=np.float64), np.asarray(CF, dtype=np.int64))[:2]
    else:
        CV, CF = SV, SF
    CV = np.array(CV, dtype=np.float64)
    CF = np.ascontiguousarray(CF, dtype=np.int64)
    return CV, CF


def _inflated_cage(CV: np.ndarray, CF: np.ndarray, V: np.ndarray, min_clear: float, max_iterations: int,
                   progress) -> np.ndarray:
    """Step 3 of :func:`build_cage`: cage vertices pushed out along their normals until every mesh vertex
    is inside and ``min_clear`` away (else the inside state with the fewest too close)."""
    import igl

    rounds: Iterable[int] = range(max_iterations)
    if progress is not None:
        rounds = progress(rounds, total=max_iterations, description="inflating cage")
    best, best_bad = None, None
    for _ in rounds:
        enc = enclosure(Mesh(CV, CF), V, min_clear)
        inside = bool((enc.winding >= 0.5).all())
        if inside and (best_bad is None or enc.outside.sum() < best_bad):
            best, best_bad = CV.copy(), int(enc.outside.sum())
        if enc.ok:
            break
        out_idx = np.flatnonzero(enc.outside)
        _, faces, _ = igl.point_mesh_squared_distance(V[out_idx], CV, CF)
        N = igl.per_vertex_normals(CV, CF, igl.PER_VERTEX_NORMALS_WEIGHTING_TYPE_ANGLE)
        need = np.where(enc.winding[out_idx] < 0.5, enc.clearance[out_idx], 0.0) + min_clear
        push = np.zeros(len(CV))
        np.maximum.at(push, CF[faces].ravel(), np.repeat(need, 3))
        CV = CV + push[:, None] * N
    if best is None:
        raise StepError(f"the cage leaves {int((enc.winding < 0.5).sum())} mesh vertices outside after "
                        f"{max_iterations} inflation rounds", field="cage",
                        fix="raise cage_offset or cage_vertices, or give a cage file")
    return best


def transfer_weights(mesh: Mesh, W, points: np.ndarray) -> sp.csr_matrix:
    """Skin weights of a mesh, carried to other points.

    Parameters
    ----------
    mesh : Mesh
    W : (m, n) sparse matrix or array
        The mesh's weights, rows summing to one.
    points : (q, 3) array

    Returns
    -------
    (q, n) scipy.sparse.csr_matrix
        ``W_q = sum_c beta_c W_{f_c}``: the weights interpolated with the
        barycentric coordinates ``beta`` of the closest point on the closest
        face ``f`` (rows still sum to one).
    """
    import igl

    P = np.ascontiguousarray(points, dtype=np.float64)
    _, faces, C = igl.point_mesh_squared_distance(P, mesh.V, mesh.F)
    tri = mesh.F[faces]
    bary = igl.barycentric_coordinates(C, mesh.V[tri[:, 0]], mesh.V[tri[:, 1]], mesh.V[tri[:, 2]])
    bary = np.clip(bary, 0.0, None)
    bary /= bary.sum(axis=1, keepdims=True)
    q = len(P)
    B = sp.csr_matrix((bary.ravel(), (np.repeat(np.arange(q), 3), tri.ravel())), shape=(q, mesh.n_vertices))
    return sp.csr_matrix(B @ sp.csr_matrix(W))


def skinned_cage_poses(cage: Mesh, cage_weights, poses: Poses) -> Poses:
    """Cage poses that follow a skeleton animation.

    Parameters
    ----------
    cage : Mesh
        Rest cage.
    cage_weights : (n_cage, n_bones) sparse matrix
        Skin weights of the cage vertices (e.g. :func:`transfer_weights`).
    poses : Poses
        Bone transforms, (p, n_bones, 3, 4).

    Returns
    -------
    Poses
        (p, n_cage, 3, 4) with ``T_i^j = [0 | c_i^j]`` and
        ``c_i^j = sum_b a_{i,b} T_b^j [c_i; 1]`` (linear blend skinning of
        the cage), same frame numbers.
    """
    C = np.stack([linear_blend(cage.V, cage_weights, T) for T in poses.T])
    return Poses(cage_transforms(C), poses.frames, source=f"{poses.source or 'poses'} (skinned cage)")
