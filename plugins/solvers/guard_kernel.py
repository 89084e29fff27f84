"""The guard's per-vertex, per-frame errors compiled: the fast path of the guard against k-largest
(:func:`rigslim.plugins.solvers.safeguards.guard_k_largest`).

For each vertex v and validation frame j the guard compares two fixed-k weightings W (the fit) and B
(k-largest's) with the input weights a:

    e_v^j(W) = || sum_l w_{v,l} T_{i_l}^j [v; 1] - sum_i a_{v,i} T_i^j [v; 1] ||^2.

:func:`frame_errors` computes ``D_v^j = e_v^j(W) - e_v^j(B)`` and both errors summed over the frames in one
pass over the vertices, in a kernel over a range of vertices that releases the GIL, run on threads over
parts of them (:func:`rigslim.numerics.row_threads.over_rows`), without forming any (m, 3) blend per frame.
The numpy reference is :func:`rigslim.plugins.solvers.safeguards._frame_excess_reference` (three
:func:`rigslim.numerics.blend.linear_blend` calls per frame); a test checks that they agree.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from rigslim.model.weights import ReducedWeights
from rigslim.numerics.row_threads import over_rows

__all__ = ["frame_errors"]


@njit(cache=True, nogil=True)
def _blend(T, j, x, y, z, handles, weights):  # pragma: no cover - numba
    """``sum_s weights_s T_{handles_s}^j [x; y; z; 1]``, the three coordinates."""
    p0 = 0.0
    p1 = 0.0
    p2 = 0.0
    for s in range(handles.shape[0]):
        i, w = handles[s], weights[s]
        p0 += w * (T[j, i, 0, 0] * x + T[j, i, 0, 1] * y + T[j, i, 0, 2] * z + T[j, i, 0, 3])
        p1 += w * (T[j, i, 1, 0] * x + T[j, i, 1, 1] * y + T[j, i, 1, 2] * z + T[j, i, 1, 3])
        p2 += w * (T[j, i, 2, 0] * x + T[j, i, 2, 1] * y + T[j, i, 2, 2] * z + T[j, i, 2, 3])
    return p0, p1, p2


@njit(cache=True, nogil=True)
def _frame_rows(start, stop, V, T, indptr, cols, vals, ia, wa, ib, wb, D, ea, eb):  # pragma: no cover - numba
    for v in range(start, stop):
        x, y, z = V[v, 0], V[v, 1], V[v, 2]
        lo, hi = indptr[v], indptr[v + 1]
        for j in range(T.shape[0]):
            f0, f1, f2 = _blend(T, j, x, y, z, cols[lo:hi], vals[lo:hi])
            a0, a1, a2 = _blend(T, j, x, y, z, ia[v], wa[v])
            b0, b1, b2 = _blend(T, j, x, y, z, ib[v], wb[v])
            da = (a0 - f0) ** 2 + (a1 - f1) ** 2 + (a2 - f2) ** 2
            db = (b0 - f0) ** 2 + (b1 - f1) ** 2 + (b2 - f2) ** 2
            D[v, j] = da - db
            ea[v] += da
            eb[v] += db


def frame_errors(V: np.ndarray, A, T: np.ndarray, W: ReducedWeights, B: ReducedWeights
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(D, e_W, e_B)``: ``D`` (m, p) float32, the per-frame excess ``e_v^j(W) - e_v^j(B)`` against the input
    weights ``A`` (sparse, m x n) over the frames ``T`` (p, n, 3, 4), and the two errors summed over them
    (module docstring)."""
    import scipy.sparse as sp

    A = sp.csr_matrix(A)
    m, p = V.shape[0], T.shape[0]
    D = np.empty((m, p), dtype=np.float32)
    ea, eb = np.zeros(m), np.zeros(m)
    over_rows(_frame_rows, m, np.ascontiguousarray(V, dtype=np.float64), np.ascontiguousarray(T, dtype=np.float64),
              A.indptr.astype(np.int64), A.indices.astype(np.int64), np.ascontiguousarray(A.data, dtype=np.float64),
              W.indices.astype(np.int64), np.ascontiguousarray(W.values, dtype=np.float64),
              B.indices.astype(np.int64), np.ascontiguousarray(B.values, dtype=np.float64), D, ea, eb)
    return D, ea, eb
