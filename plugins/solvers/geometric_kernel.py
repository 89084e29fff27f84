"""The non-negative geometric fit ([P10] eq. 3) compiled per vertex: the fast path of ``solve: geometric``.

With only the sum-to-one row and ``alpha >= 0`` the geometric energy of
:mod:`rigslim.plugins.solvers.problem` separates into one small QP per vertex,

    min_x  ||B_v^T x - y_v||^2 + eps ||x - alpha0_v||^2   s.t.  1^T x = 1,  x >= 0,

``B_v`` (k, 3p) the basis positions ``T_{i_l}^j [v; 1]`` of the vertex's
influence set over the p example poses, ``y_v = sum_i a_{v,i} T_i^j [v; 1]``
the full deformation and ``eps`` the ridge towards the k-largest weights
(``ridge`` times the mean of ``|b_{v,l}|^2`` over valid slots, as
:func:`rigslim.plugins.solvers.problem.build_problem` sets it). This module
solves them in numba, without forming the (m, k, 3p) basis, in kernels over a
range of vertices that release the GIL, run on threads over parts of the
vertices (:func:`rigslim.numerics.row_threads.over_rows`; no ``prange``, whose
parallel-loop passes cost seconds of compilation on the first call): each
vertex builds its k x k Gram matrix ``G = B B^T + eps I`` and
``c = B y + eps alpha0`` and runs the sum-to-one Lawson & Hanson method of
:mod:`rigslim.numerics.simplex_nnls` (exact: the QP is strictly convex).
:func:`rigslim.plugins.solvers.methods.solve_weights` takes this path for
non-negative geometric fits on numpy; the batched active-set reference
(:func:`rigslim.numerics.small_qp.solve_small_qps` through the local solver) is tested to agree.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from rigslim.numerics.clip_balance import fit_transforms
from rigslim.numerics.row_threads import over_rows
from rigslim.numerics.simplex_nnls import _lawson_hanson

#: Bound multipliers above ``-TOL * max_l G_ll`` count as non-negative (the batched reference uses 1e-12).
TOL = 1e-13


@njit(cache=True)
def _basis_row(v, T, h, out):  # pragma: no cover - numba
    p = T.shape[0]
    for q in range(p):
        for c in range(3):
            out[3 * q + c] = T[q, h, c, 0] * v[0] + T[q, h, c, 1] * v[1] + T[q, h, c, 2] * v[2] + T[q, h, c, 3]


@njit(cache=True, nogil=True)
def _diagonal_rows(start, stop, V, T, sel, valid, sums):  # pragma: no cover - numba
    """``sums[v] = sum_l |b_{v,l}|^2`` over vertex v's valid slots, for the vertices ``start:stop``
    (the ridge's scale). Releases the GIL: run over parts of the rows on threads."""
    k = sel.shape[1]
    D = 3 * T.shape[0]
    b = np.empty(D)
    for v in range(start, stop):
        s = 0.0
        for l in range(k):
            if valid[v, l]:
                _basis_row(V[v], T, sel[v, l], b)
                for d in range(D):
                    s += b[d] * b[d]
        sums[v] = s


@njit(cache=True, nogil=True)
def _fit_rows(start, stop, V, T, indptr, indices, data, sel, valid, alpha0, eps,  # pragma: no cover - numba
              out, energy, energy0):
    """The QP of each vertex ``start:stop`` (module docstring): its weights into ``out[v]``, its energy
    and the energy at ``alpha0[v]`` into ``energy[v]``, ``energy0[v]``. Releases the GIL: run over parts
    of the rows on threads."""
    k = sel.shape[1]
    D = 3 * T.shape[0]
    for v in range(start, stop):
        y = np.zeros(D)
        b = np.empty(D)
        for e in range(indptr[v], indptr[v + 1]):
            _basis_row(V[v], T, indices[e], b)
            for d in range(D):
                y[d] += data[e] * b[d]
        slots = np.empty(k, dtype=np.int64)
        kv = 0
        for l in range(k):
            if valid[v, l]:
                slots[kv] = l
                kv += 1
        if kv == 0:
            continue
        B = np.empty((kv, D))
        for i in range(kv):
            _basis_row(V[v], T, sel[v, slots[i]], B[i])
        G = B @ B.T
        c = B @ y
        a0 = np.empty(kv)
        yy = 0.0
        for d in range(D):
            yy += y[d] * y[d]
        scale = 1e-300
        for i in range(kv):
            a0[i] = alpha0[v, slots[i]]
            G[i, i] += eps
            c[i] += eps * a0[i]
            yy += eps * a0[i] * a0[i]
            scale = max(scale, G[i, i])
        x = np.zeros(kv)
        j0 = 0
        for i in range(1, kv):
            if G[i, i] - 2.0 * c[i] < G[j0, j0] - 2.0 * c[j0]:
                j0 = i
        x[j0] = 1.0
        F = np.zeros(kv + 1, dtype=np.int64)
        F[0] = j0
        K = np.empty((kv + 1, kv + 1))
        z = np.empty(kv + 1)
        allowed = np.ones(kv, dtype=np.bool_)
        # int64 / bool values, not literals: the selection's specialisation of the method (compiled once)
        _, e = _lawson_hanson(G, c, yy, allowed, x, F, np.int64(1), TOL * scale, 0.0, 3 * kv + 10, K, z,
                              np.bool_(False))
        e0 = yy
        for i in range(kv):
            out[v, slots[i]] = x[i]
            e0 -= 2.0 * c[i] * a0[i]
            for j in range(kv):
                e0 += a0[i] * G[i, j] * a0[j]
        energy[v] = e
        energy0[v] = max(e0, 0.0)


def geometric_nonnegative(asset, influences, alpha0, ridge: float, balance: str = "clips",
                          clip_scale: np.ndarray | None = None) -> tuple[np.ndarray, dict]:
    """Per-vertex non-negative geometric weights on ``influences`` (module docstring); the example frames
    weighted by ``balance`` and ``clip_scale`` (:func:`rigslim.numerics.clip_balance.fit_transforms`).

    Returns
    -------
    alpha : (m, k) array
        Zero on padding slots; rows sum to one.
    report : dict
        ``energy`` and ``energy_start`` (at ``alpha0``) of the geometric energy with its ridge, ``ridge``.
    """
    import scipy.sparse as sp

    V = np.ascontiguousarray(asset.mesh.V, dtype=np.float64)
    sel = np.ascontiguousarray(influences.indices, dtype=np.int64)
    T, frame_weights = fit_transforms(asset, sel.shape[1], balance, clip_scale)
    A = sp.csr_matrix(asset.weights)
    valid = np.ascontiguousarray(influences.valid)
    nvalid = int(valid.sum())
    m, k = sel.shape
    sums = np.zeros(m)
    over_rows(_diagonal_rows, m, V, T, sel, valid, sums)
    eps = float(ridge * sums.sum() / nvalid) if nvalid else 0.0
    out = np.zeros((m, k))
    energy = np.zeros(m)
    energy0 = np.zeros(m)
    data = np.ascontiguousarray(A.data, dtype=np.float64)
    over_rows(_fit_rows, m, V, T, A.indptr.astype(np.int64), A.indices.astype(np.int64), data, sel, valid,
              np.ascontiguousarray(alpha0, dtype=np.float64), eps, out, energy, energy0)
    return out, {"energy": float(energy.sum()), "energy_start": float(energy0.sum()), "ridge": eps,
                 "balance": balance if frame_weights is not None else "frames"}
