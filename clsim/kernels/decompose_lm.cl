/* Levenberg-Marquardt fits of Gaussian sums, one work-item per waveform.
 *
 * The OpenCL twin of clsim/waveforms/decompose/_batch_fit.py (the NumPy path):
 * the same model, censoring, damping (Nielsen 1999), trust region and stopping
 * rules, in float32.  Every waveform of a launch has K echoes (compile-time,
 * -DK) and a fitted (-DFIT_BASELINE=1) or held baseline.  Parameters are laid
 * out [a_1..a_K, m_1..m_K, s_1..s_K, b] (samples); the Jacobian is never
 * stored: each block of 8 samples (a float8) adds its rows to the normal matrix
 * J^T J and to J^T r in one regular pass over every entry (two blocks per pass),
 * the echoes more than REACH sigma away adding exact zeros (their exponentials
 * are not taken).
 *
 * Portability: the kernel is built without -cl-fast-relaxed-math and relies on
 * no infinity: a trial step whose residual sum overflows (or is NaN) fails the
 * finite test `ct <= cost && ct < BIG` and is rejected; a parameter with a zero
 * diagonal in J^T J is frozen instead of dividing by it.
 */
#include "common.cl"

/* The standard errors' inverse in double where the device has it (the NumPy path
 * inverts in float64), else in float32 on the matrix scaled to a unit diagonal
 * (-DCLSIM_SE_FLOAT asks for that on any device: the tests check it). */
#if defined(cl_khr_fp64) && !defined(CLSIM_SE_FLOAT)
#pragma OPENCL EXTENSION cl_khr_fp64 : enable
typedef double se_real;
#else
typedef float se_real;
#endif

#ifndef K
#error "build with -DK=<echoes per waveform>"
#endif
#ifndef FIT_BASELINE
#define FIT_BASELINE 1
#endif

#define NP (3 * K + 1)          /* parameters stored */
#define NF (3 * K + FIT_BASELINE) /* parameters fitted */
#define USE 1                   /* flag bits of a sample: it counts */
#define CENS 2                  /* it is censored (clipped) */
#define BIG 3.0e38f             /* "no value": above any residual sum that passes */

/* Sigmas beyond which an echo is left out of a block of samples (exp(-32) = 1.3e-14). */
#define REACH 8.0f

CLSIM_INLINE float hsum8(const float8 v)
{
    const float4 a = v.lo + v.hi;
    return (a.x + a.y) + (a.z + a.w);
}

/* The sums of the packed accumulators: v (M) into x, the upper triangle m
 * (M (M + 1) / 2, row by row) into the full symmetric M x M matrix mat. */
CLSIM_INLINE void unpack_sums(const float8 *v, const float8 *m, const int M, float *x,
                              float *mat)
{
    int idx = 0;
    for (int p = 0; p < M; ++p) {
        x[p] = hsum8(v[p]);
        for (int c = p; c < M; ++c) {
            const float s = hsum8(m[idx++]);
            mat[p * M + c] = s;
            mat[c * M + p] = s;
        }
    }
}

/* One block of 8 samples from i0 at q: its residuals r (zero where a sample does not
 * count, or is censored below the model: Tobin 1958), the weights kf (1 where it
 * counts, else 0) and the columns d of the weighted Jacobian (zeros for an echo out
 * of reach, whose exponential is not taken); 0 when no echo reaches the block. */
