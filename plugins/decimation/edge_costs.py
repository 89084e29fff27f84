"""Compiled (numba) per-edge costs of the articulated simplifier: the new vertex, its weights and the error.

The numpy path (:mod:`rigslim.plugins.decimation.quadrics`, :mod:`rigslim.plugins.decimation.models`,
:func:`rigslim.plugins.decimation.collapse.simplify` with ``backend="numpy"``)
is the reference; these kernels compute the same things one edge at a time,
so that nothing is padded, no work is spent on converged edges and the
collapse loop runs without Python overhead. Tests check that both backends
give the same costs and the same hierarchy.

Per-edge cost (``method``):

- ``QUARTIC`` ([S09]): with ``Q^j = Q_a^j + Q_b^j`` and the edge's bones
  ``k`` (the union of the endpoints' non-zero weights), alternate

  * the position step: ``G = sum_j L_j^T Q^j L_j`` with
    ``L_j = [[sum_k a_k M_k^j], [0 0 0 1]]``, ``G = [[A, b], [b^T, c]]``,
    ``A v = -b`` (QSlim's candidates ``v_a, v_b, (v_a + v_b) / 2`` where A is
    singular, ``|det A| <= 1e-10 (tr A / 3)^3``);
  * the weight step: ``y_k^j = [M_k^j v; 1]``, ``H_kl = sum_j y_k^jT Q^j y_l^j``
    scaled to unit mean diagonal, then
    ``min_a 1/2 a^T (H + r I) a - r a0^T a`` s.t. ``1^T a = 1`` (and ``a >= 0``
    when non-negative), i.e. ``E + r/2 |a - a0|^2`` with the Tikhonov weight
    ``r = 1e-9``. The equality-constrained optimum solves
    ``a = (H + rI)^-1 (r a0 - lambda 1)`` with ``lambda`` from ``1^T a = 1``
    (a Cholesky factorisation of ``H + rI``). With ``a >= 0`` the exact
    optimum of the convex QP is found by a primal-dual active-set method
    (Hintermueller, Ito & Kunisch 2002), warm-started from the previous
    alternation's active set and checked by the KKT conditions
    ``a_F >= 0``, ``mu_A = (H a - r a0 + lambda 1)_A >= 0``; if it does not
    settle, the primal active-set method (Nocedal & Wright, Alg. 16.3), as in
    :func:`rigslim.numerics.small_qp.solve_small_qps`, takes over;

  until the error ``E(v, a) = sum_j [v_j; 1]^T Q^j [v_j; 1]``,
  ``v_j = sum_k a_k M_k^j [v; 1]``, falls by less than ``tol`` (relative);
  then the bone limit (keep the ``max_bones`` largest, renormalise, alternate
  again on that set) and optionally the endpoint candidates.
- ``MOHR_GLEICHER``: the endpoint ``e`` of least ``E(v_e, w_e)``.
- ``DECORO``: ``Qr_a + Qr_b`` (rest-frame quadrics), QSlim's optimal point,
  weights blended by distance ``w = (|v - v_b| w_a + |v - v_a| w_b) / (|v - v_a| + |v - v_b|)``.

:func:`edge_cost` is one edge; :func:`edge_costs` many, in threads. The numpy
reference is :class:`rigslim.plugins.decimation.models.QuarticModel` (and the
other models) over :mod:`rigslim.plugins.decimation.quadrics`.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from rigslim.plugins.decimation.setup import BEST, DECORO, KEEP_A, KEEP_B, MOHR_GLEICHER, QUARTIC

#: Floating-point flags of the hot loops: reassociation (vectorised sums) and fused multiply-adds;
#: no finite-math assumptions, so infinities and NaN keep their meaning.
FAST = {"reassoc", "contract", "nsz"}

__all__ = ["DECORO", "FAST", "MOHR_GLEICHER", "QUARTIC", "anchored_cost", "collapse_cost", "edge_cost", "edge_costs",
           "quadric_floor", "quadric_weight"]


@njit(cache=True, fastmath=FAST)
def _blend(a, Tb, K, X):
    """``X_j = sum_k a_k Tb_k^j`` for the first K bones; X (P, 3, 4)."""
    P = X.shape[0]
    for j in range(P):
        for r in range(3):
            for c in range(4):
                X[j, r, c] = 0.0
    for k in range(K):
        ak = a[k]
        for j in range(P):
            for r in range(3):
                for c in range(4):
                    X[j, r, c] += ak * Tb[k, j, r, c]


@njit(cache=True, fastmath=FAST)
def _gram(Qe, X, G):
    """``G = sum_j L_j^T Q^j L_j`` with ``L_j = [[X_j], [0 0 0 1]]`` (symmetric; upper triangle mirrored)."""
    P = X.shape[0]
    M = np.empty((4, 4))
    for r in range(4):
        for c in range(4):
            G[r, c] = 0.0
    for j in range(P):
        for r in range(4):                   # M = Q_j L_j
            for c in range(3):
                M[r, c] = Qe[j, r, 0] * X[j, 0, c] + Qe[j, r, 1] * X[j, 1, c] + Qe[j, r, 2] * X[j, 2, c]
            M[r, 3] = Qe[j, r, 0] * X[j, 0, 3] + Qe[j, r, 1] * X[j, 1, 3] + Qe[j, r, 2] * X[j, 2, 3] + Qe[j, r, 3]
        for r in range(3):                   # G += L_j^T M
            for c in range(r, 4):
                G[r, c] += X[j, 0, r] * M[0, c] + X[j, 1, r] * M[1, c] + X[j, 2, r] * M[2, c]
        G[3, 3] += X[j, 0, 3] * M[0, 3] + X[j, 1, 3] * M[1, 3] + X[j, 2, 3] * M[2, 3] + M[3, 3]
    for r in range(4):
        for c in range(r):
            G[r, c] = G[c, r]


@njit(cache=True)
def _qform(G, p0, p1, p2):
    """``[p; 1]^T G [p; 1]``."""
    t0 = G[0, 0] * p0 + G[0, 1] * p1 + G[0, 2] * p2 + G[0, 3]
    t1 = G[1, 0] * p0 + G[1, 1] * p1 + G[1, 2] * p2 + G[1, 3]
    t2 = G[2, 0] * p0 + G[2, 1] * p1 + G[2, 2] * p2 + G[2, 3]
    t3 = G[3, 0] * p0 + G[3, 1] * p1 + G[3, 2] * p2 + G[3, 3]
    return p0 * t0 + p1 * t1 + p2 * t2 + t3


@njit(cache=True)
def _solve3(G, v):
    """``A v = -b`` for ``G = [[A, b], ...]`` by Gaussian elimination with partial pivoting."""
    A = np.empty((3, 4))
    for r in range(3):
        for c in range(3):
            A[r, c] = G[r, c]
        A[r, 3] = -G[r, 3]
    for c in range(3):
        p = c
        for r in range(c + 1, 3):
            if abs(A[r, c]) > abs(A[p, c]):
                p = r
        if p != c:
            for t in range(4):
                A[c, t], A[p, t] = A[p, t], A[c, t]
        for r in range(c + 1, 3):
            f = A[r, c] / A[c, c]
            for t in range(c, 4):
                A[r, t] -= f * A[c, t]
    for r in range(2, -1, -1):
        s = A[r, 3]
        for t in range(r + 1, 3):
            s -= A[r, t] * v[t]
        v[r] = s / A[r, r]


@njit(cache=True)
def _position_step(G, fb, v):
    """Optimal point of the 4x4 quadric G (``A v = -b``), else the best of the candidates fb (3, 3)."""
    det = (G[0, 0] * (G[1, 1] * G[2, 2] - G[1, 2] * G[2, 1]) - G[0, 1] * (G[1, 0] * G[2, 2] - G[1, 2] * G[2, 0])
           + G[0, 2] * (G[1, 0] * G[2, 1] - G[1, 1] * G[2, 0]))
    scale = max((G[0, 0] + G[1, 1] + G[2, 2]) / 3.0, 1e-300)
    if abs(det) > 1e-10 * scale ** 3:
        _solve3(G, v)
        return False
    best, bi = np.inf, 0
    for i in range(fb.shape[0]):
        e = _qform(G, fb[i, 0], fb[i, 1], fb[i, 2])
        if e < best:
            best, bi = e, i
    for t in range(3):
        v[t] = fb[bi, t]
    return True


@njit(cache=True)
def _quartic_error(Qe, X, v):
    """``sum_j [p_j; 1]^T Q^j [p_j; 1]`` with ``p_j = X_j [v; 1]``."""
    E = 0.0
    for j in range(X.shape[0]):
        p0 = X[j, 0, 0] * v[0] + X[j, 0, 1] * v[1] + X[j, 0, 2] * v[2] + X[j, 0, 3]
        p1 = X[j, 1, 0] * v[0] + X[j, 1, 1] * v[1] + X[j, 1, 2] * v[2] + X[j, 1, 3]
        p2 = X[j, 2, 0] * v[0] + X[j, 2, 1] * v[1] + X[j, 2, 2] * v[2] + X[j, 2, 3]
        E += _qform(Qe[j], p0, p1, p2)
    return E


@njit(cache=True, fastmath=FAST)
def _weight_hessian(Qe, Tb, K, v, H, Pk, Uk):
    """``H_kl = sum_j y_k^jT Q^j y_l^j``, ``y_k^j = [M_k^j v; 1]``, scaled to unit mean diagonal.

    With ``Q^j = [[A_j, b_j], [b_j^T, c_j]]`` and ``p_k^j = M_k^j [v; 1]``:
    ``H_kl = sum_j p_k^j . u_l^j + s_l``, ``u_l^j = A_j p_l^j + b_j``,
    ``s_l = sum_j (b_j . p_l^j + c_j)``. Pk, Uk: (>= K, 3P) workspaces.
    """
    P = Qe.shape[0]
    S = np.empty(K)
    for k in range(K):
        sk = 0.0
        for j in range(P):
            p0 = Tb[k, j, 0, 0] * v[0] + Tb[k, j, 0, 1] * v[1] + Tb[k, j, 0, 2] * v[2] + Tb[k, j, 0, 3]
            p1 = Tb[k, j, 1, 0] * v[0] + Tb[k, j, 1, 1] * v[1] + Tb[k, j, 1, 2] * v[2] + Tb[k, j, 1, 3]
            p2 = Tb[k, j, 2, 0] * v[0] + Tb[k, j, 2, 1] * v[1] + Tb[k, j, 2, 2] * v[2] + Tb[k, j, 2, 3]
            Pk[k, 3 * j], Pk[k, 3 * j + 1], Pk[k, 3 * j + 2] = p0, p1, p2
            Uk[k, 3 * j] = Qe[j, 0, 0] * p0 + Qe[j, 0, 1] * p1 + Qe[j, 0, 2] * p2 + Qe[j, 0, 3]
            Uk[k, 3 * j + 1] = Qe[j, 1, 0] * p0 + Qe[j, 1, 1] * p1 + Qe[j, 1, 2] * p2 + Qe[j, 1, 3]
            Uk[k, 3 * j + 2] = Qe[j, 2, 0] * p0 + Qe[j, 2, 1] * p1 + Qe[j, 2, 2] * p2 + Qe[j, 2, 3]
            sk += Qe[j, 3, 0] * p0 + Qe[j, 3, 1] * p1 + Qe[j, 3, 2] * p2 + Qe[j, 3, 3]
        S[k] = sk
    n3 = 3 * P
    tr = 0.0
    for k in range(K):
        for l in range(k, K):
            s = S[l]
            for t in range(n3):
                s += Pk[k, t] * Uk[l, t]
            H[k, l] = s
            H[l, k] = s
        tr += H[k, k]
    s = tr / max(K, 1)
    if s > 0:
        for k in range(K):
            for l in range(K):
                H[k, l] /= s


@njit(cache=True)
def _solve_free(H, ridge, g, K, free, x, L, w, idx):
    """Minimise ``1/2 x^T (H + ridge I) x + g^T x`` s.t. ``sum x_F = 1``, ``x_A = 0`` (F: ``free``).

    Cholesky of ``(H + ridge I)_FF``; ``x_F = y - lambda z`` with ``(H + rI) y = -g``,
    ``(H + rI) z = 1`` and ``lambda = (1^T y - 1) / 1^T z``. Returns lambda.
    ``L`` (K, K), ``w`` (2, K) and ``idx`` (K,) are workspaces.
    """
    y = w[0]
    z = w[1]
    n = 0
    for k in range(K):
        if free[k]:
            idx[n] = k
            n += 1
    for i in range(n):
        for j in range(i + 1):
            s = H[idx[i], idx[j]] + (ridge if i == j else 0.0)
            for t in range(j):
                s -= L[i, t] * L[j, t]
            if i == j:
                L[i, i] = np.sqrt(s) if s > 0 else 1e-300
            else:
                L[i, j] = s / L[j, j]
    for i in range(n):                       # forward
        sy, sz = -g[idx[i]], 1.0
        for t in range(i):
            sy -= L[i, t] * y[t]
            sz -= L[i, t] * z[t]
        y[i], z[i] = sy / L[i, i], sz / L[i, i]
    for i in range(n - 1, -1, -1):           # backward
        sy, sz = y[i], z[i]
        for t in range(i + 1, n):
            sy -= L[t, i] * y[t]
            sz -= L[t, i] * z[t]
        y[i], z[i] = sy / L[i, i], sz / L[i, i]
    sy, sz = 0.0, 0.0
    for i in range(n):
        sy += y[i]
        sz += z[i]
    lam = (sy - 1.0) / sz
    for k in range(K):
        x[k] = 0.0
    for i in range(n):
        x[idx[i]] = y[i] - lam * z[i]
    return lam


@njit(cache=True)
def _gradient(H, ridge, g, K, x, lam, k):
    """``((H + ridge I) x + g)_k + lambda``: the bound multiplier of variable k."""
    s = g[k] + ridge * x[k] + lam
    for t in range(K):
        s += H[k, t] * x[t]
    return s


@njit(cache=True)
def _weight_step(H, K, a0, nonneg, ridge, free, warm, x, L, w, idx):
    """The weight step on the scaled Hessian H (see the module docstring); ``free`` carries the active set.

    Returns True when the non-negativity constraints were active (so ``free`` is a useful warm start).
    """
    g = w[2]
    for k in range(K):
        g[k] = -ridge * a0[k]
    if not warm:
        for k in range(K):
            free[k] = True
    lam = _solve_free(H, ridge, g, K, free, x, L, w, idx)
    if not nonneg:
        return False
    if not warm:
        neg = False
        for k in range(K):
            if x[k] < 0.0:
                neg = True
        if not neg:
            return False
        for k in range(K):
            free[k] = x[k] >= 0.0
        lam = _solve_free(H, ridge, g, K, free, x, L, w, idx)
    # primal-dual active set
    for _it in range(2 * K + 5):
        rmax = 0.0
        for k in range(K):
            rmax = max(rmax, abs(_gradient(H, ridge, g, K, x, 0.0, k)))
        mtol = 1e-12 * (1.0 + rmax)
        change = False
        any_bound = False
        for k in range(K):
            if free[k]:
                if x[k] < -1e-14:
                    free[k] = False
                    change = True
            elif _gradient(H, ridge, g, K, x, lam, k) < -mtol:
                free[k] = True
                change = True
        if not change:
            for k in range(K):
                if x[k] < 0.0:
                    x[k] = 0.0
                if not free[k]:
                    any_bound = True
            return any_bound
        lam = _solve_free(H, ridge, g, K, free, x, L, w, idx)
    # did not settle: primal active set from the feasible start of rigslim.numerics.small_qp's path
    s = 0.0
    for k in range(K):
        x[k] = max(a0[k], 0.0)
        s += x[k]
    for k in range(K):
        x[k] = x[k] / s if s > 1e-12 else 1.0 / K
        free[k] = x[k] > 0.0
    xs = np.empty(K)
    for _it in range(3 * K + 10):
        lam = _solve_free(H, ridge, g, K, free, xs, L, w, idx)
        pmax, xmax = 0.0, 0.0
        for k in range(K):
            pmax = max(pmax, abs(xs[k] - x[k]))
            xmax = max(xmax, abs(x[k]))
        t, j = 1.0, -1
        if pmax > 1e-12 * (1.0 + xmax):
            for k in range(K):
                p = xs[k] - x[k]
                if free[k] and p < 0:
                    r = -x[k] / p
                    if r < t:
                        t, j = r, k
            for k in range(K):
                x[k] = max(x[k] + t * (xs[k] - x[k]), 0.0)
            if j >= 0:
                x[j] = 0.0
                free[j] = False
                continue
        else:
            for k in range(K):
                x[k] = max(xs[k], 0.0)
        rmax = 0.0
        for k in range(K):
            rmax = max(rmax, abs(_gradient(H, ridge, g, K, x, 0.0, k)))
        jm, mu_min = -1, np.inf
        for k in range(K):
            if not free[k]:
                mu = _gradient(H, ridge, g, K, x, lam, k)
                if mu < mu_min:
                    mu_min, jm = mu, k
        if jm < 0 or mu_min >= -1e-12 * (1.0 + rmax):
            break
        free[jm] = True
    return True


@njit(cache=True)
def _alternate(Qe, Tb, K, a_start, fb, iterations, tol, nonneg, ridge, v_best, a_best):
    """Alternate position and weight steps from ``a_start`` on K bones; returns the best error."""
    P = Qe.shape[0]
    X = np.empty((P, 3, 4))
    G = np.empty((4, 4))
    H = np.empty((K, K))
    L = np.empty((K, K))
    v = np.empty(3)
    a = np.empty(K)
    free = np.ones(K, np.bool_)
    w = np.empty((3, K))
    idx = np.empty(K, np.int64)
    _blend(a_start, Tb, K, X)
    _gram(Qe, X, G)
    _position_step(G, fb, v)
    best = _quartic_error(Qe, X, v)
    v_best[:] = v
    a_best[:K] = a_start[:K]
    warm = False
    Pk = np.empty((K, 3 * P))
    Uk = np.empty((K, 3 * P))
    for _ in range(iterations):
        _weight_hessian(Qe, Tb, K, v, H, Pk, Uk)
        warm = _weight_step(H, K, a_start, nonneg, ridge, free, warm, a, L, w, idx)
        _blend(a, Tb, K, X)
        _gram(Qe, X, G)
        _position_step(G, fb, v)
        E = _quartic_error(Qe, X, v)
        old = best
        if E < old:
            best = E
            v_best[:] = v
            a_best[:K] = a[:K]
        gain = (old - E) / max(abs(old), 1e-300)
        if not gain > tol:
            break
    return best


@njit(cache=True)
def _top(a, K, mask, n, keep):
    """``keep``: the n largest of ``a`` where ``mask`` (ties: lower index first, as a stable argsort)."""
    for k in range(K):
        keep[k] = False
    for _ in range(n):
        j, best = -1, -np.inf
        for k in range(K):
            if mask[k] and not keep[k] and (j < 0 or a[k] > best):
                j, best = k, a[k]
        if j < 0:
            break
        keep[j] = True


@njit(cache=True)
def _bone_limit(a, K, mask, n, out, keep):
    """Keep the n largest weights and renormalise (``rigslim.plugins.decimation.quadrics.bone_limit`` for one row)."""
    _top(a, K, mask, n, keep)
    s = 0.0
    for k in range(K):
        out[k] = a[k] if keep[k] else 0.0
        s += out[k]
    if abs(s) < 1e-9:
        s = 0.0
        for k in range(K):
            out[k] = abs(out[k])
            s += out[k]
    for k in range(K):
        out[k] /= s


@njit(cache=True)
def _endpoint_error(Qe, T, w, p):
    """Quartic error of keeping a vertex (position p, dense weights w) under the edge quadrics."""
    P, n = T.shape[0], T.shape[1]
    E = 0.0
    X = np.empty((3, 4))
    for j in range(P):
        for r in range(3):
            for c in range(4):
                s = 0.0
                for k in range(n):
                    if w[k] != 0.0:
                        s += w[k] * T[j, k, r, c]
                X[r, c] = s
        q = np.empty(3)
        for r in range(3):
            q[r] = X[r, 0] * p[0] + X[r, 1] * p[1] + X[r, 2] * p[2] + X[r, 3]
        E += _qform(Qe[j], q[0], q[1], q[2])
    return E


@njit(cache=True)
def edge_cost(method, ia, ib, V, W, Qv, T, ip, fp, v_out, w_out):
    """Cost of collapsing vertices ia, ib (``method``: QUARTIC, MOHR_GLEICHER or DECORO).

    Writes the new vertex's position to ``v_out`` (3,) and dense weights to ``w_out`` (n,);
    returns the cost (clamped at 0). ``ip = [iterations, max_bones or -1, nonnegative, endpoints]``,
    ``fp = [tol, ridge]``.
    """
    P, n = T.shape[0], T.shape[1]
    Qe = Qv[ia] + Qv[ib]
    fb = np.empty((3, 3))
    for t in range(3):
        fb[0, t], fb[1, t] = V[ia, t], V[ib, t]
        fb[2, t] = 0.5 * (V[ia, t] + V[ib, t])
    max_bones = ip[1]
    if method == MOHR_GLEICHER:
        ea = _endpoint_error(Qe, T, W[ia], V[ia])
        eb = _endpoint_error(Qe, T, W[ib], V[ib])
        e = ib if eb < ea else ia
        v_out[:] = V[e]
        w_out[:] = W[e]
        return max(min(ea, eb), 0.0)
    if method == DECORO:
        v = np.empty(3)
        _position_step(Qe[0], fb, v)
        da = np.sqrt((v[0] - fb[0, 0]) ** 2 + (v[1] - fb[0, 1]) ** 2 + (v[2] - fb[0, 2]) ** 2)
        db = np.sqrt((v[0] - fb[1, 0]) ** 2 + (v[1] - fb[1, 1]) ** 2 + (v[2] - fb[1, 2]) ** 2)
        s = da + db
        ta = db / s if s > 0 else 0.5
        w = np.empty(n)
        for k in range(n):
            w[k] = ta * W[ia, k] + (1.0 - ta) * W[ib, k]
        if max_bones >= 0 and n > max_bones:
            mask = w != 0.0
            keep = np.empty(n, np.bool_)
            _bone_limit(w.copy(), n, mask, max_bones, w, keep)
        v_out[:] = v
        w_out[:] = w
        return max(_qform(Qe[0], v[0], v[1], v[2]), 0.0)
    # QUARTIC
    iterations, nonneg, endpoints = ip[0], ip[2] != 0, ip[3] != 0
    tol, ridge = fp[0], fp[1]
    bones = np.empty(n, np.int64)
    K = 0
    for k in range(n):
        if W[ia, k] != 0.0 or W[ib, k] != 0.0:
            bones[K] = k
            K += 1
    Tb = np.empty((K, P, 3, 4))
    a0 = np.empty(K)
    for i in range(K):
        k = bones[i]
        a0[i] = 0.5 * (W[ia, k] + W[ib, k])
        for j in range(P):
            Tb[i, j] = T[j, k]
    v = np.empty(3)
    a = np.empty(K)
    E = 0.0
    for _ in range(2):                       # one call site: the kernel is compiled (inlined) once
        E = _alternate(Qe, Tb, K, a0, fb, iterations, tol, nonneg, ridge, v, a)
        if max_bones < 0:
            break
        nz = 0
        for i in range(K):
            if a[i] != 0.0:
                nz += 1
        if nz <= max_bones:
            break
        # bone limit: keep the max_bones largest, renormalise, alternate again on that set
        mask = np.ones(K, np.bool_)
        keep = np.empty(K, np.bool_)
        lim = np.empty(K)
        _bone_limit(a, K, mask, max_bones, lim, keep)
        K2 = 0
        for i in range(K):
            if keep[i]:
                bones[K2] = bones[i]
                Tb[K2] = Tb[i]
                a0[K2] = lim[i]
                K2 += 1
        K = K2
    for k in range(n):
        w_out[k] = 0.0
    for i in range(K):
        w_out[bones[i]] = a[i]
    v_out[:] = v
    E = max(E, 0.0)
    if endpoints:
        for e in (ia, ib):
            Ee = max(_endpoint_error(Qe, T, W[e], V[e]), 0.0)
            if Ee < E:
                E = Ee
                v_out[:] = V[e]
                w_out[:] = W[e]
    return E


@njit(cache=True)
def anchored_cost(method, ia, ib, keep, V, W, Qv, T, v_out, w_out):
    """Cost of a half-edge collapse of (ia, ib) onto ``keep`` (one of them): its position and weights stay.

    ``E(v_keep, w_keep)`` under the edge's summed quadrics (``QUARTIC``, ``MOHR_GLEICHER``: every pose;
    ``DECORO``: the rest-frame quadric).
    """
    Qe = Qv[ia] + Qv[ib]
    v_out[:] = V[keep]
    w_out[:] = W[keep]
    if method == DECORO:
        return max(_qform(Qe[0], V[keep, 0], V[keep, 1], V[keep, 2]), 0.0)
    return max(_endpoint_error(Qe, T, W[keep], V[keep]), 0.0)


@njit(cache=True)
def collapse_cost(method, ia, ib, place, V, W, Qv, T, ip, fp, v_out, w_out):
    """The cost of collapsing (ia, ib) with a :func:`rigslim.plugins.decimation.setup.placement`.

    ``FREE``: :func:`edge_cost`; ``KEEP_A`` / ``KEEP_B``: :func:`anchored_cost` onto that end; ``BEST``:
    the cheaper of the two (ties: a). With ``fp[3]`` non-zero the cost is normalised, ``E / (w_a + w_b)``
    (:func:`quadric_weight`). Costs below ``fp[2]`` (round-off,
    :func:`rigslim.plugins.decimation.setup.zero_cost`) are 0, so that both backends order them alike.
    """
    if place == KEEP_A:
        E = anchored_cost(method, ia, ib, ia, V, W, Qv, T, v_out, w_out)
    elif place == KEEP_B:
        E = anchored_cost(method, ia, ib, ib, V, W, Qv, T, v_out, w_out)
    elif place == BEST:
        E = anchored_cost(method, ia, ib, ia, V, W, Qv, T, v_out, w_out)
        Qe = Qv[ia] + Qv[ib]
        Eb = max(_qform(Qe[0], V[ib, 0], V[ib, 1], V[ib, 2]), 0.0) if method == DECORO else \
            max(_endpoint_error(Qe, T, W[ib], V[ib]), 0.0)
        if Eb < E and not (E < fp[2]):
            v_out[:] = V[ib]
            w_out[:] = W[ib]
            E = Eb
    else:
        E = edge_cost(method, ia, ib, V, W, Qv, T, ip, fp, v_out, w_out)
    if fp[3] != 0.0:                 # normalised: the mean squared distance over the merged planes
        w = quadric_weight(Qv, ia) + quadric_weight(Qv, ib)
        E = E / w if w > 0 else E
    return 0.0 if E < fp[2] else E


@njit(cache=True)
def quadric_weight(Qv, v):
    """``w_v = sum_j tr(Q_v^j[:3, :3])``: the total (area) weight of the planes in vertex v's quadrics."""
    s = 0.0
    for j in range(Qv.shape[1]):
        s += Qv[v, j, 0, 0] + Qv[v, j, 1, 1] + Qv[v, j, 2, 2]
    return s


