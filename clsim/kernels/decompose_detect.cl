/* Detection of echoes in many waveforms, one work-item per waveform.
 *
 * The OpenCL twin of the NumPy detection in clsim/waveforms/decompose/_batch.py
 * (_noise, _clipped_baseline, _censored, _batch_pulse and the candidate search of
 * _decompose_chunk), in float32.  Two kernels:
 *
 *   noise_stats: robust baseline and noise sigma (exact order statistics by a
 *     branch-free radix select in a per-row scratch row), no-data zeros, the samples that count and the
 *     clipped ones (flag bits), the clipped-tolerant baseline, the span of
 *     counted samples and the half-maximum width of the strongest echo (the
 *     host takes the batch's pulse width from these);
 *   candidates: matched filter, Gaussian smoothing and curvature, the peaks,
 *     shoulders and matched-filter maxima above the false-alarm level, the
 *     KCAP highest of each row and their start values (log-parabola).
 *
 * Rows are laid out as the fitting kernel reads them (decompose_lm.cl): NS
 * samples a row (a multiple of 8), flag bits USE and CENS.  No infinity or NaN
 * is created: "minus infinity" is -BIG and a failed start width is flagged.
 */
#include "common.cl"

#define USE 1
#define CENS 2
#define BIG 3.0e38f
/* 1.4826 / sqrt(2) and 1 / sqrt(12) as float32 pairs (hi + lo): x * c by fma is then
 * the float32 nearest to the exact product, as the NumPy steps' float64 is once
 * rounded, so integer samples give the same noise sigma, bit for bit */
#define MAD_HI 1.0483565e+00f
#define MAD_LO -1.9263362e-08f
#define Q_HI 2.8867513e-01f
#define Q_LO 5.1812084e-09f

/* Order statistics by bisection on the bits of order-preserving keys (a radix
 * select): branch-free counting passes over 8 keys at a time, exact, where a
 * quickselect's data-dependent branches cost several times more on a CPU.  A
 * float's key: sign bit flipped for positives, all bits for negatives. */
CLSIM_INLINE uint float_key(const float f)
{
    const uint u = as_uint(f);
    return (u & 0x80000000u) ? ~u : (u | 0x80000000u);
}

CLSIM_INLINE float key_float(const uint k)
{
    return as_float((k & 0x80000000u) ? (k & 0x7FFFFFFFu) : ~k);
}

/* How many of the keys a[0..8 nb) are below c (padding keys are 0xFFFFFFFF). */
CLSIM_INLINE int count_below(global const uint *a, const int nb, const uint c)
{
    int8 acc = (int8)(0);
    const uint8 cv = (uint8)(c);
    for (int b = 0; b < nb; ++b) acc += vload8(b, a) < cv;  /* true is -1 */
    const int4 h = acc.lo + acc.hi;
    return -((h.x + h.y) + (h.z + h.w));
}

/* Mean of the i-th and j-th smallest (0-based, j = i or i + 1) of the cnt keys in
 * a (padded with 0xFFFFFFFF to a multiple of 8); BIG when there is no j-th. */
CLSIM_INLINE float order_mean(global uint *a, const int cnt, const int i, const int j)
{
    if (j < 0 || j >= cnt) return BIG;
    const int nb = (cnt + 7) >> 3;
    for (int t = cnt; t < 8 * nb; ++t) a[t] = 0xFFFFFFFFu;
    /* the largest key with at most i keys below it is the i-th smallest */
    uint v = 0u;
    for (int bit = 31; bit >= 0; --bit) {
        const uint c = v | (1u << bit);
        if (count_below(a, nb, c) <= i) v = c;
    }
    uint w = v;
    if (j != i && count_below(a, nb, v + 1u) <= j) {
        /* the next key up: the smallest above v */
        uint8 m = (uint8)(0xFFFFFFFFu);
        const uint8 vv = (uint8)(v);
        for (int b = 0; b < nb; ++b) {
            const uint8 x = vload8(b, a);
            m = min(m, select((uint8)(0xFFFFFFFFu), x, x > vv));
        }
        const uint4 h = min(m.lo, m.hi);
        w = min(min(h.x, h.y), min(h.z, h.w));
    }
    return 0.5f * (key_float(v) + key_float(w));
}

/* Baseline (median of the lowest fifth) and noise sigma (1.4826 MAD of the first
 * differences / sqrt 2, at least the quantisation step / sqrt 12) of the samples
 * j < len, all of them (all_) or only the non-zero ones. */
