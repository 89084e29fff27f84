"""Weight generator plugins: dense input weights from a mesh and its handles.

``mean-value`` and ``harmonic`` (cage coordinates), ``bone-heat`` and
``bbw`` (skeletal weights). See docs/generators.md.
"""

from rigslim import hookimpl
from rigslim.plugins.generators.bbw import BBWGenerator
from rigslim.plugins.generators.bone_heat import BoneHeatGenerator
from rigslim.plugins.generators.harmonic import HarmonicGenerator
from rigslim.plugins.generators.mean_value import MeanValueGenerator


@hookimpl
def rigslim_weight_generators():
    return [MeanValueGenerator(), HarmonicGenerator(), BoneHeatGenerator(), BBWGenerator()]