@njit(cache=True)
def quadric_floor(Qv, a, b):
    """A lower bound of every collapse cost of the pair (a, b) before normalisation:
    ``sum_j min_p [p; 1]^T (Q_a^j + Q_b^j) [p; 1]`` over the poses j of ``Qv`` (m, P, 4, 4).

    Every method's error is ``sum_j [x_j; 1]^T Q^j [x_j; 1]`` at some point ``x_j`` per pose (the quartic's
    posed new vertex, an end point posed, DeCoro's rest point with one quadric), so it is at least the sum of
    the per-pose minima, whatever the weights, placement or bone limit. With ``Q^j = [[A, b], [b^T, c]]``:
    ``p* = -A^-1 b`` (cofactors), and since ``[p; 1]^T Q [p; 1] >= Q(p*) - r^T A^-1 r`` for the residual
    ``r = A p* + b`` of the computed p*, each pose adds ``Q(p*) - |r|^2 tr(A)^2 / (4 det A)``
    (``lambda_min >= 4 det / tr^2``) less a round-off margin of ``1e-9`` times the terms' magnitude, or 0
    where A is (nearly) singular or the result negative. So the floor never exceeds the true minimum.
    """
    total = 0.0
    for j in range(Qv.shape[1]):
        a00 = Qv[a, j, 0, 0] + Qv[b, j, 0, 0]
        a01 = Qv[a, j, 0, 1] + Qv[b, j, 0, 1]
        a02 = Qv[a, j, 0, 2] + Qv[b, j, 0, 2]
        a11 = Qv[a, j, 1, 1] + Qv[b, j, 1, 1]
        a12 = Qv[a, j, 1, 2] + Qv[b, j, 1, 2]
        a22 = Qv[a, j, 2, 2] + Qv[b, j, 2, 2]
        b0 = Qv[a, j, 0, 3] + Qv[b, j, 0, 3]
        b1 = Qv[a, j, 1, 3] + Qv[b, j, 1, 3]
        b2 = Qv[a, j, 2, 3] + Qv[b, j, 2, 3]
        cc = Qv[a, j, 3, 3] + Qv[b, j, 3, 3]
        c00 = a11 * a22 - a12 * a12
        c01 = a02 * a12 - a01 * a22
        c02 = a01 * a12 - a02 * a11
        c11 = a00 * a22 - a02 * a02
        c12 = a01 * a02 - a00 * a12
        c22 = a00 * a11 - a01 * a01
        det = a00 * c00 + a01 * c01 + a02 * c02
        tr = a00 + a11 + a22
        if not (tr > 0.0) or not (det > 1e-10 * (tr / 3.0) ** 3):
            continue                      # (nearly) singular: no better bound than 0
        p0 = -(c00 * b0 + c01 * b1 + c02 * b2) / det
        p1 = -(c01 * b0 + c11 * b1 + c12 * b2) / det
        p2 = -(c02 * b0 + c12 * b1 + c22 * b2) / det
        r0 = a00 * p0 + a01 * p1 + a02 * p2 + b0
        r1 = a01 * p0 + a11 * p1 + a12 * p2 + b1
        r2 = a02 * p0 + a12 * p1 + a22 * p2 + b2
        quad = p0 * (a00 * p0 + a01 * p1 + a02 * p2) + p1 * (a01 * p0 + a11 * p1 + a12 * p2) + \
            p2 * (a02 * p0 + a12 * p1 + a22 * p2)
        lin = 2.0 * (b0 * p0 + b1 * p1 + b2 * p2)
        q = quad + lin + cc
        q -= (r0 * r0 + r1 * r1 + r2 * r2) * tr * tr / (4.0 * det)
        q -= 1e-9 * (abs(quad) + abs(lin) + abs(cc))
        if q > 0.0:
            total += q
    return total


