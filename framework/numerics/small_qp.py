"""Batched small quadratic programs: many independent k-variable QPs at once.

Every problem of the batch is

    minimise    1/2 x^T H x + g^T x
    subject to  C x = d                (q equality rows, q = 1..4)
                x >= 0                 (optional, per problem)

with k small (up to ~16). The weight-reduction local solver ([P10] sec. 3,
docs/algorithms.md section 2) solves one such QP per vertex of a colour class;
the articulated simplifier's weight step can reuse it. This is the numpy
reference of the OpenCL kernel ``kernels/small_qp.cl`` (same algorithm,
same iteration order, so both return the same active sets).

Method
------
Exact primal active set for the bounds (Nocedal & Wright, *Numerical
Optimization*, Algorithm 16.3), vectorised over the batch:

1. start from a feasible ``x`` (given, or the equality-constrained
   minimiser when there are no bounds); the working set ``W`` holds the
   variables at zero;
2. solve the equality-constrained step
   ``min_p 1/2 p^T H p + (H x + g)^T p  s.t.  C p = 0, p_W = 0``
   through its KKT system (``k + q`` unknowns, Gaussian elimination);
3. if ``p != 0``: move ``x += t p`` with the largest ``t <= 1`` that keeps
   ``x >= 0``, and add the blocking variable to ``W``;
   if ``p == 0``: the bound multipliers are ``mu_W = (H x + g + C^T lambda)_W``;
   stop when all ``mu_W >= 0`` (KKT holds, so ``x`` is the global optimum of
   the convex QP), else release the variable of most negative ``mu``.

Redundant equality rows (e.g. linear precision on a degenerate set) are
tolerated through a tiny negative diagonal ``-delta I`` in the KKT system's
constraint block (``delta = 1e-13 |C|^2 / max diag H``), which selects the
least-squares multipliers; one step of iterative refinement against the
exact system then restores ``C p = 0`` to round-off.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Relative size of the KKT system's constraint-block regularisation.
KKT_DELTA = 1e-13
#: A step shorter than this (relative to 1 + |x|) counts as zero.
STEP_TOL = 1e-12


@dataclass
class QPResult:
    """Solutions of a batch of small QPs.

    Attributes
    ----------
    x : (B, k) array
        Minimisers.
    iterations : (B,) int array
        Active-set iterations used by each problem.
    converged : (B,) bool array
        False where the iteration limit was reached (``x`` is then feasible
        and lowers the objective, but the KKT conditions may not hold).
    """

    x: np.ndarray
    iterations: np.ndarray
    converged: np.ndarray


def _kkt_step(H, r, C, W, delta):
    """Solve ``[[H_FF, C_F^T], [C_F, -delta I]] [p_F; lam] = [-r_F; 0]`` with ``p_W = 0``.

    Returns the step ``p`` (B, k) and the equality multipliers ``lam`` (B, q).
    """
    nb, k, _ = H.shape
    q = C.shape[1]
    free = ~W
    K = np.zeros((nb, k + q, k + q))
    ff = free[:, :, None] & free[:, None, :]
    K[:, :k, :k] = np.where(ff, H, 0.0)
    diag = np.arange(k)
    K[:, diag, diag] = np.where(free, H[:, diag, diag], 1.0)
    Cf = np.where(free[:, None, :], C, 0.0)
    K[:, :k, k:] = Cf.transpose(0, 2, 1)
    K[:, k:, :k] = Cf
    qd = np.arange(k, k + q)
    K[:, qd, qd] = -delta[:, None]
    rhs = np.zeros((nb, k + q))
    rhs[:, :k] = np.where(free, -r, 0.0)
    sol = np.linalg.solve(K, rhs[..., None])
    # One step of iterative refinement against the exact (delta = 0) system.
    K[:, qd, qd] = 0.0
    sol = sol + np.linalg.solve(np.where(np.isin(np.arange(k + q), qd)[None, :, None]
                                         & np.isin(np.arange(k + q), qd)[None, None, :],
                                         -delta[:, None, None] * np.eye(k + q)[None], K),
                                rhs[..., None] - K @ sol)
    sol = sol[..., 0]
    return sol[:, :k], sol[:, k:]


def solve_small_qps(H, g, C, d, nonneg=False, x0=None, max_iter: int | None = None) -> QPResult:
    """Solve a batch of small equality- and bound-constrained convex QPs exactly.

    Parameters
    ----------
    H : (B, k, k) array
        Symmetric, positive definite on the null space of the free
        constraints (add a small ridge when in doubt).
    g : (B, k) array
    C : (B, q, k) array
        Equality constraint rows (q >= 1).
    d : (B, q) array
    nonneg : bool or (B,) bool array
        Which problems also require ``x >= 0``.
    x0 : (B, k) array, optional
        A feasible start (``C x0 = d``, and ``x0 >= 0`` where ``nonneg``).
        Required when any problem is non-negative; ignored otherwise.
    max_iter : int, optional
        Active-set iteration limit (default ``3 k + 10``).

    Returns
    -------
    QPResult

    Notes
    -----
    Without bounds the solution is one step of the KKT system
    ``[[H, C^T], [C, 0]] [p; lambda] = [-(H x0 + g); 0]`` from a feasible
    ``x0`` (the given one, else ``C^+ d``), so ``C x = d`` holds to round-off. With bounds, the primal
    active set method of the module docstring; each problem stops at the
    first iterate where ``p = 0`` and every bound multiplier
    ``mu_l = (H x + g + C^T lambda)_l``, ``l in W``, is non-negative.

    Example
    -------
    >>> H = np.eye(2)[None]; g = np.array([[-2.0, 1.0]])
    >>> C = np.ones((1, 1, 2)); d = np.ones((1, 1))
    >>> solve_small_qps(H, g, C, d, nonneg=True, x0=np.full((1, 2), 0.5)).x
    array([[1., 0.]])
    """
    H = np.asarray(H, dtype=np.float64)
    g = np.asarray(g, dtype=np.float64)
    C = np.asarray(C, dtype=np.float64)
    d = np.asarray(d, dtype=np.float64)
    nb, k = g.shape
    nonneg = np.broadcast_to(np.asarray(nonneg, dtype=bool), (nb,))
    delta = _kkt_regularisation(H, C)
    if x0 is None:
        if nonneg.any():
            raise ValueError("a feasible start x0 is needed when any problem is non-negative")
        # Least-norm point of C x = d, then one equality-constrained step from it.
        x0 = np.einsum("bkq,bq->bk", np.linalg.pinv(C), d)
    if not nonneg.any():
        x = np.array(x0, dtype=np.float64, copy=True)
        r = np.einsum("bij,bj->bi", H, x) + g
        p, _ = _kkt_step(H, r, C, np.zeros((nb, k), dtype=bool), delta)
        return QPResult(x + p, np.ones(nb, dtype=np.int64), np.ones(nb, dtype=bool))
    return _active_set(H, g, C, delta, nonneg, x0, 3 * k + 10 if max_iter is None else max_iter)


def _kkt_regularisation(H, C) -> np.ndarray:
    """``delta = KKT_DELTA |C|_F^2 / max_l |H_ll|`` (B,), the constraint block's ``-delta I`` (module docstring)."""
    k = H.shape[1]
    scale = np.abs(H[:, np.arange(k), np.arange(k)]).max(axis=1) + 1e-300
    cnorm = np.einsum("bqk,bqk->b", C, C) + 1e-300
    return KKT_DELTA * cnorm / scale


