/* Monte Carlo photon transport through a sparse voxel scene with a ground plane.
 * Physics and notation: docs/method.md.  NumPy float64 twin: clsim/transport_ref.py.
 * Compile-time constants (-D): MODE (0 exact, 1 paper), DETECT (0 nee, 1 analog),
 * WOOD_DIR (1: voxels carry bark directions, the wdir buffer), BRICK, NTAB, NG,
 * TRACE_EVENTS; CLSIM_ATOM64 where the device has 64-bit atomics.
 * Estimator features of the exact mode (docs/method.md, "Variance reduction"), each 1 by
 * default and 0 only to measure it (benchmarks/bench_mitransient.py; the NumPy oracle
 * implements the defaults): CLSIM_TIGHT (free flights at the extinction LAD G(d) + sigma_wood
 * with uniform leaf azimuths, the leaf normal drawn after the collision), CLSIM_LEAF_AVG
 * (next-event weight of a leaf event averaged over the leaf normals where the scene's
 * params say it is exact), CLSIM_QMC (first free path from a randomly shifted golden-ratio
 * Kronecker lattice over the photon ids).  Traversal: CLSIM_UNIFORM (scene.cl; 1 by default)
 * crosses a uniform brick in one segment, the same distribution as voxel by voxel. */
#include "common.cl"
#include "params.cl"
#include "philox.cl"
#include "geometry.cl"
#include "scene.cl"
#include "medium.cl"

#define EV_ESCAPE 0
#define EV_LEAF 1
#define EV_WOOD 2
#define EV_GROUND 3

#define RR_THRESHOLD 0.1f
#define RR_SURVIVE 0.5f
#define FIXED_SCALE 4294967296.0f
/* at most this many proposals for a leaf normal at a real collision (acceptance G(d) each) */
#define LEAF_TRIES 1024

#ifndef CLSIM_TIGHT
#define CLSIM_TIGHT 1
#endif
#ifndef CLSIM_LEAF_AVG
#define CLSIM_LEAF_AVG 1
#endif
#ifndef CLSIM_QMC
#define CLSIM_QMC 1
#endif
/* Profiling switches (benchmarks/bench_walk_profile.py; 1 by default, 0 only to time a part
 * by its absence, which changes the results): CLSIM_PROF_NEE (0: the shadow rays are not
 * walked, transmittance 1), CLSIM_PROF_G (0: G(d) is 1/2 without the table),
 * CLSIM_PROF_TALLY (0: no histogram atomics), CLSIM_PROF_LEAF (0: a leaf's normal is -d,
 * not drawn), CLSIM_PROF_PHILOX (philox.cl; 0: a cheap hash). */
#ifndef CLSIM_PROF_NEE
#define CLSIM_PROF_NEE 1
#endif
#ifndef CLSIM_PROF_TALLY
#define CLSIM_PROF_TALLY 1
#endif
#ifndef CLSIM_PROF_LEAF
#define CLSIM_PROF_LEAF 1
#endif

/* Kronecker lattice step: round(2^32 / phi), phi the golden ratio. */
#define QMC_STEP 2654435769u


/* A leaf normal at x from the random numbers b.z, b.w (the scene's leaf angles and azimuths). */
CLSIM_INLINE float3 scene_leaf_normal(const scene_t *S, float4 b, float3 x)
{
    return leaf_normal(S->ppf, b.z, b.w, x, S->P->crown_c[0], S->P->crown_c[1], S->P->outward);
}


/* A tentative collision at y = xi' sigma_maj - LAD (>= 0) in the wood share of
 * the majorant: 1 for a real wood hit (*cyl: on the cylinder part), 0 for a
 * null collision.  Without directions every such collision is wood. */
CLSIM_INLINE int wood_hit(const scene_t *S, size_t row, float sw, float3 d, float y, int *cyl)
{
    *cyl = 0;
#if !WOOD_DIR
    return 1;
#else
    const float2 p = wood_parts(S, row, sw, d);
    *cyl = y < p.x;
    return y < p.x + p.y;
#endif
}

