"""Non-negative least squares on the simplex, compiled: Lawson & Hanson's active-set method with a sum-to-one row.

Per problem, with the Gram matrix ``G = B B^T`` and ``c = B y`` of a small basis,

    min_w  1/2 w^T G w - c^T w   s.t.  w >= 0,  1^T w = 1,  w_j = 0 outside ``allowed``,

solved by the Lawson & Hanson active-set method (Lawson & Hanson, *Solving Least Squares Problems*,
1974, ch. 23) adapted to the sum-to-one row: start from the single best variable, add the one whose
bound multiplier ``mu_j = g_j - g_F`` is most negative, and settle the free set by ``(|F| + 1)``-square
KKT solves. Numba kernels, called per vertex inside row kernels that run on threads
(:mod:`rigslim.numerics.row_threads`): the ``best-fit`` selector's sparse fits
(:mod:`rigslim.plugins.selection.sparse_fit`) and the non-negative geometric solver
(:mod:`rigslim.plugins.solvers.geometric_kernel`).

Compilation: numba compiles a kernel once per distinct argument *type*, and a constant passed from
another kernel has its own literal type (``Literal[int](1)``, ``Literal[bool](True)``), so each call
site with other constants would compile the whole method again. :func:`_lawson_hanson` therefore
turns its count and flag into plain ``int64`` / ``bool`` values before anything it calls sees them,
and is one function (the inner settle loop and the KKT solve written in it, not called): a numba
caller re-optimises every kernel it calls with its own module, so each level of calls is paid again.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def _inverse(K, size):  # pragma: no cover - numba
    """Inverse of ``K[:size, :size]`` (Gauss-Jordan with partial pivoting; K is overwritten)."""
    Kinv = np.zeros((size, size))
    for c in range(size):
        Kinv[c, c] = 1.0
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
def _lawson_hanson(G, c, yy, allowed, x, F, nf, tol, ridge, max_outer, K, z, settle):  # pragma: no cover
    """Sum-to-one NNLS ``min x^T G x - 2 c^T x`` over the ``allowed`` variables, from the feasible ``x``
    whose free set is ``F[:nf]`` (``x`` and ``F`` are updated in place; ``K``, ``z`` are scratch).
    ``settle``: first move to the minimiser on ``F`` (when ``x`` is not yet optimal there).
    Returns ``(nf, squared error)``, the error ``|B^T x - y|^2 = x^T G x - 2 c^T x + y^T y``.

    Outer loop: the variable of most negative bound multiplier ``mu_j = g_j - g_F`` (``g = G x - c``,
    ``g_F`` its mean on the free set) enters. Inner loop (settle): move ``x`` towards the sum-to-one
    minimiser ``z`` on the free set (the KKT system ``[G_FF + ridge I, 1; 1^T, 0] [z; nu] = [c_F; 1]``,
    Gaussian elimination with partial pivoting), by the largest step ``alpha <= 1`` that keeps
    ``x >= 0``, dropping the variables that reach zero, until ``z`` is feasible. An entering variable
    that the first KKT solve gives a weight ``<= 0`` (round-off: it cannot lower the error) is removed
    again and the method stops.
    """
    n = G.shape[0]
    nfree = np.int64(nf)    # plain int64 / bool whatever the caller passed: one compilation of the loops
    pending = np.bool_(settle)
    entering = np.int64(-1)
    g = np.empty(n)
    infree = np.zeros(n, dtype=np.bool_)
    for i in range(nfree):
        infree[F[i]] = True
    outer = 0
    while True:
        if pending:
            ok = True
            for it in range(max_outer):
                for i in range(nfree):
                    for j in range(nfree):
                        K[i, j] = G[F[i], F[j]]
                    K[i, i] += ridge
                    K[i, nfree] = 1.0
                    K[nfree, i] = 1.0
                    z[i] = c[F[i]]
                K[nfree, nfree] = 0.0
                z[nfree] = 1.0
                size = nfree + 1
                for col in range(size):
                    piv = col
                    big = abs(K[col, col])
                    for i in range(col + 1, size):
                        if abs(K[i, col]) > big:
                            big = abs(K[i, col])
                            piv = i
                    if piv != col:
                        for j in range(size):
                            t = K[col, j]
                            K[col, j] = K[piv, j]
                            K[piv, j] = t
                        t = z[col]
                        z[col] = z[piv]
                        z[piv] = t
                    if K[col, col] == 0.0:
                        K[col, col] = 1e-300
                    for i in range(col + 1, size):
                        f = K[i, col] / K[col, col]
                        if f != 0.0:
                            for j in range(col, size):
                                K[i, j] -= f * K[col, j]
                            z[i] -= f * z[col]
                for col in range(size - 1, -1, -1):
                    s = z[col]
                    for j in range(col + 1, size):
                        s -= K[col, j] * z[j]
                    z[col] = s / K[col, col]
                if it == 0 and entering >= 0 and z[nfree - 1] <= 0.0:
                    infree[entering] = False
                    nfree -= 1
                    ok = False
                    break
                alpha = 1.0
                for i in range(nfree):
                    if z[i] <= 0.0:
                        xi = x[F[i]]
                        t = xi / (xi - z[i])
                        if t < alpha:
                            alpha = t
                for i in range(nfree):
                    x[F[i]] += alpha * (z[i] - x[F[i]])
                if alpha >= 1.0:
                    break
                # Drop the variables that reached zero (keep the order of the rest).
                keep = 0
                for i in range(nfree):
                    if x[F[i]] > 1e-15:
                        F[keep] = F[i]
                        keep += 1
                    else:
                        x[F[i]] = 0.0
                        infree[F[i]] = False
                nfree = keep
            if not ok:
                break
        if outer == max_outer:
            break
        outer += 1
        _gradient(G, c, x, F, nfree, g)
        gF = 0.0
        for i in range(nfree):
            gF += g[F[i]]
        gF /= max(nfree, 1)
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
        F[nfree] = best
        infree[best] = True
        nfree += 1
        entering = np.int64(best)
        pending = True
    e = yy
    for i in range(nfree):
        fi = F[i]
        e -= 2.0 * c[fi] * x[fi]
        for j in range(nfree):
            e += x[fi] * G[fi, F[j]] * x[F[j]]
    return nfree, max(e, 0.0)
