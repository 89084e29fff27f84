"""The data model: what a pipeline reads, computes and writes, with no file format or solver in it.

- :mod:`~rigslim.model.mesh`: :class:`Mesh`, a triangle mesh (V, F);
- :mod:`~rigslim.model.handles`: :class:`Handles`, a skeleton's bones or a cage's vertices;
- :mod:`~rigslim.model.poses`: :class:`Poses` (handle transforms per frame) and :class:`FrameSplit` (example
  and test frames), and the frame-spec parser;
- :mod:`~rigslim.model.weights`: dense/sparse weights checked, :class:`InfluenceSets` (k handles per vertex)
  and :class:`ReducedWeights` (k indices and values per vertex);
- :mod:`~rigslim.model.hierarchy`: :class:`ProgressiveHierarchy` (a collapse sequence) and its
  :class:`SimplifiedLevel` s;
- :mod:`~rigslim.model.asset`: :class:`Asset`, everything a pipeline holds between steps.
"""

from rigslim.model.asset import Asset
from rigslim.model.handles import Handles
from rigslim.model.hierarchy import ProgressiveHierarchy, SimplifiedLevel
from rigslim.model.mesh import Mesh
from rigslim.model.poses import FrameSplit, Poses
from rigslim.model.weights import InfluenceSets, ReducedWeights, validate_weights

__all__ = ["Asset", "FrameSplit", "Handles", "InfluenceSets", "Mesh", "Poses", "ProgressiveHierarchy",
           "ReducedWeights", "SimplifiedLevel", "validate_weights"]
