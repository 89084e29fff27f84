"""The local solver of [P10]: per-vertex QPs in parallel Gauss-Seidel sweeps.

Holding every other vertex's weights fixed, the energy of
:mod:`rigslim.plugins.solvers.problem` is, in vertex v's weights
``x = alpha_v + delta``,

    E(alpha_v + delta) - E(alpha) = 2 delta^T h_v + delta^T H_v delta
    h_v = B_v^T (Q R)_v + eps (alpha_v - alpha0_v),   H_v = Q_vv B_v^T B_v + eps I

with ``R = X - Y``. Each update solves the k-variable QP
``min 1/2 x^T H_v x + (h_v - H_v alpha_v)^T x`` s.t. ``C_v x = d_v`` [, ``x >= 0``]
exactly (:func:`rigslim.numerics.small_qp.solve_small_qps`, or the OpenCL kernel
``small_qp.cl``), so the energy never increases. Vertices of one colour of
a distance-2 colouring (:mod:`rigslim.plugins.solvers.coloring`) share no term of ``Q``,
so they are solved as one batch; afterwards ``Q R`` is updated by
``Q[:, S] (Delta X_S)``. A sweep visits every colour once.

Convergence is measured: the energy decrease of each sweep is exact
(``sum_v 2 delta^T h_v + delta^T H_v delta``), and sweeps stop when the
relative decrease falls below ``tolerance``, when no weight moves by more
than 1e-12 in a sweep (a fixed point), or after ``max_sweeps``.
"""

from __future__ import annotations

import time

import numpy as np
import scipy.sparse as sp

from rigslim.numerics.small_qp import solve_small_qps
from rigslim.plugins.solvers.coloring import color_classes, distance2_coloring


def feasible_start(prob) -> tuple[np.ndarray, int]:
    """A point that satisfies every vertex's constraints, near the k-largest weights.

    Sum-to-one only: the k-largest weights (clipped at zero and renormalised
    when non-negative). With linear precision: the k-largest weights moved
    onto the affine set ``C_v x = d_v`` (``x += C_v^+ (d_v - C_v x)``); when
    non-negative too, a phase-1 QP ``min ||C_v x - d_v||^2 + tiny ||x - x0||^2``
    s.t. ``1^T x = 1, x >= 0``. Vertices whose influence sets cannot
    reproduce them with non-negative weights keep only the sum-to-one row
    (their linear-precision rows are zeroed in ``prob``).

    Returns
    -------
    alpha : (m, k) array
    dropped : int
        Vertices whose linear-precision rows were dropped.
    """
    a0 = prob.alpha0
    valid = prob.valid
    nvalid = np.maximum(valid.sum(axis=1, keepdims=True), 1)
    if prob.nonneg:
        a = np.maximum(a0, 0.0)
        s = a.sum(axis=1, keepdims=True)
        a = np.where(s > 1e-12, a / np.where(s > 1e-12, s, 1.0), valid / nvalid)
    else:
        a = a0.copy()
    if prob.C.shape[1] == 1:
        return a, 0
    C, d = prob.C, prob.d
    m, q, k = C.shape
    if not prob.nonneg:
        r = d - np.einsum("mqk,mk->mq", C, a)
        return a + np.einsum("mkq,mq->mk", np.linalg.pinv(C), r), 0
    # Phase 1 on the linear-precision rows, keeping sum to one and x >= 0.
    H = np.einsum("mqk,mql->mkl", C[:, 1:], C[:, 1:])
    scale = np.einsum("mkk->m", H) / k + 1e-300
    tiny = 1e-10 * scale
    kk = np.arange(k)
    H[:, kk, kk] += tiny[:, None]
    H = np.where(valid[:, :, None] & valid[:, None, :], H, 0.0)
    H[:, kk, kk] = np.where(valid, H[:, kk, kk], 1.0)
    g = -np.einsum("mqk,mq->mk", C[:, 1:], d[:, 1:]) - tiny[:, None] * a
    g = np.where(valid, g, 0.0)
    res = solve_small_qps(H, g, C[:, :1], d[:, :1], nonneg=True, x0=a)
    x = res.x
    miss = np.linalg.norm(np.einsum("mqk,mk->mq", C[:, 1:], x) - d[:, 1:], axis=1)
    size = np.linalg.norm(d[:, 1:], axis=1) + np.abs(C[:, 1:]).max(axis=(1, 2))
    bad = miss > 1e-7 * size
    if bad.any():
        prob.C[bad, 1:] = 0.0
        prob.d[bad, 1:] = 0.0
    x[bad] = a[bad]
    return x, int(bad.sum())