CLSIM_INLINE float2 noise_of(global const float *y, const int len, const int all_,
                             global uint *s)
{
    int nv = 0;
    for (int j = 0; j < len; ++j)
        if (all_ || y[j] != 0.0f) s[nv++] = float_key(y[j]);
    const int k = max(3, nv / 5);
    const float base = order_mean(s, nv, (k - 1) / 2, k / 2);
    int c = 0;
    float q = BIG;
    for (int j = 0; j + 1 < len; ++j) {
        if (all_ || (y[j] != 0.0f && y[j + 1] != 0.0f)) {
            const float d = y[j + 1] - y[j];
            s[c++] = float_key(d);
            if (d != 0.0f) q = fast_min(q, fast_abs(d));
        }
    }
    if (q >= BIG) q = 1.0f;
    float sigma = 0.0f;
    if (c > 0) {
        const float med = order_mean(s, c, (c - 1) / 2, c / 2);
        int c2 = 0;
        for (int j = 0; j + 1 < len; ++j)
            if (all_ || (y[j] != 0.0f && y[j + 1] != 0.0f)) s[c2++] = float_key(fast_abs(y[j + 1] - y[j] - med));
        const float mad = order_mean(s, c, (c - 1) / 2, c / 2);
        sigma = fma(mad, MAD_HI, mad * MAD_LO);
    }
    return (float2)(base, fast_max(sigma, fma(q, Q_HI, q * Q_LO)));
}

/* OUT per row (8 floats): baseline, noise sigma, samples that count, half-maximum
 * width of the strongest echo (samples; -1: none), censored samples, first and
 * last counted sample. */
kernel void noise_stats(global const float *Y, const int ns, global const int *LEN,
                        const int sat_mode, const float sat_value, global float *SCR,
                        global uchar *FL, global int2 *SPAN, global float *NOISE,
                        global float *OUT, const int N)
{
    for (int r = get_global_id(0); r < N; r += get_global_size(0)) {
    global const float *y = Y + (size_t)r * ns;
    global uchar *fl = FL + (size_t)r * ns;
    global uint *s = (global uint *)SCR + (size_t)r * ns;
    const int len = LEN[r];
    int nzero = 0;
    for (int j = 0; j < len; ++j) nzero += y[j] == 0.0f;
    float2 bs = noise_of(y, len, 0, s);
    /* exact zeros are no-data fill when the rest sits > 4 sigma above zero */
    const int gap = nzero > 0 && nzero <= len - 4 && bs.x > 4.0f * bs.y;
    if (nzero > 0 && !gap) bs = noise_of(y, len, 1, s);
    const float sigma = bs.y;
    int nv = 0, first = -1, last = -1;
    float top = -BIG;
    for (int j = 0; j < ns; ++j) {
        const int u = j < len && (!gap || y[j] != 0.0f);
        fl[j] = u ? USE : 0;
        if (u) {
            ++nv;
            if (first < 0) first = j;
            last = j;
            top = fast_max(top, y[j]);
        }
    }
    /* clipped samples: runs of 3 or more at the row's maximum ("auto"), or at or
     * above the full-scale value */
    int ncens = 0;
    if (sat_mode == 1) {
        int run = 0;  /* length of the run of samples at the maximum ending at j */
        for (int j = 0; j <= len; ++j) {
            const int at = j < len && (fl[j] & USE) && y[j] == top;
            if (at) {
                ++run;
            } else {
                if (run >= 3) {
                    for (int i = j - run; i < j; ++i) fl[i] |= CENS;
                    ncens += run;
                }
                run = 0;
            }
        }
    } else if (sat_mode == 2) {
        for (int j = 0; j < len; ++j)
            if ((fl[j] & USE) && y[j] >= sat_value) { fl[j] |= CENS; ++ncens; }
    }
    /* baseline from the samples within 2.5 sigma of it (clipped runs do not pull it) */
    float b = bs.x;
    for (int it = 0; it < 5; ++it) {
        float sum = 0.0f;
        int cnt = 0;
        for (int j = 0; j < len; ++j) {
            const int in = (fl[j] & USE) && fast_abs(y[j] - b) < 2.5f * sigma;
            sum += in ? y[j] : 0.0f;
            cnt += in;
        }
        if (cnt >= 3) b = sum / (float)cnt;
    }
    /* half-maximum width of the strongest echo (Gaussian sigma), when 20 sigma high */
    int im = 0;
    float hm = -BIG;
    for (int j = 0; j < len; ++j)
        if ((fl[j] & USE) && y[j] - b > hm) { hm = y[j] - b; im = j; }
    float width = -1.0f;
    if (hm >= 20.0f * sigma) {
        const float halfh = 0.5f * hm;
        int left = -1, right = -1;
        for (int j = im - 1; j >= 0; --j)
            if (!(fl[j] & USE) || y[j] - b < halfh) { left = j; break; }
        for (int j = im + 1; j < len; ++j)
            if (!(fl[j] & USE) || y[j] - b < halfh) { right = j; break; }
        if (left >= 0 && right >= 0 && (fl[left] & USE) && (fl[right] & USE)) {
            const float hl = y[left] - b, hl1 = y[left + 1] - b;
            const float hr = y[right] - b, hr1 = y[right - 1] - b;
            const float xl = left + (halfh - hl) / (hl1 - hl);
            const float xr = right - (halfh - hr) / (hr1 - hr);
            const float w = (xr - xl) / 2.35482004503f;
            if (w > 0.0f && w < BIG) width = w;
        }
    }
    global float *o = OUT + (size_t)r * 8;
    o[0] = b;
    o[1] = sigma;
    o[2] = (float)nv;
    o[3] = width;
    o[4] = (float)ncens;
    SPAN[r] = (int2)(first < 0 ? 0 : first, last < 0 ? len - 1 : last);
    NOISE[r] = sigma;
    }
}

