"""k-largest influence selection ([P10] section 3): each vertex keeps its k largest weights."""

from __future__ import annotations

from typing import TYPE_CHECKING

from pydantic import Field

from rigslim.numerics.largest_entries import k_largest
from rigslim.plugin import InfluenceSelector, Params

if TYPE_CHECKING:
    from rigslim.model.asset import Asset
    from rigslim.model.weights import InfluenceSets
    from rigslim.plugin import StepContext

__all__ = ["KLargestParams", "KLargestSelector", "pass_through_note"]


class KLargestParams(Params):
    k: int = Field(ge=1, description="influences per vertex")


class KLargestSelector(InfluenceSelector[KLargestParams]):
    name = "k-largest"
    summary = "keep each vertex's k largest input weights (the baseline of every importer)"

    def select(self, asset: Asset, params: KLargestParams, ctx: StepContext) -> InfluenceSets:
        asset.require("weights", step="select: k-largest")
        weights = asset.weights
        assert weights is not None  # require() raised otherwise
        pass_through_note(params.k, weights.shape[1], ctx)
        return k_largest(weights, params.k)


def pass_through_note(k: int, n: int, ctx) -> bool:
    """Whether k >= the handle count n (every vertex keeps its influences); if so, say it in the step's report
    and log. Not an error: the weights pass through (the solvers keep them exactly)."""
    if k < n:
        return False
    note = (f"k = {k} is not smaller than the {n} handles: every vertex keeps all its influences "
            "(weights passed through)")
    if ctx is not None and hasattr(ctx, "report"):
        ctx.report["pass_through"] = note
        log = getattr(ctx, "log", None)
        if callable(log):
            log(note)
    return True
