// Linear blending of handle transforms in a vertex shader, captured with
// transform feedback ([P10] sec. 5, docs/algorithms.md sections 1 and 3); the
// GLSL twin of kernels/blend.cl. numpy reference: rigslim.blend.linear_blend,
// rigslim.plugins.normals.{blended_matrix,approximate_affine}.
//
//   v' = X_v [v; 1],  X_v = sum_l w_l T_{i_l}
//   NORMALS == 1 (skeletons): n' = sign(det R) normalize(cof(R) n), R = 3x3 part of X_v
//   NORMALS == 2 (cages):     n' = sign(det X) normalize(adj(X) q), q = (P + lambda I) n,
//                             X = sum_l w_l^2 (c_l - cbar)(chat_l - chatbar)^T + lambda I,
//                             P = sum_l w_l^2 (c_l - cbar)(c_l - cbar)^T (lambda per vertex)
//
// The Python side prepends "#version 430 core" and the defines:
//   K4       number of ivec4/vec4 attribute pairs (k rounded up to a multiple of 4)
//   WEIGHT_LOCATION  2 + K4 (GLSL 4.30 wants a literal there)
//   NORMALS  0 none, 1 blended matrix, 2 approximate affine
//   FIT_DOUBLE  1: the approximate-affine fit in double precision (GLSL 4.00+ doubles); float32
//            loses about cond(P) * 6e-8 rad, positions stay float32
// Handle records live in a texture buffer (RGBA32F), HANDLE_STRIDE texels per
// handle: T row 0, T row 1, T row 2, (chat, 0) = T [c0; 1], (c0, 0).

#define HANDLE_STRIDE 5

#if FIT_DOUBLE
#define real double
#define real3 dvec3
#else
#define real float
#define real3 vec3
#endif

layout(location = 0) in vec3 rest_position;
layout(location = 1) in vec4 normal_data;          // (rest normal n, 0) or (n, lambda)
layout(location = 2) in ivec4 influence[K4];       // handle indices, padding slots hold 0
layout(location = WEIGHT_LOCATION) in vec4 weight[K4];  // weights (WEIGHT_LOCATION = 2 + K4)

uniform samplerBuffer handles;

out vec3 out_position;
#if NORMALS
out vec3 out_normal;
#endif

vec3 unit_or_zero(vec3 n)
{
    float len = length(n);
    return len > 0.0 ? n / len : n;
}

void main()
{
    vec4 x0 = vec4(0.0), x1 = vec4(0.0), x2 = vec4(0.0);
#if NORMALS == 2
    real sw = real(0.0);
    real3 cbar = real3(0.0), hbar = real3(0.0);
#endif
    for (int j = 0; j < K4; ++j) {
        for (int c = 0; c < 4; ++c) {
            int h = HANDLE_STRIDE * influence[j][c];
            float w = weight[j][c];
            x0 = fma(vec4(w), texelFetch(handles, h), x0);
            x1 = fma(vec4(w), texelFetch(handles, h + 1), x1);
            x2 = fma(vec4(w), texelFetch(handles, h + 2), x2);
#if NORMALS == 2
            real w2 = real(w) * real(w);
            sw += w2;
            hbar = fma(real3(w2), real3(texelFetch(handles, h + 3).xyz), hbar);
            cbar = fma(real3(w2), real3(texelFetch(handles, h + 4).xyz), cbar);
#endif
        }
    }
    vec4 p4 = vec4(rest_position, 1.0);
    out_position = vec3(dot(x0, p4), dot(x1, p4), dot(x2, p4));

#if NORMALS == 1
    vec3 r0 = x0.xyz, r1 = x1.xyz, r2 = x2.xyz;
    vec3 n = normal_data.xyz;
    vec3 c12 = cross(r1, r2);
    vec3 nn = vec3(dot(c12, n), dot(cross(r2, r0), n), dot(cross(r0, r1), n));
    out_normal = (dot(r0, c12) < 0.0 ? -1.0 : 1.0) * unit_or_zero(nn);
#elif NORMALS == 2
    real inv = sw > real(0.0) ? real(1.0) / sw : real(0.0);
    cbar *= inv;
    hbar *= inv;
    real lambda = real(normal_data.w);
    real3 r0 = real3(lambda, 0.0, 0.0);         // rows of X + lambda I
    real3 r1 = real3(0.0, lambda, 0.0);
    real3 r2 = real3(0.0, 0.0, lambda);
    real3 p0 = r0, p1 = r1, p2 = r2;             // rows of P + lambda I
    for (int j = 0; j < K4; ++j) {
        for (int i = 0; i < 4; ++i) {
            int h = HANDLE_STRIDE * influence[j][i];
            real w = real(weight[j][i]);
            real3 c = real3(texelFetch(handles, h + 4).xyz) - cbar;
            real3 d = (w * w) * c;
            real3 e = real3(texelFetch(handles, h + 3).xyz) - hbar;
            r0 = fma(real3(d.x), e, r0);
            r1 = fma(real3(d.y), e, r1);
            r2 = fma(real3(d.z), e, r2);
            p0 = fma(real3(d.x), c, p0);
            p1 = fma(real3(d.y), c, p1);
            p2 = fma(real3(d.z), c, p2);
        }
    }
    // P from the same differences as X: rounding then perturbs the fit, not X^-1 P.
    real3 n = real3(normal_data.xyz);
    real3 q = real3(dot(p0, n), dot(p1, n), dot(p2, n));
    real3 c12 = cross(r1, r2);
    real3 nn = q.x * c12 + q.y * cross(r2, r0) + q.z * cross(r0, r1);
    real len = length(nn);
    real s = (dot(r0, c12) < real(0.0) ? real(-1.0) : real(1.0)) * (len > real(0.0) ? real(1.0) / len : real(0.0));
    out_normal = vec3(s * nn);
#endif
}
