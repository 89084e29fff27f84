"""Normal deviation ([P10] fig. 10): the angle between reduced and full normals, RMS and robust statistics.

Per test frame and vertex, ``theta_v = atan2(|n_v x nhat_v|, n_v . nhat_v)``
between the reduced deformation's normal ``n_v`` (the asset's normal
estimator) and the area-weighted normal ``nhat_v`` of the full deformation.

Only vertices with a defined normal count. With ``c_v = |sum_f n_f| / sum_f |n_f|``
over the faces around v (``n_f`` the area vector;
:func:`rigslim.numerics.normal_error.normal_conditioning`) and
``tau =`` :data:`~rigslim.numerics.normal_error.DEGENERATE_RATIO` (1e-3):

- a vertex whose *rest* normal is degenerate (``c_v < tau``: cancelling faces,
  zero area, no face) is left out of every frame's statistics; their number is
  ``degenerate_normals``;
- in a frame, a vertex whose *full* deformation's normal is degenerate (the
  reference has no direction there) is left out of that frame's statistics;
  their number per frame is ``normal_degenerate_posed``.

Per frame, over the remaining vertices, the metric reports

- ``normal_rms_rad``: ``sqrt(mean_v theta_v^2)`` ([P10]'s measure);
- ``normal_median_rad``, ``normal_p95_rad``, ``normal_p99_rad``: percentiles
  of ``theta_v`` (linear interpolation, ``numpy.percentile``);
- ``normal_flipped``: vertices with ``theta_v > 90`` degrees whose reduced
  deformation's normal is also defined (``c_v >= tau`` on the reduced
  positions), so that round-off cannot make a flip: unchanged weights give 0;
- ``normal_area_rms_rad``: ``sqrt(sum_v A_v theta_v^2 / sum_v A_v)`` with the
  rest mesh's Voronoi vertex areas ``A_v`` (the mass matrix diagonal).

A few flipped normals can make the whole RMS (on a 2k-vertex character, 4
flipped vertices were all of a 0.11 rad RMS while the median was 0), so the
percentiles and the flipped count say whether an error is spread or local.
Each per-frame figure is aggregated over frames as ``{"mean", "max", "per_frame"}``;
``degenerate_normals`` is one count.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from rigslim.numerics.normal_error import (
    DEGENERATE_RATIO,
    normal_angles,
    normal_conditioning,
    normal_rms_angle,
    normal_statistics,
    vertex_face_incidence,
)
from rigslim.plugin import Metric, aggregate

if TYPE_CHECKING:
    from typing import Any

    from rigslim.plugin import Params, StepContext
    from rigslim.plugin.evaluation import Evaluation

__all__ = ["NormalDeviation", "normal_angles", "normal_rms_angle", "normal_statistics"]


class NormalDeviation(Metric):
    name = "normal-deviation"
    summary = ("angle (rad) between the reduced deformation's normals (asset's normal estimator) and "
               "area-weighted normals of the full deformation, over vertices with a defined normal: RMS, "
               "median, p95, p99, flips (> 90 deg, both normals defined), area-weighted RMS; "
               "degenerate rest normals counted apart")

    def compute(self, evaluation: Evaluation, params: Params,
                ctx: StepContext | None = None) -> dict[str, Any]:
        mesh = evaluation.mesh
        areas = np.asarray(mesh.massmatrix.diagonal(), dtype=np.float64)
        incidence = vertex_face_incidence(mesh.F, mesh.n_vertices)
        rest_ok = normal_conditioning(mesh.V, mesh.F, incidence) >= DEGENERATE_RATIO
        frames, posed = [], []
        for j in range(len(evaluation)):
            full_ok = normal_conditioning(evaluation.full_positions(j), mesh.F, incidence) >= DEGENERATE_RATIO
            reduced_ok = normal_conditioning(evaluation.reduced_positions(j), mesh.F, incidence) >= DEGENERATE_RATIO
            valid = rest_ok & full_ok
            theta = normal_angles(evaluation.reduced_normals(j), evaluation.full_normals(j))
            frames.append(normal_statistics(theta, areas, valid=valid, flip_valid=valid & reduced_ok))
            posed.append(int(np.count_nonzero(rest_ok & ~full_ok)))
        if not frames:
            return {}
        out: dict[str, Any] = {key: aggregate([f.get(key, 0.0) for f in frames]) for key in frames[0]}
        out["normal_degenerate_posed"] = aggregate(posed)
        out["degenerate_normals"] = int(np.count_nonzero(~rest_ok))
        return out
