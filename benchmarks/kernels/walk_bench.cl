/* Micro-benchmark of the scene walk alone (benchmarks/bench_walk_profile.py): each work
 * item walks one straight ray from a random point above the grid, downwards, to the
 * grid's end and sums its optical depth, as a shadow ray of next-event estimation does
 * (no cut-off).  The build options are the transport kernel's. */
#include "transport.cl"

__kernel void walk_bench(__global const params_t *P, __global const int *index, __global const int4 *boxes,
                         __global const float2 *pool, __global float *od_out, __global ulong *steps_out,
                         uint seed)
{
    const uint gid = get_global_id(0);
    rng_t rng;
    rng_init(&rng, (uint2)(seed, 0x5EEDu), gid);
    const float4 b = rng_next(&rng);
    const float h = P->h;
    const float3 o = (float3)(b.x * (float)P->shape[0] * h, b.y * (float)P->shape[1] * h,
                              (float)P->shape[2] * h);
    /* cos(zenith) uniform in [0.5, 1], azimuth uniform */
    const float cz = 0.5f + 0.5f * b.z;
    const float sz = fast_sqrt(1.0f - cz * cz);
    float ca;
    const float sa = sincos_turns(b.w, &ca);
    const float3 d = (float3)(sz * ca, sz * sa, -cz);
    walker_t w;
    float od = 0.0f;
    uint2 steps = (uint2)(0u, 0u);
    if (walker_init(&w, o, d, 0.0f, CLSIM_FAR, P)) {
        float ta, tb;
        float2 e;
        while (walker_next(&w, P, index, boxes, pool, &ta, &tb, &e, &steps))
            od += (e.x * 0.5f + e.y) * (tb - ta);
    }
    od_out[gid] = od;
    steps_out[2 * gid] = steps.x;
    steps_out[2 * gid + 1] = steps.y;
}
