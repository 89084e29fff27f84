"""What both collapse loops share: their constants and the mesh setup (which edges may collapse).

The numpy reference (:func:`rigslim.plugins.decimation.collapse.simplify`) and
the compiled loop (:mod:`rigslim.plugins.decimation.compiled`) start from the
same collapsible edges, the same locked vertices and seams, and the same
degenerate-area threshold, so that they make the same collapses.
"""

from __future__ import annotations

import numpy as np

__all__ = ["BEST", "BLOCKED", "BORDER", "CLEAN", "DEAD", "DECORO", "DIRTY", "EdgeSetup", "FREE", "KEEP_A", "KEEP_B",
           "MAX_EDGE_FACES", "MOHR_GLEICHER", "NONE", "QUARTIC", "SEAM", "SOURCE_SAMPLES", "border_vertices",
           "collapsible_edges", "degenerate_area", "placement", "placements", "posed_thresholds", "rest_scale",
           "seam_arrays", "zero_cost"]

#: Edge states: queued with its true cost, queued with a lower bound, removed, refused by a guard.
CLEAN, DIRTY, DEAD, BLOCKED = 0, 1, 2, 3
#: Edge cost models (``kind`` of :class:`rigslim.plugins.decimation.models.EdgeCostModel`).
QUARTIC, MOHR_GLEICHER, DECORO = 0, 1, 2
#: The curve a fixed vertex may slide along (``along``): none (a corner or a locked vertex), a UV/material
#: seam (two charts, two seam edges), a mesh border (two border edges).
SEAM, BORDER = 1, 2
#: The most faces a non-manifold edge (a fin or flap meeting a body: three) may have and still collapse.
MAX_EDGE_FACES = 8
#: Where a collapse puts the merged vertex (:func:`placement`): not at all, where the cost model says,
#: at a (half-edge collapse onto a), at b, at whichever end costs less.
NONE, FREE, KEEP_A, KEEP_B, BEST = -1, 0, 1, 2, 3
#: At most about this many of the originals that a collapse's two vertices stand for enter its source-side
#: error (:func:`rigslim.plugins.decimation.compiled.source_error`): every s-th beyond it.
SOURCE_SAMPLES = 512


def placement(fixed_a: bool, fixed_b: bool, along_a: int, along_b: int) -> int:
    """How an edge (a, b) collapses, from its ends' classes (meshoptimizer's vertex kinds, with placement).

    - two free (manifold) ends: ``FREE``, the cost model's optimal vertex;
    - one fixed end (border, seam, locked): a half-edge collapse onto it (``KEEP_A`` / ``KEEP_B``), so that
      seams, borders and locked vertices keep their positions and weights exactly;
    - two seam vertices along their seam: ``FREE`` (both sides keep their attributes);
    - two border vertices along their border: ``BEST``, the cheaper end (the border keeps its points);
    - a seam or border vertex and a corner (a fixed vertex on no single curve): onto the corner;
    - two corners, or two vertices of different curves: ``NONE``.

    The loops also require a fixed-fixed edge to lie on the curve (:func:`collapsible_edges`).
    """
    if not fixed_a and not fixed_b:
        return FREE
    if not fixed_b:
        return KEEP_A
    if not fixed_a:
        return KEEP_B
    if along_a == SEAM and along_b == SEAM:
        return FREE
    if along_a == BORDER and along_b == BORDER:
        return BEST
    if along_a != 0 and along_b == 0:
        return KEEP_B
    if along_a == 0 and along_b != 0:
        return KEEP_A
    return NONE


def placements(fixed_a: np.ndarray, fixed_b: np.ndarray, along_a: np.ndarray, along_b: np.ndarray) -> np.ndarray:
    """:func:`placement` of many edges (int64 array)."""
    out = np.full(len(fixed_a), NONE, np.int64)
    both = fixed_a & fixed_b
    out[~fixed_a & ~fixed_b] = FREE
    out[fixed_a & ~fixed_b] = KEEP_A
    out[~fixed_a & fixed_b] = KEEP_B
    out[both & (along_a == SEAM) & (along_b == SEAM)] = FREE
    out[both & (along_a == BORDER) & (along_b == BORDER)] = BEST
    out[both & (along_a != 0) & (along_b == 0)] = KEEP_B
    out[both & (along_a == 0) & (along_b != 0)] = KEEP_A
    return out