def _active_set(H, g, C, delta, nonneg, x0, max_iter: int) -> QPResult:
    """The primal active set iterations (module docstring, steps 1-3) from the feasible ``x0``.

    Each iteration solves the KKT step of the problems still active; problems whose step is zero, or a
    full step (``t = 1``), check their bound multipliers (:func:`_bound_multipliers`), the others move
    (:func:`_ratio_step`).
    """
    nb = len(g)
    iters = np.zeros(nb, dtype=np.int64)
    x = np.array(x0, dtype=np.float64, copy=True)
    W = nonneg[:, None] & (x <= 0.0)
    x = np.where(W, 0.0, x)
    done = np.zeros(nb, dtype=bool)
    act = np.arange(nb)
    for _it in range(max_iter):
        if act.size == 0:
            break
        Ha, Ca, xa, Wa = H[act], C[act], x[act], W[act]
        r = np.einsum("bij,bj->bi", Ha, xa) + g[act]
        p, lam = _kkt_step(Ha, r, Ca, Wa, delta[act])
        iters[act] += 1
        small = np.abs(p).max(axis=1) <= STEP_TOL * (1.0 + np.abs(xa).max(axis=1))
        # Moving problems: ratio test on the variables that decrease.
        mv = ~small
        full = np.zeros(len(act), dtype=bool)
        if mv.any():
            xa[mv], Wa[mv], block = _ratio_step(p[mv], xa[mv], Wa[mv], nonneg[act][mv])
            # A full step lands on the working set's minimiser: its multipliers
            # (from the same KKT solve) decide optimality right away.
            full[np.flatnonzero(mv)[~block]] = True
            r = r.copy()
            r[full] = r[full] + np.einsum("bij,bj->bi", Ha[full], p[full])
        # Stationary problems: check bound multipliers.
        st = small | full
        if st.any():
            idx = np.flatnonzero(st)
            opt, j = _bound_multipliers(r[idx], lam[idx], Ca[idx], Wa[idx])
            Wa[idx[~opt], j[~opt]] = False
            done[act[idx[opt]]] = True
        x[act] = xa
        W[act] = Wa
        act = act[~done[act]]
    return QPResult(x, iters, done)