/* Weights w[0..size) correlated with x at samples j0..j0+7 (lag 0 at centre; x is
 * zero-padded far enough on both sides). */
CLSIM_INLINE float8 correlate8(global const float *x, const int j0, constant float *w,
                               const int size, const int centre)
{
    float8 acc = (float8)(0.0f);
    global const float *p = x + j0 - centre;
    for (int t = 0; t < size; ++t) acc += w[t] * vload8(0, p + t);
    return acc;
}

/* x[j] is a local maximum of x over the samples i < len (the first of a plateau). */
CLSIM_INLINE int is_max(const float xm, const float x0, const float xp, const int j,
                        const int len)
{
    const float lo = j > 0 ? xm : -BIG;
    const float hi = j + 1 < len ? xp : -BIG;
    return j < len && x0 > lo && x0 >= hi;
}

/* Candidates of each row.  WORK (N x 5 x ns floats): the baseline-free samples, the
 * matched filter f, the smoothed samples ys (sigma 1), the curvature d2 and the
 * smoothed samples yc (sigma 1.5); the first row padded with M zeros on both sides
 * (M: at least the pulse's and the smoothing filters' reach).  ST per row: baseline, noise sigma, detection
 * level (amplitude units); d2_noise: the curvature's noise per unit noise sigma.  FLT: pulse weights (np_, lag 0 at pc), the Gaussian
 * weights of ys (9), yc (13) and d2 (13).  CAND (N x KCAP x 3): amplitude,
 * location, sigma (samples), highest first; COUNT: how many. */
