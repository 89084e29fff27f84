"""The ``k-largest`` weight solver: keep the selected input weights and renormalise them ([P10] section 3).

Named for what it computes, apart from the ranking (:mod:`rigslim.numerics.largest_entries`) and the
k-largest selector (the ``k-largest`` influence-selection plugin).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import scipy.sparse as sp

from rigslim.errors import StepError
from rigslim.model.weights import InfluenceSets, ReducedWeights
from rigslim.plugin import WeightSolver
from rigslim.plugins.solvers.problem import gather
from rigslim.plugins.solvers.safeguards import pass_through

if TYPE_CHECKING:
    from rigslim.model.asset import Asset
    from rigslim.plugin import Params, StepContext


def renormalised_weights(A: sp.csr_matrix, influences: InfluenceSets) -> ReducedWeights:
    """Input weights restricted to the influence sets and renormalised.

    ``alpha_{v,l} = a_{v,i_l} / sum_l' a_{v,i_l'}``

    Raises
    ------
    StepError
        If a vertex's kept weights sum to zero (nothing to renormalise).
    """
    vals = gather(A, influences)
    sums = vals.sum(axis=1, keepdims=True)
    bad = np.abs(sums[:, 0]) < 1e-12
    if bad.any():
        v = int(np.flatnonzero(bad)[0])
        raise StepError(f"vertex {v}'s selected weights sum to zero; they cannot be renormalised",
                        field="solve", fix="select larger influence sets or use another solver")
    return ReducedWeights.from_influences(influences, vals / sums, A.shape[1])


class KLargestSolver(WeightSolver):
    name = "k-largest"
    summary = "keep the selected input weights and divide by their sum"

    def solve(self, asset: Asset, params: Params, ctx: StepContext) -> ReducedWeights:
        """The renormalised weights; vertices with at most k input influences keep them exactly."""
        asset.require("weights", "influences", step="solve: k-largest")
        weights, influences = asset.weights, asset.influences
        assert weights is not None and influences is not None  # require() raised otherwise
        reduced, kept = pass_through(weights, renormalised_weights(weights, influences), influences)
        if ctx is not None and hasattr(ctx, "report"):
            ctx.report["passed_through"] = kept
        return reduced
