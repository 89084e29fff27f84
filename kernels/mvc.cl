// Mean value coordinates of points with respect to a closed triangle cage
// (Ju, Schaefer & Warren 2005), one work item per point. The numpy reference
// is rigslim.plugins.generators.mean_value.mean_value_coordinates; this kernel
// follows it line by line (the stable vector form, see its Notes).
//
// Build options: -DUSE_DOUBLE for float64 (needs cl_khr_fp64).

#ifdef USE_DOUBLE
#pragma OPENCL EXTENSION cl_khr_fp64 : enable
typedef double real;
typedef double3 real3;
#else
typedef float real;
typedef float3 real3;
#endif

// Angle between unit vectors a and b, accurate near 0 and pi.
inline real angle_between(real3 a, real3 b)
{
    return (real)2.0 * atan2(length(a - b), length(a + b));
}

// (theta / 2) times the unit normal of the plane through x, a and b.
inline real3 edge_term(real3 ua, real3 ub)
{
    real3 c = cross(ua, ub);
    real len = length(c);
    if (len == (real)0.0)
        return (real3)(0.0, 0.0, 0.0);
    return ((real)0.5 * angle_between(ua, ub) / len) * c;
}

__kernel void mean_value_coordinates(__global const real *P,   // (m, 3)
                                     const int m,
                                     __global const real *V,   // (n, 3)
                                     const int n,
                                     __global const int *F,    // (f, 3)
                                     const int f,
                                     const real plane_eps,
                                     __global real *W)         // (m, n)
{
    const int i = get_global_id(0);
    if (i >= m)
        return;
    const real3 x = vload3(i, P);
    __global real *w = W + (size_t)i * (size_t)n;
    for (int j = 0; j < n; ++j)
        w[j] = (real)0.0;

    int on_face = -1;
    real3 bary = (real3)(0.0, 0.0, 0.0);
    for (int t = 0; t < f; ++t) {
        const int a = F[3 * t], b = F[3 * t + 1], c = F[3 * t + 2];
        const real3 p1 = vload3(a, V), p2 = vload3(b, V), p3 = vload3(c, V);
        const real3 D1 = p1 - x, D2 = p2 - x, D3 = p3 - x;
        const real3 N = cross(p2 - p1, p3 - p1);
        const real area2 = length(N);
        const real plane = dot(D1, N);
        if (fabs(plane) < plane_eps * area2 * sqrt(area2)) {
            // in the face's plane: on the face, or outside it (skip the face)
            const real nn = dot(N, N);
            const real la = dot(cross(p2 - x, p3 - x), N) / nn;
            const real lb = dot(cross(p3 - x, p1 - x), N) / nn;
            const real lc = (real)1.0 - la - lb;
            if (la >= (real)-1e-9 && lb >= (real)-1e-9 && lc >= (real)-1e-9) {
                on_face = t;
                bary = (real3)(fmax(la, (real)0.0), fmax(lb, (real)0.0), fmax(lc, (real)0.0));
                break;
            }
            continue;
        }
        const real d1 = length(D1), d2 = length(D2), d3 = length(D3);
        const real3 u1 = D1 / d1, u2 = D2 / d2, u3 = D3 / d3;
        const real3 mv = edge_term(u1, u2) + edge_term(u2, u3) + edge_term(u3, u1);
        const real det = plane / (d1 * d2 * d3);
        const real w1 = dot(cross(u2, u3), mv) / det / d1;
        const real w2 = dot(cross(u3, u1), mv) / det / d2;
        const real w3 = dot(cross(u1, u2), mv) / det / d3;
        if (isfinite(w1) && isfinite(w2) && isfinite(w3)) {
            w[a] += w1;
            w[b] += w2;
            w[c] += w3;
        }
    }
    if (on_face >= 0) {
        for (int j = 0; j < n; ++j)
            w[j] = (real)0.0;
        w[F[3 * on_face]] += bary.x;
        w[F[3 * on_face + 1]] += bary.y;
        w[F[3 * on_face + 2]] += bary.z;
    }
    real sum = (real)0.0;
    for (int j = 0; j < n; ++j)
        sum += w[j];
    const real inv = (real)1.0 / sum;
    for (int j = 0; j < n; ++j)
        w[j] *= inv;
}
