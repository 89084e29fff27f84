"""The ``cpu`` deformer: positions and normals fused in one compiled (numba) pass, all cores.

At bind the rest positions, the weights (vertex-major (m, k): fixed
int32/float32 or compact uint16/float16) and the normal data are packed as
float32 arrays, and the outputs are allocated; a frame copies the pose into
the (n, 16) handle table and runs one kernel of
:mod:`rigslim.plugins.deformers.cpu_kernels`, which writes the preallocated
positions (and normals). Nothing is allocated per frame on that path
(:meth:`CPUBound.launch`); :meth:`CPUBound.deform` returns float64 copies
like every bound deformer.

Sparse input weights are padded to their widest row (fixed layout, no
weight dropped).

``engine: numba`` (the default) runs this kernel; ``engine: opencl`` runs
``kernels/blend.cl`` on the CPU's OpenCL device (PoCL) instead. numba
measured faster than PoCL in every row of the same run
(``docs/results/deform-cpu.md``), so it is the ``cpu`` default; it also
needs no driver (numba is a core dependency).
"""

from __future__ import annotations

import time
from typing import Literal

import numpy as np

from rigslim.errors import StepError
from rigslim.model.weights import ReducedWeights
from rigslim.plugin import Deformer
from rigslim.plugins.deformers.base import (
    COMPACT_MAX_HANDLES,
    DeformerParams,
    DeviceBound,
    check_weights,
    fixed_k_arrays,
    n_handles_of,
    resolve_normals,
    rest_normal_data,
)


class CPUBound(DeviceBound):
    """Packed inputs and preallocated float32 outputs for one mesh and weights.

    Attributes
    ----------
    layout : {"fixed", "compact"}
    k : int
    effective : ReducedWeights
        The weights the kernel really uses (rounded to float32, or float16 for compact).
    positions, normals : (m, 3) float32 arrays
        The outputs of the last :meth:`launch` (overwritten by the next frame).
    """

    backend = "cpu"

    def __init__(self, mesh, weights, normals_mode, handles, layout: str):
        from rigslim.plugins.deformers import cpu_kernels

        n = n_handles_of(weights)
        super().__init__(mesh.n_vertices, n, normals_mode)
        self._kernels = cpu_kernels
        layout = "fixed" if layout == "auto" else layout
        if layout not in ("fixed", "compact"):
            raise StepError(f"the cpu deformer has no '{layout}' layout", field="layout",
                            fix="use layout: fixed or compact")
        idx, val = fixed_k_arrays(weights)
        m, k = idx.shape
        self.layout, self.k = layout, max(k, 1)
        if k == 0:
            idx, val = np.zeros((m, 1), np.int32), np.zeros((m, 1))
        self._offset: np.ndarray | None  # float16 decoding tables of the compact layout
        self._scale: np.ndarray | None
        if layout == "compact":
            if n > COMPACT_MAX_HANDLES:
                raise StepError(f"{n} handles do not fit 16-bit indices", field="layout", fix="use layout: fixed")
            half = np.ascontiguousarray(val, dtype=np.float16)
            self._idx = np.ascontiguousarray(idx, dtype=np.uint16)
            self._wt = half.view(np.uint16)
            self._offset, self._scale = cpu_kernels.half_tables()
            eff_values = half.astype(np.float64)
        else:
            self._idx = np.ascontiguousarray(idx, dtype=np.int32)
            self._wt = np.ascontiguousarray(val, dtype=np.float32)
            self._offset = self._scale = None
            eff_values = self._wt.astype(np.float64)
        self.effective = ReducedWeights(self._idx.astype(np.int32), eff_values, n)
        self._rest = np.ascontiguousarray(mesh.V, dtype=np.float32)
        self._H = np.zeros((n, cpu_kernels.HANDLE_STRIDE), dtype=np.float32)
        self._C0 = handles.cage.V if (handles is not None and handles.is_cage) else None
        self._C: np.ndarray | None = None
        if self._C0 is not None:
            self._C = np.zeros((n, 6))
            self._C[:, 3:] = self._C0 - self._C0.mean(axis=0)
        self._mesh, self._weights_in, self._handles_in = mesh, self.effective, handles
        self._N0 = self._ridge = None          # normal data, packed on the first frame that asks for normals
        self._W = self._tail = None            # scratch of the skeleton normal pass, allocated with the normal data
        self.positions = self._host_positions = np.empty((m, 3), dtype=np.float32)
        self.normals = self._host_normals = np.empty((m, 3), dtype=np.float32) if normals_mode else None

    def _normal_data(self):
        if self._N0 is None:
            data = rest_normal_data(self.normals_mode, self._mesh, self._weights_in, self._handles_in)
            self._N0 = np.ascontiguousarray(data[:, :3], dtype=np.float32)
            self._ridge = np.ascontiguousarray(data[:, 3], dtype=np.float32)
            if self._C is None:
                kern = self._kernels
                nblocks = (self.n_vertices + kern.BLOCK - 1) // kern.BLOCK
                self._W = np.zeros((max(nblocks, 1), kern.SCRATCH), dtype=np.float32)
                self._tail = np.zeros((2, kern.SUB, 3), dtype=np.float32)
        return self._N0, self._ridge

    def set_pose(self, T: np.ndarray) -> None:
        """Copy one pose (checked (n, 3, 4) float64) into the handle tables."""
        self._H[:, :12] = T.reshape(-1, 12)
        if self._C is not None and self._C0 is not None:
            chat = np.einsum("nij,nj->ni", T[:, :, :3], self._C0) + T[:, :, 3]
            self._C[:, :3] = chat - chat.mean(axis=0)

    def run(self, normals: bool = False) -> None:
        """One kernel call on the current handle tables: writes :attr:`positions` (and :attr:`normals`)."""
        kern = self._kernels
        N0 = ridge = out_n = None
        if normals:
            N0, ridge = self._normal_data()
            out_n = self._host_normals
        if self._C is None:
            kern.blend_skin(self._rest, self._idx, self._wt, self._offset, self._scale, self._H,
                            self._host_positions, N0, out_n, *((self._W, self._tail) if normals else (None, None)))
        else:
            kern.blend_cage(self._rest, self._idx, self._wt, self._offset, self._scale, self._H, self._C,
                            self._host_positions, N0, ridge, out_n)

    def launch(self, T: np.ndarray, normals: bool = False, read: bool = True):
        """One frame into the preallocated outputs; ``last_seconds`` is the kernel's wall time."""
        if normals and self.normals_mode is None:
            raise StepError("this deformer was bound without normals", field="normals",
                            fix="bind with normals: auto, blended-matrix or approximate-affine")
        self.set_pose(T)
        if normals:
            self._normal_data()
        t = time.perf_counter()
        self.run(normals)
        self.last_seconds = time.perf_counter() - t

    def bytes_per_frame(self, normals: bool) -> int:
        """Rest positions, weights and handle table read, positions written (+ rest normals read, normals written)."""
        m = self.n_vertices
        moved = 12 * m + self._idx.nbytes + self._wt.nbytes + self._H.nbytes + 12 * m
        if normals:
            moved += 12 * m + 12 * m + (4 * m + self._C.nbytes if self._C is not None else 0)
        return int(moved)