/* Normal of a wood element hit from d, facing -d, weighted by |n . d|: on the
 * cylinder part perpendicular to the voxel's bark axis a (n = -cos(phi) u +
 * sin(phi) v, u the unit part of d across a, v = a x u, sin(phi) = 2 u1 - 1);
 * random facets: cosine-weighted about -d.  Solid wood: an end cap (n = -+a,
 * facing -d) or the side, by their projected areas cap |cos psi| and
 * (1 - cap) sin(psi) / pi (u2 chooses). */
CLSIM_INLINE float3 wood_normal(const scene_t *S, size_t row, float3 d, int cyl, float u1, float u2)
{
#if WOOD_DIR
    if (cyl) {
        const float4 q = S->wdir[row];
        const float3 a = (float3)(q.x, q.y, q.z);
        const float ca = fast_dot(a, d);
        const float3 p = d - a * ca;
        const float l2 = fast_dot(p, p);
        if (q.w < 0.0f) {
            const float cap = -1.0f - q.w;
            const float end = cap * fast_abs(ca);
            const float side = (1.0f - cap) * fast_sqrt(l2) * (1.0f / CLSIM_PI);
            if (u2 * (end + side) < end)
                return ca > 0.0f ? -a : a;
        }
        if (l2 > 1.0e-12f) {
            const float3 u = p * (1.0f / fast_sqrt(l2));
            const float s = 2.0f * u1 - 1.0f;
            const float c = fast_sqrt(fast_max(0.0f, 1.0f - s * s));
            return s * cross(a, u) - c * u;
        }
    }
#endif
    return cosine_dir(-d, u1, u2);
}

/* The normal of a leaf hit from d (uniform leaf azimuths): drawn from p(nl) |nl . d| / G(d),
 * with b.z, b.w the first proposal's uniforms and b.y * ys its acceptance uniform (b.y
 * rescaled: uniform given the leaf).  Spherical leaf angles (P->leaf_avg): p(nl) is uniform
 * on the upper hemisphere and G = 1/2, so the density is |nl . d| / pi, the cosine law about
 * -d folded onto the upper hemisphere (nl and -nl have the same |nl . d|); drawn directly,
 * and the fold is left out because the caller uses only the side facing -d
 * (incident_side).  Other distributions: rejection, fresh blocks per proposal. */
CLSIM_INLINE float3 leaf_normal_seen(const scene_t *S, float3 d, float4 b, float3 x, float ys, rng_t *rng)
{
#if !CLSIM_PROF_LEAF
    return -d;
#endif
    if (S->P->leaf_avg)
        return cosine_dir(-d, b.z, b.w);
    float u = b.y * ys;
    float3 nl = scene_leaf_normal(S, b, x);
    for (int i = 0; i < LEAF_TRIES && u >= fast_abs(fast_dot(nl, d)); ++i) {
        b = rng_next(rng);
        u = b.y;
        nl = scene_leaf_normal(S, b, x);
    }
    return nl;
}

/* The paper's interception probability of one step ds through LAD u with leaf normal nl. */
CLSIM_INLINE float paper_leaf_prob(float u, float3 nl, float3 d, float ds)
{
    return fast_min(1.0f, u * fast_abs(fast_dot(nl, d)) * ds);
}


/* Next-event weight (1/sr) of a leaf event averaged over the leaf normals of a spherical
 * leaf-angle distribution with uniform azimuths: Ross's area scattering phase function over
 * pi G, G = 1/2, for incoming d and outgoing w (Ross 1981; docs/method.md). */
CLSIM_INLINE float leaf_avg_f(float3 d, float3 w, float R, float T)
{
    const float c = fast_min(1.0f, fast_max(-1.0f, fast_dot(d, w)));
    const float s = fast_sqrt(fast_max(0.0f, 1.0f - c * c));
    const float beta = fast_acos(c);
    return ((R + T) * (s - beta * c) * (1.0f / (3.0f * CLSIM_PI)) + T * c * (1.0f / 3.0f))
           * (2.0f / CLSIM_PI);
}

