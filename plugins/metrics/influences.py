"""Influence counts of the reduced weights."""

from __future__ import annotations

import numpy as np

from rigslim.plugin import Metric
from rigslim.weights import influence_counts


class MaxInfluences(Metric):
    name = "max-influences"
    summary = "largest number of non-zero weights of any vertex, before (input) and after (reduced)"

    def compute(self, evaluation, params, ctx=None):
        after = evaluation.asset.reduced.influence_counts()
        before = influence_counts(evaluation.asset.weights)
        return {"max_influences": int(after.max()), "mean_influences": float(np.mean(after)),
                "input_max_influences": int(before.max()), "input_mean_influences": float(np.mean(before))}
