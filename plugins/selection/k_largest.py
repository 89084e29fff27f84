"""k-largest influence selection ([P10] section 3): each vertex keeps its k largest weights."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from pydantic import Field

from rigslim.errors import StepError
from rigslim.plugin import InfluenceSelector, Params
from rigslim.weights import InfluenceSets


def k_largest(A: sp.csr_matrix, k: int, key=None) -> InfluenceSets:
    """The k largest entries of each row.

    Parameters
    ----------
    A : (m, n) sparse matrix
    k : int
    key : callable, optional
        Applied to the stored values before ranking (e.g. ``np.abs``).

    Returns
    -------
    InfluenceSets
        Sorted by decreasing value; rows with fewer than k stored non-zeros get
        padding slots (``valid`` False). Ties keep the lower handle index.

    Notes
    -----
    Vectorised over rows: entries are sorted by (row, -value, column) once,
    then each row's first k entries are kept.
    """
    A = sp.csr_matrix(A)
    A.sort_indices()
    m = A.shape[0]
    counts = np.diff(A.indptr)
    rows = np.repeat(np.arange(m), counts)
    vals = A.data if key is None else key(A.data)
    order = np.lexsort((A.indices, -vals, rows))
    rank = np.arange(len(order)) - np.repeat(A.indptr[:-1], counts)
    keep = rank < k
    sel = order[keep]
    slot = rank[keep]
    indices = np.zeros((m, k), dtype=np.int32)
    valid = np.zeros((m, k), dtype=bool)
    indices[rows[sel], slot] = A.indices[sel]
    valid[rows[sel], slot] = True
    return InfluenceSets(indices, valid)


class KLargestSelector(InfluenceSelector):
    name = "k-largest"
    summary = "keep each vertex's k largest input weights (the baseline of every importer)"

    class Params(Params):
        k: int = Field(ge=1, description="influences per vertex")

    def select(self, asset, params, ctx):
        asset.require("weights", step="select: k-largest")
        check_k(params.k, asset.weights.shape[1])
        return k_largest(asset.weights, params.k)


def check_k(k: int, n: int) -> None:
    """Reject k that would not reduce anything (k must be smaller than the handle count)."""
    if k >= n:
        raise StepError(f"k = {k} is not smaller than the number of handles ({n})", field="k",
                        fix=f"choose k between 1 and {n - 1}")