def seam_arrays(seams, m: int, n_faces: int) -> tuple[np.ndarray, np.ndarray]:
    """(2m,) int8 curve of each vertex (``SEAM`` where it may collapse along a seam, else 0) and (f,) int64
    face charts (all 0 without seams)."""
    along = np.zeros(2 * m, dtype=np.int8)
    charts = np.zeros(n_faces, dtype=np.int64)
    if seams is not None:
        a, ch = seams
        along[:m][np.asarray(a, bool)] = SEAM
        charts[:] = np.asarray(ch, np.int64)
    return along, charts


def border_vertices(uniq: np.ndarray, counts: np.ndarray, m: int) -> tuple[np.ndarray, np.ndarray]:
    """(m,) vertices on a border edge, and those on exactly two border edges and no non-manifold edge."""
    ends = uniq[counts == 1].ravel()
    n_border = np.bincount(ends, minlength=m)
    nonmanifold = np.zeros(m, bool)
    nonmanifold[uniq[counts > 2].ravel()] = True
    return n_border > 0, (n_border == 2) & ~nonmanifold


class EdgeSetup:
    """The collapsible edges of a mesh and the vertex flags the loops keep.

    Attributes
    ----------
    edges : (E, 2) int64
        Sorted unique edges ``(x < y)`` that may collapse, in increasing key order.
    boundary : (2m,) bool
        Fixed vertices: on the border (with ``keep_boundary``) or ``locked``. They never move except along
        their curve; free vertices collapse onto them.
    along : (2m,) int8, charts : (f,) int64
        The curve each fixed vertex may slide along (``SEAM``, ``BORDER`` or 0) and the face charts
        (:func:`seam_arrays`).
    """

    def __init__(self, edges: np.ndarray, boundary: np.ndarray, along: np.ndarray, charts: np.ndarray):
        self.edges, self.boundary, self.along, self.charts = edges, boundary, along, charts


