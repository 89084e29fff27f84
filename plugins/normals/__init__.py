"""Normal estimator plugins."""

from __future__ import annotations

from typing import TYPE_CHECKING

from rigslim import hookimpl
from rigslim.plugins.normals.approximate_affine import ApproximateAffineNormals
from rigslim.plugins.normals.blended_matrix import BlendedMatrixNormals
from rigslim.plugins.normals.recomputed import RecomputedNormals

if TYPE_CHECKING:
    from rigslim.plugin import NormalEstimator


@hookimpl
def rigslim_normal_estimators() -> list[NormalEstimator]:
    return [RecomputedNormals(), BlendedMatrixNormals(), ApproximateAffineNormals()]
