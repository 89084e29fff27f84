"""Normal deviation ([P10] fig. 10): the angle between reduced and full normals, RMS and robust statistics.

Per test frame and vertex, ``theta_v = atan2(|n_v x nhat_v|, n_v . nhat_v)``
between the reduced deformation's normal ``n_v`` (the asset's normal
estimator) and the area-weighted normal ``nhat_v`` of the full deformation.
Per frame the metric reports

- ``normal_rms_rad``: ``sqrt(mean_v theta_v^2)`` ([P10]'s measure);
- ``normal_median_rad``, ``normal_p95_rad``, ``normal_p99_rad``: percentiles
  of ``theta_v`` (linear interpolation, ``numpy.percentile``);
- ``normal_flipped``: how many vertices turn by more than 90 degrees;
- ``normal_area_rms_rad``: ``sqrt(sum_v A_v theta_v^2 / sum_v A_v)`` with the
  rest mesh's Voronoi vertex areas ``A_v`` (the mass matrix diagonal).

A few flipped normals can make the whole RMS (on a 2k-vertex character, 4
flipped vertices were all of a 0.11 rad RMS while the median was 0), so the
percentiles and the flipped count say whether an error is spread or local.
Each is aggregated over frames as ``{"mean", "max", "per_frame"}``.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from rigslim.numerics.normal_error import normal_angles, normal_rms_angle, normal_statistics
from rigslim.plugin import Metric, aggregate

if TYPE_CHECKING:
    from typing import Any

    from rigslim.plugin import Params, StepContext
    from rigslim.plugin.evaluation import Evaluation

__all__ = ["NormalDeviation", "normal_angles", "normal_rms_angle", "normal_statistics"]


class NormalDeviation(Metric):
    name = "normal-deviation"
    summary = ("angle (rad) between the reduced deformation's normals (asset's normal estimator) and "
               "area-weighted normals of the full deformation: RMS, median, p95, p99, count > 90 deg, "
               "area-weighted RMS")

    def compute(self, evaluation: Evaluation, params: Params,
                ctx: StepContext | None = None) -> dict[str, Any]:
        areas = np.asarray(evaluation.mesh.massmatrix.diagonal(), dtype=np.float64)
        frames = [normal_statistics(normal_angles(evaluation.reduced_normals(j), evaluation.full_normals(j)), areas)
                  for j in range(len(evaluation))]
        return {key: aggregate([f[key] for f in frames]) for key in frames[0]} if frames else {}
