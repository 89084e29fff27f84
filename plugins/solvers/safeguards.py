"""What every optimising solve ends with: small rows passed through, and the guard against k-largest.

Pass-through
    A vertex with at most k input influences loses nothing to the reduction: its
    input weights are kept exactly (bit for bit), whatever the solver would give.
    With k at least the handle count every vertex is such a vertex.

Guard
    Fitted weights can over-fit the example poses: a vertex whose example poses
    never exercise a handle (a joint that moves only in a clip not fitted) may
    get weights that reproduce the examples and fail elsewhere. With held-out
    validation frames (:attr:`rigslim.model.poses.FrameSplit.validation`), each
    vertex's squared position error over them,

        e_v(W) = sum_{j in validation} || sum_i w_{v,i} T_i^j [v; 1] - sum_i a_{v,i} T_i^j [v; 1] ||^2,

    is compared, clip by clip (the validation frames of each clip c,
    :attr:`~rigslim.model.poses.FrameSplit.segments`), between the fitted
    weights and k-largest's (the k largest input weights, renormalised, [P10]
    sec. 3). The vertices that fall back to k-largest's weights, F:

    - ``guard: k-largest`` (default): first those worse over all the clips'
      validation frames (``e_v(fit) > e_v(k-largest)``); then, while some clip c
      has ``sum_{v not in F} (e_v^c(fit) - e_v^c(k-largest)) > 0``, the vertices
      of largest excess on c, until it is not. Each clip's validation error
      ``sum_v e_v^c`` is then at most k-largest's;
    - ``guard: k-largest-per-vertex``: every vertex worse on any clip
      (``e_v^c(fit) > e_v^c(k-largest)``): the same bound per vertex, at the
      price of keeping fewer fitted vertices (one trial on six suite
      characters, all clips fitted, k = 2, 3: 0.761x k-largest's test error on
      average over clips, at most 1.001x, against 0.672x, at most 1.096x).

    A fit that helps one clip cannot buy that with another. Vertices that pass
    through (at most k influences) are left out: their weights are exact.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from rigslim.model.weights import ReducedWeights
from rigslim.numerics.blend import linear_blend
from rigslim.numerics.largest_entries import k_largest

__all__ = ["guard_k_largest", "k_largest_weights", "pass_through"]


def pass_through(A: sp.csr_matrix, reduced: ReducedWeights, sets=None) -> tuple[ReducedWeights, int]:
    """``reduced`` with every row of at most k input influences replaced by its input weights, exactly.

    With influence ``sets`` (the step's :class:`~rigslim.model.weights.InfluenceSets`), only rows whose
    input influences all lie in their set pass through: a set that leaves out an influence (a joint
    budget's dropped joint, re-fitted onto the kept ones) asks for a fit, not the input row.
    A row whose slots already hold all its influences keeps its slot order (the solvers' influence
    sets); other such rows take the input's column order. Returns the weights and the number of rows
    passed through.
    """
    A = sp.csr_matrix(A)
    A.sort_indices()
    m, k = reduced.indices.shape
    counts = np.diff(A.indptr)
    small = np.flatnonzero(counts <= k)
    if sets is not None and small.size:
        inside = sp.csr_matrix((sets.valid.ravel().astype(np.float64),
                                (np.repeat(np.arange(m), sets.indices.shape[1]), sets.indices.ravel())),
                               shape=A.shape)
        covered = np.diff(A.multiply(inside > 0).tocsr().indptr)        # input influences inside the set
        small = small[covered[small] == counts[small]]
    if small.size == 0:
        return reduced, 0
    indices, values = reduced.indices.copy(), reduced.values.copy()
    # in the slots' order, where the slots hold every influence of the row
    idx = indices[small]
    vals = np.asarray(A[np.repeat(small, k), idx.ravel()]).reshape(small.size, k)
    dup = np.zeros_like(idx, dtype=bool)
    for j in range(1, k):
        dup[:, j] = (idx[:, :j] == idx[:, j:j + 1]).any(axis=1)
    vals[dup] = 0.0
    in_slots = ((vals != 0).sum(axis=1) == counts[small])
    rows_in = small[in_slots]
    indices[rows_in] = np.where(vals[in_slots] != 0, idx[in_slots], 0)
    values[rows_in] = vals[in_slots]
    # else in the input's column order
    other = small[~in_slots]
    if other.size:
        indices[other] = 0
        values[other] = 0.0
        rows = np.repeat(np.arange(m), counts)
        slot = np.arange(A.nnz) - np.repeat(A.indptr[:-1], counts)
        keep = np.isin(rows, other)
        indices[rows[keep], slot[keep]] = A.indices[keep]
        values[rows[keep], slot[keep]] = A.data[keep]
    return ReducedWeights(indices, values, reduced.n_handles), int(small.size)


def k_largest_weights(A: sp.csr_matrix, k: int) -> ReducedWeights:
    """The k largest input weights of each row, renormalised (rows of zero sum keep their values)."""
    sets = k_largest(A, k)
    A = sp.csr_matrix(A)
    m = A.shape[0]
    rows = np.repeat(np.arange(m), k)
    vals = np.where(sets.valid, np.asarray(A[rows, sets.indices.ravel()]).reshape(m, k), 0.0)
    sums = vals.sum(axis=1, keepdims=True)
    vals = np.divide(vals, sums, out=vals.copy(), where=np.abs(sums) > 1e-12)
    return ReducedWeights.from_influences(sets, vals, A.shape[1])


def vertex_errors(asset, reduced: ReducedWeights, frames) -> np.ndarray:
    """(m,) squared position error of ``reduced`` against the input weights, summed over ``frames``."""
    V = asset.mesh.V
    T = asset.poses.select(list(frames)).T
    e = np.zeros(V.shape[0])
    for j in range(len(T)):
        d = linear_blend(V, reduced, T[j]) - linear_blend(V, asset.weights, T[j])
        e += np.einsum("vc,vc->v", d, d)
    return e


def fallback_set(per_clip, e_fit, e_kl, passes, per_vertex=False) -> np.ndarray:
    """(m,) bool: the vertices F that take k-largest's weights (module docstring).

    ``per_clip``: ``(frames, e_fit^c, e_kl^c)`` per clip; ``e_fit``, ``e_kl``: their sums; ``passes``: rows kept
    exactly anyway.
    """
    if per_vertex:
        worse = np.zeros(len(e_fit), dtype=bool)
        for _, ef, ek in per_clip:
            worse |= ef > ek
        return worse & ~passes
    worse = (e_fit > e_kl) & ~passes
    changed = True
    while changed:
        changed = False
        for _, ef, ek in per_clip:
            excess = np.where(worse | passes, 0.0, ef - ek)
            over = excess.sum()
            if over <= 0.0:
                continue
            order = np.argsort(-excess)
            cut = int(np.searchsorted(np.cumsum(excess[order]), over, side="left")) + 1
            add = order[:cut]
            add = add[excess[add] > 0]
            if add.size:
                worse[add] = True
                changed = True
    return worse


def guard_k_largest(asset, reduced: ReducedWeights, per_vertex: bool = False) -> tuple[ReducedWeights, dict]:
    """Per vertex, k-largest's weights where they beat ``reduced`` on the validation frames (module docstring).

    ``per_vertex``: the rule of ``guard: k-largest-per-vertex``.
    Returns the guarded weights and a report: ``guard``, ``validation_frames``, ``fallback_vertices``,
    and the validation position RMS (% of the diagonal) of the fit, of k-largest and of the result.
    Without validation frames the weights come back unchanged (``guard: "no validation frames"``).
    """
    split = asset.split
    frames = list(split.validation) if split is not None else []
    if not frames or asset.poses is None:
        return reduced, {"guard": "no validation frames", "fallback_vertices": 0}
    k = reduced.k
    base = k_largest_weights(asset.weights, k)
    m = asset.mesh.n_vertices
    e_fit, e_kl, worse = np.zeros(m), np.zeros(m), np.zeros(m, dtype=bool)
    passes = np.diff(sp.csr_matrix(asset.weights).indptr) <= k   # kept exactly anyway (:func:`pass_through`)
    per_clip = []
    for group in split.clip_groups(frames):
        ef, ek = vertex_errors(asset, reduced, group), vertex_errors(asset, base, group)
        e_fit += ef
        e_kl += ek
        per_clip.append((group, ef, ek))
    worse = fallback_set(per_clip, e_fit, e_kl, passes, per_vertex=per_vertex)
    indices = np.where(worse[:, None], base.indices, reduced.indices)
    values = np.where(worse[:, None], base.values, reduced.values)
    out = ReducedWeights(indices, values, reduced.n_handles)
    diag = asset.mesh.bbox_diagonal

    def rms(e, p):
        return float(100.0 * np.sqrt(e.sum() / max(m * p, 1)) / diag)

    p = len(frames)
    report = {"guard": "k-largest-per-vertex" if per_vertex else "k-largest", "validation_frames": p,
              "fallback_vertices": int(worse.sum()),
              "validation_rms_pct_fit": rms(e_fit, p), "validation_rms_pct_k_largest": rms(e_kl, p),
              "validation_rms_pct": rms(np.where(worse, e_kl, e_fit), p)}
    if len(per_clip) > 1:
        report["validation_clips"] = [{"frames": len(g), "rms_pct_fit": rms(ef, len(g)),
                                       "rms_pct_k_largest": rms(ek, len(g)),
                                       "rms_pct": rms(np.where(worse, ek, ef), len(g))} for g, ef, ek in per_clip]
    return out, report
