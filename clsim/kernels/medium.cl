/* The medium's extinction and what both transports read of the scene: the scene buffers
 * (scene_t), G(d) of the leaves and the wood's directional extinction (docs/method.md).
 * Shared by transport.cl (Monte Carlo) and first_order.cl (the deterministic first order). */
#ifndef CLSIM_MEDIUM_CL
#define CLSIM_MEDIUM_CL

#include "common.cl"
#include "params.cl"

/* Profiling switch (benchmarks/bench_walk_profile.py; transport.cl): 0: G(d) is 1/2 without the table. */
#ifndef CLSIM_PROF_G
#define CLSIM_PROF_G 1
#endif

typedef struct {
    __global const params_t *P;
    __global const int *index;
    __global const int4 *boxes;  /* uniform box per pool slot or -1, and its value (scene.cl walker_next) */
    __global const float2 *pool;
    __global const float *ppf;
    __global const float *gtab;
    __global const float4 *wdir; /* (axis, beta) per pool row; read only when WOOD_DIR */
} scene_t;

/* Directional wood (docs/method.md): the wood extinction along unit d of the
 * voxel at pool row `row`, split into its cylinder part (.x, sw beta 4 sin(psi)/pi,
 * psi the angle between d and the bark axis) and its random-facet part
 * (.y, sw (1 - beta)); sw is the direction-averaged extinction the pool holds.
 * Without directions (WOOD_DIR 0, a separate build) the parts are (0, sw)
 * and the code folds to the direction-free kernel bit for bit.
 * Solid wood (q.w = -1 - cap share < 0): opaque from every direction, all of
 * it on the surface model (.x = sw; wood_normal picks side or end cap). */
#ifndef WOOD_DIR
#define WOOD_DIR 0
#endif
#define WOOD_4_OVER_PI 1.27323954f

CLSIM_INLINE float2 wood_parts(const scene_t *S, size_t row, float sw, float3 d)
{
#if !WOOD_DIR
    return (float2)(0.0f, sw);
#else
    const float4 q = S->wdir[row];
    if (q.w < 0.0f)
        return (float2)(sw, 0.0f);
    const float c = fast_dot((float3)(q.x, q.y, q.z), d);
    const float sin_psi = fast_sqrt(fast_max(0.0f, 1.0f - c * c));
    return (float2)(sw * q.w * WOOD_4_OVER_PI * sin_psi, sw * (1.0f - q.w));
#endif
}

/* The wood extinction along d (sum of the parts). */
CLSIM_INLINE float wood_sigma(const scene_t *S, size_t row, float sw, float3 d)
{
#if !WOOD_DIR
    return sw;
#else
    const float2 p = wood_parts(S, row, sw, d);
    return p.x + p.y;
#endif
}

/* Largest wood extinction over directions (across the axis): the tracker's majorant. */
CLSIM_INLINE float wood_majorant(const scene_t *S, size_t row, float sw)
{
#if !WOOD_DIR
    return sw;
#else
    const float beta = S->wdir[row].w;
    return beta < 0.0f ? sw : sw * beta * WOOD_4_OVER_PI + sw * (1.0f - beta);
#endif
}

/* G(|cos theta|) by linear interpolation in a table of NG values on [0, 1]; spherical leaf
 * angles (P->leaf_avg) G = 1/2 without the table (which holds 0.5f there at every entry). */
CLSIM_INLINE float g_of(const scene_t *S, float mu)
{
#if !CLSIM_PROF_G
    return 0.5f;
#endif
    if (S->P->leaf_avg)
        return 0.5f;
    __global const float *gtab = S->gtab;
    const float s = fast_min(fast_abs(mu), 1.0f) * (float)(NG - 1);
    const int i = min((int)s, NG - 2);
    const float f = s - (float)i;
    return gtab[i] * (1.0f - f) + gtab[i + 1] * f;
}

/* Distance from o along d to the ground plane (CLSIM_FAR when the ray does not go down to it). */
CLSIM_INLINE float ground_t(float3 o, float3 d, __global const params_t *P)
{
    if (!P->has_ground || !(d.z <= -CLSIM_TINY))
        return CLSIM_FAR;
    return fast_max(0.0f, (P->ground_z - o.z) / d.z);
}

#endif