CLSIM_INLINE int block(global const float *y, global const uchar *fl, const int i0,
                       const float *q, const float *inv_s, const float *a_s, const float *lo,
                       const float *hi, float8 *r, float8 *kf, float8 *d)
{
    const float8 lane = (float8)(0.0f, 1.0f, 2.0f, 3.0f, 4.0f, 5.0f, 6.0f, 7.0f);
    const int8 f = convert_int8(vload8(0, fl + i0));
    const float x0 = (float)i0;
    const float8 t = (float8)(x0) + lane;
    float8 e[K], z[K];
    float8 model = (float8)(q[3 * K]);
    int reached = 0;
    for (int k = 0; k < K; ++k) {
        /* an echo out of reach adds exact zeros (its exponential is not taken) */
        z[k] = (float8)(0.0f);
        e[k] = (float8)(0.0f);
        if (x0 >= lo[k] && x0 <= hi[k]) {
            reached = 1;
            z[k] = (t - q[K + k]) * inv_s[k];
            e[k] = exp(-0.5f * z[k] * z[k]);
            model += q[k] * e[k];
        }
    }
    const float8 rr = model - vload8(0, y + i0);
    const int8 keep = ((f & USE) != 0) & ~(((f & CENS) != 0) & (rr >= 0.0f));
    *r = select((float8)(0.0f), rr, keep);
    *kf = select((float8)(0.0f), (float8)(1.0f), keep);
    for (int k = 0; k < K; ++k) {
        d[k] = e[k] * *kf;
        d[K + k] = d[k] * a_s[k] * z[k];
        d[2 * K + k] = d[K + k] * z[k];
    }
#if FIT_BASELINE
    d[3 * K] = *kf;
#endif
    return reached;
}

/* Residual sum of squares at q, J^T J (h, NF x NF, full) and J^T r (g).  Eight
 * samples at a time (float8: one SIMD register on a CPU), over the blocks [b0, b1)
 * that hold the samples that count (the others add exact zeros); rows are padded to
 * a multiple of 8 with samples that do not count.  Two blocks per pass over the
 * accumulators: each is loaded and stored once for both blocks' fused multiply-adds,
 * in the blocks' order, which halves their memory traffic once they no longer fit in
 * registers (about a tenth of the kernel's time on PoCL; fma is what PoCL contracted
 * the earlier one-block `+=` to under -cl-mad-enable, so the sums and fits are the
 * same bit for bit there). */
CLSIM_INLINE float evaluate(global const float *y, global const uchar *fl, const int b0,
                            const int b1, const float *q, float *h, float *g)
{
    float inv_s[K], a_s[K];
    for (int k = 0; k < K; ++k) {
        inv_s[k] = 1.0f / q[2 * K + k];
        a_s[k] = q[k] * inv_s[k];
    }
    /* an echo reaches the samples within REACH sigma of its peak (beyond, its
     * exponential is under 1.3e-14): a block of samples outside that reach skips it */
    float lo[K], hi[K];
    for (int k = 0; k < K; ++k) {
        lo[k] = q[K + k] - REACH * q[2 * K + k] - 7.0f;
        hi[k] = q[K + k] + REACH * q[2 * K + k];
    }
    float8 hv[NF * (NF + 1) / 2], gv[NF];
    float8 cost = (float8)(0.0f);
    for (int i = 0; i < NF * (NF + 1) / 2; ++i) hv[i] = (float8)(0.0f);
    for (int i = 0; i < NF; ++i) gv[i] = (float8)(0.0f);
    for (int i0 = b0; i0 < b1; i0 += 16) {
        const int two = i0 + 8 < b1;
        float8 r1, k1, d1[NF], r2 = (float8)(0.0f), k2 = (float8)(0.0f), d2[NF];
        int reached = block(y, fl, i0, q, inv_s, a_s, lo, hi, &r1, &k1, d1);
        if (two)
            reached |= block(y, fl, i0 + 8, q, inv_s, a_s, lo, hi, &r2, &k2, d2);
        else
            for (int p = 0; p < NF; ++p) d2[p] = (float8)(0.0f);
        cost = fma(r1, r1, cost);
        cost = fma(r2, r2, cost);
        if (!reached) {
            /* baseline alone: the echoes' rows and columns would add exact zeros */
#if FIT_BASELINE
            gv[NF - 1] = fma(k2, r2, fma(k1, r1, gv[NF - 1]));
            hv[NF * (NF + 1) / 2 - 1] = (hv[NF * (NF + 1) / 2 - 1] + k1) + k2;
#endif
            continue;
        }
        /* every entry, in one regular pass (the rows of echoes out of reach add exact
         * zeros: a branch per entry costs more than the multiply-add it saves) */
        int idx = 0;
        for (int p = 0; p < NF; ++p) {
            gv[p] = fma(d2[p], r2, fma(d1[p], r1, gv[p]));
            for (int c = p; c < NF; ++c, ++idx)
                hv[idx] = fma(d2[p], d2[c], fma(d1[p], d1[c], hv[idx]));
        }
    }
    unpack_sums(gv, hv, NF, g, h);
    return hsum8(cost);
}

