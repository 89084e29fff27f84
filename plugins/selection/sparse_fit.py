"""Per-vertex sparse fits of the example poses over all input influences (the ``best-fit`` kernel).

For vertex v with input influences ``S_v`` (the stored entries of row v of the
input weights ``A``), the basis of influence j in example pose p is
``b_j^p = T_j^p [v; 1]`` and the full deformation is ``y^p = sum_j a_{v,j} b_j^p``.
Stacking the p poses (D = 3p rows), the fit is

    min_w  ||B_v w - y_v||^2   s.t.  w >= 0,  1^T w = 1,  w_j = 0 for j not in S_v

([P10] eq. 3 over the whole input support instead of a fixed set). The input
weights themselves reach zero error when they are non-negative, so the fit
matters because of *which* optimum the method returns: the Lawson & Hanson
active-set method (Lawson & Hanson, *Solving Least Squares Problems*, 1974,
ch. 23), adapted to the sum-to-one row, starts from the single best influence
and adds, one at a time, the influence whose bound multiplier
``mu_j = g_j - g_F`` (``g = B^T (B w - y)``, ``g_F`` its common value on the
free set) is most negative, so it stops at a *sparse* optimum.

Two selections use it (``by``):

- ``weight``: the k influences with the largest weights of that fit;
- ``error``: greedy backward elimination from that fit's support: while more
  than k influences remain, drop the one whose removal raises the error of the
  (re-solved, warm-started) fit the least; influences the current fit gives
  zero weight go first, at no cost. When the support has at most k
  influences it is already the least-error set.

Implementation: numba kernels over a range of vertices that release the GIL,
run on threads over parts of the vertices (:func:`rigslim.numerics.row_threads.over_rows`); per vertex the
Gram matrix ``G = B_v B_v^T`` of the basis is formed once (for cages, whose
handle transforms are translations ``[0 | c_j]``, it is the same for every
vertex and is gathered from one handle Gram matrix), and the free-set systems
are ``(|F| + 1)``-square KKT solves on it. :func:`sparse_fit_reference` is the plain
Python/numpy reference of the same iteration (tests check both agree).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from rigslim.numerics.row_threads import over_rows
from rigslim.numerics.simplex_nnls import _gradient, _inverse, _lawson_hanson

#: Ridge of the free-set Gram matrix, relative to its largest diagonal entry.
RIDGE = 1e-12
#: Bound multipliers above ``-MU_TOL * max_j |b_j|^2`` count as non-negative (KKT holds).
MU_TOL = 1e-10
#: Up to this many handles the per-pair 4 x 4 matrices ``M_ab = sum_q (T_a^q)^T T_b^q`` are precomputed
#: (``16 n^2`` doubles) and ``G_ab = [v;1]^T M_ab [v;1]``; above it ``G = B B^T`` per vertex.
PAIR_MAX_HANDLES = 256


@njit(cache=True)
def _gram(v, V, T, cols, Gh, shared, pair):  # pragma: no cover - numba
    """Gram matrix ``G = B B^T`` (n, n) of vertex v's basis rows ``b_j = [T_j^1 [v;1]; ...; T_j^p [v;1]]``."""
    n = cols.shape[0]
    G = np.empty((n, n))
    if shared:
        # Translation-only handles (cages): the basis does not depend on the vertex.
        for a in range(n):
            for b in range(n):
                G[a, b] = Gh[cols[a], cols[b], 0, 0]
    elif pair:
        # G_ab = [v;1]^T M_ab [v;1] with M_ab = sum_q (T_a^q)^T T_b^q (4 x 4, precomputed).
        vt = np.empty(4)
        vt[0] = V[v, 0]
        vt[1] = V[v, 1]
        vt[2] = V[v, 2]
        vt[3] = 1.0
        for a in range(n):
            ha = cols[a]
            for b in range(a, n):
                hb = cols[b]
                s = 0.0
                for r in range(4):
                    t = 0.0
                    for q in range(4):
                        t += Gh[ha, hb, r, q] * vt[q]
                    s += vt[r] * t
                G[a, b] = s
                G[b, a] = s
    else:
        p = T.shape[0]
        B = np.empty((n, 3 * p))
        for a in range(n):
            h = cols[a]
            for q in range(p):
                for c in range(3):
                    B[a, 3 * q + c] = (T[q, h, c, 0] * V[v, 0] + T[q, h, c, 1] * V[v, 1] + T[q, h, c, 2] * V[v, 2]
                                       + T[q, h, c, 3])
        G = B @ B.T
    return G


