/* Directions, leaf normals, bi-Lambertian scattering.  Twin: clsim/transport_ref.py. */
#ifndef CLSIM_GEOMETRY_CL
#define CLSIM_GEOMETRY_CL

#define CLSIM_PI 3.14159265358979323846f

/* Orthonormal basis around unit n (Duff et al. 2017, JCGT 6(1), branchless). */
inline void onb(float3 n, float3 *b1, float3 *b2)
{
    const float s = copysign(1.0f, n.z);
    const float a = -1.0f / (s + n.z);
    const float b = n.x * n.y * a;
    *b1 = (float3)(1.0f + s * n.x * n.x * a, s * b, -s * n.x);
    *b2 = (float3)(b, s + n.y * n.y * a, -n.y);
}

/* Cosine-weighted direction about unit m. */
inline float3 cosine_dir(float3 m, float u1, float u2)
{
    float3 b1, b2;
    onb(m, &b1, &b2);
    const float r = sqrt(u1), ph = 2.0f * CLSIM_PI * u2;
    return normalize(r * cos(ph) * b1 + r * sin(ph) * b2 + sqrt(fmax(0.0f, 1.0f - u1)) * m);
}

/* Leaf normal (upper hemisphere): zenith from the inverse-CDF table, azimuth
 * uniform (u_az) or pointing away from the crown centre at x. */
inline float3 leaf_normal(__global const float *ppf, float u_t, float u_az, float3 x,
                          float cx, float cy, int outward)
{
    const float s = u_t * (float)(NTAB - 1);
    const int i = min((int)s, NTAB - 2);
    const float f = s - (float)i;
    const float t = ppf[i] * (1.0f - f) + ppf[i + 1] * f;
    const float ph = outward ? atan2(x.y - cy, x.x - cx) : 2.0f * CLSIM_PI * u_az;
    const float st = sin(t);
    return (float3)(st * cos(ph), st * sin(ph), cos(t));
}

/* Side of an oriented surface element facing the incoming direction d. */
inline float3 incident_side(float3 n, float3 d)
{
    return dot(n, d) > 0.0f ? -n : n;
}

/* Bi-Lambertian BSDF value (1/sr) for incident-side normal m towards w. */
inline float bsdf(float3 m, float3 w, float R, float T)
{
    const float c = dot(m, w);
    return c > 0.0f ? R * c / CLSIM_PI : -T * c / CLSIM_PI;
}

#endif