/* Cholesky factorisation in place of the M x M matrix c (lower triangle); 0 when
 * it is not positive definite. */
CLSIM_INLINE int cholesky(float *c, const int M)
{
    for (int j = 0; j < M; ++j) {
        float d = c[j * M + j];
        for (int k = 0; k < j; ++k) d -= c[j * M + k] * c[j * M + k];
        if (!(d > 0.0f)) return 0;
        d = sqrt(d);
        c[j * M + j] = d;
        for (int i = j + 1; i < M; ++i) {
            float v = c[i * M + j];
            for (int k = 0; k < j; ++k) v -= c[i * M + k] * c[j * M + k];
            c[i * M + j] = v / d;
        }
    }
    return 1;
}

/* Solve (L L^T) x = b with the factor from cholesky(); x may alias b. */
CLSIM_INLINE void chol_solve(const float *c, const float *b, float *x, const int M)
{
    for (int i = 0; i < M; ++i) {
        float v = b[i];
        for (int k = 0; k < i; ++k) v -= c[i * M + k] * x[k];
        x[i] = v / c[i * M + i];
    }
    for (int i = M - 1; i >= 0; --i) {
        float v = x[i];
        for (int k = i + 1; k < M; ++k) v -= c[k * M + i] * x[k];
        x[i] = v / c[i * M + i];
    }
}

#if FIT_BASELINE
/* Start amplitudes and baseline by linear least squares at the start locations and
 * widths (clipped samples left out), kept only when every amplitude comes out
 * positive: the twin of _batch_fit.linear_start. c: (K+1)^2 scratch. */
CLSIM_INLINE void linear_start(global const float *y, global const uchar *fl, const int b0,
                               const int b1, float *q, float *c)
{
#define NL (K + 1)
    float inv_s[K];
    for (int k = 0; k < K; ++k) inv_s[k] = 1.0f / q[2 * K + k];
    const float8 lane = (float8)(0.0f, 1.0f, 2.0f, 3.0f, 4.0f, 5.0f, 6.0f, 7.0f);
    float8 av[NL * (NL + 1) / 2], bv[NL];
    for (int i = 0; i < NL * (NL + 1) / 2; ++i) av[i] = (float8)(0.0f);
    for (int i = 0; i < NL; ++i) bv[i] = (float8)(0.0f);
    for (int i0 = b0; i0 < b1; i0 += 8) {
        const int8 f = convert_int8(vload8(0, fl + i0));
        const float8 wf = select((float8)(0.0f), (float8)(1.0f), (f & (USE | CENS)) == USE);
        const float8 t = (float8)((float)i0) + lane;
        const float8 yv = vload8(0, y + i0);
        float8 e[NL];
        for (int k = 0; k < K; ++k) {
            const float8 z = (t - q[K + k]) * inv_s[k];
            e[k] = exp(-0.5f * z * z) * wf;
        }
        e[K] = wf;
        int idx = 0;
        for (int p = 0; p < NL; ++p) {
            bv[p] += e[p] * yv;
            for (int c2 = p; c2 < NL; ++c2) av[idx++] += e[p] * e[c2];
        }
    }
    float x[NL], sc[NL];
    unpack_sums(bv, av, NL, x, c);
    for (int p = 0; p < NL; ++p) {
        if (!(c[p * NL + p] > 0.0f)) return;
        sc[p] = rsqrt(c[p * NL + p]);
    }
    for (int p = 0; p < NL; ++p) {
        for (int c2 = 0; c2 < NL; ++c2) c[p * NL + c2] *= sc[p] * sc[c2];
        c[p * NL + p] += 1.0e-6f;
        x[p] *= sc[p];
    }
    if (!cholesky(c, NL)) return;
    chol_solve(c, x, x, NL);
    for (int p = 0; p < NL; ++p) x[p] *= sc[p];
    for (int k = 0; k < K; ++k)
        if (!(x[k] > 0.0f && x[k] < BIG)) return;
    if (!(fast_abs(x[K]) < BIG)) return;
    for (int k = 0; k < K; ++k) q[k] = x[k];
    q[3 * K] = x[K];
#undef NL
}
#endif

