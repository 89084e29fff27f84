"""Weight solver plugins: the values of the reduced weights on chosen influence sets."""

from __future__ import annotations

from typing import TYPE_CHECKING

from rigslim import hookimpl
from rigslim.plugins.solvers.methods import GeometricSolver, PoissonSolver, SmoothSolver
from rigslim.plugins.solvers.renormalised import KLargestSolver

if TYPE_CHECKING:
    from rigslim.plugin import WeightSolver


@hookimpl
def rigslim_weight_solvers() -> list[WeightSolver]:
    return [KLargestSolver(), GeometricSolver(), SmoothSolver(), PoissonSolver()]
