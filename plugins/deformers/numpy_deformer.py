"""The numpy reference deformer: sparse (or fixed-k) blend of 3x4 handle transforms.

Positions are ``v' = (sum_l w_l T_{i_l}) [v; 1]`` (as :func:`rigslim.numerics.blend.linear_blend`, with
fixed-k weights turned into a sparse matrix at bind, which scipy multiplies faster than a gather);
normals, when asked for, come from the same references the normal
estimators use (blended-matrix for skeletons, approximate-affine for cages).
"""

from __future__ import annotations

import time

import numpy as np

from rigslim.model.weights import ReducedWeights
from rigslim.numerics.blend import blended_matrices, per_vertex_normals
from rigslim.plugin import Deformer
from rigslim.plugins.deformers.base import BoundDeformer, DeformerParams, check_weights, n_handles_of, resolve_normals


class NumpyBound(BoundDeformer):
    """Positions and normals in float64 numpy/scipy."""

    backend = "numpy"

    def __init__(self, mesh, weights, normals_mode, handles):
        super().__init__(mesh.n_vertices, n_handles_of(weights), normals_mode)
        self.mesh = mesh
        self.V = mesh.V
        self.weights = weights
        self.handles = handles
        self._normal_data = None
        # fixed-k weights blend fastest as a sparse product too (padding drops out; same sums)
        self._csr = weights.to_sparse() if isinstance(weights, ReducedWeights) else weights

    def _normals(self, T, X):
        """Normals of pose T (X: its blended transforms); rest-pose data is computed on the first call."""
        from rigslim.numerics.affine_normals import affine_fit_rest, approximate_affine_normals
        from rigslim.numerics.blended_normals import normals_from_linear_parts

        if self._normal_data is None:
            N0 = per_vertex_normals(self.mesh.V, self.mesh.F)
            self._normal_data = N0 if self.normals_mode == "blended-matrix" else \
                affine_fit_rest(self.weights, self.handles.cage.V, N0)
        if self.normals_mode == "blended-matrix":
            return normals_from_linear_parts(X[:, :, :3], self._normal_data)
        return approximate_affine_normals(self._csr, self.handles.cage.V, T, self._normal_data)

    def _deform(self, T, normals):
        t = time.perf_counter()
        X = blended_matrices(self._csr, T)
        P = np.einsum("vij,vj->vi", X[:, :, :3], self.V) + X[:, :, 3]
        if not normals:
            self.last_seconds = time.perf_counter() - t
            return P
        N = self._normals(T, X)
        self.last_seconds = time.perf_counter() - t
        return P, N

    def bytes_per_frame(self, normals):
        import scipy.sparse as sp

        from rigslim.model.weights import ReducedWeights

        w = self.weights
        nnz = w.indices.size if isinstance(w, ReducedWeights) else sp.csr_matrix(w).nnz
        m = self.n_vertices
        inputs = 24 * m + 12 * nnz + 96 * self.n_handles          # float64 positions, int32+float64 weights
        return inputs + 24 * m + (48 * m if normals else 0)       # rest normals read, normals written


class NumpyDeformer(Deformer):
    """The float64 reference every other deformer is tested against.

    Notes
    -----
    ``v' = X_v [v; 1]`` with ``X_v = sum_i a_{v,i} T_i`` computed as one sparse
    product ``A @ T.reshape(n, 12)``.
    """

    name = "numpy"
    summary = "reference linear blend in numpy/scipy (sparse input weights or fixed-k weights), float64"

    class Params(DeformerParams):
        pass

    def bind(self, mesh, weights, params=None, handles=None, ctx=None) -> NumpyBound:
        params = params if params is not None else self.Params()
        weights = check_weights(mesh, weights, source="numpy deformer")
        return NumpyBound(mesh, weights, resolve_normals(params.normals, handles), handles)
