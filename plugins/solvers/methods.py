"""Weight-solver plugins ``geometric``, ``smooth`` and ``poisson`` ([P10] section 3): their parameters.

Each minimises its energy on the asset's influence sets through
:func:`rigslim.plugins.solvers.reduction.solve_weights` (the solver paths, ``solver: auto | local |
global``, are described there); ``poisson`` with ``position_weight: auto`` first chooses lambda on held-out
example poses (:mod:`rigslim.plugins.solvers.auto_lambda`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Literal

from pydantic import Field, field_validator

from rigslim.model.weights import ReducedWeights
from rigslim.plugin import Params, WeightSolver
from rigslim.plugins.solvers.auto_lambda import GRID, choose_position_weight
from rigslim.plugins.solvers.problem import RIDGE
from rigslim.plugins.solvers.reduction import solve_weights

if TYPE_CHECKING:
    from rigslim.model.asset import Asset
    from rigslim.plugin import StepContext

__all__ = ["GeometricSolver", "LaplacianParams", "PoissonParams", "PoissonSolver", "ReductionParams",
           "SmoothSolver", "solve_weights"]


class ReductionParams(Params):
    """Parameters common to the optimising solvers."""

    nonnegative: bool | None = Field(None, description="weights >= 0 (default: on for skeletons and for "
                                                       "inputs without negative weights)")
    linear_precision: bool | None = Field(None, description="also reproduce the rest position on cages "
                                                            "(default: on for smooth, off otherwise)")
    solver: Literal["auto", "local", "global"] = "auto"
    tolerance: float = Field(1e-5, gt=0, description="stop sweeps when the relative energy decrease is below this")
    max_sweeps: int = Field(500, ge=1, description="upper bound on local sweeps")
    device: str = Field("numpy", description="local sweeps on 'numpy', or an OpenCL device: "
                                             "'opencl' (auto), 'gpu', 'cpu' or part of a device name")
    relaxation: float = Field(1.85, ge=1.0, lt=2.0, description="over-relaxation of local steps (1 = plain "
                                                                "Gauss-Seidel as in the paper)")
    ridge: float = Field(RIDGE, ge=0, description="ridge towards the k-largest weights, relative to the "
                                                  "mean local Hessian diagonal")
    global_max_unknowns: int | None = Field(None, ge=0, description="the global solve is sparse direct up to "
                                            "this many unknowns (m k), multilevel-preconditioned CG above "
                                            "(default: 2,000,000 with MKL PARDISO installed, 500,000 with SuperLU)")
    multilevel: bool = Field(True, description="local solver: per-vertex solves as the smoother of a multigrid "
                                               "V-cycle preconditioning CG (false: plain sweeps as in the paper)")
    residual_tolerance: float = Field(1e-6, gt=0, description="CG (multilevel / AMG-CG) stops when the reduced "
                                      "gradient norm falls below this times its starting value")
    max_iterations: int = Field(500, ge=1, description="upper bound on CG iterations")
    balance: Literal["clips", "frames"] = Field(
        "clips", description="geometric, poisson: weight the example frames so that every clip counts, each by "
        "the inverse of k-largest's error on it (rigslim.numerics.clip_balance); frames: every frame alike")
    reweight_rounds: int = Field(
        4, ge=0, description="geometric, poisson, with the guard on and validation frames of two or more clips: "
        "while a clip's validation error is above k-largest's by the guard's bound, its example frames count "
        "twice as much and the weights are solved again, at most this many times (0: off)")
    guard: Literal["k-largest", "k-largest-per-vertex", "off"] = Field(
        "k-largest", description="with validation frames (held-out frames of the clips, poses: examples: "
        "{clips: ...}): vertices fall back to k-largest's weights until every clip's validation error is below "
        "k-largest's by a margin (mean + 2 standard errors of its per-frame excess); per-vertex: every vertex "
        "worse on any clip falls back. Twin handles (alike on every seen pose) take the input's choice")


class LaplacianParams(ReductionParams):
    laplacian: Literal["mass-weighted", "plain"] = Field(
        "mass-weighted", description="||y||_*^2 = y^T L^T M^-1 L y (mass-weighted) or ||L y||^2 (plain)")


class PoissonParams(LaplacianParams):
    position_weight: float | Literal["auto"] = Field(
        0.0, description="lambda: weight of the geometric (position) term; 0 is the paper's Poisson method; "
                         "'auto' picks it on held-out example poses")
    position_weight_grid: list[float] = Field(list(GRID), min_length=1, description="position_weight: auto "
                                              "tries these lambdas")

    @field_validator("position_weight")
    @classmethod
    def _nonnegative(cls, v):
        if v != "auto" and v < 0:
            raise ValueError("position_weight must be >= 0 or 'auto'")
        return v

    @field_validator("position_weight_grid")
    @classmethod
    def _grid(cls, v):
        if any(x < 0 for x in v):
            raise ValueError("every lambda of the grid must be >= 0")
        return v


class GeometricSolver(WeightSolver[ReductionParams]):
    name = "geometric"
    summary = "per-vertex least squares fit of the example poses' positions ([P10] eq. 3)"

    def solve(self, asset: Asset, params: ReductionParams, ctx: StepContext) -> ReducedWeights:
        return solve_weights(asset, "geometric", params, ctx)[0]


class SmoothSolver(WeightSolver[LaplacianParams]):
    name = "smooth"
    summary = "weights whose Laplacian best matches the input weights' ([P10] sec. 3.1; no poses)"

    def solve(self, asset: Asset, params: LaplacianParams, ctx: StepContext) -> ReducedWeights:
        return solve_weights(asset, "smooth", params, ctx)[0]


class PoissonSolver(WeightSolver[PoissonParams]):
    name = "poisson"
    summary = "weights whose deformed Laplacians match the full deformation's ([P10] eq. 5)"

    def solve(self, asset: Asset, params: PoissonParams, ctx: StepContext) -> ReducedWeights:
        if params.position_weight != "auto":
            return solve_weights(asset, "poisson", params, ctx)[0]
        asset.require("mesh", "handles", "weights", "influences", "poses", "split", step="solve: poisson")
        lam, search = choose_position_weight(asset, params, params.position_weight_grid)
        reduced, _ = solve_weights(asset, "poisson", params.model_copy(update={"position_weight": lam}), ctx)
        if ctx is not None and hasattr(ctx, "report"):
            ctx.report["position_weight"] = lam
            ctx.report["position_weight_auto"] = search
        return reduced
