"""Progressive hierarchies of articulated meshes and the simplified levels taken from them.

This module is the data contract of the ``articulated-decimation`` stage
(docs/simplification.md). A decimation step stores

- ``asset.hierarchy``: a :class:`ProgressiveHierarchy` (or ``None``
  for methods that cannot record their collapses, e.g. ``static-qslim``), and
- ``asset.levels``: a list of :class:`SimplifiedLevel`, one per
  target the step asked for, finest first.

Writers (``hierarchy``, ``levels``) and the ``metro`` metric read them.

A hierarchy is a progressive mesh in the "merge tree" form: vertices
``0..m-1`` are the original ones; collapse ``i`` merges the two vertices
``collapses[i]`` into the new vertex ``m + i``, which has its own rest
position and skin weights. Reading the collapses backwards gives the vertex
splits (Hoppe 1997). Any prefix of the collapses is a valid mesh: map each
original vertex to its newest ancestor and drop the faces that became
degenerate.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from rigslim.errors import InputError
from rigslim.model.mesh import Mesh
from rigslim.model.weights import ReducedWeights

#: Format tag stored in saved hierarchies.
FORMAT = "rigslim-progressive-hierarchy-1"


@dataclass(frozen=True, eq=False)
class SimplifiedLevel:
    """One level of detail of a skinned mesh.

    Parameters
    ----------
    mesh : Mesh
        The simplified rest mesh.
    weights : ReducedWeights
        Skin weights of its vertices (rows sum to one; at most ``max_bones``
        non-zeros per row when the step set a bone limit).
    label : str
        Name of the level in reports and file names (e.g. ``"quartic-10pct"``).
    vertex_ids : (v,) int64 array, optional
        Ids of the level's vertices in the hierarchy's vertex table
        (``None`` for levels not taken from a hierarchy).
    error : float
        Largest collapse error applied to reach this level (``nan`` if unknown).
    method : str
        The decimation plugin that made it.
    """

    mesh: Mesh
    weights: ReducedWeights
    label: str
    vertex_ids: np.ndarray | None = None
    error: float = float("nan")
    method: str = ""

    @property
    def n_faces(self) -> int:
        return self.mesh.n_faces

    @property
    def n_vertices(self) -> int:
        return self.mesh.n_vertices


@dataclass(eq=False)
class ProgressiveHierarchy:
    """Every collapse of a greedy simplification, replayable to any resolution.

    Parameters
    ----------
    V : (N, 3) float64 array
        Rest position of every vertex that ever existed: the ``m`` original
        vertices, then vertex ``m + i`` made by collapse ``i``.
    weights : ReducedWeights
        (N, k) skin weights of every vertex, same numbering.
    F : (f, 3) int64 array
        The original faces.
    collapses : (c, 2) int64 array
        ``collapses[i] = (a, b)``: the vertices collapse ``i`` merges into ``m + i``.
    errors : (c,) float64 array
        Error (cost) of each collapse when it was made.
    n_faces : (c,) int64 array
        Number of faces after collapses ``0..i``.
    method : str
        Plugin that built the hierarchy.
    params : dict
        Its parameters (for provenance).

    Notes
    -----
    With ``r_t(v)`` the newest ancestor of original vertex ``v`` after the
    first ``t`` collapses, the level-``t`` mesh has faces
    ``{(r_t(i), r_t(j), r_t(k)) : (i, j, k) in F, all three distinct}``.
    """

    V: np.ndarray
    weights: ReducedWeights
    F: np.ndarray
    collapses: np.ndarray
    errors: np.ndarray
    n_faces: np.ndarray
    method: str = ""
    params: dict = field(default_factory=dict)

    def __post_init__(self):
        self.V = np.asarray(self.V, dtype=np.float64)
        self.F = np.asarray(self.F, dtype=np.int64)
        self.collapses = np.asarray(self.collapses, dtype=np.int64).reshape(-1, 2)
        self.errors = np.asarray(self.errors, dtype=np.float64)
        self.n_faces = np.asarray(self.n_faces, dtype=np.int64)
        c = len(self.collapses)
        m = len(self.V) - c
        if self.weights.n_vertices != len(self.V):
            raise ValueError(f"{self.weights.n_vertices} weight rows for {len(self.V)} vertices")
        if len(self.errors) != c or len(self.n_faces) != c:
            raise ValueError(f"{c} collapses but {len(self.errors)} errors and {len(self.n_faces)} face counts")
        if self.F.size and self.F.max() >= m:
            raise ValueError(f"faces use vertex {self.F.max()} but there are {m} original vertices")
        if c and (self.collapses >= m + np.arange(c)[:, None]).any():
            raise ValueError("a collapse merges a vertex that does not exist yet")

    # -- sizes -------------------------------------------------------------
    @property
    def n_original(self) -> int:
        """Number of original vertices m."""
        return len(self.V) - len(self.collapses)

    @property
    def n_collapses(self) -> int:
        return len(self.collapses)

    def faces_after(self, t: int) -> int:
        """Face count after the first ``t`` collapses."""
        return len(self.F) if t == 0 else int(self.n_faces[t - 1])

    # -- extraction --------------------------------------------------------
    def _ancestors(self, applied: np.ndarray) -> np.ndarray:
        """(m,) newest ancestor of each original vertex, given a mask of applied collapses."""
        m = self.n_original
        parent = np.arange(len(self.V), dtype=np.int64)
        idx = np.flatnonzero(applied)
        parent[self.collapses[idx, 0]] = m + idx
        parent[self.collapses[idx, 1]] = m + idx
        r = parent[:m]
        while True:  # pointer jumping: parents have larger ids, so this ends
            nxt = parent[r]
            if np.array_equal(nxt, r):
                return r
            r = nxt

    def _level(self, applied: np.ndarray, label: str, selective: bool = False) -> SimplifiedLevel:
        r = self._ancestors(applied)
        F = r[self.F]
        keep = (F[:, 0] != F[:, 1]) & (F[:, 1] != F[:, 2]) & (F[:, 2] != F[:, 0])
        F = F[keep]
        if selective and not applied.all() and applied.any():
            # Selective (non-prefix) refinement may close a sheet into two opposite faces: drop both, but
            # not the faces the source itself has twice (double-sided cards), which a prefix keeps too.
            key = np.sort(F, axis=1)
            _, inv, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
            src = np.sort(self.F, axis=1)
            _, sinv, scounts = np.unique(src, axis=0, return_inverse=True, return_counts=True)
            twice = (scounts[sinv.ravel()] > 1)[keep]
            F = F[(counts[inv.ravel()] == 1) | twice]
        ids, Fc = np.unique(F, return_inverse=True)
        Fc = Fc.reshape(-1, 3)
        w = ReducedWeights(self.weights.indices[ids], self.weights.values[ids], self.weights.n_handles)
        errs = self.errors[applied]
        return SimplifiedLevel(Mesh(self.V[ids], Fc, source=f"{self.method} hierarchy"), w, label, ids,
                               float(errs.max()) if errs.size else 0.0, self.method)

    def prefix(self, t: int, label: str | None = None) -> SimplifiedLevel:
        """The mesh after the first ``t`` collapses."""
        t = int(np.clip(t, 0, self.n_collapses))
        applied = np.zeros(self.n_collapses, dtype=bool)
        applied[:t] = True
        return self._level(applied, label or f"{self.method}-{self.faces_after(t)}f")

    def at_faces(self, target: int, label: str | None = None) -> SimplifiedLevel:
        """The first level with at most ``target`` faces (the coarsest one if none has so few)."""
        hit = np.flatnonzero(self.n_faces <= int(target))
        t = int(hit[0]) + 1 if hit.size else self.n_collapses
        if target >= len(self.F):
            t = 0
        return self.prefix(t, label)

    def at_error(self, threshold: float, label: str | None = None) -> SimplifiedLevel:
        """The longest prefix of collapses whose errors are all at most ``threshold``."""
        over = np.flatnonzero(self.errors > threshold)
        t = int(over[0]) if over.size else self.n_collapses
        return self.prefix(t, label or f"{self.method}-err{threshold:.3g}")

    def adaptive(self, budget, label: str | None = None) -> SimplifiedLevel:
        """Selective refinement by region ([S09] fig. 3): a per-vertex error budget.

        Parameters
        ----------
        budget : (m,) array
            Largest error allowed at each original vertex (e.g. small near the
            viewer or on the face, large elsewhere).

        Notes
        -----
        Collapse ``i`` is applied when both vertices it merges exist (are
        original or made by applied collapses) and
        ``errors[i] <= min_{v in subtree(i)} budget[v]``, the subtree being
        the original vertices the new vertex stands for.
        """
        budget = np.asarray(budget, dtype=np.float64)
        m = self.n_original
        if budget.shape != (m,):
            raise InputError(f"budget has shape {budget.shape}, expected ({m},)", field="budget",
                             fix="give one error budget per original vertex")
        # min budget over each vertex's subtree, children before parents
        lim = np.empty(len(self.V))
        lim[:m] = budget
        a, b = self.collapses[:, 0], self.collapses[:, 1]
        exists = np.zeros(len(self.V), dtype=bool)
        exists[:m] = True
        applied = np.zeros(self.n_collapses, dtype=bool)
        for i in range(self.n_collapses):
            lim[m + i] = min(lim[a[i]], lim[b[i]])
            if exists[a[i]] and exists[b[i]] and self.errors[i] <= lim[m + i]:
                applied[i] = True
                exists[m + i] = True
        return self._level(applied, label or f"{self.method}-adaptive", selective=True)
