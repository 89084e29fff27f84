"""Position error ([P10] fig. 10): RMS vertex distance per test frame, in world units and in % of the reference
diagonal (the world-space bounding-box diagonal of the first test frame, :mod:`rigslim.numerics.units`)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from rigslim.numerics.units import reference_diagonal
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
    summary = ("RMS over vertices of |v(alpha) - vhat| per test frame, in world units (m for glTF) and % of the "
               "world-space diagonal of the first test frame")

    def compute(self, evaluation: Evaluation, params: Params,
                ctx: StepContext | None = None) -> dict[str, Any]:
        D = reference_diagonal(evaluation)
        per_frame = [position_rms(evaluation.reduced_positions(j), evaluation.full_positions(j))
                     for j in range(len(evaluation))]
        return {"position_rms_pct": aggregate(100.0 * np.asarray(per_frame) / D),
                "position_rms_m": aggregate(per_frame), "reference_diagonal_m": D}
