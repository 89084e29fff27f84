"""Compiled (numba) kernels of the ``cpu`` deformer: positions and normals in one pass over the vertices.

Every kernel runs ``prange`` over blocks of :data:`BLOCK` vertices and, per
vertex, blends the 3x4 handle transforms of its k influences into one
16-float vector accumulator (:func:`blend_row`: one cache-line load and one
FMA per influence; the handle table, n x 16 float32, stays in L1/L2), then
writes the position and, optionally, the normal:

- positions: ``v' = X_v [v; 1]``, ``X_v = sum_l w_l T_{i_l}``;
- blended-matrix normals (skeletons): ``n' = sign(det R) normalize(cof(R) n)``,
  ``R`` the 3x3 part of ``X_v``, computed per sub-block of :data:`SUB` vertices on
  8-lane vectors (:func:`cofactor_normals`) from a structure-of-arrays scratch;
- approximate-affine normals (cages, [P10] section 5):
  ``n' = sign(det X) normalize(adj(X) (P + lambda I) n)`` with
  ``X = sum_l w_l^2 (c_l - cbar)(chat_l - chatbar)^T + lambda I`` and
  ``P = sum_l w_l^2 (c_l - cbar)(c_l - cbar)^T``, formed in float64 from the
  same differences (as the OpenCL kernel's double-precision fit).

Weights are vertex-major (m, k): fixed (int32 index, float32 weight) or
compact (uint16 index, float16 weight stored as its uint16 bits and decoded
exactly by :func:`half_tables`: ``w = ((h & 1023) + offset[h >> 10]) * scale[h >> 10]``).
The numpy references are :func:`rigslim.numerics.blend.linear_blend` and the
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
from numba.core import cgutils  # noqa: E402
from numba.extending import intrinsic  # noqa: E402

#: Vertices per parallel work unit (a few hundred KB of inputs and outputs).
BLOCK = 2048
#: Vertices per sub-block of the fused normal pass (a multiple of :data:`LANES`; :data:`BLOCK` is a multiple of it).
SUB = 64
#: float32 lanes of the explicit vector code of :func:`cofactor_normals` (one AVX ymm register).
LANES = 8
#: float32 scratch per block of the skeleton normal pass: the 9 blended 3x3 entries, each a
#: structure-of-arrays row of :data:`SUB` vertices.
SCRATCH = 9 * SUB
assert BLOCK % SUB == 0 and SUB % LANES == 0, "only the mesh's last sub-block may be partial"
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


@intrinsic
def cofactor_normals(typingctx, W, N, O, row0):
    """Blended-matrix normals of one sub-block of :data:`SUB` vertices, :data:`LANES` per vector instruction.

    ``W`` is one (:data:`SCRATCH`,) float32 scratch row in structure-of-arrays order: rows 0-8 hold
    ``R_00 R_01 R_02 R_10 ... R_22`` of the :data:`SUB` vertices. Their rest normals are
    ``N[row0 : row0 + SUB]`` and ``O[row0 : row0 + SUB]`` receives
    ``n' = sign(det R) cof(R) n / |cof(R) n|`` with
    ``cof(R) n = ((r_1 x r_2) . n, (r_2 x r_0) . n, (r_0 x r_1) . n)`` (rows ``r_i`` of ``R``) and
    ``det R = r_0 . (r_1 x r_2)``; ``N`` and ``O`` are (., 3) float32, C-contiguous, read and written
    as :data:`LANES` x 3 floats per step (one wide load / store, de- / re-interleaved by shuffles).
    numba has no SIMD types and LLVM did not vectorise this loop written in Python, so it is emitted
    here on ``<8 x float>`` values with fast-math flags: the three cross products, one ``sqrt`` and a
    reciprocal (LLVM emits ``vrsqrtps`` + one Newton step), ``copysign`` for the orientation and
    ``maxnum(|p|^2, 1e-30)`` for degenerate blends (their normal is 0, as the reference's guarded
    division).
    """
    arrays = (W, N, O)
    if not all(isinstance(a, types.Array) and a.layout == "C" and a.dtype == types.float32 for a in arrays):
        return None
    if W.ndim != 1 or N.ndim != 2 or O.ndim != 2:
        return None

    def codegen(context, builder, sig, args):
        wa, na, oa = (context.make_array(t)(context, builder, v) for t, v in zip(sig.args[:3], args[:3], strict=False))
        f32, i32, i64 = ir.FloatType(), ir.IntType(32), ir.IntType(64)
        vty = ir.VectorType(f32, LANES)
        wide = ir.VectorType(f32, 3 * LANES)
        fl = ("fast",)
        mod = builder.module
        v_sqrt = cgutils.get_or_insert_function(mod, ir.FunctionType(vty, [vty]), f"llvm.sqrt.v{LANES}f32")
        v_max = cgutils.get_or_insert_function(mod, ir.FunctionType(vty, [vty, vty]), f"llvm.maxnum.v{LANES}f32")
        v_sign = cgutils.get_or_insert_function(mod, ir.FunctionType(vty, [vty, vty]), f"llvm.copysign.v{LANES}f32")
        base = builder.mul(args[3], ir.Constant(i64, 3))
        pre = builder.block
        head = builder.function.append_basic_block("cofactor_normals.head")
        body = builder.function.append_basic_block("cofactor_normals.body")
        done = builder.function.append_basic_block("cofactor_normals.done")
        builder.branch(head)
        builder.position_at_end(head)
        j = builder.phi(i64)
        j.add_incoming(ir.Constant(i64, 0), pre)
        builder.cbranch(builder.icmp_signed("<", j, ir.Constant(i64, SUB)), body, done)
        builder.position_at_end(body)

        def row(r):
            p = builder.gep(wa.data, [builder.add(j, ir.Constant(i64, r * SUB))], inbounds=True)
            return builder.bitcast(p, vty.as_pointer())

        def shuffle(a, b, mask):
            return builder.shuffle_vector(a, b, ir.Constant(ir.VectorType(i32, len(mask)), mask))

        def mul(a, b):
            return builder.fmul(a, b, flags=fl)

        def add(a, b):
            return builder.fadd(a, b, flags=fl)

        def sub(a, b):
            return builder.fsub(a, b, flags=fl)

        def dot(a, b):
            return add(add(mul(a[0], b[0]), mul(a[1], b[1])), mul(a[2], b[2]))

        def cross(a, b):
            return (sub(mul(a[1], b[2]), mul(a[2], b[1])), sub(mul(a[2], b[0]), mul(a[0], b[2])),
                    sub(mul(a[0], b[1]), mul(a[1], b[0])))

        R = [builder.load(row(r), align=4) for r in range(9)]
        at = builder.add(base, builder.mul(j, ir.Constant(i64, 3)))
        xyz = builder.load(builder.bitcast(builder.gep(na.data, [at], inbounds=True), wide.as_pointer()), align=4)
        n = [shuffle(xyz, ir.Constant(wide, ir.Undefined), [3 * i + c for i in range(LANES)]) for c in range(3)]
        r0, r1, r2 = R[0:3], R[3:6], R[6:9]
        c12, c20, c01 = cross(r1, r2), cross(r2, r0), cross(r0, r1)
        p = (dot(c12, n), dot(c20, n), dot(c01, n))
        det = dot(r0, c12)
        l2 = builder.call(v_max, [dot(p, p), ir.Constant(vty, [1e-30] * LANES)])
        s = builder.fdiv(ir.Constant(vty, [1.0] * LANES), builder.call(v_sqrt, [l2]), flags=fl)
        s = builder.call(v_sign, [s, det])
        ox, oy, oz = (mul(s, pc) for pc in p)
        xy = shuffle(ox, oy, list(range(2 * LANES)))
        zz = shuffle(oz, ir.Constant(vty, ir.Undefined), list(range(LANES)) + [LANES] * LANES)
        inter = shuffle(xy, zz, [c * LANES + i for i in range(LANES) for c in range(3)])
        builder.store(inter, builder.bitcast(builder.gep(oa.data, [at], inbounds=True), wide.as_pointer()), align=4)
        j.add_incoming(builder.add(j, ir.Constant(i64, LANES)), builder.block)
        builder.branch(head)
        builder.position_at_end(done)
        return context.get_dummy_value()

    return types.none(W, N, O, types.intp), codegen


@njit(inline="always", fastmath=FAST)
def _weight(wt, v, l, offset, scale):
    if offset is None:
        return wt[v, l]
    h = np.int32(wt[v, l])
    t = h >> 10
    return (np.float32(h & 1023) + offset[t]) * scale[t]


@njit(parallel=True, fastmath=FAST, cache=True)
def blend_skin(rest, idx, wt, offset, scale, H, out_p, N0, out_n, W, tail):  # pragma: no cover - numba
    """Positions (and blended-matrix normals when ``N0`` is not None) of every vertex.

    With normals, each block runs in sub-blocks of :data:`SUB` vertices: the blend loop writes the
    positions and stores the blended 3x3 ``R`` of each vertex into the block's scratch row ``W[b]``
    (structure of arrays); :func:`cofactor_normals` then computes the :data:`SUB` normals with
    vector instructions straight from ``N0`` into ``out_n``. Only the mesh's last sub-block can be
    partial (:data:`BLOCK` is a multiple of :data:`SUB`); it goes through ``tail``, whose rows past
    the mesh hold stale finite values and are not copied out. The scratch is allocated once by the
    caller.

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
    W : (ceil(m / BLOCK), SCRATCH) float32 scratch (finite values), or None when N0 is None
    tail : (2, SUB, 3) float32 scratch (finite values), or None when N0 is None
    """
    m, k = idx.shape
    Hf = H.ravel()
    nblocks = (m + BLOCK - 1) // BLOCK
    for b in prange(nblocks):
        start = b * BLOCK
        end = min(m, start + BLOCK)
        if N0 is None:
            for v in range(start, end):
                a = blend_row(idx, wt, Hf, v)
                x = rest[v, 0]
                y = rest[v, 1]
                z = rest[v, 2]
                out_p[v, 0] = a[0] * x + a[1] * y + a[2] * z + a[3]
                out_p[v, 1] = a[4] * x + a[5] * y + a[6] * z + a[7]
                out_p[v, 2] = a[8] * x + a[9] * y + a[10] * z + a[11]
        else:
            Wb = W[b]
            for s0 in range(start, end, SUB):
                s1 = min(end, s0 + SUB)
                for v in range(s0, s1):
                    a = blend_row(idx, wt, Hf, v)
                    x = rest[v, 0]
                    y = rest[v, 1]
                    z = rest[v, 2]
                    out_p[v, 0] = a[0] * x + a[1] * y + a[2] * z + a[3]
                    out_p[v, 1] = a[4] * x + a[5] * y + a[6] * z + a[7]
                    out_p[v, 2] = a[8] * x + a[9] * y + a[10] * z + a[11]
                    j = v - s0
                    Wb[j] = a[0]
                    Wb[SUB + j] = a[1]
                    Wb[2 * SUB + j] = a[2]
                    Wb[3 * SUB + j] = a[4]
                    Wb[4 * SUB + j] = a[5]
                    Wb[5 * SUB + j] = a[6]
                    Wb[6 * SUB + j] = a[8]
                    Wb[7 * SUB + j] = a[9]
                    Wb[8 * SUB + j] = a[10]
                if s1 - s0 == SUB:
                    cofactor_normals(Wb, N0, out_n, s0)
                else:                   # the mesh's last, partial sub-block: through the padded tail arrays
                    for v in range(s0, s1):
                        for c in range(3):
                            tail[0, v - s0, c] = N0[v, c]
                    cofactor_normals(Wb, tail[0], tail[1], 0)
                    for v in range(s0, s1):
                        for c in range(3):
                            out_n[v, c] = tail[1, v - s0, c]


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
