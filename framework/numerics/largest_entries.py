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
from rigslim.model.weights import InfluenceSets

__all__ = ["check_k", "k_largest"]


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


def check_k(k: int, n: int) -> None:
    """Reject k that would not reduce anything (k must be smaller than the handle count)."""
    if k >= n:
        raise StepError(f"k = {k} is not smaller than the number of handles ({n})", field="k",
                        fix=f"choose k between 1 and {n - 1}")
