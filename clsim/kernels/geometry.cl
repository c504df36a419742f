/* Directions, leaf normals, bi-Lambertian scattering.  Twin: clsim/transport/reference_geometry.py. */
#ifndef CLSIM_GEOMETRY_CL
#define CLSIM_GEOMETRY_CL

#include "common.cl"

#define CLSIM_PI 3.14159265358979323846f

/* sin and cos of |x| <= pi/4 by their Taylor series to x^9 and x^10
 * (truncation error below 3e-9, under float32 rounding). */
CLSIM_INLINE float sincos_small(float x, float *c)
{
    const float x2 = x * x;
    *c = 1.0f + x2 * (-0.5f + x2 * (1.0f / 24.0f + x2 * (-1.0f / 720.0f + x2 * (1.0f / 40320.0f
         + x2 * (-1.0f / 3628800.0f)))));
    return x * (1.0f + x2 * (-1.0f / 6.0f + x2 * (1.0f / 120.0f + x2 * (-1.0f / 5040.0f
           + x2 * (1.0f / 362880.0f)))));
}

/* sin and cos of 2 pi u for u in [0, 1].  The quadrant comes from u itself,
 * so the reduction is exact; PoCL's sin and cos spend most of their time on
 * a general argument reduction. */
CLSIM_INLINE float sincos_turns(float u, float *c)
{
    const float q = u * 4.0f;
    const int k = (int)(q + 0.5f); /* nearest quadrant (q >= 0) */
    float ca;
    const float sa = sincos_small((q - (float)k) * (0.5f * CLSIM_PI), &ca);
    const int quadrant = k & 3;
    /* rotate (ca, sa) by quadrant * 90 degrees */
    const float cr = quadrant == 0 ? ca : (quadrant == 1 ? -sa : (quadrant == 2 ? -ca : sa));
    const float sr = quadrant == 0 ? sa : (quadrant == 1 ? ca : (quadrant == 2 ? -sa : -ca));
    *c = cr;
    return sr;
}

/* acos(x) for x in [-1, 1]: sqrt(1 - |x|) times a degree-7 polynomial in |x|
 * (Abramowitz & Stegun 4.4.46, absolute error below 2e-8, under float32
 * rounding), reflected for x < 0.  PoCL's acos is a library call. */
CLSIM_INLINE float fast_acos(float x)
{
    const float a = fast_abs(x);
    const float p = 1.5707963050f + a * (-0.2145988016f + a * (0.0889789874f + a * (-0.0501743046f
                    + a * (0.0308918810f + a * (-0.0170881256f + a * (0.0066700901f
                    + a * -0.0012624911f))))));
    const float r = fast_sqrt(fast_max(0.0f, 1.0f - a)) * p;
    return x < 0.0f ? CLSIM_PI - r : r;
}

/* sin and cos of t in [0, pi/2]: t = pi/4 + a, |a| <= pi/4. */
CLSIM_INLINE float sincos_quarter(float t, float *c)
{
    float ca;
    const float sa = sincos_small(t - 0.25f * CLSIM_PI, &ca);
    const float r = 0.70710678118654752f;
    *c = r * (ca - sa);
    return r * (sa + ca);
}

/* Orthonormal basis around unit n (Duff et al. 2017, JCGT 6(1), branchless). */
CLSIM_INLINE void onb(float3 n, float3 *b1, float3 *b2)
{
    const float s = n.z >= 0.0f ? 1.0f : -1.0f;
    const float a = -1.0f / (s + n.z);
    const float b = n.x * n.y * a;
    *b1 = (float3)(1.0f + s * n.x * n.x * a, s * b, -s * n.x);
    *b2 = (float3)(b, s + n.y * n.y * a, -n.y);
}

/* Cosine-weighted direction about unit m. */
CLSIM_INLINE float3 cosine_dir(float3 m, float u1, float u2)
{
    float3 b1, b2;
    onb(m, &b1, &b2);
    const float r = fast_sqrt(u1);
    float c;
    const float s = sincos_turns(u2, &c);
    return fast_normalize3(r * c * b1 + r * s * b2 + fast_sqrt(fast_max(0.0f, 1.0f - u1)) * m);
}

/* Leaf normal (upper hemisphere): zenith from the inverse-CDF table, azimuth
 * uniform (u_az) or pointing away from the crown centre at x. */
CLSIM_INLINE float3 leaf_normal(__global const float *ppf, float u_t, float u_az, float3 x,
                          float cx, float cy, int outward)
{
    const float s = u_t * (float)(NTAB - 1);
    const int i = min((int)s, NTAB - 2);
    const float f = s - (float)i;
    const float t = ppf[i] * (1.0f - f) + ppf[i + 1] * f;
    float ct, cp, sp;
    const float st = sincos_quarter(fast_min(fast_max(t, 0.0f), 0.5f * CLSIM_PI), &ct);
    if (outward) { /* azimuth atan2(dy, dx): its cosine and sine directly */
        const float dx = x.x - cx, dy = x.y - cy, rr = dx * dx + dy * dy;
        const float ir = rr > 0.0f ? rsqrt(rr) : 0.0f;
        cp = rr > 0.0f ? dx * ir : 1.0f;
        sp = dy * ir;
    } else {
        sp = sincos_turns(u_az, &cp);
    }
    return (float3)(st * cp, st * sp, ct);
}

/* Is v (sensor -> point) inside the receiver's field of view around the unit
 * axis?  Tested on the offset from the axis, not on a cosine: cos(1 mrad) =
 * 1 - 5e-7 lies a few float32 steps from 1, which would blur the FOV edge. */
CLSIM_INLINE int in_fov(float3 v, float3 axis, float tan2_fov)
{
    const float along = fast_dot(v, axis);
    const float3 off = v - along * axis;
    return along > 0.0f && fast_dot(off, off) <= tan2_fov * along * along;
}

/* Side of an oriented surface element facing the incoming direction d. */
CLSIM_INLINE float3 incident_side(float3 n, float3 d)
{
    return fast_dot(n, d) > 0.0f ? -n : n;
}

/* Bi-Lambertian BSDF value (1/sr) for incident-side normal m towards w. */
CLSIM_INLINE float bsdf(float3 m, float3 w, float R, float T)
{
    const float c = fast_dot(m, w);
    return c > 0.0f ? R * c / CLSIM_PI : -T * c / CLSIM_PI;
}

#endif