/* A 32-bit lattice coordinate as a uniform in (0, 1), the mapping of rng_next. */
CLSIM_INLINE float unit_of(uint x)
{
    return ((float)(x >> 9) + 0.5f) * 1.1920928955078125e-07f;
}

/* Fixed point, 2^-32 units; capped below 2^63 (a float beyond ulong range
 * would be undefined to convert; no real weight comes near the cap). */
CLSIM_INLINE ulong to_fixed(float v)
{
    return v > 0.0f ? (ulong)fast_min(v * FIXED_SCALE + 0.5f, 9.0e18f) : 0ul;
}

CLSIM_INLINE void add_fixed(__global ulong *p, float v)
{
    if (v > 0.0f)
        add_u64(p, to_fixed(v));
}


/* The paper's fixed steps: points k ds (k >= 1) inside the walker's clipped
 * range; empty bricks are jumped over. */
typedef struct {
    float ds, t_end;
    int k;
    float tk;  /* the current step point: distance, */
    float3 x;  /* position */
    float2 e;  /* and the voxel's LAD and wood extinction there */
    size_t row; /* its pool row */
} stepper_t;

/* Clip [0, t_limit] to the grid; 0 when the ray misses it. */
CLSIM_INLINE int stepper_init(stepper_t *p, float3 o, float3 d, float t_limit, __global const params_t *P)
{
    walker_t w;
    if (!walker_init(&w, o, d, 0.0f, t_limit, P))
        return 0;
    p->ds = P->ds;
    p->t_end = w.t_end;
    p->k = max(1, (int)ceil(w.t / p->ds));
    return 1;
}

/* Next step point with non-zero extinction (p->tk, p->x, p->e); 0 at the end. */
CLSIM_INLINE int stepper_next(stepper_t *p, const scene_t *S, float3 o, float3 d, uint2 *steps)
{
    while ((float)p->k * p->ds < p->t_end) {
        const float t = (float)p->k * p->ds;
        const float3 xk = o + d * t;
        float skip;
        size_t row;
        const float2 v = point_value(xk, S->P, S->index, S->pool, o, d, &skip, &row);
        *steps += (uint2)(1u, 1u);
        if (skip >= 0.0f) {
            p->k = max(p->k + 1, (int)floor(skip / p->ds) + 1);
            continue;
        }
        ++p->k;
        if (v.x + v.y > 0.0f) {
            p->tk = t;
            p->x = xk;
            p->e = v;
            p->row = row;
            return 1;
        }
    }
    return 0;
}

/* The null-collision walk shared by free flights (delta tracking) and the
 * transmittance of outward-facing leaves (ratio tracking): tentative
 * collisions at the majorant sigma = LAD + sigma_wood of each voxel, with
 * an exponential optical depth tau that the caller redraws after each. */
typedef struct {
    walker_t w;
    float ta, tb, tau; /* current voxel segment; optical depth left */
    float2 e;          /* its LAD and (direction-averaged) wood extinction */
    float wmaj;        /* its wood majorant (wood_majorant) */
    float gl;          /* majorant of the leaves per unit LAD: 1, or G(d) where that is exact */
    int live;          /* a segment is loaded */
} tracker_t;

CLSIM_INLINE int tracker_init(tracker_t *k, float3 o, float3 d, float t_limit, float tau, float gl,
                              __global const params_t *P)
{
    k->tau = tau;
    k->gl = gl;
    k->live = 0;
    return walker_init(&k->w, o, d, 0.0f, t_limit, P);
}

