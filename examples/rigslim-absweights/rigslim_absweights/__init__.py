"""Influence selection by largest absolute weight, as a third-party rigslim plugin."""

from __future__ import annotations

import numpy as np
from pydantic import Field

from rigslim import hookimpl
from rigslim.numerics.k_largest import check_k, k_largest
from rigslim.plugin import InfluenceSelector, Params


class LargestAbsSelector(InfluenceSelector):
    """Keep, per vertex, the k input weights with the largest ``|a_{v,i}|``."""

    name = "largest-abs"
    summary = "keep each vertex's k weights of largest magnitude (for coordinates that can be negative)"

    class Params(Params):
        k: int = Field(ge=1, description="influences per vertex")

    def select(self, asset, params, ctx):
        asset.require("weights", step="select: largest-abs")
        check_k(params.k, asset.weights.shape[1])
        return k_largest(asset.weights, params.k, key=np.abs)


@hookimpl
def rigslim_influence_selectors():
    return [LargestAbsSelector()]
