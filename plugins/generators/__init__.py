"""Weight generator plugins: dense input weights from a mesh and its handles.

``mean-value`` and ``harmonic`` (cage coordinates), ``bone-heat`` and
``bbw`` (skeletal weights). See docs/generators.md.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from rigslim import hookimpl
from rigslim.plugins.generators.bbw import BBWGenerator
from rigslim.plugins.generators.bone_heat import BoneHeatGenerator
from rigslim.plugins.generators.harmonic import HarmonicGenerator
from rigslim.plugins.generators.mean_value import MeanValueGenerator

if TYPE_CHECKING:
    from rigslim.plugin import WeightGenerator


@hookimpl
def rigslim_weight_generators() -> list[WeightGenerator]:
    return [MeanValueGenerator(), HarmonicGenerator(), BoneHeatGenerator(), BBWGenerator()]
