"""Weights of a level without some joints: re-fitted over the example poses, or given to the parent.

A level ``l`` of a skinned mesh has rest vertices ``v`` and weights ``W`` over the skin's ``n``
joints; its example-pose deformation is the target

    y_v^p = sum_j W_vj T_j^p [v; 1]        (p = 1..P example poses).

Given the joints ``K`` a level keeps, a vertex whose weights use a joint outside ``K`` gets new
weights on ``K`` only:

- ``refit`` (rigslim): the vertex's **candidates** ``C_v`` are the kept joints among its own and its
  one-ring neighbours' influences, and, for each dropped joint it used, that joint's nearest kept
  ancestor and nearest kept descendants (:func:`proxy_matrix`); if none is left, the kept joint whose
  bind position is closest. The skin's ``geometric`` weight solver ([P10] eq. 3, non-negative, rows
  summing to one; reached through the plugin host, as every plugin reaches another) fits the target
  over the example poses on all of ``C_v``; a vertex with more than ``k`` candidates (the level's
  bone limit) keeps the ``k`` with the largest fitted weights (``best-fit``'s rule) and is fitted
  again on those:

      min_a  sum_p || sum_{i in C} a_i T_i^p [v; 1] - y_v^p ||^2   s.t.  a >= 0,  1^T a = 1,  |C| <= k.

- ``parent`` (Unreal's ``BonesToRemove``): each dropped joint's weight goes to its nearest kept
  ancestor (the nearest kept descendant for a dropped root, the closest kept joint if neither
  exists), ``W' = W Pi``; rows still sum to one.

The example-pose error of vertex ``v`` is ``e_v = sum_p ||y'_v^p - y_v^p||^2`` (squared metres
for glTF, whose poses are in world space).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

from rigslim.model.weights import InfluenceSets, ReducedWeights
from rigslim.numerics.blend import linear_blend

__all__ = ["LevelTarget", "proxy_matrix", "refit_rows", "parent_rows", "row_errors", "METHODS"]

#: How a level's weights lose a joint.
METHODS = ("refit", "parent")


@dataclass
class LevelTarget:
    """What every re-fit of one level needs: rest vertices, target weights, example poses, the joint tree.

    Attributes
    ----------
    V : (m, 3) rest positions; W : (m, n) csr target weights (the level's weights with every joint)
    T : (P, n, 3, 4) example-pose joint transforms; Y : (P, m, 3) target positions
    parents : (n,) parent joint of each joint (-1 for roots); joint_positions : (n, 3) bind positions
    k : int, the bone limit; area : (m,) vertex areas (Voronoi); support, ring : (m, n) bool
        each vertex's own influences and those of its one-ring (itself included)
    """

    V: np.ndarray
    W: sp.csr_matrix
    T: np.ndarray
    parents: np.ndarray
    joint_positions: np.ndarray
    k: int
    area: np.ndarray
    support: np.ndarray = field(init=False)
    ring: np.ndarray = field(init=False)
    Y: np.ndarray = field(init=False)
    adjacency: sp.csr_matrix | None = None

    def __post_init__(self):
        W = sp.csr_matrix(self.W)
        W.eliminate_zeros()
        self.W = W
        self.support = (W != 0).toarray()
        S = sp.csr_matrix(self.support.astype(np.float64))
        if self.adjacency is not None:
            A = sp.csr_matrix(self.adjacency, dtype=np.float64) + sp.identity(len(self.V), format="csr")
            self.ring = (A @ S).toarray() > 0
        else:
            self.ring = self.support.copy()
        self.Y = np.stack([linear_blend(self.V, W, Tp) for Tp in self.T]) if len(self.T) else \
            np.zeros((0, len(self.V), 3))

    @property
    def n(self) -> int:
        return self.W.shape[1]

    def children(self) -> list[list[int]]:
        out: list[list[int]] = [[] for _ in range(self.n)]
        for j, p in enumerate(self.parents):
            if p >= 0:
                out[int(p)].append(j)
        return out


def proxy_matrix(kept: np.ndarray, parents: np.ndarray, *, descendants: bool = True) -> np.ndarray:
    """(n, n) bool ``Pi``: ``Pi[j, j]`` for a kept joint; for a dropped one its nearest kept ancestor and
    (``descendants``) the first kept joint on every path down from it.

    A dropped root (no kept ancestor) always gets its nearest kept descendants.
    """
    n = len(kept)
    children: list[list[int]] = [[] for _ in range(n)]
    for j, p in enumerate(parents):
        if p >= 0:
            children[int(p)].append(j)
    P = np.zeros((n, n), bool)
    for j in range(n):
        if kept[j]:
            P[j, j] = True
            continue
        a = int(parents[j])
        while a >= 0 and not kept[a]:
            a = int(parents[a])
        if a >= 0:
            P[j, a] = True
        if descendants or a < 0:
            stack = list(children[j])
            while stack:
                c = stack.pop()
                if kept[c]:
                    P[j, c] = True
                else:
                    stack.extend(children[c])
    return P


def _closest_kept(target: LevelTarget, rows: np.ndarray, kept: np.ndarray) -> np.ndarray:
    """(r,) the kept joint whose bind position is closest to each row's vertex."""
    ids = np.flatnonzero(kept)
    d = np.linalg.norm(target.V[rows][:, None, :] - target.joint_positions[ids][None], axis=2)
    return ids[np.argmin(d, axis=1)]


def _sets(C: np.ndarray) -> InfluenceSets:
    """Fixed-width influence sets of the True entries of (r, n) ``C`` (ascending joint order)."""
    width = max(1, int(C.sum(axis=1).max(initial=1)))
    order = np.argsort(~C, axis=1, kind="stable")[:, :width]
    valid = np.take_along_axis(C, order, 1)
    return InfluenceSets(np.where(valid, order, 0).astype(np.int32), valid)


def candidates(target: LevelTarget, rows: np.ndarray, kept: np.ndarray) -> np.ndarray:
    """(r, n) bool candidate joints ``C_v`` of each row for the kept mask (module docstring)."""
    P = proxy_matrix(kept, target.parents)
    S = target.support[rows]
    C = (target.ring[rows] & kept[None]) | ((S.astype(np.int32) @ P.astype(np.int32)) > 0)
    empty = ~C.any(axis=1)
    if empty.any():
        C[np.flatnonzero(empty), _closest_kept(target, rows[empty], kept)] = True
    return C


def _solve(target: LevelTarget, rows: np.ndarray, sets: InfluenceSets, solver, handles) -> np.ndarray:
    """(r, w) weights of the skin's weight solver on ``sets`` for the target rows (a sub-asset of those rows)."""
    from rigslim.model.asset import Asset
    from rigslim.model.mesh import Mesh
    from rigslim.model.poses import FrameSplit, Poses
    from rigslim.plugin import StepContext

    sub = Asset(mesh=Mesh(target.V[rows], np.zeros((0, 3), np.int64), source="joint budget rows"),
                handles=handles, weights=target.W[rows], poses=Poses(target.T),
                split=FrameSplit(list(range(len(target.T))), [0], []), influences=sets)
    plugin, params = solver
    reduced = plugin.solve(sub, params, StepContext())
    return np.where(sets.valid, reduced.values, 0.0)


def refit_rows(target: LevelTarget, rows: np.ndarray, kept: np.ndarray, solver, handles
               ) -> tuple[np.ndarray, np.ndarray]:
    """Re-fitted ``(indices, values)`` (r, k) of ``rows`` on the kept joints (module docstring).

    ``kept`` is one (n,) mask for every row, or (r, n) masks row by row (several candidate choices in one solve).
    ``solver`` is ``(plugin, params)`` of a weight solver; ``handles`` the skin's handles.
    """
    rows = np.asarray(rows, np.int64)
    K = np.broadcast_to(kept, (len(rows), target.n))
    C = np.zeros((len(rows), target.n), bool)
    masks, inverse = np.unique(K, axis=0, return_inverse=True)
    for g, mask in enumerate(masks):
        sel = np.flatnonzero(inverse.reshape(-1) == g)
        C[sel] = candidates(target, rows[sel], mask)
    sets = _sets(C)
    alpha = _solve(target, rows, sets, solver, handles)
    k = target.k
    idx, val = sets.indices, alpha
    if sets.k > k:
        wide = sets.valid.sum(axis=1) > k
        order = np.argsort(-np.where(sets.valid, alpha, -1.0), axis=1, kind="stable")[:, :k]
        top = InfluenceSets(np.take_along_axis(sets.indices, order, 1), np.take_along_axis(sets.valid, order, 1))
        narrow_vals = np.take_along_axis(alpha, order, 1)
        if wide.any():
            w = np.flatnonzero(wide)
            again = InfluenceSets(top.indices[w], top.valid[w])
            narrow_vals[w] = _solve(target, rows[w], again, solver, handles)
        idx, val = np.where(top.valid, top.indices, 0), narrow_vals
    return _fixed(idx, val, k)


def parent_rows(target: LevelTarget, rows: np.ndarray, kept: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(indices, values)`` (r, k) of ``rows`` with each dropped joint's weight moved to its nearest kept
    ancestor (module docstring)."""
    rows = np.asarray(rows, np.int64)
    K = np.broadcast_to(kept, (len(rows), target.n))
    out = np.zeros((len(rows), target.n))
    masks, inverse = np.unique(K, axis=0, return_inverse=True)
    for g, mask in enumerate(masks):
        sel = np.flatnonzero(inverse.reshape(-1) == g)
        P = proxy_matrix(mask, target.parents, descendants=False).astype(np.float64)
        P /= np.maximum(P.sum(axis=1, keepdims=True), 1.0)            # a dropped root: split among descendants
        block = np.asarray(target.W[rows[sel]] @ P)
        lost = block.sum(axis=1) < 0.5                                 # nothing kept above or below
        if lost.any():
            r = np.flatnonzero(lost)
            block[r] = 0.0
            block[r, _closest_kept(target, rows[sel][r], mask)] = 1.0
        out[sel] = block
    order = np.argsort(-out, axis=1, kind="stable")[:, :max(target.k, 1)]
    vals = np.take_along_axis(out, order, 1)
    vals = vals / np.maximum(vals.sum(axis=1, keepdims=True), 1e-300)
    return _fixed(np.where(vals > 0, order, 0), vals, target.k)


def _fixed(idx: np.ndarray, val: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Pad or cut (r, w) slots to exactly k (a row never has more than k non-zero weights here)."""
    idx, val = np.asarray(idx, np.int64), np.maximum(np.asarray(val, np.float64), 0.0)
    r, w = val.shape
    if w < k:
        idx = np.pad(idx, ((0, 0), (0, k - w)))
        val = np.pad(val, ((0, 0), (0, k - w)))
    elif w > k:
        order = np.argsort(-val, axis=1, kind="stable")[:, :k]
        idx, val = np.take_along_axis(idx, order, 1), np.take_along_axis(val, order, 1)
    s = val.sum(axis=1, keepdims=True)
    val = np.where(s > 0, val / np.where(s > 0, s, 1.0), val)
    return np.where(val > 0, idx, 0), val


def row_errors(target: LevelTarget, rows: np.ndarray, idx: np.ndarray, val: np.ndarray) -> np.ndarray:
    """(r,) ``e_v = sum_p ||y'_v^p - y_v^p||^2`` of weights ``(idx, val)`` on ``rows``."""
    rows = np.asarray(rows, np.int64)
    vh = np.concatenate([target.V[rows], np.ones((len(rows), 1))], axis=1)
    e = np.zeros(len(rows))
    for p in range(len(target.T)):
        X = np.einsum("rl,rlij,rj->ri", val, target.T[p][idx], vh)
        e += ((X - target.Y[p, rows]) ** 2).sum(axis=1)
    return e


def level_weights(indices: np.ndarray, values: np.ndarray, n: int) -> ReducedWeights:
    """The level's :class:`ReducedWeights` from (m, k) slots."""
    return ReducedWeights(np.where(values > 0, indices, 0), np.where(values > 0, values, 0.0), n)
