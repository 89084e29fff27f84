// Batched small convex QPs, one work item per problem (numpy reference: rigslim.qp.solve_small_qps).
//
//   minimise 1/2 x^T H x + g^T x   s.t.  C x = d  [, x >= 0]
//
// Exact primal active set for the bounds from a feasible start x0; each step
// solves the KKT system [[H_FF, C_F^T], [C_F, -delta I]] [p; lam] = [-r_F; 0]
// (r = H x + g, p_W = 0) by LU with partial pivoting plus one step of
// iterative refinement against delta = 0, exactly as the numpy reference.
//
// Compile-time constants: K (variables), Q (equality rows), NONNEG (0/1),
// MAXIT (active-set iteration limit). Problem b of the call reads H, C, d at
// index (offset + b) of the device-resident arrays, and g, x0 at index b.

#pragma OPENCL EXTENSION cl_khr_fp64 : enable

#define N (K + Q)
#define KKT_DELTA 1e-13
#define STEP_TOL 1e-12

static void lu_factor(double *A, int *piv) {
    for (int c = 0; c < N; ++c) {
        int best = c;
        double bv = fabs(A[c * N + c]);
        for (int r = c + 1; r < N; ++r) {
            double v = fabs(A[r * N + c]);
            if (v > bv) { bv = v; best = r; }
        }
        piv[c] = best;
        if (best != c) {
            for (int j = 0; j < N; ++j) {
                double t = A[c * N + j]; A[c * N + j] = A[best * N + j]; A[best * N + j] = t;
            }
        }
        double dia = A[c * N + c];
        if (dia == 0.0) continue;
        for (int r = c + 1; r < N; ++r) {
            double f = A[r * N + c] / dia;
            A[r * N + c] = f;
            for (int j = c + 1; j < N; ++j) A[r * N + j] -= f * A[c * N + j];
        }
    }
}

static void lu_solve(const double *A, const int *piv, double *b) {
    // Rows were swapped whole during factorisation: apply every swap, then substitute.
    for (int c = 0; c < N; ++c) {
        int p = piv[c];
        if (p != c) { double t = b[c]; b[c] = b[p]; b[p] = t; }
    }
    for (int c = 0; c < N; ++c)
        for (int r = c + 1; r < N; ++r) b[r] -= A[r * N + c] * b[c];
    for (int c = N - 1; c >= 0; --c) {
        double s = b[c];
        for (int j = c + 1; j < N; ++j) s -= A[c * N + j] * b[j];
        b[c] = s / A[c * N + c];
    }
}

// KKT step with working set W; writes p[K] and lam[Q].
static void kkt_step(__global const double *H, __global const double *C, const double *r,
                     const int *W, double delta, double *p, double *lam) {
    double A[N * N], A0[N * N], sol[N], res[N], rhs[N];
    int piv[N];
    for (int i = 0; i < K; ++i) {
        for (int j = 0; j < K; ++j) {
            double h = (W[i] || W[j]) ? 0.0 : H[i * K + j];
            if (i == j) h = W[i] ? 1.0 : H[i * K + i];
            A0[i * N + j] = h;
        }
        for (int q = 0; q < Q; ++q) {
            double c = W[i] ? 0.0 : C[q * K + i];
            A0[i * N + K + q] = c;
            A0[(K + q) * N + i] = c;
        }
        rhs[i] = W[i] ? 0.0 : -r[i];
    }
    for (int q = 0; q < Q; ++q) {
        for (int s = 0; s < Q; ++s) A0[(K + q) * N + K + s] = 0.0;
        rhs[K + q] = 0.0;
    }
    for (int i = 0; i < N * N; ++i) A[i] = A0[i];
    for (int q = 0; q < Q; ++q) A[(K + q) * N + K + q] = -delta;
    lu_factor(A, piv);
    for (int i = 0; i < N; ++i) sol[i] = rhs[i];
    lu_solve(A, piv, sol);
    // One step of iterative refinement against the exact system A0.
    for (int i = 0; i < N; ++i) {
        double s = rhs[i];
        for (int j = 0; j < N; ++j) s -= A0[i * N + j] * sol[j];
        res[i] = s;
    }
    lu_solve(A, piv, res);
    for (int i = 0; i < K; ++i) p[i] = sol[i] + res[i];
    for (int q = 0; q < Q; ++q) lam[q] = sol[K + q] + res[K + q];
}

__kernel void small_qp(__global const double *Hall, __global const double *Call, __global const double *dall,
                       __global const double *g, __global const double *x0, __global double *xout,
                       __global int *iters, const int offset, const int count) {
    int b = get_global_id(0);
    if (b >= count) return;
    __global const double *H = Hall + (size_t)(offset + b) * K * K;
    __global const double *C = Call + (size_t)(offset + b) * Q * K;
    double x[K], r[K], p[K], lam[Q];
    int W[K];
    double scale = 1e-300, cnorm = 1e-300;
    for (int i = 0; i < K; ++i) scale = fmax(scale, fabs(H[i * K + i]));
    for (int i = 0; i < Q * K; ++i) cnorm += C[i] * C[i];
    double delta = KKT_DELTA * cnorm / scale;
    for (int i = 0; i < K; ++i) {
        x[i] = x0[(size_t)b * K + i];
        W[i] = NONNEG && x[i] <= 0.0;
        if (W[i]) x[i] = 0.0;
    }
    int it = 0;
    for (; it < MAXIT; ++it) {
        for (int i = 0; i < K; ++i) {
            double s = g[(size_t)b * K + i];
            for (int j = 0; j < K; ++j) s += H[i * K + j] * x[j];
            r[i] = s;
        }
        kkt_step(H, C, r, W, delta, p, lam);
        double pmax = 0.0, xmax = 0.0;
        for (int i = 0; i < K; ++i) { pmax = fmax(pmax, fabs(p[i])); xmax = fmax(xmax, fabs(x[i])); }
        if (!NONNEG) {
            for (int i = 0; i < K; ++i) x[i] += p[i];
            it += 1;
            break;
        }
        if (pmax > STEP_TOL * (1.0 + xmax)) {
            double t = 1.0;
            int jb = -1;
            for (int i = 0; i < K; ++i) {
                if (!W[i] && p[i] < 0.0) {
                    double ratio = -x[i] / p[i];
                    if (ratio < t) { t = ratio; jb = i; }
                }
            }
            for (int i = 0; i < K; ++i) x[i] += t * p[i];
            if (jb >= 0) { W[jb] = 1; x[jb] = 0.0; }
            for (int i = 0; i < K; ++i) x[i] = fmax(x[i], 0.0);
            if (jb >= 0) continue;
            // Full step: r at the new point, multipliers from the same solve.
            for (int i = 0; i < K; ++i) {
                double s = 0.0;
                for (int j = 0; j < K; ++j) s += H[i * K + j] * p[j];
                r[i] += s;
            }
        }
        double rmax = 0.0, mumin = INFINITY;
        int jm = -1;
        for (int i = 0; i < K; ++i) {
            rmax = fmax(rmax, fabs(r[i]));
            if (W[i]) {
                double mu = r[i];
                for (int q = 0; q < Q; ++q) mu += C[q * K + i] * lam[q];
                if (mu < mumin) { mumin = mu; jm = i; }
            }
        }
        if (jm < 0 || mumin >= -1e-12 * (1.0 + rmax)) { it += 1; break; }
        W[jm] = 0;
    }
    for (int i = 0; i < K; ++i) xout[(size_t)b * K + i] = x[i];
    iters[b] = it;
}
