"""Compiled (numba) kernels of the ``cpu`` deformer: positions and normals in one pass over the vertices.

Every kernel runs ``prange`` over blocks of :data:`BLOCK` vertices and, per
vertex, blends the 3x4 handle transforms of its k influences into one
16-float vector accumulator (:func:`blend_row`: one cache-line load and one
FMA per influence; the handle table, n x 16 float32, stays in L1/L2), then
writes the position and, optionally, the normal:

- positions: ``v' = X_v [v; 1]``, ``X_v = sum_l w_l T_{i_l}``;
- blended-matrix normals (skeletons): ``n' = sign(det R) normalize(cof(R) n)``,
  ``R`` the 3x3 part of ``X_v``;
- approximate-affine normals (cages, [P10] section 5):
  ``n' = sign(det X) normalize(adj(X) (P + lambda I) n)`` with
  ``X = sum_l w_l^2 (c_l - cbar)(chat_l - chatbar)^T + lambda I`` and
  ``P = sum_l w_l^2 (c_l - cbar)(c_l - cbar)^T``, formed in float64 from the
  same differences (as the OpenCL kernel's double-precision fit).

Weights are vertex-major (m, k): fixed (int32 index, float32 weight) or
compact (uint16 index, float16 weight stored as its uint16 bits and decoded
exactly by :func:`half_tables`: ``w = ((h & 1023) + offset[h >> 10]) * scale[h >> 10]``).
The numpy references are :func:`rigslim.blend.linear_blend` and the
estimators' math in :mod:`rigslim.numerics.blended_normals` and :mod:`rigslim.numerics.affine_normals`.
"""

from __future__ import annotations

import os

import numpy as np

# libgomp's default spin-then-sleep wait made every parallel region of numba's OpenMP layer cost ~8 ms on a
# loaded 2-core VM (0.01 ms passive); read once when numba first starts its thread pool. A user's setting wins.
os.environ.setdefault("OMP_WAIT_POLICY", "passive")

from llvmlite import ir  # noqa: E402
from numba import njit, prange, types  # noqa: E402
from numba.extending import intrinsic  # noqa: E402

#: Vertices per parallel work unit (a few hundred KB of inputs and outputs).
BLOCK = 2048
#: Floats per handle record (the 12 entries of T_i, padded to 16: one 64-byte cache line).
HANDLE_STRIDE = 16
#: fastmath without reassociation (the per-vertex normal arithmetic): with ``reassoc`` LLVM vectorised
#: the k-term sums into gathers and horizontal adds, 2.3x slower than scalar FMA chains.
FAST = {"contract", "nnan", "ninf", "nsz", "arcp", "afn"}


def half_tables() -> tuple[np.ndarray, np.ndarray]:
    """(64,) float32 offset and scale tables that decode float16 bits ``h``.

    ``w = ((h & 1023) + offset[h >> 10]) * scale[h >> 10]``: for a biased
    exponent ``e > 0`` the implicit leading bit (``offset = 1024``) and
    ``scale = +-2^(e - 25)``; subnormals (``e = 0``) ``offset = 0``,
    ``scale = +-2^-24``. Exact in float32 for every finite half.
    """
    top = np.arange(64)
    e = top & 31
    sign = np.where(top >= 32, -1.0, 1.0)
    offset = np.where(e > 0, 1024.0, 0.0).astype(np.float32)
    scale = (sign * np.ldexp(1.0, np.where(e > 0, e - 25, -24))).astype(np.float32)
    return offset, scale