@njit(cache=True, nogil=True)
def _vertex_system(v, V, T, cols, avals, Gh, shared, pair):  # pragma: no cover - numba
    """Vertex v's least-squares system over its influences ``cols`` with input weights ``avals``: the Gram
    matrix G (:func:`_gram`), ``c = G a``, ``y^T y = a^T G a``, and the tolerances scaled by G's largest
    diagonal entry (``MU_TOL``, ``RIDGE``), with the Lawson-Hanson iteration cap ``3 n + 10``."""
    n = cols.shape[0]
    G = _gram(v, V, T, cols, Gh, shared, pair)
    c = G @ avals
    yy = 0.0
    scale = 1e-300
    for a in range(n):
        yy += avals[a] * c[a]
        scale = max(scale, G[a, a])
    return G, c, yy, MU_TOL * scale, RIDGE * scale, 3 * n + 10


@njit(cache=True, nogil=True)
def _fit_rows(start, stop, V, T, indptr, indices, data, k, by_error, Gh, shared, pair,  # pragma: no cover - numba
              fit, member, errors, support):
    """Vertices ``start:stop``: the fit over each one's influences and, ``by_error``, backward elimination
    down to k; writes their entries of ``fit`` and ``member``, ``errors[v]`` and ``support[v]`` (the fit's
    free set size). Releases the GIL: :func:`sparse_fit` runs parts of the rows on threads."""
    for v in range(start, stop):
        lo = indptr[v]
        hi = indptr[v + 1]
        if hi == lo:
            continue
        n = hi - lo
        G, c, yy, tol, ridge, max_outer = _vertex_system(v, V, T, indices[lo:hi], data[lo:hi], Gh, shared, pair)
        K = np.empty((n + 1, n + 1))
        K2 = np.empty((n + 1, n + 1))
        z = np.empty(n + 1)
        x = np.zeros(n)
        F = np.zeros(n + 1, dtype=np.int64)
        Fc = np.zeros(n + 1, dtype=np.int64)
        allowed = np.ones(n, dtype=np.bool_)
        # Start: the single influence of least error G_jj - 2 c_j + y^T y (lowest index on ties).
        j0 = 0
        for a in range(1, n):
            if G[a, a] - 2.0 * c[a] < G[j0, j0] - 2.0 * c[j0]:
                j0 = a
        x[j0] = 1.0
        F[0] = j0
        nf, err = _lawson_hanson(G, c, yy, allowed, x, F, np.int64(1), tol, ridge, max_outer, K, z, np.bool_(False))
        support[v] = nf
        inset = x > 0.0
        if by_error and nf > k:
            x, err = _eliminate(G, c, yy, x, inset, err, nf, k, tol, ridge, max_outer, F, Fc, K, K2, z, allowed)
        for a in range(n):
            fit[lo + a] = x[a]
            member[lo + a] = inset[a]
        errors[v] = err


