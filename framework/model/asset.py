"""The asset: everything that flows through a pipeline.

Readers fill the inputs (mesh, handles, weights, poses); steps add results
(influence sets, reduced weights, hierarchies, evaluations). Steps read what
they need and raise :class:`rigslim.errors.StepError` when it is missing.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import scipy.sparse as sp

from rigslim.errors import StepError
from rigslim.model.handles import Handles
from rigslim.model.hierarchy import ProgressiveHierarchy, SimplifiedLevel
from rigslim.model.mesh import Mesh
from rigslim.model.poses import FrameSplit, Poses
from rigslim.model.weights import InfluenceSets, ReducedWeights


@dataclass
class Asset:
    """What a pipeline works on.

    Attributes
    ----------
    mesh : Mesh
        The rest mesh.
    handles : Handles
        Skeleton or cage.
    weights : scipy.sparse.csr_matrix
        Input (full) weights, m x n.
    poses : Poses
        Every available pose (e.g. all frames of an animation).
    split : FrameSplit
        Example and test frames.
    influences : InfluenceSets
        Output of the ``select`` stage.
    reduced : ReducedWeights
        Output of the ``solve`` stage.
    levels : list of SimplifiedLevel
        Output of the ``decimate`` stage: the simplified levels, finest first.
    hierarchy : ProgressiveHierarchy or None
        Output of the ``decimate`` stage: every collapse, replayable to any
        resolution (None when the decimator records none).
    deformer, normal_estimator : str
        Plugins evaluations use (``numpy`` and ``recomputed`` by default).
    extras : dict
        Anything else plugins attach (tetrahedra, glTF documents...).
    provenance : dict
        Input paths and what each step did.
    """

    mesh: Mesh | None = None
    handles: Handles | None = None
    weights: sp.csr_matrix | None = None
    poses: Poses | None = None
    split: FrameSplit | None = None
    influences: InfluenceSets | None = None
    reduced: ReducedWeights | None = None
    levels: list[SimplifiedLevel] = field(default_factory=list)
    hierarchy: ProgressiveHierarchy | None = None
    deformer: str = "numpy"
    deformer_params: dict = field(default_factory=dict)
    normal_estimator: str = "recomputed"
    normal_params: dict = field(default_factory=dict)
    extras: dict[str, Any] = field(default_factory=dict)
    provenance: dict[str, Any] = field(default_factory=dict)

    def require(self, *names: str, step: str = "this step") -> None:
        """Raise a StepError naming the first missing attribute."""
        producers = {"mesh": "inputs.mesh", "handles": "inputs.skeleton or inputs.cage",
                     "weights": "inputs.weights or a 'generate' step", "poses": "inputs.animation",
                     "split": "a 'poses' section", "influences": "a 'select' step",
                     "reduced": "a 'solve' step"}
        for name in names:
            if getattr(self, name, None) is None:
                raise StepError(f"{step} needs {name}, which nothing has provided",
                                field=name, fix=f"add {producers.get(name, name)} before it")

    def example_poses(self) -> Poses:
        """The example poses (used for fitting)."""
        self.require("poses", "split")
        assert self.poses is not None and self.split is not None
        return self.poses.select(self.split.examples)

    def test_poses(self) -> Poses:
        """The test poses (used for measuring, never for fitting)."""
        self.require("poses", "split")
        assert self.poses is not None and self.split is not None
        return self.poses.select(self.split.test)
