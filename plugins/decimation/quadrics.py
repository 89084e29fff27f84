"""Per-pose quadrics and the quartic error of articulated simplification ([S09], docs/algorithms.md sec. 4).

The functions are batched over edges: the alternating position / weight
solves of many edges at once are plain numpy array programs (the numpy
backend's, and the reference of :mod:`rigslim.plugins.decimation.edge_costs`);
the initial quadrics of every vertex in every pose are one compiled pass
over the faces (:func:`vertex_quadrics`, with :func:`vertex_quadrics_reference`).

Notation: ``P`` example poses, ``n`` bones, ``B`` edges in a batch, ``K``
bones in an edge's restricted set (padded to the batch's largest).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from numba import njit

from rigslim.numerics.blend import linear_blend

#: Weight of the border planes (:func:`border_quadrics`) relative to the faces' area weights.
BORDER_WEIGHT = 1.0


def homogeneous(T: np.ndarray) -> np.ndarray:
    """(..., 3, 4) affine transforms as (..., 4, 4) matrices with last row ``[0, 0, 0, 1]``."""
    out = np.zeros(T.shape[:-2] + (4, 4))
    out[..., :3, :] = T
    out[..., 3, 3] = 1.0
    return out


def face_planes(X: np.ndarray, F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit planes ``[n; d]`` (with ``n . x + d = 0`` on the face) and areas of the faces.

    Parameters
    ----------
    X : (..., m, 3) array
        Vertex positions (a leading axis, e.g. poses, is allowed).
    F : (f, 3) int array

    Returns
    -------
    planes : (..., f, 4) array
    areas : (..., f) array
    """
    p0, p1, p2 = X[..., F[:, 0], :], X[..., F[:, 1], :], X[..., F[:, 2], :]
    c = np.cross(p1 - p0, p2 - p0)
    norm = np.linalg.norm(c, axis=-1)
    n = c / np.maximum(norm, 1e-300)[..., None]
    d = -np.einsum("...i,...i->...", n, p0)
    return np.concatenate([n, d[..., None]], axis=-1), 0.5 * norm


def vertex_quadrics(X: np.ndarray, F: np.ndarray, area_weighted: bool = True) -> np.ndarray:
    """Fundamental quadrics of every vertex (Garland & Heckbert 1997), for one or many poses.

    Parameters
    ----------
    X : (m, 3) or (P, m, 3) array
        Vertex positions (in one pose, or a stack of poses).
    F : (f, 3) int array
    area_weighted : bool
        Weight each face's plane by its area (the usual QSlim refinement).

    Returns
    -------
    (m, 4, 4) or (m, P, 4, 4) array

    Notes
    -----
    ``Q_v = sum_{faces f at v} w_f [n_f; d_f][n_f; d_f]^T`` with ``w_f`` the
    face area (or 1), so ``p^T Q_v p`` is the (weighted) sum of squared
    distances of the homogeneous point p to the planes of v's faces.
    Compiled (:func:`_vertex_quadrics`: one pass over the faces per pose);
    :func:`vertex_quadrics_reference` is the numpy reference.
    """
    single = X.ndim == 2
    Xs = np.ascontiguousarray(X[None] if single else X, dtype=np.float64)
    F = np.ascontiguousarray(F, dtype=np.int64).reshape(-1, 3)
    Q = np.zeros((Xs.shape[1], Xs.shape[0], 4, 4))
    _vertex_quadrics(Xs, F, bool(area_weighted), Q)
    return Q[:, 0] if single else Q


@njit(cache=True)
def _vertex_quadrics(X, F, area_weighted, Q):  # pragma: no cover - numba
    """:func:`vertex_quadrics` into Q (m, P, 4, 4), zeroed: pose p's faces add ``w [n; d][n; d]^T`` to
    ``Q[:, p]`` of their corners, in face order."""
    pl = np.empty(4)
    for p in range(X.shape[0]):
        for f in range(F.shape[0]):
            a, b, c = F[f, 0], F[f, 1], F[f, 2]
            u0, u1, u2 = X[p, b, 0] - X[p, a, 0], X[p, b, 1] - X[p, a, 1], X[p, b, 2] - X[p, a, 2]
            v0, v1, v2 = X[p, c, 0] - X[p, a, 0], X[p, c, 1] - X[p, a, 1], X[p, c, 2] - X[p, a, 2]
            c0, c1, c2 = u1 * v2 - u2 * v1, u2 * v0 - u0 * v2, u0 * v1 - u1 * v0
            norm = np.sqrt(c0 * c0 + c1 * c1 + c2 * c2)
            s = max(norm, 1e-300)
            pl[0], pl[1], pl[2] = c0 / s, c1 / s, c2 / s
            pl[3] = -(pl[0] * X[p, a, 0] + pl[1] * X[p, a, 1] + pl[2] * X[p, a, 2])
            w = 0.5 * norm if area_weighted else 1.0
            for i in range(4):
                for j in range(4):
                    k = w * pl[i] * pl[j]
                    Q[a, p, i, j] += k
                    Q[b, p, i, j] += k
                    Q[c, p, i, j] += k