@njit(cache=True)
def _eliminate(G, c, yy, x, inset, err, nf, k, tol, ridge, max_outer, F, Fc, K, K2, z,  # pragma: no cover
               allowed):
    """Backward elimination from the fit's free set ``F[:nf]`` down to k: drop the influence whose removal
    raises the fit error least; ``inset`` is updated in place. Returns the final fit and its error."""
    n = G.shape[0]
    ns = nf
    have_inv = False
    Kinv = np.empty((1, 1))
    besti = 0
    bestneg = False
    while ns > k:
        bestj = -1
        for j in range(n):
            if inset[j] and x[j] == 0.0:
                bestj = j  # free: the fit does not use it
                break
        if bestj >= 0:
            inset[bestj] = False
            ns -= 1
            have_inv = False
            continue
        # Removing j from the free set P (= the set now) under the sum-to-one row alone raises the
        # error by x_j^2 / (K^-1)_jj (K the KKT matrix on P), a lower bound of the non-negative
        # fit's increase, exact when the downdated x stays >= 0. Candidates are tried by
        # increasing bound until the bound exceeds the best exact increase found.
        if not have_inv:
            nf = 0
            for a in range(n):
                if inset[a]:
                    F[nf] = a
                    nf += 1
            for i in range(nf):
                for j in range(nf):
                    K[i, j] = G[F[i], F[j]]
                K[i, i] += ridge
                K[i, nf] = 1.0
                K[nf, i] = 1.0
            K[nf, nf] = 0.0
            Kinv = _inverse(K, nf + 1)
        bound = np.empty(nf)
        for i in range(nf):
            xi = x[F[i]]
            bound[i] = xi * xi / max(Kinv[i, i], 1e-300)
        # Candidates by increasing bound (lowest position first on ties, NaN last: numba's argsort order for
        # up to 15 candidates), picked one at a time: no sort to compile. Only the minimum exact increase
        # matters, so past 15 the order among equal bounds can only pick another candidate of equal error.
        tried = np.zeros(nf, dtype=np.bool_)
        beste = np.inf
        bestx = x
        for _ in range(nf):
            i = -1
            for l in range(nf):
                if not tried[l] and (i < 0 or bound[l] < bound[i] or (bound[i] != bound[i] and bound[l] == bound[l])):
                    i = l
            tried[i] = True
            if err + bound[i] >= beste:
                break
            j = F[i]
            xc = x.copy()
            f = x[j] / max(Kinv[i, i], 1e-300)
            neg = False
            for l in range(nf):
                xc[F[l]] -= f * Kinv[l, i]
                if l != i and xc[F[l]] < 0.0:
                    neg = True
            xc[j] = 0.0
            if neg:
                for a in range(n):
                    allowed[a] = inset[a]
                    xc[a] = x[a]
                allowed[j] = False
                xc[j] = 0.0
                nfc = 0
                for a in range(n):
                    if xc[a] > 0.0:
                        xc[a] /= 1.0 - x[j]
                        Fc[nfc] = a
                        nfc += 1
                nfc, ec = _lawson_hanson(G, c, yy, allowed, xc, Fc, np.int64(nfc), tol, ridge, max_outer, K2, z,
                                         np.bool_(True))
            else:
                ec = err + bound[i]
            if ec < beste:
                beste = ec
                bestj = j
                besti = i
                bestx = xc
                bestneg = neg
        inset[bestj] = False
        ns -= 1
        x = bestx
        err = beste
        if bestneg:
            have_inv = False
        else:
            # The free set lost exactly F[besti]: downdate K^-1 (Schur complement), drop its row and column.
            size = nf + 1
            piv = Kinv[besti, besti]
            for r in range(size):
                if r != besti:
                    f = Kinv[r, besti] / piv
                    for q in range(size):
                        Kinv[r, q] -= f * Kinv[besti, q]
            keep = 0
            for r in range(size):
                if r == besti:
                    continue
                kq = 0
                for q in range(size):
                    if q == besti:
                        continue
                    Kinv[keep, kq] = Kinv[r, q]
                    kq += 1
                keep += 1
            for r in range(besti, nf - 1):
                F[r] = F[r + 1]
            nf -= 1
            have_inv = True
    return x, err


@njit(cache=True, nogil=True)
def _exchange_rows(start, stop, V, T, indptr, indices, data, k, swaps, Gh, shared, pair,  # pragma: no cover
                   fit, member, errors, support):
    """Exchange passes on the eliminated sets of vertices ``start:stop`` (``fit``, ``member``, ``errors`` of
    :func:`_fit_rows`, updated in place): the best swap of a member i for a non-member j that lowers the
    error. Releases the GIL."""
    for v in range(start, stop):
        lo = indptr[v]
        hi = indptr[v + 1]
        if hi == lo or support[v] <= k:
            continue  # no elimination ran: the fit's own support is already the least-error set
        n = hi - lo
        G, c, yy, tol, ridge, max_outer = _vertex_system(v, V, T, indices[lo:hi], data[lo:hi], Gh, shared, pair)
        K = np.empty((n + 1, n + 1))
        K2 = np.empty((n + 1, n + 1))
        z = np.empty(n + 1)
        F = np.zeros(n + 1, dtype=np.int64)
        Fc = np.zeros(n + 1, dtype=np.int64)
        allowed = np.ones(n, dtype=np.bool_)
        x = np.empty(n)
        inset = np.empty(n, dtype=np.bool_)
        for a in range(n):
            x[a] = fit[lo + a]
            inset[a] = member[lo + a]
        err = errors[v]
        g = np.empty(n)
        for _ in range(swaps):
            best_gain_e = err * (1.0 - 1e-9) - 1e-15 * yy
            besti = -1
            bestj = -1
            bestx = x
            for i in range(n):
                if not inset[i]:
                    continue
                for a in range(n):
                    allowed[a] = inset[a]
                allowed[i] = False
                xi = x.copy()
                nfi = 0
                if x[i] < 1.0:
                    xi[i] = 0.0
                    for a in range(n):
                        if xi[a] > 0.0:
                            xi[a] /= 1.0 - x[i]
                            Fc[nfi] = a
                            nfi += 1
                else:  # i carries everything: restart from the best other member
                    xi[i] = 0.0
                    j1 = -1
                    for a in range(n):
                        if allowed[a] and (j1 < 0 or G[a, a] - 2.0 * c[a] < G[j1, j1] - 2.0 * c[j1]):
                            j1 = a
                    if j1 < 0:
                        continue
                    xi[j1] = 1.0
                    Fc[0] = j1
                    nfi = 1
                nfi, _ = _lawson_hanson(G, c, yy, allowed, xi, Fc, np.int64(nfi), tol, ridge, max_outer, K2, z,
                                        np.bool_(True))
                _gradient(G, c, xi, Fc, nfi, g)
                gF = 0.0
                for l in range(nfi):
                    gF += g[Fc[l]]
                gF /= max(nfi, 1)
                for j in range(n):
                    if inset[j] or g[j] - gF >= -tol:
                        continue
                    for a in range(n):
                        allowed[a] = inset[a]
                    allowed[i] = False
                    allowed[j] = True
                    xc = xi.copy()
                    for l in range(nfi):
                        F[l] = Fc[l]
                    nfc, ec = _lawson_hanson(G, c, yy, allowed, xc, F, np.int64(nfi), tol, ridge, max_outer, K, z,
                                             np.bool_(False))
                    if ec < best_gain_e:
                        best_gain_e = ec
                        besti = i
                        bestj = j
                        bestx = xc
            if besti < 0:
                break
            inset[besti] = False
            inset[bestj] = True
            x = bestx
            err = best_gain_e
        for a in range(n):
            fit[lo + a] = x[a]
            member[lo + a] = inset[a]
        errors[v] = err