kernel void candidates(global const float *Y, const int ns, const int n,
                       global const int *LEN, global const uchar *FL,
                       global const float *ST, constant float *FLT, const int np_,
                       const int pc, const int d, const float d2_noise, const float psig,
                       const int kcap, const int M, global float *WORK, global float *CAND,
                       global int *COUNT, const int N)
{
    for (int r = get_global_id(0); r < N; r += get_global_size(0)) {
    global const float *y = Y + (size_t)r * ns;
    global const uchar *fl = FL + (size_t)r * ns;
    global float *ybp = WORK + (size_t)r * (5 * ns + 2 * M);
    global float *yb = ybp + M;
    global float *f = ybp + ns + 2 * M, *ys = f + ns, *d2 = ys + ns, *yc = d2 + ns;
    constant float *g1 = FLT + np_, *gc = g1 + 9, *g2 = gc + 13;
    const int len = LEN[r];
    const float b = ST[3 * r], sigma = ST[3 * r + 1], level = ST[3 * r + 2];
    int anycens = 0;
    for (int j = -M; j < ns + M; ++j) {
        const int in = j >= 0 && j < n;
        const uchar fj = in ? fl[j] : 0;
        yb[j] = (fj & USE) ? y[j] - b : 0.0f;
        anycens |= fj & CENS;
    }
    for (int j0 = 0; j0 < n; j0 += 8) {
        vstore8(correlate8(yb, j0, FLT, np_, pc), 0, f + j0);
        vstore8(correlate8(yb, j0, g1, 9, 4), 0, ys + j0);
        vstore8(correlate8(yb, j0, gc, 13, 6), 0, yc + j0);
        vstore8(correlate8(yb, j0, g2, 13, 6), 0, d2 + j0);
    }
    const float s4 = 4.0f * sigma;
    /* pass 1: peaks of the smoothed samples (bit 1) and curvature minima (bit 2) */
    global uchar *cls = (global uchar *)(ybp);  /* reuse: yb is no longer needed */
    for (int j = 0; j < n; ++j) {
        const int jm = max(j - 1, 0), jp = min(j + 1, n - 1);
        const int sig = f[j] >= level;
        int c = 0;
        if (sig && ys[j] >= s4 && is_max(ys[jm], ys[j], ys[jp], j, len)) c |= 1;
        if (sig && -d2[j] >= 4.0f * d2_noise * sigma && yc[j] >= s4
            && is_max(-d2[jm], -d2[j], -d2[jp], j, len)) c |= 2;
        cls[j] = c;
    }
    /* pass 2: shoulders away from peaks (and clipped runs), matched-filter maxima away
     * from both; the kcap highest, highest first (ties: the earlier sample) */
    float ca[32], cm[32];
    int ci[32], ct[32];
    int cnt = 0;
    for (int j = 0; j < n; ++j) {
        const int jm = max(j - 1, 0), jp = min(j + 1, n - 1);
        int peak = cls[j] & 1;
        int sh = (cls[j] & 2) != 0;
        if (sh) {
            int blocked = (cls[jm] & 1) | (cls[jp] & 1) | peak;
            if (anycens)
                for (int i = max(j - d, 0); i <= min(j + d, n - 1); ++i)
                    blocked |= (fl[i] & CENS) != 0;
            sh = !blocked;
        }
        float h = -BIG;
        int type = 0;
        if (peak) { h = ys[j]; type = 1; }
        else if (sh) { h = yc[j]; type = 2; }
        else if ((fl[j] & USE) && f[j] >= level && is_max(f[jm], f[j], f[jp], j, len)) {
            int near = 0;
            for (int i = max(j - d, 0); i <= min(j + d, n - 1) && !near; ++i) {
                int strong = cls[i] & 1;
                if (!strong && (cls[i] & 2)) {
                    /* a shoulder at i counts only when not blocked */
                    const int im_ = max(i - 1, 0), ip_ = min(i + 1, n - 1);
                    int bl = (cls[im_] & 1) | (cls[ip_] & 1);
                    if (anycens)
                        for (int t = max(i - d, 0); t <= min(i + d, n - 1); ++t)
                            bl |= (fl[t] & CENS) != 0;
                    strong = !bl;
                }
                near = strong;
            }
            if (!near) { h = f[j]; type = 3; }
        }
        if (!type) continue;
        /* insert after every candidate at least as high */
        int pos = cnt;
        while (pos > 0 && ca[pos - 1] < h) --pos;
        if (pos >= kcap) continue;
        const int last = min(cnt, kcap - 1);
        for (int t = last; t > pos; --t) {
            ca[t] = ca[t - 1];
            ci[t] = ci[t - 1];
            ct[t] = ct[t - 1];
        }
        ca[pos] = h;
        ci[pos] = j;
        ct[pos] = type;
        cnt = min(cnt + 1, kcap);
    }
    /* start values: a log-parabola through the three samples around each candidate
     * of the curve that found it (Caruana et al. 1986); shoulders' widths from the
     * curvature (sigma^2 = -yc / d2 - CURV^2) */
    global float *out = CAND + (size_t)r * kcap * 3;
    for (int c = 0; c < cnt; ++c) {
        const int j = ci[c], type = ct[c];
        const int jm = max(j - 1, 0), jp = min(j + 1, n - 1);
        global const float *src = type == 1 ? ys : (type == 3 ? f : d2);
        const float sgn = type == 2 ? -1.0f : 1.0f;
        const float f0 = sgn * src[j], fm = sgn * src[jm], fp = sgn * src[jp];
        float loc = (float)j, var = 0.0f;
        int ok = 0;
        if (j > 0 && j < n - 1 && fm > 0.0f && fp > 0.0f && f0 > 0.0f) {
            const float lm = log(fm), l0 = log(f0), lp = log(fp);
            const float den = lm - 2.0f * l0 + lp;
            if (den < 0.0f) {
                loc = j + clamp(0.5f * (lm - lp) / den, -0.5f, 0.5f);
                var = -1.0f / den;
                ok = 1;
            }
        }
        if (type == 1) var -= 1.0f;
        else if (type == 3) var -= psig * psig;
        else {
            ok = d2[j] != 0.0f;
            var = ok ? -yc[j] / d2[j] - 2.25f : 0.0f;
        }
        float s0 = ok && var > 0.25f ? sqrt(var) : psig;
        s0 = clamp(s0, 0.5f, 0.5f * (float)n);
        out[3 * c] = ca[c];
        out[3 * c + 1] = loc;
        out[3 * c + 2] = s0;
    }
    COUNT[r] = cnt;
    }
}
