"""Influence counts of the reduced weights."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from rigslim.model.weights import influence_counts
from rigslim.plugin import Metric

if TYPE_CHECKING:
    from typing import Any

    from rigslim.plugin import Params, StepContext
    from rigslim.plugin.evaluation import Evaluation


class MaxInfluences(Metric):
    name = "max-influences"
    summary = ("largest number of non-zero weights of any vertex, before (input) and after (reduced weights, "
               "or every simplified level)")

    def compute(self, evaluation: Evaluation, params: Params,
                ctx: StepContext | None = None) -> dict[str, Any]:
        if evaluation.asset.reduced is None and evaluation.levels:
            # A simplification: every level's own weights (the [S09] bone limit holds at each level).
            after = np.concatenate([level.weights.influence_counts() for level in evaluation.levels])
        else:
            evaluation.asset.require("reduced", step="max-influences")
            assert evaluation.asset.reduced is not None  # require() raised otherwise
            after = evaluation.asset.reduced.influence_counts()
        before = influence_counts(evaluation.asset.weights)
        return {"max_influences": int(after.max()), "mean_influences": float(np.mean(after)),
                "input_max_influences": int(before.max()), "input_mean_influences": float(np.mean(before))}
