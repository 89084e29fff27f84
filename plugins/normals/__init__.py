"""Normal estimator plugins."""

from rigslim import hookimpl
from rigslim.plugins.normals.recomputed import RecomputedNormals


@hookimpl
def rigslim_normal_estimators():
    return [RecomputedNormals()]
