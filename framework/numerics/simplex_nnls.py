"""Non-negative least squares on the simplex, compiled: Lawson & Hanson's active-set method with a sum-to-one row.

Per problem, with the Gram matrix ``G = B B^T`` and ``c = B y`` of a small basis,

    min_w  1/2 w^T G w - c^T w   s.t.  w >= 0,  1^T w = 1,  w_j = 0 outside ``allowed``,

solved by the Lawson & Hanson active-set method (Lawson & Hanson, *Solving Least Squares Problems*,
1974, ch. 23) adapted to the sum-to-one row: start from the single best variable, add the one whose
bound multiplier ``mu_j = g_j - g_F`` is most negative, and settle the free set by ``(|F| + 1)``-square
KKT solves. Numba kernels, called per vertex inside parallel loops: the ``best-fit`` selector's sparse
fits (:mod:`rigslim.plugins.selection.sparse_fit`) and the non-negative geometric solver
(:mod:`rigslim.plugins.solvers.geometric_kernel`).
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def _solve_inplace(K, r, size):  # pragma: no cover - numba
    """Gaussian elimination with partial pivoting on ``K[:size, :size] x = r[:size]``; x overwrites r."""
    for c in range(size):
        piv = c
        big = abs(K[c, c])
        for i in range(c + 1, size):
            if abs(K[i, c]) > big:
                big = abs(K[i, c])
                piv = i
        if piv != c:
            for j in range(size):
                t = K[c, j]
                K[c, j] = K[piv, j]
                K[piv, j] = t
            t = r[c]
            r[c] = r[piv]
            r[piv] = t
        if K[c, c] == 0.0:
            K[c, c] = 1e-300
        for i in range(c + 1, size):
            f = K[i, c] / K[c, c]
            if f != 0.0:
                for j in range(c, size):
                    K[i, j] -= f * K[c, j]
                r[i] -= f * r[c]
    for c in range(size - 1, -1, -1):
        s = r[c]
        for j in range(c + 1, size):
            s -= K[c, j] * r[j]
        r[c] = s / K[c, c]


@njit(cache=True)
def _inverse(K, size):  # pragma: no cover - numba
    """Inverse of ``K[:size, :size]`` (Gauss-Jordan with partial pivoting; K is overwritten)."""
    Kinv = np.eye(size)
    for c in range(size):
        piv = c
        big = abs(K[c, c])
        for i in range(c + 1, size):
            if abs(K[i, c]) > big:
                big = abs(K[i, c])
                piv = i
        if piv != c:
            for j in range(size):
                t = K[c, j]
                K[c, j] = K[piv, j]
                K[piv, j] = t
                t = Kinv[c, j]
                Kinv[c, j] = Kinv[piv, j]
                Kinv[piv, j] = t
        if K[c, c] == 0.0:
            K[c, c] = 1e-300
        d = 1.0 / K[c, c]
        for j in range(size):
            K[c, j] *= d
            Kinv[c, j] *= d
        for i in range(size):
            if i != c and K[i, c] != 0.0:
                f = K[i, c]
                for j in range(size):
                    K[i, j] -= f * K[c, j]
                    Kinv[i, j] -= f * Kinv[c, j]
    return Kinv


@njit(cache=True)
def _gradient(G, c, x, F, nf, g):  # pragma: no cover - numba
    """``g = G x - c`` (half the gradient of the fit error; ``x`` is zero outside ``F[:nf]``)."""
    n = G.shape[0]
    for a in range(n):
        s = -c[a]
        for i in range(nf):
            s += G[a, F[i]] * x[F[i]]
        g[a] = s


@njit(cache=True)
def _error(G, c, yy, x, F, nf):  # pragma: no cover - numba
    """``|B^T x - y|^2 = x^T G x - 2 c^T x + y^T y`` over the support ``F[:nf]``."""
    e = yy
    for i in range(nf):
        fi = F[i]
        e -= 2.0 * c[fi] * x[fi]
        for j in range(nf):
            e += x[fi] * G[fi, F[j]] * x[F[j]]
    return max(e, 0.0)


@njit(cache=True)
def _settle(G, c, x, F, nf, infree, ridge, max_outer, K, z, entering):  # pragma: no cover - numba
    """Inner loop of Lawson & Hanson: move ``x`` towards the sum-to-one minimiser on the free set
    ``F[:nf]``, dropping variables that reach zero, until that minimiser is feasible.
    Returns ``(nf, ok)``; ``ok`` is False when the ``entering`` variable (last of ``F``) was
    rejected at once (round-off: it cannot lower the error) and has been removed again."""
    for it in range(max_outer):
        for i in range(nf):
            for j in range(nf):
                K[i, j] = G[F[i], F[j]]
            K[i, i] += ridge
            K[i, nf] = 1.0
            K[nf, i] = 1.0
            z[i] = c[F[i]]
        K[nf, nf] = 0.0
        z[nf] = 1.0
        _solve_inplace(K, z, nf + 1)
        if it == 0 and entering >= 0 and z[nf - 1] <= 0.0:
            infree[entering] = False
            return nf - 1, False
        alpha = 1.0
        for i in range(nf):
            if z[i] <= 0.0:
                xi = x[F[i]]
                t = xi / (xi - z[i])
                if t < alpha:
                    alpha = t
        for i in range(nf):
            x[F[i]] += alpha * (z[i] - x[F[i]])
        if alpha >= 1.0:
            break
        # Drop the variables that reached zero (keep the order of the rest).
        keep = 0
        for i in range(nf):
            if x[F[i]] > 1e-15:
                F[keep] = F[i]
                keep += 1
            else:
                x[F[i]] = 0.0
                infree[F[i]] = False
        nf = keep
    return nf, True


@njit(cache=True)
def _lawson_hanson(G, c, yy, allowed, x, F, nf, tol, ridge, max_outer, K, z, settle):  # pragma: no cover
    """Sum-to-one NNLS ``min x^T G x - 2 c^T x`` over the ``allowed`` variables, from the feasible ``x``
    whose free set is ``F[:nf]`` (``x`` and ``F`` are updated in place; ``K``, ``z`` are scratch).
    ``settle``: first move to the minimiser on ``F`` (when ``x`` is not yet optimal there).
    Returns ``(nf, squared error)``."""
    n = G.shape[0]
    g = np.empty(n)
    infree = np.zeros(n, dtype=np.bool_)
    for i in range(nf):
        infree[F[i]] = True
    if settle:
        nf, _ = _settle(G, c, x, F, nf, infree, ridge, max_outer, K, z, -1)
    for _ in range(max_outer):
        _gradient(G, c, x, F, nf, g)
        gF = 0.0
        for i in range(nf):
            gF += g[F[i]]
        gF /= max(nf, 1)
        best = -1
        bestmu = -tol
        for a in range(n):
            if allowed[a] and not infree[a]:
                mu = g[a] - gF
                if mu < bestmu:
                    bestmu = mu
                    best = a
        if best < 0:
            break
        F[nf] = best
        infree[best] = True
        nf, ok = _settle(G, c, x, F, nf + 1, infree, ridge, max_outer, K, z, best)
        if not ok:
            break
    return nf, _error(G, c, yy, x, F, nf)
