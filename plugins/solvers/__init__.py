"""Weight solver plugins: the values of the reduced weights on chosen influence sets."""

from rigslim import hookimpl
from rigslim.plugins.solvers.k_largest import KLargestSolver
from rigslim.plugins.solvers.methods import GeometricSolver, PoissonSolver, SmoothSolver


@hookimpl
def rigslim_weight_solvers():
    return [KLargestSolver(), GeometricSolver(), SmoothSolver(), PoissonSolver()]