@njit(cache=True, nogil=True)
def _edge_costs_into(method, ea, eb, place, V, W, Qv, T, ip, fp, v, w, E):
    """:func:`collapse_cost` of the edges ``(ea[i], eb[i])`` into v (B, 3), w (B, n), E (B,); releases the GIL."""
    for i in range(len(ea)):
        E[i] = collapse_cost(method, ea[i], eb[i], place[i], V, W, Qv, T, ip, fp, v[i], w[i])


def edge_costs(method, ea, eb, V, W, Qv, T, ip, fp, threads: int | None = None, place=None):
    """:func:`collapse_cost` of many edges: returns v (B, 3), w (B, n), E (B,).

    ``place`` (B,) int64: each edge's :func:`rigslim.plugins.decimation.setup.placement` (default
    ``FREE``). Large batches are split over ``threads`` Python threads (default: the CPU count), which run
    the compiled loop without the GIL.
    """
    import os
    from concurrent.futures import ThreadPoolExecutor

    ea = np.ascontiguousarray(ea, dtype=np.int64)
    eb = np.ascontiguousarray(eb, dtype=np.int64)
    place = np.zeros(len(ea), np.int64) if place is None else np.ascontiguousarray(place, dtype=np.int64)
    if len(fp) < 4:                 # no round-off threshold and no normalisation given: none
        fp = np.concatenate([fp, np.zeros(4 - len(fp))])
    B, n = len(ea), W.shape[1]
    v, w, E = np.empty((B, 3)), np.empty((B, n)), np.empty(B)
    threads = threads or os.cpu_count() or 1
    if threads == 1 or B < 4096:
        _edge_costs_into(method, ea, eb, place, V, W, Qv, T, ip, fp, v, w, E)
        return v, w, E
    parts = [p for p in np.array_split(np.arange(B), 8 * threads) if len(p)]   # small parts balance uneven costs

    def part(p):
        sl = slice(p[0], p[-1] + 1)
        _edge_costs_into(method, ea[sl], eb[sl], place[sl], V, W, Qv, T, ip, fp, v[sl], w[sl], E[sl])

    with ThreadPoolExecutor(threads) as pool:
        list(pool.map(part, parts))
    return v, w, E