@intrinsic
def blend_row(typingctx, idx, wt, hf, v):
    """``sum_l w_{v,l} H[idx[v, l]]`` as one 16-float vector: a UniTuple(float32, 16) (entries 12-15 unused).

    numba has no SIMD types and LLVM does not vectorise twelve scalar accumulators over a runtime k,
    so the loop over the influences is emitted here with a ``<16 x float>`` accumulator: per
    influence one load of the handle's cache line and one FMA with the broadcast weight
    (measured 2.7x faster than twelve scalar FMA chains at k = 8). ``idx`` (m, k) int32 or uint16
    and ``wt`` (m, k) float32, or uint16 float16 bits (converted exactly by ``fpext half``), are
    C-contiguous; ``hf`` is the flat (n * 16) float32 handle table. Same summation order as a
    scalar loop over the influences.
    """
    if not all(isinstance(a, types.Array) and a.layout == "C" for a in (idx, wt, hf)):
        return None                     # the row arithmetic below assumes C-contiguous arrays
    tup = types.UniTuple(types.float32, HANDLE_STRIDE)
    half_bits = isinstance(wt.dtype, types.Integer)

    def codegen(context, builder, sig, args):
        idx_v, wt_v, hf_v, v_v = args
        ia = context.make_array(sig.args[0])(context, builder, idx_v)
        wa = context.make_array(sig.args[1])(context, builder, wt_v)
        ha = context.make_array(sig.args[2])(context, builder, hf_v)
        i32, i64 = ir.IntType(32), ir.IntType(64)
        vty = ir.VectorType(ir.FloatType(), HANDLE_STRIDE)
        k = builder.extract_value(ia.shape, 1)
        row = builder.mul(v_v, k)
        pre = builder.block
        head = builder.function.append_basic_block("blend_row.head")
        body = builder.function.append_basic_block("blend_row.body")
        done = builder.function.append_basic_block("blend_row.done")
        builder.branch(head)
        builder.position_at_end(head)
        l = builder.phi(i64)
        acc = builder.phi(vty)
        l.add_incoming(ir.Constant(i64, 0), pre)
        acc.add_incoming(ir.Constant(vty, [0.0] * HANDLE_STRIDE), pre)
        builder.cbranch(builder.icmp_signed("<", l, k), body, done)
        builder.position_at_end(body)
        p = builder.add(row, l)
        h = builder.load(builder.gep(ia.data, [p], inbounds=True))
        h = builder.zext(h, i64) if h.type.width < 64 else h           # indices are non-negative
        w = builder.load(builder.gep(wa.data, [p], inbounds=True))
        if half_bits:
            w = builder.fpext(builder.bitcast(w, ir.HalfType()), ir.FloatType())
        hp = builder.gep(ha.data, [builder.mul(h, ir.Constant(i64, HANDLE_STRIDE))], inbounds=True)
        hv = builder.load(builder.bitcast(hp, vty.as_pointer()), align=4)
        wv = builder.insert_element(ir.Constant(vty, ir.Undefined), w, ir.Constant(i32, 0))
        wv = builder.shuffle_vector(wv, ir.Constant(vty, ir.Undefined),
                                    ir.Constant(ir.VectorType(i32, HANDLE_STRIDE), [0] * HANDLE_STRIDE))
        nacc = builder.fadd(acc, builder.fmul(wv, hv, flags=("contract",)), flags=("contract",))
        l.add_incoming(builder.add(l, ir.Constant(i64, 1)), builder.block)
        acc.add_incoming(nacc, builder.block)
        builder.branch(head)
        builder.position_at_end(done)
        out = context.get_constant_undef(tup)
        for i in range(HANDLE_STRIDE):
            out = builder.insert_value(out, builder.extract_element(acc, ir.Constant(i32, i)), i)
        return out

    return tup(idx, wt, hf, types.intp), codegen


@njit(inline="always", fastmath=FAST)
def _weight(wt, v, l, offset, scale):
    if offset is None:
        return wt[v, l]
    h = np.int32(wt[v, l])
    t = h >> 10
    return (np.float32(h & 1023) + offset[t]) * scale[t]