/* The damped normal matrix h + lam diag(h) (lam at least 1e-6) into c's lower
 * triangle and diagonal (what cholesky() reads), scaled to a unit diagonal
 * (Marquardt 1963: the same step, and float32 factorises it far more accurately
 * than the raw matrix, whose diagonal spans many orders), with its
 * right-hand side -g scaled alike; the step is x * sc.  A parameter whose diagonal
 * is (relatively) zero is frozen: its row and column become the identity, its
 * right-hand side zero, so it takes no step. */
CLSIM_INLINE void damped(const float *h, const float *g, const float lam, float *c, float *rhs,
                         float *sc)
{
    float dmax = 0.0f;
    for (int p = 0; p < NF; ++p) dmax = fast_max(dmax, h[p * NF + p]);
    const float tiny = 1.0e-7f * dmax;
    for (int p = 0; p < NF; ++p) sc[p] = h[p * NF + p] > tiny ? rsqrt(h[p * NF + p]) : 0.0f;
    for (int p = 0; p < NF; ++p) {
        for (int c2 = 0; c2 < p; ++c2) c[p * NF + c2] = h[p * NF + c2] * sc[p] * sc[c2];
        c[p * NF + p] = sc[p] > 0.0f ? 1.0f + fast_max(lam, 1.0e-6f) : 1.0f;
        rhs[p] = -g[p] * sc[p];
    }
}

/* What a work-item returns, one row of OUT (floats): the fit (NP), the residual
 * sum of squares, the samples that count, the iterations, the standard errors (NP;
 * -1: none), and when the host searches for further echoes (RESID) the samples
 * minus the model at the fit (n; zero where a sample does not count or is censored)
 * with M zeros on either side (the filters' reach), and that residual through the
 * host's two filters (n each): the matched filter and the Gaussian of sigma 1
 * sample.  One row (OUT_RES, + 2 M + 3 n with RESID), so one copy back per launch. */
#define OUT_RSS NP
#define OUT_NEFF (NP + 1)
#define OUT_ITER (NP + 2)
#define OUT_SE (NP + 3)
#define OUT_RES (2 * NP + 3)
/* Index of (i, j), j <= i, in a packed lower triangle. */
#define LIDX(i, j) ((i) * ((i) + 1) / 2 + (j))

/* Standard errors sqrt(diag((J^T J)^-1) RSS / (n - NF)) from h = J^T J (NF x NF) into
 * se (NP; -1 where there is none: a diagonal not positive, no degree of freedom
 * left, a zero pivot; the baseline's when it is held): the twin of
 * _batch_fit.standard_errors, with its ridge of 1e-12 of the largest diagonal.  The
 * matrix is scaled to a unit diagonal and factorised L D L^T (no square root, so a
 * matrix made slightly indefinite by rounding still gives an answer, as the host's
 * LU inverse did); diag(A^-1)_p = sum_j (L^-1)_jp^2 / D_j. */
