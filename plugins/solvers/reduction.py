"""The ``solve`` step of the optimising weight solvers ``geometric``, ``smooth`` and ``poisson`` ([P10] section 3).

:func:`solve_weights` assembles the method's energy (:mod:`rigslim.plugins.solvers.problem`) on the
asset's influence sets and minimises it with

- ``solver: global``: the equality-constrained optimum
  (:mod:`rigslim.plugins.solvers.global_solver`): sparse direct solve up to
  ``global_max_unknowns`` (m k) unknowns, multilevel-preconditioned CG
  (AMG-CG) above; not available with ``nonnegative``;
- ``solver: local``: [P10]'s per-vertex QPs. With equality constraints only
  and ``multilevel`` on (default), they are the smoother of a V-cycle that
  preconditions CG (:mod:`rigslim.plugins.solvers.multilevel_solver`);
  with ``multilevel: false``, plain parallel Gauss-Seidel sweeps over a
  distance-2 colouring (:mod:`rigslim.plugins.solvers.local_solver`), on
  numpy or OpenCL (``device``), from the k-largest weights. With
  non-negativity: the multilevel equality-only optimum projected per vertex
  onto the feasible set, then projected local sweeps (``multilevel: false``:
  sweeps from the k-largest weights);
- ``solver: auto``: global without non-negativity; with it, the global
  (direct or AMG-CG) optimum projected per vertex onto the feasible set (in
  each vertex's local Hessian metric), then local sweeps to convergence.

The step's report (metrics JSON ``solver`` section) holds the method, the
solver path, iterations, sweeps, energies, convergence, the KKT residual
and, when the equality-only optimum is known, the relative gap to it.
"""

from __future__ import annotations

import time

import numpy as np

from rigslim.errors import StepError
from rigslim.model.weights import ReducedWeights
from rigslim.numerics.clip_balance import example_clips
from rigslim.numerics.small_qp import solve_small_qps
from rigslim.plugins.solvers.geometric_kernel import geometric_nonnegative
from rigslim.plugins.solvers.global_solver import global_solve
from rigslim.plugins.solvers.local_solver import feasible_start, kkt_residual, local_solve
from rigslim.plugins.solvers.multilevel_solver import multilevel_solve
from rigslim.plugins.solvers.problem import build_problem, default_nonnegative, initial_weights
from rigslim.plugins.solvers.safeguards import failing_clips, guard_k_largest, pass_through

__all__ = ["REWEIGHT_FACTOR", "project_feasible", "solve_weights"]

#: The factor on a failing clip's example-frame weights per round of the validated reweighting.
REWEIGHT_FACTOR = 2.0


def project_feasible(prob, target, start) -> np.ndarray:
    """Per vertex, the feasible point nearest ``target`` in the local Hessian metric:
    ``min 1/2 (x - t)^T H_v (x - t)  s.t.  C_v x = d_v, x >= 0`` (exact small QPs)."""
    H = prob.local_hessians()
    g = -np.einsum("mkl,ml->mk", H, target)
    g = np.where(prob.valid, g, 0.0)
    return solve_small_qps(H, g, prob.C, prob.d, nonneg=prob.nonneg, x0=start).x


def solve_weights(asset, method: str, params, ctx=None) -> tuple[ReducedWeights, dict]:
    """Solve the weight values of one optimising method on the asset's influence sets.

    The ``solve`` step of the geometric, smooth and Poisson solvers: the influence sets are given
    (``asset.influences``); :func:`rigslim.reduce_weights` is the public select-and-solve on arrays.
    Then (:mod:`rigslim.plugins.solvers.safeguards`) the guard (``guard: k-largest``, with validation
    frames) and the pass-through of vertices with at most k input influences (their weights exactly).
    Returns the reduced weights and the solver's report (``fallback_vertices``, ``passed_through``).
    """
    t0 = time.perf_counter()
    reduced, report = _solve(asset, method, params, ctx)
    guard = getattr(params, "guard", "off")
    if guard != "off" and method != "smooth" and getattr(params, "reweight_rounds", 0) > 0:
        reduced, report = _reweighted(asset, method, params, ctx, reduced, report)
    if guard in ("k-largest", "k-largest-per-vertex"):
        reduced, grep = guard_k_largest(asset, reduced, per_vertex=guard == "k-largest-per-vertex")
        report.update(grep)
    reduced, report["passed_through"] = pass_through(asset.weights, reduced, asset.influences)
    report["seconds"] = time.perf_counter() - t0
    if ctx is not None and hasattr(ctx, "report"):
        ctx.report.update(report)
    return reduced, report


