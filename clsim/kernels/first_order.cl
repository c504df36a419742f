/* The deterministic first order: the expected single-scattering waveform of a pulse, integrated
 * through the voxels along a fixed set of beam samples (docs/method.md, "Deterministic first
 * order"), for every pulse of a batch in one launch; then the pulse convolution and the
 * digitiser's samples, on the device.  NumPy float64 twin: clsim/transport/first_order.py.
 *
 * Along a beam sample from the sensor in direction d, a voxel segment [ta, tb] of extinction
 * sigma = LAD G(d) + sigma_wood(d) sends back, per metre at distance s,
 *     w (d . axis) phi exp(-m tau(s)) / s^2,
 * phi = LAD (R_leaf / pi) E[(n . d)^2] + the wood's backscatter, tau the optical depth from
 * the sensor, m = 2 (the turbid two-way path) or 1 (P->hotspot: the return retraces the free
 * incoming path).  That is the expectation of the Monte Carlo kernel's order-1 next-event
 * tally (transport.cl), whose receiver direction is exactly -d at a first event.  Each fine
 * bin receives the exact integral of that exponential over its part of the segment.
 * Compile-time constants (-D) as transport.cl: BRICK, BRICK_SHIFT, NTAB, NG, WOOD_DIR. */
#include "common.cl"
#include "params.cl"
#include "geometry.cl"
#include "scene.cl"
#include "medium.cl"

#define C_M_PER_NS 0.299792458f
/* floats per pulse record (clsim/transport/first_order.py PULSE_FIELDS): sensor, axis, e1, e2,
 * the first fine edge (ns), the pulse's fine bins */
#define PULSE_STRIDE 16

/* Backscatter of the wood per metre towards -d (1/sr, times the extinction parts): random
 * facets cosine-weighted about -d give R 2 / (3 pi) per unit extinction; the cylinder part
 * R sin(psi) / 4 (the mean of cos(phi) sin(psi) R / pi over a uniform impact parameter);
 * solid wood mixes that with its end caps (R |cos psi| / pi) by their projected areas. */
CLSIM_INLINE float wood_back(const scene_t *S, size_t row, float2 parts, float3 d)
{
    const float R = S->P->wood_R;
    float v = parts.y * R * (2.0f / (3.0f * CLSIM_PI));
#if WOOD_DIR
    if (parts.x > 0.0f) {
        const float4 q = S->wdir[row];
        const float ca = fast_abs(fast_dot((float3)(q.x, q.y, q.z), d));
        const float sin_psi = fast_sqrt(fast_max(0.0f, 1.0f - ca * ca));
        float fc = R * sin_psi * 0.25f;
        if (q.w < 0.0f) {
            const float cap = -1.0f - q.w;
            const float end = cap * ca, side = (1.0f - cap) * sin_psi * (1.0f / CLSIM_PI);
            const float tot = end + side;
            fc = tot > 0.0f ? (end * R * ca * (1.0f / CLSIM_PI) + side * fc) / tot : 0.0f;
        }
        v += parts.x * fc;
    }
#endif
    return v;
}

/* Adds a * exp(-k (s - ta)) / s^2 integrated over [ta, tb] to the fine bins of h (1 / s^2 at the
 * middle of each bin's piece) (bin i covers
 * covers distances s0 + i / inv_ds .. s0 + (i + 1) / inv_ds); what falls outside goes to *out. */
CLSIM_INLINE void deposit(__global float *h, int F, float ta, float tb, float k, float a, float s0,
                          float inv_ds, float *out)
{
    int i = (int)floor((ta - s0) * inv_ds);
    float x = ta, e = a;
    while (x < tb) {
        const float b = fast_min(fast_max(s0 + (float)(i + 1) / inv_ds, x), tb);
        const float l = b - x;
        const float q = k * l;
        const float em = q > 1.0e-4f ? -expm1(-q) : q * (1.0f - 0.5f * q);
        const float xm = x + 0.5f * l;
        const float v = (k > 0.0f ? e * em / k : e * l) / (xm * xm);
        if (i >= 0 && i < F)
            h[i] += v;
        else
            *out += v;
        e *= 1.0f - em;
        x = b;
        ++i;
    }
}