def sparse_fit(V, T, A, k: int, by: str = "weight", swaps: int = 0):
    """Sum-to-one NNLS fits of the example poses over each vertex's input influences.

    Parameters
    ----------
    V : (m, 3) array
        Rest positions.
    T : (p, n, 3, 4) array
        Example-pose handle transforms.
    A : (m, n) csr_matrix
        Input weights (sorted indices).
    k : int
    by : {"weight", "error"}
        ``error``: backward elimination from the fit's support down to k influences.
    swaps : int
        ``by: error``: passes of single exchanges after the elimination (a kernel of their own,
        compiled only when used).

    Returns
    -------
    fit : (nnz,) array
        Fitted weight of every stored entry of ``A`` (``by: error``: the fit on the final set).
    member : (nnz,) bool array
        ``by: error``: the final set (at most k per row); ``by: weight``: the fit's support.
    errors : (m,) array
        Squared example-pose error ``||B_v^T w - y_v||^2`` of that fit.
    """
    V = np.ascontiguousarray(V, dtype=np.float64)
    T = np.ascontiguousarray(T, dtype=np.float64)
    fit = np.zeros(A.nnz)
    member = np.zeros(A.nnz, dtype=bool)
    errors = np.zeros(V.shape[0])
    support = np.zeros(V.shape[0], dtype=np.int64)
    shared = not np.any(T[..., :3])
    pair = not shared and T.shape[1] <= PAIR_MAX_HANDLES
    if shared:
        Gh = np.einsum("pnc,plc->nl", T[..., 3], T[..., 3])[:, :, None, None]
    elif pair:
        Gh = np.ascontiguousarray(np.einsum("pacr,pbcs->abrs", T, T, optimize=True))
    else:
        Gh = np.zeros((1, 1, 1, 1))
    Gh = np.ascontiguousarray(Gh, dtype=np.float64)
    args = (V, T, A.indptr.astype(np.int64), A.indices.astype(np.int64),
            np.ascontiguousarray(A.data, dtype=np.float64), int(k))
    m = V.shape[0]
    over_rows(_fit_rows, m, *args, by == "error", Gh, bool(shared), bool(pair), fit, member, errors, support)
    if by == "error" and swaps > 0:
        over_rows(_exchange_rows, m, *args, int(swaps), Gh, bool(shared), bool(pair), fit, member, errors, support)
    return fit, member, errors


# --------------------------------------------------------------------------- numpy reference

def _reference_error(G, c, yy, x):
    return max(float(yy - 2.0 * c @ x + x @ G @ x), 0.0)