/* Next tentative collision: its distance *tc (k->e holds the voxel's values); 0 at the end. */
CLSIM_INLINE int tracker_next(tracker_t *k, const scene_t *S, float *tc, uint2 *steps)
{
    for (;;) {
        if (!k->live) {
            if (!walker_next(&k->w, S->P, S->index, S->boxes, S->pool, &k->ta, &k->tb, &k->e, steps))
                return 0;
            k->wmaj = wood_majorant(S, k->w.row, k->e.y);
            k->live = 1;
        }
        const float sig = k->e.x * k->gl + k->wmaj;
        const float opt = sig * (k->tb - k->ta);
        if (opt <= k->tau) {
            k->tau -= opt;
            k->live = 0;
            continue;
        }
        *tc = k->ta + k->tau / sig;
        k->ta = *tc;
        return 1;
    }
}

/* Next real interaction along (o, d).  Returns the event type, its distance
 * *t and the surface normal *n (leaf: sampled normal, wood: facing normal).
 * u_tau > 0 replaces the first uniform of the free path (the lattice point of
 * a first flight, CLSIM_QMC). */
CLSIM_INLINE int flight(const scene_t *S, float3 o, float3 d, rng_t *rng, float u_tau, float *t,
                  float3 *n, uint2 *steps)
{
    __global const params_t *P = S->P;
    const float tg = ground_t(o, d, P);
#if MODE == 0
    float4 b = rng_next(rng);
    if (u_tau > 0.0f)
        b.x = u_tau;
    /* With uniform leaf azimuths the leaves' extinction is exactly LAD G(d): that is the
     * majorant (no null collisions); outward azimuths keep LAD, thinned by |nl . d|. */
    const int tight = CLSIM_TIGHT && !P->outward;
    const float gl = tight ? g_of(S, d.z) : 1.0f;
    tracker_t k;
    if (tracker_init(&k, o, d, tg, neg_log_unit(b.x), gl, P)) {
        float tc;
        while (tracker_next(&k, S, &tc, steps)) {
            const float sl = k.e.x * gl;
            const float sig = sl + k.wmaj;
            const float3 x = o + d * tc;
            if (b.y * sig >= sl) { /* wood share of the majorant */
                int cyl;
                if (wood_hit(S, k.w.row, k.e.y, d, b.y * sig - sl, &cyl)) {
                    *n = wood_normal(S, k.w.row, d, cyl, b.z, b.w);
                    *t = tc;
                    walker_stop(&k.w, tc, steps);
                    return EV_WOOD;
                }
            } else if (tight) {
                /* a leaf: its normal from p(nl) |nl . d| / G(d) */
                *n = leaf_normal_seen(S, d, b, x, sig / sl, rng);
                *t = tc;
                walker_stop(&k.w, tc, steps);
                return EV_LEAF;
            } else {
                const float3 nl = scene_leaf_normal(S, b, x);
                if (b.y * sig < k.e.x * fast_abs(fast_dot(nl, d))) {
                    *n = nl;
                    *t = tc;
                    walker_stop(&k.w, tc, steps);
                    return EV_LEAF;
                }
            }
            b = rng_next(rng); /* null collision */
            k.tau = neg_log_unit(b.x);
        }
    }
#else
    stepper_t p;
    if (stepper_init(&p, o, d, tg, P)) {
        const float ds = p.ds;
        while (stepper_next(&p, S, o, d, steps)) {
            const float4 b = rng_next(rng);
            const float3 nl = scene_leaf_normal(S, b, p.x);
            if (b.x < paper_leaf_prob(p.e.x, nl, d, ds)) {
                *n = nl;
                *t = p.tk;
                return EV_LEAF;
            }
            const float2 wp = wood_parts(S, p.row, p.e.y, d);
            const float sw = wood_sigma(S, p.row, p.e.y, d);
            if (b.y < -expm1(-sw * ds)) {
                const float4 b2 = rng_next(rng);
                *n = wood_normal(S, p.row, d, b2.y * sw < wp.x, b2.z, b2.w);
                *t = p.tk;
                return EV_WOOD;
            }
        }
    }
#endif
    if (tg < CLSIM_FAR) {
        *t = tg;
        *n = (float3)(0.0f, 0.0f, 1.0f);
        return EV_GROUND;
    }
    *t = CLSIM_FAR;
    return EV_ESCAPE;
}