def _reweighted(asset, method: str, params, ctx, reduced: ReducedWeights, report: dict):
    """Validated reweighting: while some clip's validation error is above k-largest's by the guard's bound
    (:func:`rigslim.plugins.solvers.safeguards.failing_clips`), the weights of that clip's example frames
    are multiplied by :data:`REWEIGHT_FACTOR` and the energy is solved again, at most ``params.reweight_rounds``
    times. The guard then acts on the last solution. The report records the rounds and each clip's factor."""
    segments = getattr(asset.split, "segments", None) or []
    if example_clips(asset.split) is None or not list(asset.split.validation):
        return reduced, report
    scale = np.ones(len(segments))
    rounds = 0
    for _ in range(params.reweight_rounds):
        failing = failing_clips(asset, reduced)
        if not failing:
            break
        scale[failing] *= REWEIGHT_FACTOR
        reduced, report = _solve(asset, method, params, ctx, clip_scale=scale)
        rounds += 1
    report["reweight_rounds"] = rounds
    if rounds:
        report["clip_scale"] = [float(x) for x in scale]
    return reduced, report


def _solve(asset, method: str, params, ctx, clip_scale=None) -> tuple[ReducedWeights, dict]:
    """The optimum of ``method`` on the influence sets (:func:`solve_weights` before its safeguards), the
    example clips' frames weighted by ``params.balance`` and ``clip_scale``."""
    t0 = time.perf_counter()
    asset.require("mesh", "handles", "weights", "influences", step=f"solve: {method}")
    if method != "smooth":
        asset.require("poses", "split", step=f"solve: {method}")
    lp = _linear_precision(asset, method, params.linear_precision)
    nonneg = default_nonnegative(asset) if params.nonnegative is None else bool(params.nonnegative)
    if (method == "geometric" and nonneg and params.device == "numpy" and params.solver in ("auto", "local")
            and not (lp and asset.handles.is_cage)):
        return _geometric_per_vertex(asset, lp, params.ridge, t0, params.balance, clip_scale)
    prob = build_problem(asset, method, nonnegative=params.nonnegative,
                         laplacian=getattr(params, "laplacian", "mass-weighted"), linear_precision=lp,
                         position_weight=getattr(params, "position_weight", 0.0), ridge=params.ridge,
                         balance=params.balance, clip_scale=clip_scale)
    if params.solver == "global" and prob.nonneg:
        raise StepError("the global solver handles equality constraints only, and non-negativity is on",
                        field="solver", fix="use solver: auto or local, or set nonnegative: false")
    report = {"method": method, "nonnegative": prob.nonneg, "linear_precision": lp, **prob.info}
    alpha = _minimise(prob, asset.mesh, params, getattr(ctx, "progress", None), report)
    report.pop("energy_history", None)
    report["seconds"] = time.perf_counter() - t0
    alpha = np.where(asset.influences.valid, alpha, 0.0)
    if prob.nonneg:
        alpha = np.maximum(alpha, 0.0)
    return ReducedWeights.from_influences(asset.influences, alpha, asset.weights.shape[1]), report


def _linear_precision(asset, method: str, linear_precision: bool | None) -> bool:
    """Whether the energy also reproduces the rest position: as asked, by default only for ``smooth``,
    which on a cage needs it (without poses nothing else ties the weights to the shape)."""
    if method == "smooth" and asset.handles.is_cage:
        if linear_precision is False:
            raise StepError("smooth weights on a cage need linear precision (without poses nothing else "
                            "ties them to the shape)", field="linear_precision",
                            fix="remove 'linear_precision: false' or use the poisson or geometric solver")
        linear_precision = True
    return bool(linear_precision) if linear_precision is not None else method == "smooth"


