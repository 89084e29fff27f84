"""Metro error (Cignoni et al. 1998): two-sided surface distance on test poses, via pymeshlab.

For a simplification, each level deformed by its own skin weights is
compared with the original mesh deformed by the input weights, per test
pose; for a weight reduction, the mesh deformed by the reduced weights is
compared with the full deformation.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from pydantic import Field

from rigslim.errors import StepError
from rigslim.model.poses import spread_frames
from rigslim.numerics.surface_distance import metro_distance, pymeshlab_available
from rigslim.numerics.units import reference_diagonal
from rigslim.plugin import Metric, Params, aggregate

if TYPE_CHECKING:
    from typing import Any

    from rigslim.plugin import Params, StepContext
    from rigslim.plugin.evaluation import Evaluation

__all__ = ["Metro", "metro_distance"]


class MetroParams(Params):
    samples: int = Field(default=20000, ge=100)
    """Surface samples per direction and pose."""
    frames: int = Field(default=0, ge=0)
    """At most this many test frames, evenly spread over them (0: every test frame). A character fitted on every
    clip has a third of all its frames as test frames (hundreds for a game character), each a pymeshlab run."""


class Metro(Metric[MetroParams]):
    name = "metro"
    summary = ("two-sided Metro/Hausdorff distance (pymeshlab) per test pose, RMS and max in world units and % of "
               "the world-space diagonal of the first test frame")

    def compute(self, evaluation: Evaluation, params: MetroParams,
                ctx: StepContext | None = None) -> dict[str, Any]:
        if not pymeshlab_available():  # pragma: no cover - pymeshlab is in the 'metro' extra
            raise StepError("the metro metric needs pymeshlab", field="evaluate",
                            fix="pip install 'rigslim[metro]'")
        mesh = evaluation.mesh
        D = reference_diagonal(evaluation)
        frames = spread_frames(len(evaluation), params.frames)
        if evaluation.levels:
            out: dict = {"levels": [], "reference_diagonal_m": D}
            for i, level in enumerate(evaluation.levels):
                d = [metro_distance(level_positions(evaluation, i, j), level.mesh.F, evaluation.full_positions(j),
                                    mesh.F, params.samples) for j in frames]
                values = _values(d, D)
                if i == 0:
                    out.update(values)
                out["levels"].append({"name": level.label, "faces": level.n_faces, **values})
            return out
        d = [metro_distance(evaluation.reduced_positions(j), mesh.F, evaluation.full_positions(j), mesh.F,
                            params.samples) for j in frames]
        return {**_values(d, D), "reference_diagonal_m": D}


def _values(d: list[dict], D: float) -> dict:
    """Per-frame RMS and max in % of the reference diagonal ``D`` and in world units."""
    rms = np.array([x["rms"] for x in d])
    mx = np.array([x["max"] for x in d])
    return {"hausdorff_rms_pct": aggregate(100.0 * rms / D), "hausdorff_max_pct": aggregate(100.0 * mx / D),
            "hausdorff_rms_m": aggregate(rms), "hausdorff_max_m": aggregate(mx)}


def level_positions(evaluation, i, j):
    return evaluation.level_positions(i, j)
