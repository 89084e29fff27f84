"""The ``blended-matrix`` normal estimator for skeletons ([P10] section 5).

The math is in :mod:`rigslim.numerics.blended_normals`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from rigslim.errors import StepError
from rigslim.numerics.blend import per_vertex_normals
from rigslim.numerics.blended_normals import blended_matrix_normals
from rigslim.plugin import NormalEstimator, Params
from rigslim.plugins.normals.backends import Backend, normals_from_backend

if TYPE_CHECKING:
    from rigslim.model.handles import Handles
    from rigslim.model.mesh import Mesh
    from rigslim.model.weights import ReducedWeights
    from rigslim.plugin import StepContext


class BlendedMatrixNormalsParams(Params):
    backend: Backend = "numpy"
    """Where to evaluate: numpy reference, the compiled cpu kernel, the OpenCL kernel, or the GLSL vertex shader."""
    device: str | None = None
    """OpenCL device spec (opencl backend only)."""


class BlendedMatrixNormals(NormalEstimator[BlendedMatrixNormalsParams]):
    name = "blended-matrix"
    summary = "skeletons: rest normals times the inverse transpose of sum_l w_l R_l (numpy, cpu, opencl or opengl)"

    def __init__(self):
        self._rest = (None, None)

    def rest_normals(self, mesh) -> np.ndarray:
        if self._rest[0] is not mesh:
            self._rest = (mesh, per_vertex_normals(mesh.V, mesh.F))
        return self._rest[1]

    def estimate(self, mesh: Mesh, weights: ReducedWeights, handles: Handles | None, T: np.ndarray,
                 positions: np.ndarray | None, params: BlendedMatrixNormalsParams,
                 ctx: StepContext | None = None) -> np.ndarray:
        if handles is not None and handles.is_cage:
            raise StepError("blended-matrix normals need bone transforms; a cage's blended linear part is zero",
                            field="normals", fix="use 'normals: approximate-affine' for cages")
        if params.backend != "numpy":
            return normals_from_backend(params.backend, "blended-matrix", mesh, weights, handles, T,
                                        device=params.device)
        return blended_matrix_normals(self.rest_normals(mesh), weights, np.asarray(T, dtype=np.float64))