/* Transmittance from o along unit d over distance r.  Exact mode: with
 * uniform leaf azimuths the extinction LAD G(d) + sigma_wood is constant in a
 * voxel and T = exp(-sum sigma l) exactly (no random numbers); with outward
 * azimuths G varies inside a voxel and ratio tracking (unbiased) is used.
 * Paper mode: the product over the paper's steps. */
CLSIM_INLINE float transmittance(const scene_t *S, float3 o, float3 d, float r, rng_t *rng, uint2 *steps)
{
    __global const params_t *P = S->P;
    float T = 1.0f;
#if !CLSIM_PROF_NEE
    return T;
#endif
#if MODE == 0
    walker_t w;
    float ta, tb;
    float2 e;
    if (!P->outward) {
        if (!walker_init(&w, o, d, 0.0f, r, P))
            return T;
        const float gd = g_of(S, d.z);
        float od = 0.0f;
        while (walker_next(&w, P, S->index, S->boxes, S->pool, &ta, &tb, &e, steps)) {
            const float sig = e.x * gd + wood_sigma(S, w.row, e.y, d);
            const float od0 = od;
            od += sig * (tb - ta);
            if (od > 40.0f) {
                /* cut off where the optical depth passes 40: the voxel walk stops in that voxel */
                walker_stop(&w, ta + (40.0f - od0) / sig, steps);
                return 0.0f;
            }
        }
        return exp(-od);
    }
    float4 b = rng_next(rng);
    tracker_t k;
    if (!tracker_init(&k, o, d, r, neg_log_unit(b.x), 1.0f, P))
        return T;
    float tc;
    while (tracker_next(&k, S, &tc, steps)) {
        const float sig = k.e.x + k.wmaj;
        const float3 x = o + d * tc;
        const float3 nl = scene_leaf_normal(S, b, x);
        T *= 1.0f - (k.e.x * fast_abs(fast_dot(nl, d)) + wood_sigma(S, k.w.row, k.e.y, d)) / sig;
        if (T < RR_THRESHOLD) {
            if (b.y * RR_SURVIVE < T) {
                T = RR_SURVIVE;
            } else {
                walker_stop(&k.w, tc, steps);
                return 0.0f;
            }
        }
        b = rng_next(rng);
        k.tau = neg_log_unit(b.x);
    }
#else
    stepper_t p;
    if (!stepper_init(&p, o, d, r, P))
        return T;
    const float ds = p.ds;
    while (stepper_next(&p, S, o, d, steps)) {
        const float4 b = rng_next(rng);
        const float3 nl = scene_leaf_normal(S, b, p.x);
        T *= (1.0f - paper_leaf_prob(p.e.x, nl, d, ds)) * exp(-wood_sigma(S, p.row, p.e.y, d) * ds);
        if (T < RR_THRESHOLD) {
            if (b.y * RR_SURVIVE < T)
                T = RR_SURVIVE;
            else
                return 0.0f;
        }
    }
#endif
    return T;
}

CLSIM_INLINE void tally(__global ulong *hist, __global ulong *stats, __global const params_t *P,
                  uint batch, int order, int kind, float t_ns, float value)
{
#if !CLSIM_PROF_TALLY
    return;
#endif
    const float s = (t_ns - P->t0_ns) / P->dt_ns;
    if (s >= 0.0f && s < (float)P->nbins) {
        const size_t i = (((size_t)batch * P->max_order + (order - 1)) * 2 + kind) * P->nbins + (size_t)s;
        add_fixed(hist + i, value);
    } else {
        add_fixed(stats + batch * NSTAT + ST_OUTSIDE, value);
    }
}

CLSIM_INLINE void record(__global float4 *trace, ulong pid, int k, float3 x, int type, __global const params_t *P)
{
    if (pid < (ulong)P->n_trace && k < TRACE_EVENTS)
        trace[pid * TRACE_EVENTS + k] = (float4)(x, (float)type);
}

