"""Position error ([P10] fig. 10): RMS vertex distance, as % of the bounding-box diagonal."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from rigslim.plugin import Metric, aggregate

if TYPE_CHECKING:
    from typing import Any

    from rigslim.plugin import Params, StepContext
    from rigslim.plugin.evaluation import Evaluation


def position_rms(X: np.ndarray, Xhat: np.ndarray) -> float:
    """``sqrt(mean_v ||x_v - xhat_v||^2)``."""
    return float(np.sqrt(np.mean(np.sum((X - Xhat) ** 2, axis=1))))


class PositionRMS(Metric):
    name = "position-rms"
    summary = "RMS over vertices of |v(alpha) - vhat| per test frame, % of the rest bounding-box diagonal"

    def compute(self, evaluation: Evaluation, params: Params,
                ctx: StepContext | None = None) -> dict[str, Any]:
        scale = 100.0 / evaluation.mesh.bbox_diagonal
        per_frame = [scale * position_rms(evaluation.reduced_positions(j), evaluation.full_positions(j))
                     for j in range(len(evaluation))]
        return {"position_rms_pct": aggregate(per_frame)}
