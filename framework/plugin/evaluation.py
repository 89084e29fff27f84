"""Evaluation of a reduction on test poses: full against reduced deformation.

For a simplification (``asset.levels``) it also deforms every
simplified level with its own weights (:meth:`Evaluation.level_positions`),
to be compared with the full mesh under the full weights.

An :class:`Evaluation` is handed to every metric. It deforms the rest mesh
to each test pose twice, with the full input weights (the reference, always
the numpy deformer) and with the reduced weights (through the asset's chosen
deformer), and caches positions and normals so that several metrics share
the work.
"""

from __future__ import annotations

from functools import cached_property
from typing import TYPE_CHECKING

import numpy as np

from rigslim.numerics.blend import linear_blend, per_vertex_normals

if TYPE_CHECKING:
    from rigslim.model.asset import Asset
    from rigslim.model.mesh import Mesh
    from rigslim.plugin.contract import StepContext
    from rigslim.plugin.host import PluginHost


class Evaluation:
    """Per-test-frame deformations of one asset.

    Parameters
    ----------
    asset : rigslim.model.asset.Asset
        Needs mesh, weights, poses, split and reduced weights.
    host : rigslim.plugin.host.PluginHost
        To find the asset's deformer and normal estimator.
    ctx : rigslim.plugin.StepContext, optional
        The evaluate step's context, handed to the deformer and the normal estimator.
    """

    def __init__(self, asset: Asset, host: PluginHost, ctx: StepContext | None = None):
        #: Simplified levels (``asset.levels``, from a ``decimate`` step), finest first.
        self.levels = list(asset.levels)
        need = ("mesh", "weights", "poses", "split") + (() if self.levels else ("reduced",))
        asset.require(*need, step="evaluate")
        self.asset = asset
        self.host = host
        self.ctx = ctx
        assert asset.mesh is not None  # required above
        self.mesh: Mesh = asset.mesh
        self.poses = asset.test_poses()
        self.frames = [int(f) for f in np.asarray(self.poses.frames)]
        self._cache: dict = {}

    def __len__(self) -> int:
        return len(self.frames)

    @cached_property
    def _reduced_deform(self):
        self.asset.require("reduced", step="this metric")
        deformer = self.host.get("deformer", self.asset.deformer)
        params = deformer.parse_params(self.asset.deformer_params)
        return deformer.bind(self.mesh, self.asset.reduced, params, ctx=self.ctx)

    @cached_property
    def _normal_estimator(self):
        est = self.host.get("normal-estimator", self.asset.normal_estimator)
        return est, est.parse_params(self.asset.normal_params)

    def _cached(self, key, j, compute):
        if (key, j) not in self._cache:
            self._cache[(key, j)] = compute()
        return self._cache[(key, j)]

    def full_positions(self, j: int) -> np.ndarray:
        """(m, 3) positions of test pose j with the full input weights."""
        return self._cached("full", j, lambda: linear_blend(self.mesh.V, self.asset.weights, self.poses.T[j]))

    def reduced_positions(self, j: int) -> np.ndarray:
        """(m, 3) positions of test pose j with the reduced weights."""
        return self._cached("reduced", j, lambda: np.asarray(self._reduced_deform(self.poses.T[j]),
                                                             dtype=np.float64))

    def full_normals(self, j: int) -> np.ndarray:
        """Area-weighted normals recomputed on the full deformation (the reference)."""
        return self._cached("full_n", j, lambda: per_vertex_normals(self.full_positions(j), self.mesh.F))

    def reduced_normals(self, j: int) -> np.ndarray:
        """Normals of the reduced deformation from the asset's normal estimator."""
        est, params = self._normal_estimator
        return self._cached("reduced_n", j, lambda: est.estimate(
            self.mesh, self.asset.reduced, self.asset.handles, self.poses.T[j], self.reduced_positions(j), params,
            self.ctx))

    def level_positions(self, i: int, j: int) -> np.ndarray:
        """(v, 3) positions of simplified level i in test pose j, blended with the level's own weights."""
        level = self.levels[i]
        return self._cached(("level", i), j, lambda: linear_blend(level.mesh.V, level.weights, self.poses.T[j]))