/* One photon: its path, tallies (atomics into hist) and statistics (added to acc). */
CLSIM_INLINE void photon(const scene_t *S, __global ulong *hist, __global ulong *stats, __global float4 *trace,
                         uint2 key, ulong pid, uint batch, ulong *acc)
{
    __global const params_t *P = S->P;
    rng_t rng;
    rng_init(&rng, key, pid);

    const float3 sensor = (float3)(P->sensor[0], P->sensor[1], P->sensor[2]);
    const float3 axis = (float3)(P->axis[0], P->axis[1], P->axis[2]);
    const float3 e1 = (float3)(P->e1[0], P->e1[1], P->e1[2]), e2 = (float3)(P->e2[0], P->e2[1], P->e2[2]);
    const float4 b0 = rng_next(&rng);
    float u_first = 0.0f;
#if MODE == 0 && CLSIM_QMC
    /* the photon's point of the golden-ratio lattice shifted by the seed (P->qmc) */
    u_first = unit_of(P->qmc + (uint)pid * QMC_STEP);
#endif
    const float rr = P->beam_sigma * fast_sqrt(2.0f * neg_log_unit(b0.x));
    float cph;
    const float sph = sincos_turns(b0.y, &cph);
    float3 d = fast_normalize3(axis + rr * cph * e1 + rr * sph * e2);
    float3 x = sensor;
    float L = 0.0f, w = 1.0f;
    int last = EV_LEAF;
    uint2 steps = (uint2)(0u, 0u);
    uint events = 0u, shadow = 0u;
    record(trace, pid, 0, x, -2, P);

    for (int k = 1;; ++k) {
        float t;
        float3 n;
        const int ev = flight(S, x, d, &rng, k == 1 ? u_first : 0.0f, &t, &n, &steps);
        if (ev == EV_ESCAPE) {
            acc[(d.z >= 0.0f ? ST_ESC_UP : ST_ESC_DOWN)] += to_fixed(w);
            record(trace, pid, k, x + d * 10.0f, EV_ESCAPE, P);
#if DETECT == 1
            if (k >= 2) {
                const float den = fast_dot(d, axis);
                const float3 sx = x - sensor;
                const float along = fast_dot(sx, axis);
                if (den < -1.0e-6f && in_fov(sx, axis, P->tan2_fov)) { /* towards the sensor; no overflow in s */
                    const float s = -along / den;
                    const float3 q = x + d * s - sensor;
                    if (fast_dot(q, q) <= P->virt_r2) {
                        tally(hist, stats, P, batch, k - 1, last == EV_GROUND, (L + s) / 0.299792458f,
                              w * P->norm_analog);
                        acc[ST_DETECTIONS] += 1ul;
                    }
                }
            }
#endif
            break;
        }
        x = x + d * t;
        L += t;
        events += 1u;
        record(trace, pid, k, x, ev, P);
        if (ev == EV_GROUND && k == 1)
            acc[ST_GROUND_DIRECT] += to_fixed(w);
        if (k > P->max_order) {
            acc[ST_TRUNCATED] += to_fixed(w);
            break;
        }
        float R, T;
        float3 m;
        last = ev;
        if (ev == EV_LEAF) {
            R = P->leaf_R; T = P->leaf_T; m = incident_side(n, d);
        } else if (ev == EV_WOOD) {
            R = P->wood_R; T = P->wood_T; m = n;
        } else {
            R = P->ground_R; T = 0.0f; m = n;
        }
#if DETECT == 0
        {
            const float3 to = sensor - x;
            const float r = fast_sqrt(fast_dot(to, to));
            const float3 drx = to / r;
            const float cosr = -fast_dot(drx, axis);
#if CLSIM_LEAF_AVG
            const float f = (ev == EV_LEAF && P->leaf_avg) ? leaf_avg_f(d, drx, R, T) : bsdf(m, drx, R, T);
#else
            const float f = bsdf(m, drx, R, T);
#endif
            /* skip_first: the order-1 return is computed elsewhere (first_order.cl) */
            if (f > 0.0f && !(k == 1 && P->skip_first) && in_fov(-to, axis, P->tan2_fov)) {
                shadow += 1u;
                /* hot spot: a single-scattering return retraces its incoming path, which was free */
                const float Tr = (P->hotspot && k == 1) ? 1.0f : transmittance(S, x, drx, r, &rng, &steps);
                if (Tr > 0.0f)
                    tally(hist, stats, P, batch, k, ev == EV_GROUND, (L + r) / 0.299792458f,
                          w * f * Tr * cosr * P->norm_nee / (r * r));
            }
        }
        if (k == P->max_order) {
            acc[ST_TRUNCATED] += to_fixed(w);
            break;
        }
#endif
        const float4 s = rng_next(&rng);
        const float a = R + T;
        int reflect;
#if MODE == 0
        if (a <= 0.0f) {
            acc[ST_ABSORBED] += to_fixed(w);
            break;
        }
        reflect = s.x * a < R;
        acc[ST_ABSORBED] += to_fixed(w * (1.0f - a));
        w *= a;
        if (w < RR_THRESHOLD) {
            if (s.w * RR_SURVIVE < w) {
                acc[ST_RR_ADDED] += to_fixed(RR_SURVIVE - w);
                w = RR_SURVIVE;
            } else {
                acc[ST_RR_KILLED] += to_fixed(w);
                break;
            }
        }
#else
        if (s.x >= a) {
            acc[ST_ABSORBED] += to_fixed(w);
            record(trace, pid, k + 1, x, -1, P);
            break;
        }
        reflect = s.x < R;
#endif
        d = cosine_dir(reflect ? m : -m, s.y, s.z);
    }
    acc[ST_VOXEL_STEPS] += steps.x;
    acc[ST_WALK_STEPS] += steps.y;
    acc[ST_EVENTS] += events;
    acc[ST_SHADOW] += shadow;
}

