"""The OpenCL deformer: ``kernels/blend.cl``, one work-item per vertex.

At bind the rest positions, the packed weights (fixed-k int32/float32,
compact uint16/float16, or full CSR) and the per-vertex normal data go to the
device once; each frame uploads only the handle records (n x 5 float4) and
runs one kernel that writes positions and, optionally, normals. Kernel time
comes from the profiling event of the launch (``last_seconds``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Annotated, Literal

import numpy as np
from pydantic import Field

from rigslim.errors import StepError
from rigslim.plugin import Deformer
from rigslim.plugins.deformers.base import (
    DeformerParams,
    DeviceBound,
    Layout,
    check_weights,
    handle_data,
    n_handles_of,
    pack_weights,
    resolve_normals,
    rest_normal_data,
)

if TYPE_CHECKING:
    import pyopencl

_NORMALS_CODE = {None: 0, "blended-matrix": 1, "approximate-affine": 2}
_LAYOUT_CODE = {"fixed": 0, "compact": 1, "csr": 2}


class OpenCLBound(DeviceBound):
    """Device buffers for one mesh and weights, reused across frames."""

    backend = "opencl"

    def __init__(self, mesh, weights, normals_mode, handles, layout: str, device: str | None,
                 local_size: int | None, fit_precision: str = "auto"):
        import pyopencl as cl

        from rigslim.device.opencl import check_local_size, get_runtime

        n = n_handles_of(weights)
        super().__init__(mesh.n_vertices, n, normals_mode)
        self.runtime = rt = get_runtime(device)
        check_local_size(rt, local_size, source="opencl deformer")   # the device's bound, before any upload
        has_fp64 = "cl_khr_fp64" in rt.device.extensions
        if fit_precision == "double" and not has_fp64:
            raise StepError(f"{rt.name} has no double precision (cl_khr_fp64)", field="fit_precision",
                            fix="use fit_precision: single or auto")
        #: approximate-affine fit in double precision (positions and blended-matrix normals stay float32)
        self.fit_double = normals_mode == "approximate-affine" and fit_precision != "single" and has_fp64
        self.packed = pack_weights(weights, layout, n)
        self.layout = self.packed.layout
        self.local_size = local_size
        self.C0 = handles.cage.V if (handles is not None and handles.is_cage) else None
        m = self.n_vertices
        mf = cl.mem_flags
        ctx = rt.context

        def upload(a):
            return cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=np.ascontiguousarray(a))

        rest = np.zeros((m, 4), dtype=np.float32)
        rest[:, :3] = mesh.V
        self._rest = upload(rest)
        if self.layout == "csr":
            self._indices = upload(self.packed.indices if self.packed.indices.size else np.zeros(1, np.int32))
            self._weights = upload(self.packed.values if self.packed.values.size else np.zeros(1, np.float32))
            self._indptr = upload(self.packed.indptr)
        else:  # slot-major: work-item v reads [l * m + v], so neighbours read neighbouring words
            self._indices = upload(self.packed.indices.T.copy())
            self._weights = upload(self.packed.values.T.copy())
            self._indptr = None
        self._handles = cl.Buffer(ctx, mf.READ_ONLY, size=n * 5 * 16)
        self._positions = cl.Buffer(ctx, mf.WRITE_ONLY, size=max(m, 1) * 12)
        self._mesh, self._weights_in, self._handles_in = mesh, self.packed.effective, handles
        self._normal_data: pyopencl.Buffer | None = None  # uploaded, and the normals kernel built, on the first
        self._normals: pyopencl.Buffer | None = None      # normals frame
        self._kernels: dict[bool, pyopencl.Kernel] = {}
        self._host_positions = np.empty((m, 3), dtype=np.float32)
        self._host_normals = np.empty((m, 3), dtype=np.float32)

    def _kernel(self, normals: bool):
        """The kernel for this layout and normal mode, built (and normal data uploaded) on first use."""
        import pyopencl as cl

        from rigslim.device.opencl import build_program, check_local_size

        if normals and self._normal_data is None:
            data = rest_normal_data(self.normals_mode, self._mesh, self._weights_in, self._handles_in)
            mf = cl.mem_flags
            self._normal_data = cl.Buffer(self.runtime.context, mf.READ_ONLY | mf.COPY_HOST_PTR,
                                          hostbuf=np.ascontiguousarray(data, dtype=np.float32))
            self._normals = cl.Buffer(self.runtime.context, mf.WRITE_ONLY, size=max(self.n_vertices, 1) * 12)
        if normals not in self._kernels:
            options = [f"-DLAYOUT={_LAYOUT_CODE[self.layout]}", f"-DK={max(self.packed.k, 1)}",
                       f"-DNORMALS={_NORMALS_CODE[self.normals_mode] if normals else 0}",
                       f"-DFIT_DOUBLE={int(self.fit_double)}", "-cl-mad-enable"]
            kernel = cl.Kernel(build_program(self.runtime, "blend.cl", options), "blend")
            # the kernel's own bound (registers) can be below the device's: refused here, not by the launch
            check_local_size(self.runtime, self.local_size, kernel, source="opencl deformer")
            self._kernels[normals] = kernel
        return self._kernels[normals]

    def _args(self, normals: bool) -> list:
        args = [np.int32(self.n_vertices), self._rest, self._indices, self._weights, self._handles, self._positions]
        if self._indptr is not None:
            args.append(self._indptr)
        if normals:
            args += [self._normal_data, self._normals]
        return args

    def launch(self, T: np.ndarray, normals: bool = False, read: bool = True):
        """Upload T, run the kernel; returns the kernel event (positions/normals stay on the device unless read)."""
        import pyopencl as cl

        queue = self.runtime.queue
        self._records = handle_data(T, self.C0)    # kept alive until the non-blocking upload is done
        cl.enqueue_copy(queue, self._handles, self._records, is_blocking=False)
        kernel = self._kernel(normals)
        global_size = self.n_vertices
        local = None
        if self.local_size is not None:
            global_size = -(-self.n_vertices // self.local_size) * self.local_size
            local = (self.local_size,)
        event = kernel(queue, (max(global_size, 1),), local, *self._args(normals))
        if read:
            cl.enqueue_copy(queue, self._host_positions, self._positions, is_blocking=not normals)
            if normals:
                assert self._normals is not None  # allocated by self._kernel(normals=True)
                cl.enqueue_copy(queue, self._host_normals, self._normals, is_blocking=True)
        event.wait()
        self.last_seconds = (event.profile.end - event.profile.start) * 1e-9
        return event

    def bytes_per_frame(self, normals: bool) -> int:
        m = self.n_vertices
        moved = 16 * m + self.packed.nbytes + self.n_handles * 80 + 12 * m
        if normals:
            moved += 16 * m + 12 * m
        return int(moved)

    def close(self) -> None:
        for name in ("_rest", "_indices", "_weights", "_indptr", "_handles", "_positions", "_normal_data",
                     "_normals"):
            buf = getattr(self, name, None)
            if buf is not None:
                buf.release()
                setattr(self, name, None)


class OpenCLDeformer(Deformer):
    """Linear blend skinning in an OpenCL kernel, one work-item per vertex.

    Notes
    -----
    Work-item v computes ``X_v = sum_l w_l T_{i_l}`` (three float4 rows) and
    ``v' = X_v [v; 1]``; with normals, ``n' = sign(det R) normalize(cof(R) n)``
    (blended matrix, ``R`` the 3x3 part of ``X_v``) or
    ``n' = sign(det X) normalize(adj(X) (P + lambda I) n)`` (approximate affine,
    see :mod:`rigslim.numerics.affine_normals`). The numpy
    reference is :class:`rigslim.plugins.deformers.numpy_deformer.NumpyDeformer`.
    """

    name = "opencl"
    summary = ("OpenCL kernel (kernels/blend.cl), one work-item per vertex; fixed-k, compact 16-bit or "
               "full CSR weights; optional normals in the same kernel; buffers reused across frames")

    class Params(DeformerParams):
        device: str | None = None
        """OpenCL device spec: auto, gpu, cpu or part of a device/platform name."""
        layout: Layout = "auto"
        """Weight layout on the device: auto (fixed for reduced weights, csr for full sparse weights), fixed (int32 +
        float32), compact (uint16 + float16) or csr."""
        local_size: Annotated[int, Field(ge=1)] | None = None
        """Work-group size (None lets the driver choose); at most the device's and the kernel's work-group size
        (``CL_DEVICE_MAX_WORK_GROUP_SIZE``, ``CL_KERNEL_WORK_GROUP_SIZE``), checked before the first launch."""
        fit_precision: Literal["auto", "single", "double"] = "auto"
        """Arithmetic of the approximate-affine fit: auto (double where the device has cl_khr_fp64), single (float32:
        error about cond(P) * 6e-8 rad) or double."""

    def bind(self, mesh, weights, params=None, handles=None, ctx=None) -> OpenCLBound:
        params = params if params is not None else self.Params()
        weights = check_weights(mesh, weights, source="opencl deformer")
        mode = resolve_normals(params.normals, handles)
        return OpenCLBound(mesh, weights, mode, handles, params.layout, params.device, params.local_size,
                           params.fit_precision)
