"""Recomputed normals: area-weighted vertex normals of the deformed mesh (precomputed face->vertex operator)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from rigslim.numerics.blend import per_vertex_normals
from rigslim.plugin import NormalEstimator

if TYPE_CHECKING:
    from rigslim.model.handles import Handles
    from rigslim.model.mesh import Mesh
    from rigslim.model.weights import ReducedWeights
    from rigslim.plugin import Params, StepContext


class RecomputedNormals(NormalEstimator):
    name = "recomputed"
    summary = ("area-weighted vertex normals of the deformed mesh (precomputed face->vertex operator, "
               "compiled; equal to igl.per_vertex_normals to rounding)")

    def estimate(self, mesh: Mesh, weights: ReducedWeights, handles: Handles | None, T: np.ndarray,
                 positions: np.ndarray, params: Params, ctx: StepContext | None = None) -> np.ndarray:
        return per_vertex_normals(positions, mesh.F)
