"""The k largest entries of each row of a sparse matrix: the influence sets of [P10] section 3.

The ranking only: the ``select`` step that uses it is the k-largest selector
(:mod:`rigslim.plugins.selection.k_largest`), the ``solve`` step that keeps the selected input weights is
:mod:`rigslim.plugins.solvers.renormalised`. Shared with selectors of plugin packages and the benchmarks.
(Was ``rigslim.numerics.k_largest``; that path still imports, see :mod:`rigslim.compat`.)
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import scipy.sparse as sp

from rigslim.errors import StepError
from rigslim.model.weights import InfluenceSets, ReducedWeights

__all__ = ["check_k", "k_largest", "k_largest_weights"]


def k_largest(A: sp.spmatrix, k: int, key: Callable[[np.ndarray], np.ndarray] | None = None) -> InfluenceSets:
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
    then each row's first k entries are kept. Where the rows hold about as
    many entries each (skinning and cage weights: the padded table is at most
    four times the stored entries), each row is sorted in a padded table
    instead, which is several times faster and gives the same sets.
    """
    A = sp.csr_matrix(A)
    A.sort_indices()
    m = A.shape[0]
    counts = np.diff(A.indptr)
    vals = A.data if key is None else key(A.data)
    width = int(counts.max()) if m else 0
    if 0 < m * width <= 4 * A.nnz and not np.isnan(vals).any():
        return _k_largest_padded(A, vals, counts, width, k)
    rows = np.repeat(np.arange(m), counts)
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


def _k_largest_padded(A: sp.csr_matrix, vals: np.ndarray, counts: np.ndarray, width: int, k: int) -> InfluenceSets:
    """:func:`k_largest` by a stable sort of each row of an (m, width) table of ``-vals`` padded with +inf:
    the row's entries are in column order, so equal values keep the lower handle index first."""
    m = A.shape[0]
    start = A.indptr[:-1]
    pos = np.arange(A.nnz) - np.repeat(start, counts)
    table = np.full((m, width), np.inf)
    table[np.repeat(np.arange(m), counts), pos] = -vals
    order = np.argsort(table, axis=1, kind="stable")[:, :k]
    valid = np.zeros((m, k), dtype=bool)
    valid[:, :order.shape[1]] = np.arange(order.shape[1]) < counts[:, None]
    indices = np.zeros((m, k), dtype=np.int32)
    at = (start[:, None] + order)[valid[:, :order.shape[1]]]
    indices[valid] = A.indices[at]
    return InfluenceSets(indices, valid)


def check_k(k: int, n: int) -> None:
    """Reject k that would not reduce anything (k must be smaller than the handle count)."""
    if k >= n:
        raise StepError(f"k = {k} is not smaller than the number of handles ({n})", field="k",
                        fix=f"choose k between 1 and {n - 1}")


def k_largest_weights(A: sp.spmatrix, k: int) -> ReducedWeights:
    """The k largest input weights of each row, renormalised: ``a_{v,i_l} / sum_l' a_{v,i_l'}`` over the
    row's k largest (rows whose kept weights sum to zero keep their values). The baseline of [P10] sec. 3,
    which the solvers' guard and the clip balance measure against."""
    sets = k_largest(A, k)
    A = sp.csr_matrix(A)
    m = A.shape[0]
    rows = np.repeat(np.arange(m), k)
    vals = np.where(sets.valid, np.asarray(A[rows, sets.indices.ravel()]).reshape(m, k), 0.0)
    sums = vals.sum(axis=1, keepdims=True)
    vals = np.divide(vals, sums, out=vals.copy(), where=np.abs(sums) > 1e-12)
    return ReducedWeights.from_influences(sets, vals, A.shape[1])
