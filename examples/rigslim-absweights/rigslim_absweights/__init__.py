"""Influence selection by largest absolute weight, as a third-party rigslim plugin."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from pydantic import Field

from rigslim import hookimpl
from rigslim.numerics.largest_entries import check_k, k_largest
from rigslim.plugin import InfluenceSelector, Params

if TYPE_CHECKING:
    from rigslim.model.asset import Asset
    from rigslim.model.weights import InfluenceSets
    from rigslim.plugin import StepContext

#: The rigslim plugin API this package is written against (docs/plugins.md, "What is stable").
RIGSLIM_PLUGIN_API = "1.0"


class LargestAbsParams(Params):
    """Parameters of ``select: largest-abs``."""

    k: int = Field(ge=1)
    """influences per vertex"""


class LargestAbsSelector(InfluenceSelector[LargestAbsParams]):
    """Keep, per vertex, the k input weights with the largest ``|a_{v,i}|``."""

    name = "largest-abs"
    summary = "keep each vertex's k weights of largest magnitude (for coordinates that can be negative)"

    def select(self, asset: Asset, params: LargestAbsParams, ctx: StepContext) -> InfluenceSets:
        asset.require("weights", step="select: largest-abs")  # a StepError naming what provides it
        weights = asset.weights
        assert weights is not None
        check_k(params.k, weights.shape[1])
        return k_largest(weights, params.k, key=np.abs)


@hookimpl
def rigslim_influence_selectors() -> list[InfluenceSelector[LargestAbsParams]]:
    return [LargestAbsSelector()]