def vertex_quadrics_reference(X: np.ndarray, F: np.ndarray, area_weighted: bool = True) -> np.ndarray:
    """:func:`vertex_quadrics` in numpy: the planes of :func:`face_planes`, their outer products, and a sparse
    vertex-face incidence matrix that sums them at the corners."""
    single = X.ndim == 2
    Xs = X[None] if single else X
    planes, areas = face_planes(Xs, F)                      # (P, f, 4), (P, f)
    w = areas if area_weighted else np.ones_like(areas)
    K = np.einsum("pf,pfi,pfj->fpij", w, planes, planes)    # (f, P, 4, 4)
    f = len(F)
    m = Xs.shape[1]
    inc = sp.csr_matrix((np.ones(3 * f), (F.T.ravel(), np.tile(np.arange(f), 3))), shape=(m, f))
    Q = np.asarray(inc @ K.reshape(f, -1)).reshape(m, Xs.shape[0], 4, 4)
    return Q[:, 0] if single else Q


def border_quadrics(X: np.ndarray, F: np.ndarray, weight: float = BORDER_WEIGHT,
                    charts: np.ndarray | None = None, seam_weight: float = 0.0) -> np.ndarray:
    """Quadrics of the planes through every border (and seam) edge, perpendicular to its face, for every pose.

    Parameters
    ----------
    X : (P, m, 3) array
        Vertex positions in each pose.
    F : (f, 3) int array
    weight : float
        Relative weight: a border edge e of face f adds ``weight |e|^2 [n_e; d_e][n_e; d_e]^T`` to both
        its vertices, ``n_e = normalize(e x n_f)`` (the plane contains e and f's normal).
    charts : (f,) int array, optional
        Face charts (UV/material charts, :func:`rigslim.io.gltf.seams.face_charts`). An edge whose two
        faces lie in different charts is a seam edge: each of its faces adds its plane with ``seam_weight``.
    seam_weight : float
        Relative weight of the seam planes (0: none).

    Returns
    -------
    (m, P, 4, 4) array (zero where a vertex has no border or seam edge)

    Notes
    -----
    Garland & Heckbert 1997's boundary constraint planes, as meshoptimizer adds them: without them a
    collapse along a border (or onto it) of a flat part costs nothing, so a planar sheet's outline, a
    fin or an ear, is eaten from its edge. ``|e|^2`` has the units of the faces' area weights.
    Garland & Heckbert 1998 and Hoppe 1999 treat attribute discontinuities the same way: the seam
    planes make a seam vertex's error grow with its distance from the seam line, so a seam vertex may
    move, but along its seam (where both charts' textures stay where they were) far more cheaply than
    across it, and a seam corner (where two seam lines meet) is held by two planes.
    """
    P, m = X.shape[0], X.shape[1]
    E = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    opp = np.concatenate([F[:, 2], F[:, 0], F[:, 1]])
    key = np.sort(E, axis=1)
    _, inv, counts = np.unique(key[:, 0] * m + key[:, 1], return_inverse=True, return_counts=True)
    w_edge = np.where(counts[inv] == 1, weight, 0.0)
    if charts is not None and seam_weight > 0:
        ch = np.tile(np.asarray(charts, np.int64), 3)
        lo = np.full(len(counts), np.iinfo(np.int64).max)
        hi = np.full(len(counts), np.iinfo(np.int64).min)
        np.minimum.at(lo, inv, ch)
        np.maximum.at(hi, inv, ch)
        seam = (counts == 2) & (lo != hi)
        w_edge = np.where(seam[inv], seam_weight, w_edge)
    Q = np.zeros((m, P, 4, 4))
    on = w_edge > 0
    if not on.any():
        return Q
    a, b, c = E[on, 0], E[on, 1], opp[on]
    pa, pb, pc = X[:, a], X[:, b], X[:, c]                             # (P, k, 3)
    e = pb - pa
    nf = np.cross(e, pc - pa)
    n = np.cross(e, nf)
    ln = np.linalg.norm(n, axis=-1, keepdims=True)
    n = np.where(ln > 0, n / np.where(ln > 0, ln, 1.0), 0.0)
    d = -(n * pa).sum(axis=-1)
    plane = np.concatenate([n, d[..., None]], axis=-1)                 # (P, k, 4)
    w = w_edge[on][None] * (e * e).sum(axis=-1)                        # (P, k)
    K = np.einsum("pk,pki,pkj->kpij", w, plane, plane)
    np.add.at(Q, a, K)
    np.add.at(Q, b, K)
    return Q