class CPUDeformer(Deformer):
    """Fused linear blend skinning and normals on all CPU cores (numba ``parallel=True``, fastmath, float32).

    Notes
    -----
    Per vertex ``X_v = sum_l w_l T_{i_l}`` (one 16-float vector accumulator,
    handle rows gathered from an (n, 16) table) and ``v' = X_v [v; 1]``; with
    normals ``n' = sign(det R) normalize(cof(R) n)`` (blended matrix) or
    ``n' = sign(det X) normalize(adj(X) (P + lambda I) n)`` (approximate
    affine, fit in float64), written in the same pass. The reference is
    :class:`rigslim.plugins.deformers.numpy_deformer.NumpyDeformer`.
    """

    name = "cpu"
    summary = ("fused positions + normals in one numba pass over vertex blocks (all cores, float32, "
               "fixed int32/float32 or compact uint16/float16 weights, preallocated outputs)")

    class Params(DeformerParams):
        layout: Literal["auto", "fixed", "compact"] = "auto"
        """Weight layout: auto/fixed (int32 + float32 per influence) or compact (uint16 + float16)."""
        engine: Literal["numba", "opencl"] = "numba"
        """numba (this module's kernel, measured fastest) or opencl (kernels/blend.cl on the CPU device, PoCL)."""

    def bind(self, mesh, weights, params=None, handles=None, ctx=None):
        """A :class:`CPUBound` (numba) or an OpenCL bound deformer on the CPU device (``engine``)."""
        params = params if params is not None else self.Params()
        weights = check_weights(mesh, weights, source="cpu deformer")
        if params.engine == "opencl":
            from rigslim.plugins.deformers.opencl_deformer import OpenCLDeformer

            layout = "fixed" if params.layout == "auto" else params.layout
            cl = OpenCLDeformer()
            bound = cl.bind(mesh, weights, cl.Params(normals=params.normals, layout=layout, device="cpu"),
                            handles=handles)
            bound.engine = "opencl"
            return bound
        bound = CPUBound(mesh, weights, resolve_normals(params.normals, handles), handles, params.layout)
        bound.engine = "numba"
        return bound