def _geometric_per_vertex(asset, lp: bool, ridge: float, t0: float, balance: str = "clips",
                          clip_scale=None) -> tuple[ReducedWeights, dict]:
    """Non-negative geometric weights: independent per-vertex QPs with the sum-to-one row only,
    ``min ||sum_l alpha_l B_l - Y_v||^2  s.t.  1^T alpha = 1, alpha >= 0``, in the compiled kernel
    (:func:`rigslim.plugins.solvers.geometric_kernel.geometric_nonnegative`)."""
    alpha0 = initial_weights(asset.weights, asset.influences)
    alpha, rep = geometric_nonnegative(asset, asset.influences, alpha0, ridge, balance, clip_scale)
    report = {"method": "geometric", "nonnegative": True, "linear_precision": lp, "energy_name": "geometric",
              "constraints": 1, "example_poses": len(asset.split.examples), "path": "local",
              "backend": "numba", "sweeps": 1, "colors": 1, "converged": True, **rep,
              "seconds": time.perf_counter() - t0}
    alpha = np.maximum(np.where(asset.influences.valid, alpha, 0.0), 0.0)
    return ReducedWeights.from_influences(asset.influences, alpha, asset.weights.shape[1]), report


def _minimise(prob, mesh, params, progress, report: dict) -> np.ndarray:
    """Minimise ``prob`` on the path ``params.solver`` selects (module docstring); the path's figures
    go into ``report``.

    Paths: the global equality optimum (no non-negativity); local sweeps (uncoupled energies, or
    ``multilevel: false``); the multilevel equality optimum (``solver: local``, no non-negativity);
    else the equality optimum projected onto the feasible set, then local sweeps
    (:func:`_projected_local`).
    """
    backend = "numpy" if params.device == "numpy" else "opencl"
    cl_device = None if params.device in ("numpy", "opencl") else params.device
    sweep_args = dict(tolerance=params.tolerance, max_sweeps=params.max_sweeps, backend=backend,
                      device=cl_device, progress=progress, relaxation=params.relaxation)
    cg_args = dict(tolerance=params.residual_tolerance, max_iterations=params.max_iterations,
                   coordinates=mesh.V)

    def equality_optimum(kind, start):
        if kind == "global":
            return global_solve(prob, method="auto", max_direct_unknowns=params.global_max_unknowns,
                                start=start, **cg_args)
        alpha, rep = multilevel_solve(prob, start, **cg_args)
        return alpha, dict(solver="multilevel", **rep)

    if params.solver == "global" or (params.solver == "auto" and not prob.nonneg):
        alpha, rep = equality_optimum("global", None)
        report.update(path="global" if rep["solver"] == "direct" else "global: amg-cg", **rep)
        if rep["solver"] == "direct":
            report["gap"] = 0.0
    elif not prob.coupled or (params.solver == "local" and not params.multilevel):
        alpha, rep = local_solve(prob, mesh.adjacency, **sweep_args)
        report.update(path="local", **rep)
    elif params.solver == "local" and not prob.nonneg:
        start, _ = feasible_start(prob)
        alpha, rep = equality_optimum("local", start)
        report.update(path="local: multilevel", **rep)
    else:
        kind = "global" if params.solver == "auto" else "local"
        alpha = _projected_local(prob, mesh.adjacency, lambda start: equality_optimum(kind, start),
                                 sweep_args, params.solver, report)
    return alpha


def _projected_local(prob, adjacency, equality_optimum, sweep_args: dict, solver: str, report: dict) -> np.ndarray:
    """Non-negative optimum from the equality optimum: projected per vertex onto the feasible set
    (:func:`project_feasible`), then local sweeps to convergence; ``report`` gets both stages' figures,
    the gap of the result above the equality optimum and its KKT residual relative to the start's."""
    start, dropped = feasible_start(prob)
    unconstrained, grep = equality_optimum(None if prob.C.shape[1] > 1 else start)
    projected = project_feasible(prob, unconstrained, start)
    alpha, rep = local_solve(prob, adjacency, projected, **sweep_args)
    if dropped:
        rep["linear_precision_dropped"] = dropped
    k0 = kkt_residual(prob, start)
    eq = "global" if grep["solver"] == "direct" else grep["solver"]
    report.update(path=f"{solver}: {eq}, projection, local", **rep,
                  equality_optimum=grep["energy"], equality_seconds=grep["seconds"],
                  equality_iterations=grep.get("iterations"), factorisation=grep.get("factorisation"),
                  gap_above_equality_optimum=relative_gap(rep["energy"], grep["energy"]),
                  kkt_residual=kkt_residual(prob, alpha) / k0 if k0 > 0 else 0.0)
    return alpha


def relative_gap(energy: float, optimum: float) -> float:
    """``(E - E*) / |E*|``; where the optimum is exactly 0 (every vertex keeps its one influence: a rigid rig)
    the absolute gap ``E - E*`` instead."""
    return (energy - optimum) / abs(optimum) if optimum != 0 else energy - optimum