def _ratio_step(p, x, W, nonneg):
    """Move ``x += t p`` with the largest ``t <= 1`` that keeps the bounded variables at or above zero.

    ``t = min(1, min_{l not in W, p_l < 0} -x_l / p_l)`` on problems with bounds (``nonneg``); where
    ``t < 1`` the blocking variable joins the working set ``W`` and is set to exactly zero, and
    round-off negatives of bounded problems are clipped.

    Parameters
    ----------
    p, x : (b, k) arrays
        Steps and iterates of the moving problems.
    W : (b, k) bool array
    nonneg : (b,) bool array

    Returns
    -------
    x, W : new (b, k) arrays
    blocked : (b,) bool array
        ``t < 1`` (a variable blocked the step).
    """
    limited = nonneg[:, None] & (p < 0) & ~W
    ratio = np.where(limited, -x / np.where(limited, p, -1.0), np.inf)
    j = np.argmin(ratio, axis=1)
    t = np.minimum(1.0, ratio[np.arange(len(j)), j])
    x = x + t[:, None] * p
    blocked = t < 1.0
    rows = np.flatnonzero(blocked)
    W = W.copy()
    W[rows, j[rows]] = True
    x[rows, j[rows]] = 0.0
    # Bound variables stay exactly at zero; round-off negatives are clipped.
    x = np.where(nonneg[:, None], np.maximum(x, 0.0), x)
    return x, W, blocked


def _bound_multipliers(r, lam, C, W):
    """Optimality of stationary problems: ``mu_W = (H x + g + C^T lambda)_W`` all ``>= -tol``.

    Parameters
    ----------
    r : (b, k) array
        ``H x + g`` at the working set's minimiser.
    lam : (b, q) array
        Equality multipliers of the KKT step.
    C : (b, q, k) array
    W : (b, k) bool array

    Returns
    -------
    optimal : (b,) bool array
        ``min_W mu >= -1e-12 (1 + |r|_inf)`` (KKT holds).
    release : (b,) int array
        The variable of most negative ``mu`` (to leave ``W`` where not optimal).
    """
    mu = r + np.einsum("bqk,bq->bk", C, lam)
    mu = np.where(W, mu, np.inf)
    release = np.argmin(mu, axis=1)
    mumin = mu[np.arange(len(release)), release]
    tol = 1e-12 * (1.0 + np.abs(r).max(axis=1))
    return mumin >= -tol, release