def per_pose_quadrics(V: np.ndarray, F: np.ndarray, weights, T: np.ndarray, area_weighted: bool = True):
    """Quadrics of every vertex in every example pose, ``Q_v^j`` of [S09] eq. 2.

    Parameters
    ----------
    V : (m, 3) rest positions
    F : (f, 3) faces
    weights : (m, n) sparse matrix or ReducedWeights
        The skin weights that deform the input mesh.
    T : (P, n, 3, 4) array
        Bone transforms of the example poses.

    Returns
    -------
    Q : (m, P, 4, 4) array
    X : (P, m, 3) array
        The deformed positions (linear blend skinning) the planes come from.
    """
    X = np.stack([linear_blend(V, weights, T[j]) for j in range(len(T))])
    return vertex_quadrics(X, F, area_weighted), X


def _blend(a: np.ndarray, Tb: np.ndarray) -> np.ndarray:
    """(B, P, 3, 4) blended transforms ``sum_k a_k T_k`` from a (B, K) and Tb (B, K, P, 3, 4)."""
    B, K, P = Tb.shape[:3]
    return (a[:, None, :] @ Tb.reshape(B, K, P * 12)).reshape(B, P, 3, 4)


def _posed(X: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(B, P, 3) points ``X_j [v; 1]`` for X (B, P, 3, 4) and v (B, 3)."""
    return (X[..., :3] @ v[:, None, :, None])[..., 0] + X[..., 3]


def quadric_floor_reference(Q: np.ndarray) -> float:
    """:func:`rigslim.plugins.decimation.edge_costs.quadric_floor` in numpy, for the summed quadrics Q (P, 4, 4)
    of one pair: ``sum_j max(0, min_p [p; 1]^T Q^j [p; 1])``, the minimum ``c - b^T A^-1 b`` of each pose's
    quadric ``[[A, b], [b^T, c]]`` where A is well conditioned (``det A > 1e-10 (tr A / 3)^3``), else 0.

    A lower bound of every collapse cost of the pair (before normalisation): each method's error is a sum
    over the poses of the quadric at one point per pose. The compiled one keeps a round-off margin of
    ``1e-9`` of the terms' size below this value; the two agree to that.
    """
    A, b, c = Q[:, :3, :3], Q[:, :3, 3], Q[:, 3, 3]
    tr = np.trace(A, axis1=1, axis2=2)
    ok = (tr > 0) & (np.linalg.det(A) > 1e-10 * (tr / 3.0) ** 3)
    if not ok.any():
        return 0.0
    p = -np.linalg.solve(A[ok], b[ok][..., None])[..., 0]
    q = c[ok] + np.einsum("ji,ji->j", b[ok], p)
    return float(np.maximum(q, 0.0).sum())


def quadric_error(Q: np.ndarray, p: np.ndarray) -> np.ndarray:
    """``[p; 1]^T Q [p; 1]`` for batches: Q (..., 4, 4), p (..., 3)."""
    ph = np.concatenate([p, np.ones(p.shape[:-1] + (1,))], axis=-1)
    return (ph[..., None, :] @ Q @ ph[..., :, None])[..., 0, 0]


def quartic_error(Q: np.ndarray, Tb: np.ndarray, a: np.ndarray, v: np.ndarray) -> np.ndarray:
    """The quartic error of [S09] eq. 3 for a batch of candidate vertices.

    Parameters
    ----------
    Q : (B, P, 4, 4) array
        Per-pose quadrics of each edge (``Q_v1^j + Q_v2^j``).
    Tb : (B, K, P, 3, 4) array
        Transforms of each edge's bones in each pose (bone-major, so that
        blending and the weight step's products work on contiguous blocks).
    a : (B, K) array
        Weights over those bones (rows sum to one).
    v : (B, 3) array
        Rest positions.

    Returns
    -------
    (B,) array

    Notes
    -----
    ``E(v, a) = sum_j (sum_k a_k M_k^j v)^T Q^j (sum_k a_k M_k^j v)``.
    """
    return _quartic_error_blended(Q, _blend(a, Tb), v)


def _quartic_error_blended(Q: np.ndarray, X: np.ndarray, v: np.ndarray) -> np.ndarray:
    """:func:`quartic_error` from the blended transforms ``X = sum_k a_k M_k`` (B, P, 3, 4)."""
    return quadric_error(Q, _posed(X, v)).sum(axis=1)


def position_step(Q: np.ndarray, Tb: np.ndarray, a: np.ndarray, fallback: np.ndarray):
    """Optimal rest position for fixed weights ([S09] sec. 3.1), batched.

    Parameters
    ----------
    Q : (B, P, 4, 4), Tb : (B, K, P, 3, 4), a : (B, K)
    fallback : (B, c, 3) array
        Candidate points (e.g. the edge's endpoints and midpoint) used where
        the 3x3 system is singular, as QSlim does.

    Returns
    -------
    v : (B, 3) array
    singular : (B,) bool array

    Notes
    -----
    With ``L_j = [[X_j], [0 0 0 1]]`` the blended 4x4 transform of pose j,
    ``G = sum_j L_j^T Q^j L_j = [[A, b], [b^T, c]]`` and ``A v = -b``.
    """
    return _position_step_blended(Q, _blend(a, Tb), fallback)


def _position_step_blended(Q: np.ndarray, X: np.ndarray, fallback: np.ndarray):
    """:func:`position_step` from the blended transforms ``X = sum_k a_k M_k`` (B, P, 3, 4)."""
    L = np.zeros(X.shape[:2] + (4, 4))
    L[..., :3, :] = X
    L[..., 3, 3] = 1.0
    G = (np.swapaxes(L, -1, -2) @ Q @ L).sum(axis=1)
    A, rhs = G[:, :3, :3], -G[:, :3, 3]
    scale = np.trace(A, axis1=1, axis2=2) / 3.0
    det = np.linalg.det(A)
    singular = ~(np.abs(det) > 1e-10 * np.maximum(scale, 1e-300) ** 3)
    A_safe = np.where(singular[:, None, None], np.eye(3), A)
    v = np.linalg.solve(A_safe, rhs[..., None])[..., 0]
    if singular.any():
        s = np.flatnonzero(singular)
        c = fallback.shape[1]
        cand = fallback[s]                                          # (S, c, 3)
        e = np.stack([quadric_error(G[s], cand[:, i]) for i in range(c)], axis=1)
        v[s] = cand[np.arange(len(s)), np.argmin(e, axis=1)]
    return v, singular


#: Default Tikhonov weight of the weight step (see :func:`weight_step`); the compiled backend uses it too.
WEIGHT_RIDGE = 1e-9


def weight_step(Q: np.ndarray, Tb: np.ndarray, v: np.ndarray, a0: np.ndarray, mask: np.ndarray,
                method: str = "tikhonov", ridge: float = WEIGHT_RIDGE, nonnegative: bool = False) -> np.ndarray:
    """Minimum-norm weight offset for a fixed position ([S09] sec. 3.2), batched.

    Parameters
    ----------
    Q : (B, P, 4, 4), Tb : (B, K, P, 3, 4), v : (B, 3)
    a0 : (B, K) array
        Starting weights (a vertex's own, or the mean of an edge's endpoints').
    mask : (B, K) bool array
        Which of the K slots are bones of the restricted set (padding is False).
    method : {"tikhonov", "pinv"}
        ``"pinv"`` applies the Moore-Penrose pseudo-inverse of the KKT matrix
        (an eigendecomposition per edge, the exact formula); ``"tikhonov"``
        (default, ~8x faster) solves the KKT system with ``ridge * I`` added
        to the (scaled) H block, i.e. minimises
        ``E + ridge |da|^2`` under the constraint, whose solution tends to the
        minimum-norm minimiser as ``ridge -> 0``; the two agree except along
        directions whose curvature is below ``ridge`` (tested).
    ridge : float
        Tikhonov weight relative to H's mean diagonal.
    nonnegative : bool
        Also require ``a >= 0`` (skin weights engines accept). The step is then
        the small QP ``min a^T H a + ridge |a - a0|^2`` s.t. ``1^T a = 1``,
        ``a >= 0``, solved exactly by the batched active-set method
        (:func:`rigslim.numerics.small_qp.solve_small_qps`); ``method`` is ignored.

    Returns
    -------
    (B, K) array
        ``a = a0 + da``, zero on padding, rows summing to one.

    Notes
    -----
    ``V_j = [M_1^j v, ..., M_K^j v]`` (4 x K), ``H = sum_j V_j^T Q^j V_j`` and

        [da; lambda] = -pinv([[H, 1], [1^T, 0]]) [H a0; 0],

    the minimum-norm minimiser of ``(a0 + da)^T H (a0 + da)`` subject to
    ``1^T da = 0``. H is scaled to unit mean diagonal first (this does not
    change da) so one relative pseudo-inverse threshold fits every edge.
    """
    B, K, P = Tb.shape[:3]
    vh = np.concatenate([v, np.ones((B, 1))], axis=1)
    Yh = np.ones((B, P, K, 4))                                          # rows: (M_k^j v)^T, homogeneous
    Yh[..., :3] = (Tb.reshape(B, -1, 4) @ vh[:, :, None]).reshape(B, K, P, 3).transpose(0, 2, 1, 3)
    Yh *= mask[:, None, :, None]
    H = ((Yh @ Q) @ Yh.transpose(0, 1, 3, 2)).sum(axis=1)
    H = 0.5 * (H + np.swapaxes(H, 1, 2))
    kk = np.maximum(mask.sum(axis=1), 1)
    s = np.trace(H, axis1=1, axis2=2) / kk
    H = H / np.where(s > 0, s, 1.0)[:, None, None]
    if nonnegative:
        method = "tikhonov"   # the non-negative step minimises the Tikhonov objective
    KKT = np.zeros((B, K + 1, K + 1))
    KKT[:, :K, :K] = H
    KKT[:, :K, K] = mask
    KKT[:, K, :K] = mask
    rhs = np.zeros((B, K + 1))
    rhs[:, :K] = (H @ a0[..., None])[..., 0]
    if method == "pinv":
        sol = -(np.linalg.pinv(KKT, rcond=1e-10, hermitian=True) @ rhs[..., None])[..., 0]
    elif method == "tikhonov":
        KKT[:, np.arange(K), np.arange(K)] += ridge
        sol = -np.linalg.solve(KKT, rhs[..., None])[..., 0]
    else:
        raise ValueError(f"unknown weight-step method {method!r}")
    a = (a0 + sol[:, :K]) * mask
    if nonnegative:
        # The equality-constrained optimum is the answer wherever it is already non-negative
        # (convex problem); only the other edges need the active-set QP.
        neg = ((a < 0) & mask).any(axis=1)
        if neg.any():
            a[neg] = _nonnegative_weight_step(H[neg], a0[neg], mask[neg], ridge)
    return a


def _nonnegative_weight_step(H: np.ndarray, a0: np.ndarray, mask: np.ndarray, ridge: float) -> np.ndarray:
    """``min a^T H a + ridge |a - a0|^2`` s.t. ``1^T a = 1``, ``a >= 0``, ``a = 0`` off the mask."""
    from rigslim.numerics.small_qp import solve_small_qps

    B, K = a0.shape
    eye = np.eye(K)[None]
    pad = ~mask
    # Padding slots: cost x^2/2 + x on x >= 0 has its minimum at x = 0 and no coupling (H is zero there).
    Hq = H * (mask[:, :, None] & mask[:, None, :]) + ridge * eye * mask[:, None, :] + eye * pad[:, None, :]
    g = np.where(mask, -ridge * a0, 1.0)
    C = mask[:, None, :].astype(np.float64)
    d = np.ones((B, 1))
    x0 = np.where(mask, np.clip(a0, 0.0, None), 0.0)
    sums = x0.sum(axis=1, keepdims=True)
    uniform = mask / np.maximum(mask.sum(axis=1, keepdims=True), 1)
    x0 = np.where(sums > 1e-12, x0 / np.where(sums > 1e-12, sums, 1.0), uniform)
    return solve_small_qps(Hq, g, C, d, nonneg=True, x0=x0).x * mask


def bone_limit(a: np.ndarray, mask: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Keep the n largest weights of each row and renormalise ([S09] sec. 3.2, bone limit).

    Returns
    -------
    a : (B, K) array
        Rows with at most n non-zeros, summing to one.
    mask : (B, K) bool array
        The restricted bone sets.
    """
    B, K = a.shape
    if K <= n:
        return a, mask
    key = np.where(mask, a, -np.inf)
    top = np.argsort(-key, axis=1, kind="stable")[:, :n]
    keep = np.zeros_like(mask)
    np.put_along_axis(keep, top, True, axis=1)
    keep &= mask
    out = np.where(keep, a, 0.0)
    sums = out.sum(axis=1, keepdims=True)
    bad = np.abs(sums[:, 0]) < 1e-9
    if bad.any():   # the kept weights cancel out: fall back to their magnitudes
        out[bad] = np.abs(out[bad])
        sums[bad] = out[bad].sum(axis=1, keepdims=True)
    return out / sums, keep


def alternate(Q, Tb, a0, mask, fallback, *, iterations: int = 10, tol: float = 1e-6, max_bones: int | None = None,
              nonnegative: bool = False):
    """Alternating minimisation of the quartic error over position and weights, batched.

    Parameters
    ----------
    Q : (B, P, 4, 4) per-pose quadrics of each edge
    Tb : (B, K, P, 3, 4) transforms of each edge's bones
    a0 : (B, K) starting weights (rows sum to one)
    mask : (B, K) bool, the restricted bone sets
    fallback : (B, c, 3) candidate points for singular position steps
    iterations : int
        Most alternations (position step then weight step) per pass.
    tol : float
        Stop once no edge's error fell by more than ``tol`` (relative).
    max_bones : int, optional
        Bone limit: after the alternation keep the n largest weights,
        renormalise, and alternate again on that set.
    nonnegative : bool
        Weight steps keep ``a >= 0`` (see :func:`weight_step`).

    Returns
    -------
    v : (B, 3), a : (B, K), E : (B,)
        The best point and weights found and their error; E never exceeds
        the error of the first position step with ``a0``.
    """
    def run(a_start, m):
        X = _blend(a_start, Tb)                # shared by the position step and the error
        v, _ = _position_step_blended(Q, X, fallback)
        E = _quartic_error_blended(Q, X, v)
        best_v, best_a, best_E = v, a_start.copy(), E
        act = np.arange(len(a_start))          # edges still improving
        v_act = v
        for _ in range(iterations):
            if act.size == 0:
                break
            if act.size == len(a_start):           # all edges still active: no copies
                q, tb, fb = Q, Tb, fallback
            else:
                q, tb, fb = Q[act], Tb[act], fallback[act]
            a = weight_step(q, tb, v_act, a0=a_start[act], mask=m[act], nonnegative=nonnegative)
            X = _blend(a, tb)
            v_act, _ = _position_step_blended(q, X, fb)
            E_new = _quartic_error_blended(q, X, v_act)
            old = best_E[act]
            better = E_new < old
            gain = (old - E_new) / np.maximum(np.abs(old), 1e-300)
            upd = act[better]
            best_v[upd], best_a[upd], best_E[upd] = v_act[better], a[better], E_new[better]
            keep = gain > tol
            act, v_act = act[keep], v_act[keep]
        return best_v, best_a, best_E

    v, a, E = run(a0, mask)
    if max_bones is not None and (np.count_nonzero(np.abs(a) > 0, axis=1) > max_bones).any():
        over = np.count_nonzero(np.abs(a) > 0, axis=1) > max_bones
        a_lim, m_lim = bone_limit(a[over], mask[over], max_bones)
        v2, a2, E2 = alternate(Q[over], Tb[over], a_lim, m_lim, fallback[over], iterations=iterations, tol=tol,
                               nonnegative=nonnegative)
        v[over], a[over], E[over] = v2, a2, E2
    return v, a, E