def kkt_residual(prob, alpha: np.ndarray) -> float:
    """Norm of the KKT residual of ``alpha`` (feasible) for ``min E  s.t.  C_v alpha_v = d_v [, alpha >= 0]``.

    With ``g = H alpha + f`` (:meth:`ReductionProblem.gradient`), per vertex
    the multipliers ``lambda_v`` are the least-squares solution of
    ``g_F + C_F^T lambda = 0`` on the free slots ``F`` (all valid slots, or
    those with ``alpha > 1e-10`` under non-negativity), ``s = g + C^T lambda``,
    and the residual collects ``s_F`` and, on slots at zero, ``min(s, 0)``
    (a negative bound multiplier). Zero exactly at the optimum.
    """
    g = prob.gradient(alpha)
    free = prob.valid & (alpha > 1e-10) if prob.nonneg else prob.valid.copy()
    C = np.where(free[:, None, :], prob.C, 0.0)
    gF = np.where(free, g, 0.0)
    if C.shape[1] == 1:
        cc = np.einsum("mqk,mqk->m", C, C)
        lam = -(np.einsum("mqk,mk->mq", C, gF) / np.where(cc > 0, cc, 1.0)[:, None])
    else:
        lam = -np.einsum("mqk,mk->mq", np.linalg.pinv(C.transpose(0, 2, 1)), gF)
    s = g + np.einsum("mqk,mq->mk", np.where(prob.valid[:, None, :], prob.C, 0.0), lam)
    res = np.where(free, s, np.where(prob.valid, np.minimum(s, 0.0), 0.0))
    return float(np.linalg.norm(res))


def vertex_classes(prob, adjacency) -> list[np.ndarray]:
    """Batches of independent vertices: one class when ``Q`` is diagonal, else the
    classes of a distance-2 colouring of the mesh graph."""
    if not prob.coupled:
        return [np.arange(prob.m)]
    return color_classes(distance2_coloring(adjacency))


def _relaxed_step(a, delta, omega, nonneg):
    """Step lengths ``min(omega, max feasible)`` per row (``a + t delta >= 0`` when non-negative)."""
    t = np.full(len(a), float(omega))
    if nonneg:
        neg = delta < 0
        ratio = np.where(neg, a / np.where(neg, -delta, 1.0), np.inf)
        t = np.minimum(t, ratio.min(axis=1, initial=np.inf))
        t = np.maximum(t, 1.0)
    return t


class _NumpyQP:
    """Batched small QPs in numpy (the reference)."""

    name = "numpy"

    def __init__(self, prob, H, order, bounds):
        self.prob, self.H = prob, H

    def solve(self, ci, S, g, x0):
        p = self.prob
        return solve_small_qps(self.H[S], g, p.C[S], p.d[S], nonneg=p.nonneg, x0=x0).x


class _OpenCLQP:
    """Batched small QPs in the OpenCL kernel ``small_qp.cl``; H, C, d live on the device."""

    def __init__(self, prob, H, order, bounds, device=None):
        from rigslim.plugins.solvers.opencl_qp import BatchedQP

        self.qp = BatchedQP(H[order], prob.C[order], prob.d[order], nonneg=prob.nonneg, device=device)
        self.bounds = bounds
        self.name = f"opencl: {self.qp.runtime.name}"

    def solve(self, ci, S, g, x0):
        lo, hi = self.bounds[ci], self.bounds[ci + 1]
        return self.qp.solve_range(lo, hi, g, x0)


def local_solve(prob, adjacency, alpha=None, *, tolerance: float = 1e-8, max_sweeps: int = 1000,
                backend: str = "numpy", device: str | None = None, progress=None,
                min_sweeps: int = 1, relaxation: float = 1.0) -> tuple[np.ndarray, dict]:
    """Gauss-Seidel sweeps of exact per-vertex QPs (see module docstring).

    Parameters
    ----------
    prob : ReductionProblem
    adjacency : (m, m) sparse matrix
        Mesh one-ring adjacency, for the distance-2 colouring.
    alpha : (m, k) array, optional
        Feasible start (default :func:`feasible_start`).
    tolerance : float
        Stop when a sweep lowers the energy by less than ``tolerance * E``.
    max_sweeps : int
    backend : {"numpy", "opencl"}
    device : str, optional
        OpenCL device spec (see :mod:`rigslim.device.opencl`).
    progress : callable, optional
        ``progress(iterable, total=, description=)`` wrapper of the sweep loop.
    relaxation : float
        Over-relaxation factor omega in [1, 2): each vertex moves ``t delta``
        with ``t = min(omega, largest feasible step)`` (>= 1, because the exact
        step is feasible). The energy along the line is a parabola with its
        minimum at t = 1, so any t in (0, 2) still lowers it (block SOR).

    Returns
    -------
    alpha : (m, k) array
    report : dict
        ``sweeps``, ``energy``, ``energy_start``, ``last_relative_decrease``,
        ``max_step`` (largest weight change in the last sweep), ``colors``,
        ``backend``, ``converged``, ``seconds``, ``energy_history``.
    """
    t0 = time.perf_counter()
    report: dict = {}
    if alpha is None:
        alpha, dropped = feasible_start(prob)
        if dropped:
            report["linear_precision_dropped"] = dropped
    alpha = np.array(alpha, dtype=np.float64, copy=True)
    if not prob.coupled:
        relaxation = 1.0  # independent vertices: the exact local step is the optimum
    sweeper = _ColourSweeps(prob, vertex_classes(prob, adjacency), backend, device, relaxation)
    _, QR = prob.residual_energy_terms(alpha)
    energy = prob.energy(alpha)
    E0 = energy
    history = [energy]
    rel = np.inf
    max_step = np.inf
    sweeps = 0
    converged = False
    loop = range(max_sweeps)
    if progress is not None:
        loop = progress(loop, total=max_sweeps, description="local sweeps")
    for _ in loop:
        dE, max_step = sweeper.sweep(alpha, QR)
        sweeps += 1
        new = energy + dE
        rel = (energy - new) / max(abs(new), 1e-300)
        energy = new
        history.append(energy)
        # Weights are dimensionless: a sweep that moves none by more than 1e-12 is a fixed point.
        if sweeps >= min_sweeps and (rel <= tolerance or max_step <= 1e-12 or not prob.coupled):
            converged = True
            break
    exact = prob.energy(alpha)
    report.update(sweeps=sweeps, energy=exact, energy_start=E0, last_relative_decrease=float(rel),
                  max_step=float(max_step), colors=len(sweeper.classes), backend=sweeper.qp.name,
                  converged=converged, seconds=time.perf_counter() - t0,
                  energy_history=[float(e) for e in history])
    return alpha, report