def collapsible_edges(Fm: np.ndarray, m: int, *, keep_boundary: bool, locked=None, seams=None,
                      border_collapses: bool = True) -> EdgeSetup:
    """Classify vertices (free, border, seam, locked) and keep the edges a collapse may remove.

    Parameters
    ----------
    Fm : (f, 3) int64
        The faces.
    m : int
        Vertex count (the loops' tables hold 2m rows: the originals and the new vertices).
    keep_boundary, locked, seams
        As in :func:`rigslim.plugins.decimation.collapse.simplify`.
    border_collapses : bool
        With ``keep_boundary``: border vertices on one border curve (two border edges, not locked) may
        collapse along it (``BORDER``); false fixes every border vertex.

    Notes
    -----
    An edge with one face is a border edge. An edge may collapse when :func:`placement` allows it and, if
    both ends are fixed, it lies on their curve: a seam edge (two faces of different charts) for seam
    vertices, a border edge for border vertices.
    """
    N = 2 * m
    f = len(Fm)
    E_all = np.sort(np.concatenate([Fm[:, [0, 1]], Fm[:, [1, 2]], Fm[:, [2, 0]]]), axis=1)
    keys, counts = np.unique(E_all[:, 0] * N + E_all[:, 1], return_counts=True)    # = np.unique(E_all, axis=0)
    uniq = np.stack([keys // N, keys % N], axis=1)
    boundary = np.zeros(N, dtype=bool)
    along, charts = seam_arrays(seams, m, f)
    if keep_boundary:
        on_border, on_one = border_vertices(uniq, counts, m)
        boundary[:m] = on_border
        if border_collapses:
            free_border = on_one if locked is None else on_one & ~np.asarray(locked, bool)
            along[:m][free_border] = BORDER
    if locked is not None:
        boundary[:m] |= np.asarray(locked, bool)
    along[:m][~boundary[:m]] = 0
    a, b = uniq[:, 0], uniq[:, 1]
    place = placements(boundary[a], boundary[b], along[a], along[b])
    ok = place != NONE
    both = np.flatnonzero(ok & boundary[a] & boundary[b])
    if len(both):
        curve = np.maximum(along[a[both]], along[b[both]])
        on_border = counts[both] == 1
        seam = np.zeros(len(both), bool)
        two = np.flatnonzero((counts[both] == 2) & (curve == SEAM))
        if len(two):
            seam[two] = _seam_pairs(Fm, uniq[both[two]], charts)
        ok[both] = np.where(curve == BORDER, on_border, seam)
    edges = np.ascontiguousarray(uniq[ok], dtype=np.int64)
    return EdgeSetup(edges, boundary, along, charts)


def _seam_pairs(Fm: np.ndarray, pairs: np.ndarray, charts: np.ndarray) -> np.ndarray:
    """For edges with two faces, whether the two faces lie in different charts."""
    vfs: list[set[int]] = [set() for _ in range(int(Fm.max(initial=-1)) + 1)]
    for i, (x, y, z) in enumerate(Fm.tolist()):
        vfs[x].add(i)
        vfs[y].add(i)
        vfs[z].add(i)
    out = np.zeros(len(pairs), bool)
    for i, (x, y) in enumerate(pairs.tolist()):
        fs = vfs[x] & vfs[y]
        out[i] = len(fs) == 2 and charts[min(fs)] != charts[max(fs)]
    return out


def rest_scale(W, T: np.ndarray) -> float:
    """How many posed units one rest unit is: the scale of the skinning transforms.

    ``s = exp(l)``, ``l`` the median of the joints' ``l_i`` weighted by ``u_i = sum_v |w_vi|`` (how much the mesh
    uses joint i), ``l_i = median_j log |det A_i^j| / 3`` over the example poses j where ``A_i^j`` (the linear
    part of joint i's transform) is not singular; rounded to 6 significant digits, so that rigid transforms give
    exactly 1 despite their round-off. Medians, so that a part hidden by scaling its joint to nothing in some
    poses, or a joint that squashes, does not move the scale. A file whose rest positions are in other units
    than its poses (KHR_mesh_quantization's integers dequantised by the inverse bind matrices; an FBX export in
    centimetres under a 0.01 armature) has ``s != 1``; the terms of the collapse cost measured in the rest pose
    (:func:`zero_cost`, the face-side error) are scaled by it, so that a collapse costs the same whatever units
    the rest is in.
    """
    T = np.asarray(T, np.float64)
    if T.ndim != 4 or not T.shape[0] or not T.shape[1]:
        return 1.0
    det = np.abs(np.linalg.det(T[..., :3]))                              # (P, n)
    logs = np.log(np.where(det > 0, det, np.nan)) / 3.0
    ok = ~np.isnan(logs).all(axis=0)
    used = np.asarray(abs(W).sum(axis=0)).ravel()
    if used.shape != ok.shape or not (used[ok] > 0).any():
        return 1.0
    per_joint = np.nanmedian(logs[:, ok], axis=0)
    order = np.argsort(per_joint, kind="stable")
    cum = np.cumsum(used[ok][order])
    median = float(per_joint[order][np.searchsorted(cum, 0.5 * cum[-1])])
    return float(f"{np.exp(median):.6g}")


def posed_thresholds(V: np.ndarray, F: np.ndarray, W, T: np.ndarray, normalised: bool) -> tuple[float, float, float]:
    """What both loops take from the rest pose, in posed units: the :func:`zero_cost`, the
    :func:`degenerate_area` and the face-side error's factor ``s^2`` (``s`` the :func:`rest_scale`)."""
    s = rest_scale(W, T)
    return zero_cost(V, np.asarray(F, np.int64), len(T), normalised, s), degenerate_area(V, s), s * s


def zero_cost(V: np.ndarray, F: np.ndarray, n_poses: int, normalised: bool = False, scale: float = 1.0) -> float:
    """Collapse costs below this count as 0 (both backends): round-off of the quadric forms.

    ``(1e-7 s D)^2 s^2 A P``, D the rest bounding-box diagonal, A the mean rest face area, s the
    :func:`rest_scale` (the posed units of a rest unit), P the poses: the cost
    of moving a vertex by 1e-7 D off the planes of its faces in every pose, about a hundred times the
    round-off of ``[p; 1]^T Q [p; 1]`` at coordinates of size D; ``(1e-7 D)^2`` for normalised costs (a
    mean squared distance). Without it, the half-edge collapses of flat regions (exactly zero in exact
    arithmetic) would be ordered by round-off, differently in numpy and in the compiled loop.
    """
    if not len(F):
        return 0.0
    D = scale * float(np.linalg.norm(V.max(axis=0) - V.min(axis=0)))
    if normalised:
        return (1e-7 * D) ** 2
    P = V[F]
    A = 0.5 * scale ** 2 * float(np.linalg.norm(np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]), axis=1).mean())
    return (1e-7 * D) ** 2 * A * n_poses


def degenerate_area(V: np.ndarray, scale: float = 1.0) -> float:
    """Squared-length threshold below which a face normal counts as degenerate: 1e-14 of the squared diagonal
    (in posed units: ``scale`` is the :func:`rest_scale`)."""
    return 1e-14 * (scale * float(np.linalg.norm(V.max(axis=0) - V.min(axis=0)))) ** 2
