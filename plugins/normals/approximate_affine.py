"""The ``approximate-affine`` normal estimator for cages ([P10] section 5).

The math is in :mod:`rigslim.numerics.affine_normals`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from rigslim.numerics.affine_normals import (
    AffineFitRest,
    affine_fit_rest,
    approximate_affine_normals,
    cage_rest_positions,
)
from rigslim.numerics.blend import per_vertex_normals
from rigslim.plugin import NormalEstimator, Params
from rigslim.plugins.normals.backends import Backend, normals_from_backend

if TYPE_CHECKING:
    from rigslim.model.handles import Handles
    from rigslim.model.mesh import Mesh
    from rigslim.model.weights import ReducedWeights
    from rigslim.plugin import StepContext


class ApproximateAffineNormalsParams(Params):
    backend: Backend = "numpy"
    """Where to evaluate: numpy reference, the compiled cpu kernel, the OpenCL kernel, or the GLSL vertex shader."""
    device: str | None = None
    """OpenCL device spec (opencl backend only)."""


class ApproximateAffineNormals(NormalEstimator[ApproximateAffineNormalsParams]):
    name = "approximate-affine"
    summary = ("cages: normals moved by the inverse transpose of the w^2-weighted affine fit of each "
               "vertex's handles, normalize(adj(X) P n) (numpy, cpu, opencl or opengl)")

    def __init__(self):
        self._key = None
        self._rest = None

    def rest_fit(self, mesh, weights, handles) -> AffineFitRest:
        key = (mesh, weights, handles)
        if self._key is None or any(a is not b for a, b in zip(self._key, key, strict=False)):
            C0 = cage_rest_positions(handles)
            self._rest = affine_fit_rest(weights, C0, per_vertex_normals(mesh.V, mesh.F))
            self._key = key
        return self._rest

    def estimate(self, mesh: Mesh, weights: ReducedWeights, handles: Handles | None, T: np.ndarray,
                 positions: np.ndarray | None, params: ApproximateAffineNormalsParams,
                 ctx: StepContext | None = None) -> np.ndarray:
        C0 = cage_rest_positions(handles)
        if params.backend != "numpy":
            return normals_from_backend(params.backend, "approximate-affine", mesh, weights, handles, T,
                                        device=params.device)
        return approximate_affine_normals(weights, C0, np.asarray(T, dtype=np.float64),
                                          self.rest_fit(mesh, weights, handles))
