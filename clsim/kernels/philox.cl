/* Philox4x32-10 counter-based RNG (Salmon et al. 2011, doi:10.1145/2063384.2063405).
 * Twin of clsim/rng.py: block `ctr` of photon `pid` under key (seed_lo, seed_hi)
 * is philox(counter = (ctr, pid_lo, pid_hi, 0)); uniforms ((x >> 8) + 0.5) 2^-24. */
#ifndef CLSIM_PHILOX_CL
#define CLSIM_PHILOX_CL

#include "common.cl"

CLSIM_INLINE uint4 philox4x32_10(uint4 c, uint2 k)
{
    for (int r = 0; r < 10; ++r) {
        if (r) {
            k.x += 0x9E3779B9u;
            k.y += 0xBB67AE85u;
        }
        /* one 64-bit product gives both halves (PoCL calls mul_hi out of line) */
        const ulong p0 = (ulong)0xD2511F53u * c.x, p1 = (ulong)0xCD9E8D57u * c.z;
        const uint lo0 = (uint)p0, hi0 = (uint)(p0 >> 32);
        const uint lo1 = (uint)p1, hi1 = (uint)(p1 >> 32);
        c = (uint4)(hi1 ^ c.y ^ k.x, lo1, hi0 ^ c.w ^ k.y, lo0);
    }
    return c;
}

typedef struct {
    uint2 key;
    uint pid_lo, pid_hi;
    uint ctr;
} rng_t;

CLSIM_INLINE void rng_init(rng_t *r, uint2 key, ulong pid)
{
    r->key = key;
    r->pid_lo = (uint)(pid & 0xFFFFFFFFul);
    r->pid_hi = (uint)(pid >> 32);
    r->ctr = 0u;
}

/* Next block of four uniforms in (0, 1). */
CLSIM_INLINE float4 rng_next(rng_t *r)
{
    const uint4 x = philox4x32_10((uint4)(r->ctr, r->pid_lo, r->pid_hi, 0u), r->key);
    r->ctr += 1u;
    return (convert_float4(x >> 8u) + 0.5f) * 5.9604644775390625e-08f;
}

#endif
