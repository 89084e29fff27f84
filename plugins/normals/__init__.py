"""Normal estimator plugins."""

from rigslim import hookimpl
from rigslim.plugins.normals.approximate_affine import ApproximateAffineNormals
from rigslim.plugins.normals.blended_matrix import BlendedMatrixNormals
from rigslim.plugins.normals.recomputed import RecomputedNormals


@hookimpl
def rigslim_normal_estimators():
    return [RecomputedNormals(), BlendedMatrixNormals(), ApproximateAffineNormals()]
