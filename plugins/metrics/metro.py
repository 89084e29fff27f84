"""Metro error (Cignoni et al. 1998): two-sided surface distance on test poses, via pymeshlab.

For a simplification, each level deformed by its own skin weights is
compared with the original mesh deformed by the input weights, per test
pose; for a weight reduction, the mesh deformed by the reduced weights is
compared with the full deformation.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from pydantic import Field

from rigslim.errors import StepError
from rigslim.numerics.surface_distance import metro_distance, pymeshlab_available
from rigslim.plugin import Metric, Params, aggregate

if TYPE_CHECKING:
    from typing import Any

    from rigslim.evaluation import Evaluation
    from rigslim.plugin import Params, StepContext

__all__ = ["Metro", "metro_distance"]


class Metro(Metric):
    name = "metro"
    summary = "two-sided Metro/Hausdorff distance (pymeshlab) per test pose, RMS and max as % of the bbox diagonal"

    class Params(Params):
        samples: int = Field(default=20000, ge=100)
        """Surface samples per direction and pose."""

    def compute(self, evaluation: Evaluation, params: Params,
                ctx: StepContext | None = None) -> dict[str, Any]:
        if not pymeshlab_available():  # pragma: no cover - pymeshlab is in the 'metro' extra
            raise StepError("the metro metric needs pymeshlab", field="evaluate",
                            fix="pip install 'rigslim[metro]'")
        mesh = evaluation.mesh
        scale = 100.0 / mesh.bbox_diagonal
        frames = range(len(evaluation))
        if evaluation.levels:
            out: dict = {"levels": []}
            for i, level in enumerate(evaluation.levels):
                rms, mx = [], []
                for j in frames:
                    d = metro_distance(level_positions(evaluation, i, j), level.mesh.F,
                                       evaluation.full_positions(j), mesh.F, params.samples)
                    rms.append(scale * d["rms"])
                    mx.append(scale * d["max"])
                if i == 0:
                    out["hausdorff_rms_pct"], out["hausdorff_max_pct"] = aggregate(rms), aggregate(mx)
                out["levels"].append({"name": level.label, "faces": level.n_faces,
                                      "hausdorff_rms_pct": aggregate(rms), "hausdorff_max_pct": aggregate(mx)})
            return out
        rms, mx = [], []
        for j in frames:
            d = metro_distance(evaluation.reduced_positions(j), mesh.F, evaluation.full_positions(j), mesh.F,
                               params.samples)
            rms.append(scale * d["rms"])
            mx.append(scale * d["max"])
        return {"hausdorff_rms_pct": aggregate(rms), "hausdorff_max_pct": aggregate(mx)}


def level_positions(evaluation, i, j):
    return evaluation.level_positions(i, j)
