"""k-largest influence selection ([P10] section 3): each vertex keeps its k largest weights."""

from __future__ import annotations

from typing import TYPE_CHECKING

from pydantic import Field

from rigslim.numerics.largest_entries import check_k, k_largest
from rigslim.plugin import InfluenceSelector, Params

if TYPE_CHECKING:
    from rigslim.model.asset import Asset
    from rigslim.model.weights import InfluenceSets
    from rigslim.plugin import StepContext

__all__ = ["KLargestSelector"]


class KLargestSelector(InfluenceSelector):
    name = "k-largest"
    summary = "keep each vertex's k largest input weights (the baseline of every importer)"

    class Params(Params):
        k: int = Field(ge=1, description="influences per vertex")

    def select(self, asset: Asset, params: Params, ctx: StepContext) -> InfluenceSets:
        asset.require("weights", step="select: k-largest")
        check_k(params.k, asset.weights.shape[1])
        return k_largest(asset.weights, params.k)