/* Outward leaf azimuths (P->outward): at a point whose leaves face away from the crown centre,
 * n . d = A sin(theta) + B cos(theta) = rho sin(theta + beta), with A the part of d along the
 * outward horizontal, B = d.z, rho = |(A, B)|, beta = atan2(B, A): G = rho E|sin(theta + beta)|
 * and E[(n . d)^2] = rho^2 E[sin^2(theta + beta)], the two expectations over the leaf zenith
 * tabulated on NG values of beta in [-pi, pi] (otab: the first NG, then the next NG). */
CLSIM_INLINE float2 outward_leaf(__global const float *otab, float3 x, float3 d, float cx, float cy)
{
    const float dx = x.x - cx, dy = x.y - cy, rr = dx * dx + dy * dy;
    const float ir = rr > 0.0f ? rsqrt(rr) : 0.0f;
    const float cp = rr > 0.0f ? dx * ir : 1.0f, sp = dy * ir;
    const float A = d.x * cp + d.y * sp, B = d.z;
    const float rho2 = A * A + B * B;
    const float u = (atan2(B, A) + CLSIM_PI) * (1.0f / (2.0f * CLSIM_PI)) * (float)(NG - 1);
    const int i = clamp((int)u, 0, NG - 2);
    const float f = fast_min(fast_max(u - (float)i, 0.0f), 1.0f);
    const float g = otab[i] * (1.0f - f) + otab[i + 1] * f;
    const float q = otab[NG + i] * (1.0f - f) + otab[NG + i + 1] * f;
    return (float2)(fast_sqrt(rho2) * g, rho2 * q);
}

/* Pulse gid: its fine energies (2 F floats: vegetation, ground) into fine, the energy beyond
 * the fine grid into outside[gid].  samples[j] = (a, b, w, 0): the sample's direction is
 * axis + beam_sigma (a e1 + b e2), normalised, with weight w (the weights sum to 1).
 * leaf_c2 is E[cos^2] of the leaf zenith (the leaf-angle distribution's; uniform azimuths);
 * otab the outward azimuths' tables (outward_leaf).  With outward azimuths G and the
 * backscatter vary inside a voxel: each segment is cut into pieces of at most a voxel's size,
 * each with its values at its middle. */