def _reference_lh(G, c, yy, allowed, x, F, tol, ridge, settle=False):
    """Python transcription of :func:`_lawson_hanson` (same order of operations)."""
    F = list(F)
    n = len(G)

    def inner(F, entering):
        for it in range(3 * n + 10):
            nf = len(F)
            K = np.zeros((nf + 1, nf + 1))
            K[:nf, :nf] = G[np.ix_(F, F)] + ridge * np.eye(nf)
            K[:nf, nf] = K[nf, :nf] = 1.0
            z = np.linalg.solve(K, np.r_[c[F], 1.0])[:nf]
            if it == 0 and entering and z[-1] <= 0.0:
                return F[:-1], False
            neg = z <= 0.0
            alpha = min(1.0, float(np.min(x[F][neg] / (x[F][neg] - z[neg]), initial=1.0)))
            x[F] += alpha * (z - x[F])
            if alpha >= 1.0:
                break
            x[[j for j in F if x[j] <= 1e-15]] = 0.0
            F = [j for j in F if x[j] > 1e-15]
        return F, True

    if settle:
        F, _ = inner(F, False)
    for _ in range(3 * n + 10):
        g = G[:, F] @ x[F] - c
        gF = g[F].mean()
        mu = np.where(allowed & ~np.isin(np.arange(n), F), g - gF, np.inf)
        best = int(np.argmin(mu))
        if not mu[best] < -tol:
            break
        F, ok = inner(F + [best], True)
        if not ok:
            break
    return x, F, max(float(yy - 2.0 * c @ x + x @ G @ x), 0.0)


def sparse_fit_reference(V, T, A, k: int, by: str = "weight", swaps: int = 0):
    """Numpy reference of :func:`sparse_fit` (a Python loop over vertices; for tests)."""
    A = A.tocsr()
    m = A.shape[0]
    fit = np.zeros(A.nnz)
    member = np.zeros(A.nnz, dtype=bool)
    errors = np.zeros(m)
    for v in range(m):
        lo, hi = A.indptr[v], A.indptr[v + 1]
        if hi == lo:
            continue
        cols = A.indices[lo:hi]
        Tv = T[:, cols]                                            # (p, n, 3, 4)
        B = (np.einsum("pncd,d->npc", Tv[..., :3], V[v]) + Tv[..., 3].transpose(1, 0, 2)).reshape(len(cols), -1)
        G = B @ B.T
        c = G @ A.data[lo:hi]
        yy = float(A.data[lo:hi] @ c)
        scale = max(float(G.diagonal().max()), 1e-300)
        tol, ridge = MU_TOL * scale, RIDGE * scale
        n = len(cols)
        x = np.zeros(n)
        j0 = int(np.argmin(G.diagonal() - 2.0 * c))
        x[j0] = 1.0
        x, F, e = _reference_lh(G, c, yy, np.ones(n, bool), x, [j0], tol, ridge)
        x0 = x.copy()
        inset = x > 0
        while by == "error" and inset.sum() > k:
            zero = np.flatnonzero(inset & (x == 0))
            if zero.size:
                inset[zero[0]] = False
                continue
            drop: tuple[float, int, np.ndarray] = (np.inf, -1, x)  # (error, dropped influence, fit)
            for j in map(int, np.flatnonzero(inset)):
                allowed = inset.copy()
                allowed[j] = False
                xc = x.copy()
                xc[j] = 0.0
                xc[xc > 0] /= 1.0 - x[j]
                xc, _, ec = _reference_lh(G, c, yy, allowed, xc, list(np.flatnonzero(xc > 0)), tol, ridge, True)
                if ec < drop[0]:
                    drop = (ec, j, xc)
            e, dropped, x = drop
            inset[dropped] = False
        for _ in range(swaps if by == "error" and (int((x0 > 0).sum())) > k else 0):
            # (error, leaving member, entering non-member, fit); an exchange must lower the error
            best: tuple[float, int, int, np.ndarray] = (e * (1.0 - 1e-9) - 1e-15 * yy, -1, -1, x)
            for i in map(int, np.flatnonzero(inset)):
                allowed = inset.copy()
                allowed[i] = False
                xi = x.copy()
                if x[i] < 1.0:
                    xi[i] = 0.0
                    xi[xi > 0] /= 1.0 - x[i]
                else:
                    xi[i] = 0.0
                    cand = np.flatnonzero(allowed)
                    if not cand.size:
                        continue
                    xi[cand[np.argmin(G.diagonal()[cand] - 2.0 * c[cand])]] = 1.0
                xi, Fi, _ = _reference_lh(G, c, yy, allowed, xi, list(np.flatnonzero(xi > 0)), tol, ridge, True)
                g = G[:, Fi] @ xi[Fi] - c
                gF = g[Fi].mean()
                for j in range(n):
                    if inset[j] or g[j] - gF >= -tol:
                        continue
                    allowed = inset.copy()
                    allowed[i] = False
                    allowed[j] = True
                    xc, _, ec = _reference_lh(G, c, yy, allowed, xi.copy(), Fi, tol, ridge)
                    if ec < best[0]:
                        best = (ec, i, j, xc)
            if best[1] < 0:
                break
            e, i, j, x = best
            inset[i] = False
            inset[j] = True
        fit[lo:hi] = x
        member[lo:hi] = inset
        errors[v] = e
    return fit, member, errors