@njit(parallel=True, fastmath=FAST, cache=True)
def blend_skin(rest, idx, wt, offset, scale, H, out_p, N0, out_n):  # pragma: no cover - numba
    """Positions (and blended-matrix normals when ``N0`` is not None) of every vertex.

    Parameters
    ----------
    rest : (m, 3) float32
    idx : (m, k) int32 or uint16
    wt : (m, k) float32, or uint16 float16 bits when ``offset`` is not None
    offset, scale : (64,) float32 from :func:`half_tables`, or None (float32 weights)
    H : (n, 16) float32, C-contiguous
        Rows of the handle transforms ``T_i`` (row-major 3x4), padded to :data:`HANDLE_STRIDE`.
    out_p : (m, 3) float32, written
    N0 : (m, 3) float32 rest normals, or None
    out_n : (m, 3) float32, written when N0 is not None
    """
    m, k = idx.shape
    Hf = H.ravel()
    nblocks = (m + BLOCK - 1) // BLOCK
    for b in prange(nblocks):
        end = min(m, (b + 1) * BLOCK)
        for v in range(b * BLOCK, end):
            a = blend_row(idx, wt, Hf, v)
            a0, a1, a2, a3, a4, a5, a6, a7, a8, a9, a10, a11 = a[0], a[1], a[2], a[3], a[4], a[5], a[6], a[7], \
                a[8], a[9], a[10], a[11]
            x = rest[v, 0]
            y = rest[v, 1]
            z = rest[v, 2]
            out_p[v, 0] = a0 * x + a1 * y + a2 * z + a3
            out_p[v, 1] = a4 * x + a5 * y + a6 * z + a7
            out_p[v, 2] = a8 * x + a9 * y + a10 * z + a11
            if N0 is not None:
                # rows r0 = (a0, a1, a2), r1 = (a4, a5, a6), r2 = (a8, a9, a10);
                # cof(R) n = ((r1 x r2) . n, (r2 x r0) . n, (r0 x r1) . n)
                c0 = a5 * a10 - a6 * a9
                c1 = a6 * a8 - a4 * a10
                c2 = a4 * a9 - a5 * a8
                d0 = a9 * a2 - a10 * a1
                d1 = a10 * a0 - a8 * a2
                d2 = a8 * a1 - a9 * a0
                e0 = a1 * a6 - a2 * a5
                e1 = a2 * a4 - a0 * a6
                e2 = a0 * a5 - a1 * a4
                nx = N0[v, 0]
                ny = N0[v, 1]
                nz = N0[v, 2]
                px = c0 * nx + c1 * ny + c2 * nz
                py = d0 * nx + d1 * ny + d2 * nz
                pz = e0 * nx + e1 * ny + e2 * nz
                det = a0 * c0 + a1 * c1 + a2 * c2
                ln = np.sqrt(px * px + py * py + pz * pz)
                s = np.float32(0.0)
                if ln > 0:
                    s = np.float32(1.0) / ln
                if det < 0:
                    s = -s
                out_n[v, 0] = s * px
                out_n[v, 1] = s * py
                out_n[v, 2] = s * pz