CLSIM_INLINE void std_errors(const float *h, const float rss, const int n_eff,
                             global float *se)
{
    for (int p = 0; p < NP; ++p) se[p] = -1.0f;
    float dmax = 0.0f;
    int ok = n_eff > NF;
    for (int p = 0; p < NF; ++p) {
        ok &= h[p * NF + p] > 0.0f;
        dmax = fast_max(dmax, h[p * NF + p]);
    }
    if (!ok) return;
    const se_real ridge = (se_real)1.0e-12 * (se_real)dmax;
    se_real a[NF * (NF + 1) / 2], d[NF], sc[NF];
    for (int p = 0; p < NF; ++p) sc[p] = (se_real)1.0 / sqrt((se_real)h[p * NF + p] + ridge);
    for (int i = 0; i < NF; ++i) {
        for (int j = 0; j < i; ++j) a[LIDX(i, j)] = (se_real)h[i * NF + j] * sc[i] * sc[j];
        a[LIDX(i, i)] = ((se_real)h[i * NF + i] + ridge) * sc[i] * sc[i];
    }
    /* L D L^T in place (L unit lower, below the diagonal; D apart) */
    for (int j = 0; j < NF; ++j) {
        se_real dj = a[LIDX(j, j)];
        for (int k = 0; k < j; ++k) dj -= a[LIDX(j, k)] * a[LIDX(j, k)] * d[k];
        if (dj == (se_real)0.0) return;
        d[j] = dj;
        for (int i = j + 1; i < NF; ++i) {
            se_real v = a[LIDX(i, j)];
            for (int k = 0; k < j; ++k) v -= a[LIDX(i, k)] * a[LIDX(j, k)] * d[k];
            a[LIDX(i, j)] = v / dj;
        }
    }
    /* L^-1 in place, column by column (column j reads L's columns beyond j only) */
    for (int j = 0; j < NF; ++j)
        for (int i = j + 1; i < NF; ++i) {
            se_real v = a[LIDX(i, j)];
            for (int k = j + 1; k < i; ++k) v += a[LIDX(i, k)] * a[LIDX(k, j)];
            a[LIDX(i, j)] = -v;
        }
    const se_real s2 = (se_real)rss / (se_real)(n_eff - NF);
    for (int p = 0; p < NF; ++p) {
        se_real v = (se_real)1.0 / d[p];
        for (int j = p + 1; j < NF; ++j) v += a[LIDX(j, p)] * a[LIDX(j, p)] / d[j];
        v *= sc[p] * sc[p] * s2;
        if (v != v)  /* NaN (an inf or NaN in h): left at -1, NaN on the host, as NumPy's */
            continue;
        /* (a variance beyond float range, of a parameter the data do not pin down:
         * BIG, a finite "no bound", as the host's float64 figure was finite) */
        const se_real root = v > (se_real)0.0 ? sqrt(v) : (se_real)0.0;
        se[p] = root < (se_real)BIG ? (float)root : BIG;
    }
}

/* x (zero outside [b0, b1), and zero-padded far enough beyond [0, n)) correlated
 * with the weights w[0..size), lag 0 at centre, at samples [b0, b1) into out, eight
 * at a time; zero elsewhere in [0, n). */
CLSIM_INLINE void correlate(global const float *x, const int b0, const int b1, const int n,
                            global const float *w, const int size, const int centre,
                            global float *out)
{
    for (int j0 = 0; j0 < b0; j0 += 8) vstore8((float8)(0.0f), 0, out + j0);
    for (int j0 = b1; j0 < n; j0 += 8) vstore8((float8)(0.0f), 0, out + j0);
    for (int j0 = b0; j0 < b1; j0 += 8) {
        float8 acc = (float8)(0.0f);
        global const float *p = x + j0 - centre;
        for (int t = 0; t < size; ++t) acc += w[t] * vload8(0, p + t);
        vstore8(acc, 0, out + j0);
    }
}

