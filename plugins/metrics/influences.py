"""Influence counts of the reduced weights."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from rigslim.plugin import Metric
from rigslim.weights import influence_counts

if TYPE_CHECKING:
    from typing import Any

    from rigslim.evaluation import Evaluation
    from rigslim.plugin import Params, StepContext


class MaxInfluences(Metric):
    name = "max-influences"
    summary = "largest number of non-zero weights of any vertex, before (input) and after (reduced)"

    def compute(self, evaluation: Evaluation, params: Params,
                ctx: StepContext | None = None) -> dict[str, Any]:
        after = evaluation.asset.reduced.influence_counts()
        before = influence_counts(evaluation.asset.weights)
        return {"max_influences": int(after.max()), "mean_influences": float(np.mean(after)),
                "input_max_influences": int(before.max()), "input_mean_influences": float(np.mean(before))}
