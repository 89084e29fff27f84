"""What both collapse loops share: their constants and the mesh setup (which edges may collapse).

The numpy reference (:func:`rigslim.plugins.decimation.collapse.simplify`) and
the compiled loop (:mod:`rigslim.plugins.decimation.compiled`) start from the
same collapsible edges, the same locked vertices and seams, and the same
degenerate-area threshold, so that they make the same collapses.
"""

from __future__ import annotations

import numpy as np

__all__ = ["BLOCKED", "CLEAN", "DEAD", "DECORO", "DIRTY", "MOHR_GLEICHER", "QUARTIC", "EdgeSetup", "collapsible_edges",
           "degenerate_area", "seam_arrays"]

#: Edge states: queued with its true cost, queued with a lower bound, removed, refused by a guard.
CLEAN, DIRTY, DEAD, BLOCKED = 0, 1, 2, 3
#: Edge cost models (``kind`` of :class:`rigslim.plugins.decimation.models.EdgeCostModel`).
QUARTIC, MOHR_GLEICHER, DECORO = 0, 1, 2


def seam_arrays(seams, m: int, n_faces: int) -> tuple[np.ndarray, np.ndarray]:
    """(2m,) bool "may collapse along a seam" and (f,) int64 face charts (all False / all 0 without seams)."""
    along = np.zeros(2 * m, dtype=bool)
    charts = np.zeros(n_faces, dtype=np.int64)
    if seams is not None:
        a, ch = seams
        along[:m] = np.asarray(a, bool)
        charts[:] = np.asarray(ch, np.int64)
    return along, charts


class EdgeSetup:
    """The collapsible edges of a mesh and the vertex flags the loops keep.

    Attributes
    ----------
    edges : (E, 2) int64
        Sorted unique edges ``(x < y)`` that may collapse, in increasing key order.
    boundary : (2m,) bool
        Vertices that never move: on the boundary (with ``keep_boundary``) or ``locked``.
    along : (2m,) bool, charts : (f,) int64
        Seam vertices that may collapse with each other along a seam edge, and face charts
        (:func:`seam_arrays`).
    """

    def __init__(self, edges: np.ndarray, boundary: np.ndarray, along: np.ndarray, charts: np.ndarray):
        self.edges, self.boundary, self.along, self.charts = edges, boundary, along, charts


def collapsible_edges(Fm: np.ndarray, m: int, *, keep_boundary: bool, locked=None, seams=None) -> EdgeSetup:
    """Classify vertices (boundary, locked, seam) and keep the edges a collapse may remove.

    Parameters
    ----------
    Fm : (f, 3) int64
        The faces.
    m : int
        Vertex count (the loops' tables hold 2m rows: the originals and the new vertices).
    keep_boundary, locked, seams
        As in :func:`rigslim.plugins.decimation.collapse.simplify`.

    Notes
    -----
    An edge with one face is a boundary edge. An edge may collapse when neither
    end is fixed, or when both ends are seam vertices and the edge is a seam
    edge: exactly two faces, in different charts.
    """
    N = 2 * m
    f = len(Fm)
    E_all = np.sort(np.concatenate([Fm[:, [0, 1]], Fm[:, [1, 2]], Fm[:, [2, 0]]]), axis=1)
    keys, counts = np.unique(E_all[:, 0] * N + E_all[:, 1], return_counts=True)    # = np.unique(E_all, axis=0)
    uniq = np.stack([keys // N, keys % N], axis=1)
    boundary = np.zeros(N, dtype=bool)
    if keep_boundary:
        boundary[uniq[counts == 1].ravel()] = True
    if locked is not None:
        boundary[:m] |= np.asarray(locked, bool)
    along, charts = seam_arrays(seams, m, f)
    free_edge = ~(boundary[uniq[:, 0]] | boundary[uniq[:, 1]])
    both = np.flatnonzero(~free_edge & along[uniq[:, 0]] & along[uniq[:, 1]])
    if len(both):
        vfs: list[set[int]] = [set() for _ in range(m)]
        for i, (x, y, z) in enumerate(Fm.tolist()):
            vfs[x].add(i)
            vfs[y].add(i)
            vfs[z].add(i)
        for i in both:
            fs = vfs[int(uniq[i, 0])] & vfs[int(uniq[i, 1])]
            free_edge[i] = len(fs) == 2 and charts[min(fs)] != charts[max(fs)]
    edges = np.ascontiguousarray(uniq[free_edge], dtype=np.int64)
    return EdgeSetup(edges, boundary, along, charts)


def degenerate_area(V: np.ndarray) -> float:
    """Squared-length threshold below which a face normal counts as degenerate: 1e-14 of the squared diagonal."""
    scale = float(np.linalg.norm(V.max(axis=0) - V.min(axis=0))) ** 2
    return 1e-14 * scale
