"""``best-fit`` influence selection: each vertex keeps the influences a sparse fit of the example poses uses.

[P10] sec. 3 chooses the k largest input weights and notes that "there may be
other heuristics for choosing influence sets that work better". ``best-fit``
fits, per vertex, the example poses over *all* the vertex's input influences
with non-negative weights that sum to one (:mod:`rigslim.plugins.selection.sparse_fit`)
and keeps

- ``by: weight`` (default): the k influences with the largest fitted weights;
- ``by: error``: greedy backward elimination from the fit's support, each
  step dropping the influence whose removal raises the example-pose error of
  the re-solved fit the least, until k remain; then ``swaps`` passes of the
  best single exchange (a member for a non-member) that lowers it further.

Slots the fit leaves empty (it used fewer than k influences) are filled with
the vertex's largest remaining input weights, so the solver still has k
degrees of freedom.

Coherence between neighbours (seams between different sets are where normals
break) was measured and is *not* a plugin option: ranking by
``w_v + beta * mean_{u in N(v)} w_u`` (fitted weights of the one-ring,
:func:`one_ring_vote`, ``coherence=beta`` of :func:`best_fit`) did not lower
the elephant's normal error (docs/results/reduction_quality_best_fit.md); by
error, the eliminated sets are kept whatever the vote.

The step's report holds the fit's example-pose error (RMS over vertices, % of
the bounding-box diagonal), how many vertices' fits needed more than k
influences, and the time.
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING, Literal

import numpy as np
import scipy.sparse as sp
from numba import njit
from pydantic import Field

from rigslim.model.weights import InfluenceSets
from rigslim.numerics.clip_balance import fit_transforms
from rigslim.numerics.largest_entries import k_largest
from rigslim.plugin import InfluenceSelector, Params
from rigslim.plugins.selection.k_largest import pass_through_note
from rigslim.plugins.selection.sparse_fit import sparse_fit

if TYPE_CHECKING:
    from rigslim.model.asset import Asset
    from rigslim.plugin import Params, StepContext


@njit(cache=True)
def _rank_rows(indptr, indices, data, score, k, out, valid):  # pragma: no cover - numba
    """Per row, the k entries first in the order (score desc, data desc, index asc), in that order.
    One thread: O(k) passes over each row's few entries cost milliseconds, where a parallel loop's
    compilation cost seconds on the first call."""
    m = indptr.shape[0] - 1
    for v in range(m):
        lo = indptr[v]
        hi = indptr[v + 1]
        taken = np.zeros(hi - lo, dtype=np.bool_)
        for r in range(min(k, hi - lo)):
            b = -1
            for e in range(lo, hi):
                if taken[e - lo]:
                    continue
                if b < 0 or score[e] > score[b] or (score[e] == score[b] and (
                        data[e] > data[b] or (data[e] == data[b] and indices[e] < indices[b]))):
                    b = e
            taken[b - lo] = True
            out[v, r] = indices[b]
            valid[v, r] = True


def rank_entries(A: sp.csr_matrix, score: np.ndarray, k: int) -> InfluenceSets:
    """Per row, the k stored entries of largest ``score`` (ties: larger input weight, then lower index)."""
    m = A.shape[0]
    indices = np.zeros((m, k), dtype=np.int32)
    valid = np.zeros((m, k), dtype=bool)
    _rank_rows(A.indptr.astype(np.int64), A.indices.astype(np.int64), np.ascontiguousarray(A.data, dtype=np.float64),
               np.ascontiguousarray(score, dtype=np.float64), int(k), indices, valid)
    return InfluenceSets(indices, valid)


def rank_entries_reference(A: sp.csr_matrix, score: np.ndarray, k: int) -> InfluenceSets:
    """Numpy reference of :func:`rank_entries` (a lexsort of all entries; for tests)."""
    m = A.shape[0]
    counts = np.diff(A.indptr)
    rows = np.repeat(np.arange(m), counts)
    order = np.lexsort((A.indices, -A.data, -score, rows))
    rank = np.arange(len(order)) - np.repeat(A.indptr[:-1], counts)
    keep = rank < k
    sel = order[keep]
    indices = np.zeros((m, k), dtype=np.int32)
    valid = np.zeros((m, k), dtype=bool)
    indices[rows[sel], rank[keep]] = A.indices[sel]
    valid[rows[sel], rank[keep]] = True
    return InfluenceSets(indices, valid)


def one_ring_vote(A: sp.csr_matrix, fit: np.ndarray, adjacency, beta: float) -> np.ndarray:
    """``w_v + beta * mean_{u in N(v)} w_u`` on the stored entries of ``A`` (fitted weights ``w``)."""
    if beta == 0:
        return fit
    X = sp.csr_matrix((fit, A.indices, A.indptr), shape=A.shape)
    adj = sp.csr_matrix(adjacency, dtype=np.float64)
    adj.data[:] = 1.0
    deg = np.maximum(np.asarray(adj.sum(axis=1)).ravel(), 1.0)
    N = sp.csr_matrix(sp.diags(1.0 / deg) @ adj @ X)
    rows = np.repeat(np.arange(A.shape[0]), np.diff(A.indptr))
    return fit + beta * np.asarray(N[rows, A.indices]).ravel()


def best_fit(asset, k: int, by: str = "weight", coherence: float = 0.0, swaps: int = 0,
             balance: str = "clips") -> tuple[InfluenceSets, dict]:
    """Influence sets of the sparse example-pose fit (module docstring) and a report.

    ``balance``: ``clips`` weights the example frames so that every clip counts
    (:mod:`rigslim.numerics.clip_balance`), ``frames`` weights them alike."""
    t0 = time.perf_counter()
    A = sp.csr_matrix(asset.weights)
    A.sort_indices()
    T, frame_weights = fit_transforms(asset, k, balance)
    fit, member, errors = sparse_fit(asset.mesh.V, T, A, k, by, swaps)
    score = one_ring_vote(A, fit, asset.mesh.adjacency, coherence) if coherence > 0 else fit.copy()
    if by == "error":
        score += 2.0 * member  # the eliminated set first, by (voted) fitted weight
    sets = rank_entries(A, score, k)
    rows = np.repeat(np.arange(A.shape[0]), np.diff(A.indptr))
    support = np.bincount(rows, weights=(fit > 0), minlength=A.shape[0]).astype(np.int64)
    p = T.shape[0]
    diag = asset.mesh.bbox_diagonal
    report = {"by": by, "coherence": float(coherence), "swaps": int(swaps), "example_poses": int(p),
              "balance": balance if frame_weights is not None else "frames",
              "fit_rms_pct": float(100.0 * np.sqrt(errors.sum() / (max(len(errors), 1) * max(p, 1))) / diag),
              "fit_support_mean": float(support.mean()) if support.size else 0.0,
              "fit_support_max": int(support.max(initial=0)),
              "vertices_fit_above_k": int((support > k).sum()),
              "seconds": time.perf_counter() - t0}
    return sets, report


class BestFitParams(Params):
    k: int = Field(ge=1, description="influences per vertex")
    by: Literal["weight", "error"] = Field("weight", description="keep the k largest fitted weights, or "
                                           "drop influences greedily by least example-pose error")
    swaps: int = Field(0, ge=0, description="by: error: passes of single exchanges (member for "
                       "non-member) that lower the example-pose error further")
    balance: Literal["clips", "frames"] = Field("clips", description="clips: weight the example frames so "
                                                "that every clip counts by its k-largest error; frames: alike")


class BestFitSelector(InfluenceSelector[BestFitParams]):
    name = "best-fit"
    summary = ("keep the influences of a sparse non-negative sum-to-one fit of the example poses over "
               "all input influences (by weight or by greedy error reduction)")

    def select(self, asset: Asset, params: BestFitParams, ctx: StepContext) -> InfluenceSets:
        asset.require("mesh", "handles", "weights", "poses", "split", step="select: best-fit")
        weights = asset.weights
        assert weights is not None  # require() raised otherwise
        if pass_through_note(params.k, weights.shape[1], ctx):
            return k_largest(weights, params.k)
        sets, report = best_fit(asset, params.k, params.by, swaps=params.swaps, balance=params.balance)
        if ctx is not None and hasattr(ctx, "report"):
            ctx.report.update(report)
        return sets