class _ColourSweeps:
    """One Gauss-Seidel sweep of exact per-vertex QPs over the colour classes (module docstring).

    Parameters
    ----------
    prob : ReductionProblem
    classes : list of (s,) int arrays
        Batches of vertices that share no term of ``Q`` (:func:`vertex_classes`).
    backend : {"numpy", "opencl"}
    device : str or None
        OpenCL device spec.
    relaxation : float
        Over-relaxation factor omega (:func:`local_solve`).
    """

    def __init__(self, prob, classes: list[np.ndarray], backend: str, device: str | None, relaxation: float):
        self.prob, self.classes, self.relaxation = prob, classes, relaxation
        self.H = prob.local_hessians()
        order = np.concatenate(classes)
        bounds = np.concatenate([[0], np.cumsum([len(S) for S in classes])])
        Qc = sp.csc_matrix(prob.Q)
        # Q's columns of each class, for the update Q R += Q[:, S] Delta X_S (its diagonal when uncoupled).
        self.Qcols = [sp.csr_matrix(Qc[:, S]) for S in classes] if prob.coupled else []
        self.Qdiag = prob.Q.diagonal()
        self.qp: _NumpyQP | _OpenCLQP
        if backend == "opencl":
            self.qp = _OpenCLQP(prob, self.H, order, bounds, device=device)
        elif backend == "numpy":
            self.qp = _NumpyQP(prob, self.H, order, bounds)
        else:
            raise ValueError(f"unknown backend {backend!r}")

    def sweep(self, alpha: np.ndarray, QR: np.ndarray) -> tuple[float, float]:
        """Visit every colour once, updating ``alpha`` and ``Q R`` in place.

        Per class ``S``: ``h_S = B_S^T (Q R)_S + eps (alpha_S - alpha0_S)``, the QPs' linear terms
        ``h_S - H_S alpha_S``, the (relaxed) step ``delta``, and the exact energy change
        ``2 delta^T h + delta^T H delta``.

        Returns
        -------
        dE : float
            Energy change of the sweep (<= 0).
        max_step : float
            Largest weight change.
        """
        prob, H = self.prob, self.H
        pad = ~prob.valid
        dE = 0.0
        max_step = 0.0
        for ci, S in enumerate(self.classes):
            BS = prob.B[S]
            a = alpha[S]
            h = np.einsum("skd,sd->sk", BS, QR[S]) + prob.eps * (a - prob.alpha0[S])
            h[pad[S]] = 0.0
            HS = H[S]
            g = h - np.einsum("skl,sl->sk", HS, a)
            x = self.qp.solve(ci, S, g, a)
            delta = x - a
            if self.relaxation != 1.0:
                delta = delta * _relaxed_step(a, delta, self.relaxation, prob.nonneg)[:, None]
                x = a + delta
            dE += float(2.0 * np.sum(h * delta) + np.einsum("sk,skl,sl->", delta, HS, delta))
            alpha[S] = x
            dX = np.einsum("skd,sk->sd", BS, delta)
            if prob.coupled:
                QR += self.Qcols[ci] @ dX
            else:
                QR[S] += self.Qdiag[S, None] * dX
            if delta.size:
                max_step = max(max_step, float(np.abs(delta).max()))
        return dE, max_step
