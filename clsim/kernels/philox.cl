/* Philox4x32-10 counter-based RNG (Salmon et al. 2011, doi:10.1145/2063384.2063405).
 * Twin of clsim/rng.py: block `ctr` of photon `pid` under key (seed_lo, seed_hi)
 * is philox(counter = (ctr, pid_lo, pid_hi, 0)); uniforms ((x >> 9) + 0.5) 2^-23. */
#ifndef CLSIM_PHILOX_CL
#define CLSIM_PHILOX_CL

#include "common.cl"

/* One round on scalar words (vector lane shuffles cost more than the round
 * on PoCL); a 64-bit product gives both halves of each multiply. */
#define PHILOX_ROUND(k0, k1)                                                \
    {                                                                       \
        const ulong p0 = (ulong)0xD2511F53u * c0, p1 = (ulong)0xCD9E8D57u * c2; \
        const uint n0 = (uint)(p1 >> 32) ^ c1 ^ (k0);                       \
        const uint n2 = (uint)(p0 >> 32) ^ c3 ^ (k1);                       \
        c1 = (uint)p1;                                                      \
        c3 = (uint)p0;                                                      \
        c0 = n0;                                                            \
        c2 = n2;                                                            \
    }

CLSIM_INLINE uint4 philox4x32_10(uint4 c, uint2 k)
{
    uint c0 = c.x, c1 = c.y, c2 = c.z, c3 = c.w;
    const uint a = k.x, b = k.y;
    PHILOX_ROUND(a, b)
    PHILOX_ROUND(a + 0x9E3779B9u, b + 0xBB67AE85u)
    PHILOX_ROUND(a + 2u * 0x9E3779B9u, b + 2u * 0xBB67AE85u)
    PHILOX_ROUND(a + 3u * 0x9E3779B9u, b + 3u * 0xBB67AE85u)
    PHILOX_ROUND(a + 4u * 0x9E3779B9u, b + 4u * 0xBB67AE85u)
    PHILOX_ROUND(a + 5u * 0x9E3779B9u, b + 5u * 0xBB67AE85u)
    PHILOX_ROUND(a + 6u * 0x9E3779B9u, b + 6u * 0xBB67AE85u)
    PHILOX_ROUND(a + 7u * 0x9E3779B9u, b + 7u * 0xBB67AE85u)
    PHILOX_ROUND(a + 8u * 0x9E3779B9u, b + 8u * 0xBB67AE85u)
    PHILOX_ROUND(a + 9u * 0x9E3779B9u, b + 9u * 0xBB67AE85u)
    return (uint4)(c0, c1, c2, c3);
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
#ifndef CLSIM_PROF_PHILOX
#define CLSIM_PROF_PHILOX 1
#endif
CLSIM_INLINE uint prof_hash(uint x)
{
    x ^= x >> 16;
    x *= 0x7FEB352Du;
    x ^= x >> 15;
    x *= 0x846CA68Bu;
    return x ^ (x >> 16);
}

CLSIM_INLINE float4 rng_next(rng_t *r)
{
#if CLSIM_PROF_PHILOX
    const uint4 x = philox4x32_10((uint4)(r->ctr, r->pid_lo, r->pid_hi, 0u), r->key);
#else /* profiling only (transport.cl): a cheap hash instead of Philox */
    const uint h = prof_hash(r->ctr * 0x9E3779B9u ^ r->pid_lo ^ r->key.x);
    const uint4 x = (uint4)(h, prof_hash(h + 1u), prof_hash(h + 2u), prof_hash(h + 3u));
#endif
    r->ctr += 1u;
    /* 23 bits + 1/2 fit float32's 24-bit significand: exact, and never 0 or 1 */
    const float q = 1.1920928955078125e-07f; /* 2^-23 */
    return (float4)(((float)(x.x >> 9) + 0.5f) * q, ((float)(x.y >> 9) + 0.5f) * q,
                    ((float)(x.z >> 9) + 0.5f) * q, ((float)(x.w >> 9) + 0.5f) * q);
}

#endif
