/* Linear blending of handle transforms, one work-item per vertex ([P10] sec. 5,
 * docs/algorithms.md sections 1 and 3). numpy reference: rigslim.blend.linear_blend,
 * rigslim.plugins.normals.{blended_matrix,approximate_affine}.
 *
 *   v' = X_v [v; 1],  X_v = sum_l w_l T_{i_l}                    (positions)
 *   n' = sign(det R) normalize(cof(R) n),  R = 3x3 part of X_v    (NORMALS == 1, skeletons)
 *   n' = sign(det X) normalize(adj(X) q),  q = (P + lambda I) n,  (NORMALS == 2, cages)
 *        X = sum_l w_l^2 (c_l - cbar)(chat_l - chatbar)^T + lambda I,
 *        P = sum_l w_l^2 (c_l - cbar)(c_l - cbar)^T (both in the kernel; lambda per vertex)
 *
 * Compile-time options:
 *   LAYOUT   0 fixed (int32 index, float32 weight, slot-major [l*m + v]),
 *            1 compact (uint16 index, float16 weight, slot-major),
 *            2 csr (row pointers, int32 columns, float32 values)
 *   K        slots per vertex (fixed and compact layouts)
 *   NORMALS  0 none, 1 blended matrix, 2 approximate affine
 *   FIT_DOUBLE  1: the approximate-affine fit (centroids, X, P, adjugate) in double precision
 *            (cl_khr_fp64). In float32 its error grows like cond(P) * 6e-8 rad (about 1e-4 rad
 *            at cond(P) = 1e3, which nearly coplanar influences reach); positions stay float32.
 *
 * Per-handle records (float4 each, HANDLE_STRIDE per handle):
 *   T row 0, T row 1, T row 2, (chat, 0) = T [c0; 1], (c0, 0).
 */

#define HANDLE_STRIDE 5

#ifndef FIT_DOUBLE
#define FIT_DOUBLE 0
#endif
#if FIT_DOUBLE
#pragma OPENCL EXTENSION cl_khr_fp64 : enable
typedef double real;
typedef double3 real3;
#define TO_REAL3(x) convert_double3(x)
#else
typedef float real;
typedef float3 real3;
#define TO_REAL3(x) (x)
#endif

#ifndef LAYOUT
#define LAYOUT 0
#endif
#ifndef K
#define K 4
#endif
#ifndef NORMALS
#define NORMALS 0
#endif

#if LAYOUT == 1
#define INDEX_T ushort
#define WEIGHT_T half
#define LOAD_W(p) vload_half((p), weights)
#else
#define INDEX_T int
#define WEIGHT_T float
#define LOAD_W(p) weights[(p)]
#endif

#if LAYOUT == 2
#define ROW_ARGS , __global const int *restrict indptr
#define ROW_BEGIN const int base = indptr[v]; const int count = indptr[v + 1] - base; const int stride = 1;
#else
#define ROW_ARGS
#define ROW_BEGIN const int base = v; const int count = K; const int stride = m;
#endif

#if NORMALS
#define NORMAL_ARGS , __global const float4 *restrict normal_data, __global float *restrict out_normals
#else
#define NORMAL_ARGS
#endif

inline float3 unit_or_zero(float3 n)
{
    const float len = length(n);
    return len > 0.0f ? n / len : n;
}

__kernel void blend(const int m,
                    __global const float4 *restrict rest,      /* (m) rest positions, w unused   */
                    __global const INDEX_T *restrict indices,  /* slot-major or csr columns      */
                    __global const WEIGHT_T *restrict weights,
                    __global const float4 *restrict handles,   /* (n * HANDLE_STRIDE) records    */
                    __global float *restrict out_positions     /* (3m) packed                    */
                    ROW_ARGS NORMAL_ARGS)
{
    const int v = get_global_id(0);
    if (v >= m)
        return;
    ROW_BEGIN
    float4 x0 = (float4)(0.0f), x1 = (float4)(0.0f), x2 = (float4)(0.0f);
#if NORMALS == 2
    real sw = 0;
    real3 cbar = (real3)(0), hbar = (real3)(0);
#endif
    for (int t = 0; t < count; ++t) {
        const int p = base + t * stride;
        const int h = HANDLE_STRIDE * (int)indices[p];
        const float w = LOAD_W(p);
        x0 = fma((float4)(w), handles[h], x0);
        x1 = fma((float4)(w), handles[h + 1], x1);
        x2 = fma((float4)(w), handles[h + 2], x2);
#if NORMALS == 2
        const real w2 = (real)w * (real)w;
        sw += w2;
        hbar = fma((real3)(w2), TO_REAL3(handles[h + 3].xyz), hbar);
        cbar = fma((real3)(w2), TO_REAL3(handles[h + 4].xyz), cbar);
#endif
    }
    const float4 p4 = (float4)(rest[v].xyz, 1.0f);
    vstore3((float3)(dot(x0, p4), dot(x1, p4), dot(x2, p4)), v, out_positions);

#if NORMALS == 1
    const float3 r0 = x0.xyz, r1 = x1.xyz, r2 = x2.xyz;
    const float3 n = normal_data[v].xyz;
    const float3 c12 = cross(r1, r2);
    const float3 nn = (float3)(dot(c12, n), dot(cross(r2, r0), n), dot(cross(r0, r1), n));
    const float s = dot(r0, c12) < 0.0f ? -1.0f : 1.0f;
    vstore3(s * unit_or_zero(nn), v, out_normals);
#elif NORMALS == 2
    const real inv = sw > 0 ? 1 / sw : 0;
    cbar *= inv;
    hbar *= inv;
    const float4 nd = normal_data[v];                  /* (rest normal n, lambda) */
    const real lambda = nd.w;
    real3 r0 = (real3)(lambda, 0, 0);                  /* rows of X + lambda I */
    real3 r1 = (real3)(0, lambda, 0);
    real3 r2 = (real3)(0, 0, lambda);
    real3 p0 = r0, p1 = r1, p2 = r2;                   /* rows of P + lambda I */
    for (int t = 0; t < count; ++t) {
        const int p = base + t * stride;
        const int h = HANDLE_STRIDE * (int)indices[p];
        const real w = LOAD_W(p);
        const real3 c = TO_REAL3(handles[h + 4].xyz) - cbar;
        const real3 d = (w * w) * c;
        const real3 e = TO_REAL3(handles[h + 3].xyz) - hbar;
        r0 = fma((real3)(d.x), e, r0);
        r1 = fma((real3)(d.y), e, r1);
        r2 = fma((real3)(d.z), e, r2);
        p0 = fma((real3)(d.x), c, p0);
        p1 = fma((real3)(d.y), c, p1);
        p2 = fma((real3)(d.z), c, p2);
    }
    /* P from the same differences as X: rounding of the handle positions then perturbs
       the fitted map instead of the product X^-1 P. */
    const real3 n = TO_REAL3(nd.xyz);
    const real3 q = (real3)(dot(p0, n), dot(p1, n), dot(p2, n));
    const real3 c12 = cross(r1, r2);
    const real3 nn = q.x * c12 + q.y * cross(r2, r0) + q.z * cross(r0, r1);
    const real len = length(nn);
    const real s = (dot(r0, c12) < 0 ? -1 : 1) * (len > 0 ? 1 / len : 0);
#if FIT_DOUBLE
    vstore3(convert_float3(s * nn), v, out_normals);
#else
    vstore3(s * nn, v, out_normals);
#endif
#endif
}