/* One launch: waveform `row[r0 + w]` of the uploaded samples for each work-item w,
 * from the start values at Q + q0 (G x NP), its row of results at OUT + o0 + w x
 * (OUT_RES, + 2 M + 3 n with RESID): the launches of one round of fits (one per number of
 * echoes) share the row, start and result buffers.  FW: the matched filter's
 * weights (np_, lag 0 at pc), then the 9 of the Gaussian of sigma 1 (lag 0 at 4);
 * M at least max(pc, np_ - 1 - pc, 4) + 8. */
kernel void lm_fit(global const float *Y, global const uchar *FL, const int n,
                   global const int *ROW, global const int2 *span,
                   global const float *noise, global const float *Q, global float *OUT,
                   const int G, const int max_iter, const float tol, const int linear,
                   global const float *FW, const int np_, const int pc, const int M,
                   const int resid, const int r0, const long q0, const long o0)
{
    const int w = get_global_id(0);
    if (w >= G) return;
    global const int *row = ROW + r0;
    global const float *qin = Q + q0 + (size_t)w * NP;
    global const float *y = Y + (size_t)row[w] * n;
    global const uchar *fl = FL + (size_t)row[w] * n;
    global float *out = OUT + o0 + (size_t)w * (OUT_RES + (resid ? 2 * M + 3 * n : 0));
    float q[NP], qt[NP], step[NF], rhs[NF], sc[NF];
    float h[NF * NF], ht[NF * NF], c[NF * NF], g[NF], gt[NF];
    for (int p = 0; p < NP; ++p) q[p] = qin[p];
    const float first = (float)span[row[w]].x, last = (float)span[row[w]].y;
    /* the blocks of 8 samples from the first counted sample to the last */
    const int b0 = span[row[w]].x & ~7, b1 = min(n, (span[row[w]].y & ~7) + 8);
    const float enough_noise = 0.01f * noise[row[w]] * noise[row[w]];
#if FIT_BASELINE
    if (linear) linear_start(y, fl, b0, b1, q, c);
#endif
    float cost = evaluate(y, fl, b0, b1, q, h, g);
    float lam = 1.0e-3f, nu = 2.0f;
    int it = 0;
    while (it < max_iter) {
        ++it;
        damped(h, g, lam, c, rhs, sc);
        int done = 0;
        if (!cholesky(c, NF)) {
            lam *= nu;
            nu *= 2.0f;
            if (lam > 1.0e8f) break;
            continue;
        }
        chol_solve(c, rhs, step, NF);
        for (int p = 0; p < NF; ++p) step[p] *= sc[p];
        /* trust region in the natural scales: no location moves more than
         * 2 sigma + 1 sample, no width more than half of itself + 0.5 sample */
        float ratio = 1.0f;
        for (int k = 0; k < K; ++k) {
            const float s = q[2 * K + k];
            ratio = fast_max(ratio, fast_abs(step[K + k]) / (2.0f * s + 1.0f));
            ratio = fast_max(ratio, fast_abs(step[2 * K + k]) / (0.5f * s + 0.5f));
        }
        for (int p = 0; p < NF; ++p) step[p] /= ratio;
        /* predicted decrease of the RSS: -2 g.d - d.H.d */
        float pred = 0.0f;
        for (int p = 0; p < NF; ++p) {
            float hd = 0.0f;
            for (int c2 = 0; c2 < NF; ++c2) hd += h[p * NF + c2] * step[c2];
            pred -= step[p] * (2.0f * g[p] + hd);
        }
        /* converged: at the start or after an accepted step (nu back at 2), a step the
         * trust region leaves whole would lower the RSS by less than the gain that
         * stops the fit; it is not taken (nor counted) */
        if (nu == 2.0f && ratio <= 1.0f && pred <= fast_max(tol * cost, enough_noise)) {
            --it;
            break;
        }
        for (int p = 0; p < NP; ++p) qt[p] = q[p] + (p < NF ? step[p] : 0.0f);
        for (int k = 0; k < K; ++k)
            qt[2 * K + k] = clamp(fast_abs(qt[2 * K + k]), 0.2f, (float)n);
        const float ct = evaluate(y, fl, b0, b1, qt, ht, gt);
        if (ct <= cost && ct < BIG) {
            const float gain = cost - ct;
            const float rho = pred > 0.0f ? clamp(gain / pred, 0.0f, 1.0f) : 0.0f;
            const float x = 2.0f * rho - 1.0f;
            lam *= fast_max(1.0f / 3.0f, 1.0f - x * x * x);
            nu = 2.0f;
            for (int p = 0; p < NP; ++p) q[p] = qt[p];
            for (int p = 0; p < NF * NF; ++p) h[p] = ht[p];
            for (int p = 0; p < NF; ++p) g[p] = gt[p];
            cost = ct;
            done = gain <= fast_max(tol * cost, enough_noise);
        } else {
            lam *= nu;
            nu *= 2.0f;
        }
        /* MINPACK's xtol: the step under tol of the parameters' size */
        float size2 = 0.0f, step2 = 0.0f;
        for (int p = 0; p < 3 * K; ++p) {
            size2 += q[p] * q[p];
            step2 += step[p] * step[p];
        }
        done |= step2 <= tol * tol * size2;
        done |= lam > 1.0e8f;
        /* an echo collapsed or left the record: model selection takes over */
        for (int k = 0; k < K; ++k) {
            const float s = q[2 * K + k], m = q[K + k];
            done |= (s <= 0.25f) | (q[k] <= 0.0f) | (m < first - s) | (m > last + s);
        }
        if (done) break;
    }
    int n_eff = 0;
    for (int i = b0; i < b1; ++i) n_eff += (fl[i] & USE) && !(fl[i] & CENS);
    /* J^T J at the solution into standard errors */
    std_errors(h, cost, n_eff, out + OUT_SE);
    for (int p = 0; p < NP; ++p) out[p] = q[p];
    out[OUT_RSS] = cost;
    out[OUT_NEFF] = (float)n_eff;
    out[OUT_ITER] = (float)it;
    if (!resid) return;
    /* the residual at the fit, for the host's search for further echoes */
    global float *res = out + OUT_RES + M;
    for (int i = -M; i < 0; ++i) res[i] = 0.0f;
    for (int i = n; i < n + M; ++i) res[i] = 0.0f;
    float inv_s[K];
    for (int k = 0; k < K; ++k) inv_s[k] = 1.0f / q[2 * K + k];
    const float8 lane = (float8)(0.0f, 1.0f, 2.0f, 3.0f, 4.0f, 5.0f, 6.0f, 7.0f);
    for (int i0 = 0; i0 < b0; i0 += 8) vstore8((float8)(0.0f), 0, res + i0);
    for (int i0 = b1; i0 < n; i0 += 8) vstore8((float8)(0.0f), 0, res + i0);
    for (int i0 = b0; i0 < b1; i0 += 8) {
        const float x0 = (float)i0;
        const float8 t = (float8)(x0) + lane;
        float8 model = (float8)(q[3 * K]);
        for (int k = 0; k < K; ++k) {
            const float reach = REACH * q[2 * K + k];
            if (x0 >= q[K + k] - reach - 7.0f && x0 <= q[K + k] + reach) {
                const float8 z = (t - q[K + k]) * inv_s[k];
                model += q[k] * exp(-0.5f * z * z);
            }
        }
        const int8 f = convert_int8(vload8(0, fl + i0));
        vstore8(select((float8)(0.0f), vload8(0, y + i0) - model, (f & (USE | CENS)) == USE),
                0, res + i0);
    }
    correlate(res, b0, b1, n, FW, np_, pc, res + n + M);
    correlate(res, b0, b1, n, FW + np_, 9, 4, res + 2 * n + M);
}