__kernel void first_order(__global const params_t *P, __global const int *index,
                          __global const int4 *boxes, __global const float2 *pool, __global const float *ppf,
                          __global const float *gtab, __global const float4 *wdir,
                          __global const float *pulses, __global const float4 *samples, uint n_samples,
                          float leaf_c2, __global const float *otab, __global float *fine,
                          __global float *outside, uint n)
{
    const uint gid = get_global_id(0);
    if (gid >= n)
        return;
    const scene_t S = {P, index, boxes, pool, ppf, gtab, wdir};
    __global const float *pr = pulses + (size_t)gid * PULSE_STRIDE;
    const int stride = P->nbins;
    /* the pulse's own window (its bins whatever the batch's longest): results per pulse do not
     * depend on which pulses share its batch */
    const int F = min((int)pr[13], stride);
    __global float *hv = fine + (size_t)gid * 2 * (size_t)stride;
    __global float *hg = hv + stride;
    for (int i = 0; i < 2 * stride; ++i)
        hv[i] = 0.0f;
    const float3 sensor = (float3)(pr[0], pr[1], pr[2]);
    const float3 axis = (float3)(pr[3], pr[4], pr[5]);
    const float3 e1 = (float3)(pr[6], pr[7], pr[8]), e2 = (float3)(pr[9], pr[10], pr[11]);
    const float s0 = 0.5f * C_M_PER_NS * pr[12];     /* distance of the fine grid's first edge */
    const float inv_ds = 2.0f / (C_M_PER_NS * P->dt_ns); /* fine bins per metre of distance */
    const float m = P->hotspot ? 1.0f : 2.0f;
    const float sig_b = P->beam_sigma;
    float out = 0.0f;
    uint2 steps = (uint2)(0u, 0u);
    for (uint j = 0; j < n_samples; ++j) {
        const float4 q = samples[j];
        const float3 d = fast_normalize3(axis + sig_b * (q.x * e1 + q.y * e2));
        if (!in_fov(d, axis, P->tan2_fov))
            continue;
        const float wgt = q.z * fast_dot(d, axis);
        const float gd = g_of(&S, d.z);
        const float mu2 = d.z * d.z;
        const float leaf_back = P->leaf_avg ? P->leaf_R * (1.0f / (3.0f * CLSIM_PI))
            : P->leaf_R * (1.0f / CLSIM_PI) * (mu2 * leaf_c2 + (1.0f - mu2) * (1.0f - leaf_c2) * 0.5f);
        const float tg = ground_t(sensor, d, P);
        float od = 0.0f;
        walker_t w;
        float ta, tb;
        float2 e;
        if (walker_init(&w, sensor, d, 0.0f, tg, P)) {
            while (od <= 40.0f && walker_next(&w, P, index, boxes, pool, &ta, &tb, &e, &steps)) {
                const float2 parts = wood_parts(&S, w.row, e.y, d);
                const float wback = wood_back(&S, w.row, parts, d);
                const int pieces = P->outward && e.x > 0.0f ? max(1, (int)ceil((tb - ta) / P->h)) : 1;
                const float len = (tb - ta) / (float)pieces;
                for (int k = 0; k < pieces && od <= 40.0f; ++k) {
                    const float a = ta + (float)k * len, b = k == pieces - 1 ? tb : a + len;
                    float gl = gd, bl = leaf_back;
                    if (P->outward) {
                        const float2 o = outward_leaf(otab, sensor + d * (0.5f * (a + b)), d, P->crown_c[0],
                                                      P->crown_c[1]);
                        gl = o.x;
                        bl = P->leaf_R * (1.0f / CLSIM_PI) * o.y;
                    }
                    const float sig = e.x * gl + parts.x + parts.y;
                    const float phi = e.x * bl + wback;
                    if (phi > 0.0f)
                        deposit(hv, F, a, b, m * sig, wgt * phi * exp(-m * od), s0, inv_ds, &out);
                    od += sig * (b - a);
                }
            }
        }
        if (tg < CLSIM_FAR && od <= 40.0f) {
            const float v = wgt * P->ground_R * (1.0f / CLSIM_PI) * (-d.z) * exp(-m * od) / (tg * tg);
            const int i = (int)floor((tg - s0) * inv_ds);
            if (i >= 0 && i < F)
                hg[i] += v;
            else
                out += v;
        }
    }
    outside[gid] = out;
}

/* Pulse gid's digitised waveform: the fine energies of both kinds convolved with the pulse
 * kernel taps[0 .. n_taps - 1] (zero lag at lag0, weights summing to 1) and divided by the
 * fine bin, at the fine centres k (bins per sample) apart from the first: the sample s lies at
 * fine bin k s.  wave holds S samples per pulse; energy[gid] the fine energies' sum. */
__kernel void digitize_rows(__global const params_t *P, __global const float *fine, __constant float *taps,
                            int n_taps, int lag0, int k, int S, __global float *wave,
                            __global float *energy, uint n)
{
    const uint gid = get_global_id(0);
    if (gid >= n)
        return;
    const int F = P->nbins;
    __global const float *hv = fine + (size_t)gid * 2 * (size_t)F;
    __global const float *hg = hv + F;
    float tot = 0.0f;
    int lo = F, hi = -1;
    for (int i = 0; i < F; ++i) {
        const float v = hv[i] + hg[i];
        tot += v;
        if (v != 0.0f) {
            lo = min(lo, i);
            hi = i;
        }
    }
    energy[gid] = tot;
    const float inv_dt = 1.0f / P->dt_ns;
    __global float *y = wave + (size_t)gid * (size_t)S;
    for (int s = 0; s < S; ++s) {
        const int c = k * s;
        float acc = 0.0f;
        /* output c = sum_t taps[t] h[c - t + lag0], over the bins that hold energy */
        const int t_lo = max(0, c + lag0 - hi), t_hi = min(n_taps - 1, c + lag0 - lo);
        for (int t = t_lo; t <= t_hi; ++t) {
            const int i = c - t + lag0;
            acc += taps[t] * (hv[i] + hg[i]);
        }
        y[s] = acc * inv_dt;
    }
}