@njit(parallel=True, fastmath=FAST, cache=True)
def blend_cage(rest, idx, wt, offset, scale, H, C, out_p, N0, ridge, out_n):  # pragma: no cover - numba
    """Positions (and approximate-affine normals when ``N0`` is not None) of every vertex.

    Parameters
    ----------
    rest, idx, wt, offset, scale, H, out_p : as :func:`blend_skin`
    C : (n, 6) float64
        Deformed handle positions ``chat_i = T_i [c_i; 1]`` and rest ``c_i``, each centred on its mean.
    N0 : (m, 3) float32 rest normals, or None
    ridge : (m,) float32
        ``lambda`` per vertex (0 where the fit is determined).
    out_n : (m, 3) float32, written when N0 is not None
    """
    m, k = idx.shape
    Hf = H.ravel()
    nblocks = (m + BLOCK - 1) // BLOCK
    for b in prange(nblocks):
        end = min(m, (b + 1) * BLOCK)
        for v in range(b * BLOCK, end):
            a = blend_row(idx, wt, Hf, v)
            a0, a1, a2, a3, a4, a5, a6, a7, a8, a9, a10, a11 = a[0], a[1], a[2], a[3], a[4], a[5], a[6], a[7], \
                a[8], a[9], a[10], a[11]
            sw = hx = hy = hz = cx = cy = cz = 0.0
            if N0 is not None:
                for l in range(k):
                    h = idx[v, l]
                    w = _weight(wt, v, l, offset, scale)
                    w2 = np.float64(w) * np.float64(w)
                    sw += w2
                    hx += w2 * C[h, 0]
                    hy += w2 * C[h, 1]
                    hz += w2 * C[h, 2]
                    cx += w2 * C[h, 3]
                    cy += w2 * C[h, 4]
                    cz += w2 * C[h, 5]
            x = rest[v, 0]
            y = rest[v, 1]
            z = rest[v, 2]
            out_p[v, 0] = a0 * x + a1 * y + a2 * z + a3
            out_p[v, 1] = a4 * x + a5 * y + a6 * z + a7
            out_p[v, 2] = a8 * x + a9 * y + a10 * z + a11
            if N0 is not None:
                inv = 1.0 / sw if sw > 0 else 0.0
                hx *= inv
                hy *= inv
                hz *= inv
                cx *= inv
                cy *= inv
                cz *= inv
                lam = np.float64(ridge[v])
                # rows of X + lambda I (x..) and P + lambda I (p..)
                x00 = x11 = x22 = lam
                x01 = x02 = x10 = x12 = x20 = x21 = 0.0
                p00 = p11 = p22 = lam
                p01 = p02 = p12 = 0.0
                for l in range(k):
                    h = idx[v, l]
                    w = np.float64(_weight(wt, v, l, offset, scale))
                    w2 = w * w
                    qx = C[h, 3] - cx
                    qy = C[h, 4] - cy
                    qz = C[h, 5] - cz
                    ex = C[h, 0] - hx
                    ey = C[h, 1] - hy
                    ez = C[h, 2] - hz
                    dx = w2 * qx
                    dy = w2 * qy
                    dz = w2 * qz
                    x00 += dx * ex
                    x01 += dx * ey
                    x02 += dx * ez
                    x10 += dy * ex
                    x11 += dy * ey
                    x12 += dy * ez
                    x20 += dz * ex
                    x21 += dz * ey
                    x22 += dz * ez
                    p00 += dx * qx
                    p01 += dx * qy
                    p02 += dx * qz
                    p11 += dy * qy
                    p12 += dy * qz
                    p22 += dz * qz
                nx = np.float64(N0[v, 0])
                ny = np.float64(N0[v, 1])
                nz = np.float64(N0[v, 2])
                qx = p00 * nx + p01 * ny + p02 * nz
                qy = p01 * nx + p11 * ny + p12 * nz
                qz = p02 * nx + p12 * ny + p22 * nz
                # adj(X) q = q.x (r1 x r2) + q.y (r2 x r0) + q.z (r0 x r1), rows r_i of X
                c0 = x11 * x22 - x12 * x21
                c1 = x12 * x20 - x10 * x22
                c2 = x10 * x21 - x11 * x20
                d0 = x21 * x02 - x22 * x01
                d1 = x22 * x00 - x20 * x02
                d2 = x20 * x01 - x21 * x00
                e0 = x01 * x12 - x02 * x11
                e1 = x02 * x10 - x00 * x12
                e2 = x00 * x11 - x01 * x10
                px = qx * c0 + qy * d0 + qz * e0
                py = qx * c1 + qy * d1 + qz * e1
                pz = qx * c2 + qy * d2 + qz * e2
                det = x00 * c0 + x01 * c1 + x02 * c2
                ln = np.sqrt(px * px + py * py + pz * pz)
                s = 1.0 / ln if ln > 0 else 0.0
                if det < 0:
                    s = -s
                out_n[v, 0] = s * px
                out_n[v, 1] = s * py
                out_n[v, 2] = s * pz


@njit(parallel=True, cache=True)
def copy_rows(src, dst):  # pragma: no cover - numba
    """``dst[:] = src`` over the same blocks as the kernels (a copy-bandwidth probe on the same threads)."""
    m = src.shape[0]
    nblocks = (m + BLOCK - 1) // BLOCK
    for b in prange(nblocks):
        end = min(m, (b + 1) * BLOCK)
        for v in range(b * BLOCK, end):
            for j in range(src.shape[1]):
                dst[v, j] = src[v, j]
