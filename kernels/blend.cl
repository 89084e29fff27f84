/* Linear blending of handle transforms, one work-item per vertex ([P10] sec. 5,
 * ALGORITHMS.md sections 1 and 3). numpy reference: rigslim.blend.linear_blend,
 * rigslim.plugins.normals.{blended_matrix,approximate_affine}.
 *
 *   v' = X_v [v; 1],  X_v = sum_l w_l T_{i_l}                    (positions)
 *   n' = sign(det R) normalize(cof(R) n),  R = 3x3 part of X_v    (NORMALS == 1, skeletons)
 *   n' = sign(det X) normalize(adj(X) q),  q = (P + lambda I) n,  (NORMALS == 2, cages)
 *        X = sum_l w_l^2 (c_l - cbar)(chat_l - chatbar)^T + lambda I
 *
 * Compile-time options:
 *   LAYOUT   0 fixed (int32 index, float32 weight, slot-major [l*m + v]),
 *            1 compact (uint16 index, float16 weight, slot-major),
 *            2 csr (row pointers, int32 columns, float32 values)
 *   K        slots per vertex (fixed and compact layouts)
 *   NORMALS  0 none, 1 blended matrix, 2 approximate affine
 *
 * Per-handle records (float4 each, HANDLE_STRIDE per handle):
 *   T row 0, T row 1, T row 2, (chat, 0) = T [c0; 1], (c0, 0).
 */

#define HANDLE_STRIDE 5

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
    float sw = 0.0f;
    float3 cbar = (float3)(0.0f), hbar = (float3)(0.0f);
#endif
    for (int t = 0; t < count; ++t) {
        const int p = base + t * stride;
        const int h = HANDLE_STRIDE * (int)indices[p];
        const float w = LOAD_W(p);
        x0 = fma((float4)(w), handles[h], x0);
        x1 = fma((float4)(w), handles[h + 1], x1);
        x2 = fma((float4)(w), handles[h + 2], x2);
#if NORMALS == 2
        const float w2 = w * w;
        sw += w2;
        hbar = fma((float3)(w2), handles[h + 3].xyz, hbar);
        cbar = fma((float3)(w2), handles[h + 4].xyz, cbar);
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
    const float inv = sw > 0.0f ? 1.0f / sw : 0.0f;
    cbar *= inv;
    hbar *= inv;
    const float4 nd = normal_data[v];                  /* (q, lambda) */
    float3 r0 = (float3)(nd.w, 0.0f, 0.0f);            /* rows of X + lambda I */
    float3 r1 = (float3)(0.0f, nd.w, 0.0f);
    float3 r2 = (float3)(0.0f, 0.0f, nd.w);
    for (int t = 0; t < count; ++t) {
        const int p = base + t * stride;
        const int h = HANDLE_STRIDE * (int)indices[p];
        const float w = LOAD_W(p);
        const float3 d = (w * w) * (handles[h + 4].xyz - cbar);
        const float3 e = handles[h + 3].xyz - hbar;
        r0 = fma((float3)(d.x), e, r0);
        r1 = fma((float3)(d.y), e, r1);
        r2 = fma((float3)(d.z), e, r2);
    }
    const float3 c12 = cross(r1, r2);
    const float3 nn = nd.x * c12 + nd.y * cross(r2, r0) + nd.z * cross(r0, r1);
    const float s = dot(r0, c12) < 0.0f ? -1.0f : 1.0f;
    vstore3(s * unit_or_zero(nn), v, out_normals);
#endif
}
