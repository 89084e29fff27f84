"""Normal deviation ([P10] fig. 10): RMS angle between reduced and full normals."""

from __future__ import annotations

import numpy as np

from rigslim.plugin import Metric, aggregate


def normal_rms_angle(N: np.ndarray, Nhat: np.ndarray) -> float:
    """``sqrt(mean_v angle(n_v, nhat_v)^2)`` in radians, for unit normals.

    The angle is ``atan2(|n x nhat|, n . nhat)``, accurate for small angles too.
    """
    cross = np.linalg.norm(np.cross(N, Nhat), axis=1)
    dot = np.einsum("ij,ij->i", N, Nhat)
    return float(np.sqrt(np.mean(np.arctan2(cross, dot) ** 2)))


class NormalDeviation(Metric):
    name = "normal-deviation"
    summary = ("RMS over vertices of the angle (rad) between the reduced deformation's normals "
               "(asset's normal estimator) and area-weighted normals of the full deformation")

    def compute(self, evaluation, params, ctx=None):
        per_frame = [normal_rms_angle(evaluation.reduced_normals(j), evaluation.full_normals(j))
                     for j in range(len(evaluation))]
        return {"normal_rms_rad": aggregate(per_frame)}
