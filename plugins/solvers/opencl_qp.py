"""Batched small QPs on an OpenCL device (kernel ``small_qp.cl``).

The per-vertex Hessians, constraint rows and right-hand sides stay on the
device for the whole solve (uploaded once, in colour order); each call sends
a colour class's linear terms and starting points and reads back the
solutions. Same algorithm as :func:`rigslim.numerics.small_qp.solve_small_qps`, which is
its reference.
"""

from __future__ import annotations

import numpy as np


class BatchedQP:
    """Device-resident ``H`` (B, k, k), ``C`` (B, q, k), ``d`` (B, q); solve contiguous ranges.

    Parameters
    ----------
    H, C, d : arrays
        One problem per row, in the order ranges will address them.
    nonneg : bool
    device : str, optional
        OpenCL device spec (:func:`rigslim.device.opencl.get_runtime`).
    """

    def __init__(self, H, C, d, *, nonneg: bool, device: str | None = None):
        import pyopencl as cl

        from rigslim.device.opencl import OpenCLUnavailable, build_program, get_runtime

        self.cl = cl
        self.runtime = get_runtime(device)
        if "cl_khr_fp64" not in self.runtime.device.extensions:
            raise OpenCLUnavailable(f"{self.runtime.name} has no double precision", field="device",
                                    fix="choose a device with cl_khr_fp64 (any recent GPU or PoCL), or device: numpy")
        nb, k, _ = H.shape
        q = C.shape[1]
        self.k = k
        opts = (f"-DK={k}", f"-DQ={q}", f"-DNONNEG={int(bool(nonneg))}", f"-DMAXIT={3 * k + 10}")
        self.program = build_program(self.runtime, "small_qp.cl", opts)
        self.kernel = cl.Kernel(self.program, "small_qp")
        mf = cl.mem_flags
        ctx = self.runtime.context
        self.H = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=np.ascontiguousarray(H, dtype=np.float64))
        self.C = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=np.ascontiguousarray(C, dtype=np.float64))
        self.d = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=np.ascontiguousarray(d, dtype=np.float64))
        cap = max(int(nb), 1)
        self.g = cl.Buffer(ctx, mf.READ_ONLY, size=cap * k * 8)
        self.x0 = cl.Buffer(ctx, mf.READ_ONLY, size=cap * k * 8)
        self.x = cl.Buffer(ctx, mf.WRITE_ONLY, size=cap * k * 8)
        self.it = cl.Buffer(ctx, mf.WRITE_ONLY, size=cap * 4)
        self.last_iterations: np.ndarray | None = None  # per problem, of the last solve_range

    def solve_range(self, lo: int, hi: int, g, x0) -> np.ndarray:
        """Solve problems ``lo..hi-1`` with linear terms ``g`` and feasible starts ``x0`` (hi-lo, k)."""
        cl = self.cl
        count = hi - lo
        if count == 0:
            return np.zeros((0, self.k))
        queue = self.runtime.queue
        cl.enqueue_copy(queue, self.g, np.ascontiguousarray(g, dtype=np.float64))
        cl.enqueue_copy(queue, self.x0, np.ascontiguousarray(x0, dtype=np.float64))
        self.kernel(queue, (count,), None, self.H, self.C, self.d, self.g, self.x0, self.x, self.it,
                    np.int32(lo), np.int32(count))
        out = np.empty((count, self.k))
        its = np.empty(count, dtype=np.int32)
        cl.enqueue_copy(queue, out, self.x)
        cl.enqueue_copy(queue, its, self.it)
        self.last_iterations = its
        return out


def solve_small_qps_opencl(H, g, C, d, nonneg: bool, x0, device: str | None = None) -> np.ndarray:
    """One-shot batched solve on the device (test and benchmark helper)."""
    qp = BatchedQP(H, C, d, nonneg=nonneg, device=device)
    return qp.solve_range(0, len(g), g, x0)