/* Adds a work item's statistics acc of one batch to stats (one atomic per non-zero
 * statistic) and clears them. */
CLSIM_INLINE void flush_stats(__global ulong *stats, uint batch, ulong *acc)
{
    for (int j = 0; j < NSTAT; ++j) {
        if (acc[j])
            add_u64(stats + batch * NSTAT + j, acc[j]);
        acc[j] = 0ul;
    }
}

/* Work item gid simulates photons pid0 + gid, pid0 + gid + stride, ... below pid0 + n, stride
 * the launch's global size.  Its statistics are summed privately and added with one atomic
 * per non-zero statistic when the batch (pid % n_batches) changes or at the end: the host
 * makes the global size a multiple of n_batches on CPUs (several photons per work item), so
 * the atomics, which contend between cores there, fall from one set per photon to one per
 * work item.  Integer sums keep runs bit-identical whatever the grouping and order. */
__kernel void simulate(__global const params_t *P, __global const int *index,
                       __global const int4 *boxes, __global const float2 *pool, __global const float *ppf,
                       __global const float *gtab, __global const float4 *wdir, __global ulong *hist, __global ulong *stats, __global float4 *trace,
                       uint2 key, ulong pid0, uint n)
{
    const uint gid = get_global_id(0);
    if (gid >= n)
        return;
    const uint stride = (uint)get_global_size(0);
    const scene_t S = {P, index, boxes, pool, ppf, gtab, wdir};
    ulong acc[NSTAT] = {0};
    uint batch = (uint)((pid0 + gid) % (ulong)P->n_batches);
    for (uint i = gid; i < n; i += stride) {
        const ulong pid = pid0 + i;
        const uint b = (uint)(pid % (ulong)P->n_batches);
        if (b != batch) {
            flush_stats(stats, batch, acc);
            batch = b;
        }
        photon(&S, hist, stats, trace, key, pid, batch, acc);
    }
    flush_stats(stats, batch, acc);
}
