/* Shared by every clsim kernel header. */
#ifndef CLSIM_COMMON_CL
#define CLSIM_COMMON_CL

/* PoCL (the CPU device of the tests) does not inline small helpers on its
 * own; a call per voxel step or per Philox round costs more than the work.
 * Forcing inlining makes the transport kernel about 2x faster there, and
 * GPU compilers inline anyway. */
#if defined(__clang__) || defined(__GNUC__)
#define CLSIM_INLINE inline __attribute__((always_inline))
#else
#define CLSIM_INLINE inline
#endif

/* PoCL 3.0 also calls fmin, fmax, fabs and dot out of line.  These twins
 * compile to single instructions everywhere; they assume no NaN operands,
 * which the kernels never produce (infinities are fine). */
CLSIM_INLINE float fast_min(float a, float b) { return a < b ? a : b; }
CLSIM_INLINE float fast_max(float a, float b) { return a > b ? a : b; }
CLSIM_INLINE float fast_abs(float a) { return as_float(as_uint(a) & 0x7FFFFFFFu); }
CLSIM_INLINE float fast_dot(float3 a, float3 b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
/* PoCL's sqrt is a call too; clang's builtin is one instruction.  The host
 * defines CLSIM_CLANG_BUILTINS for PoCL only (other compilers: plain sqrt). */
#ifdef CLSIM_CLANG_BUILTINS
#define fast_sqrt(x) __builtin_sqrtf(x)
#else
#define fast_sqrt(x) sqrt(x)
#endif
/* for vectors of length near 1 (no overflow guard) */
CLSIM_INLINE float3 fast_normalize3(float3 a) { return a * (1.0f / fast_sqrt(fast_dot(a, a))); }
CLSIM_INLINE int3 clamp_index(int3 v, int nx, int ny, int nz)
{
    return (int3)(v.x < 0 ? 0 : (v.x >= nx ? nx - 1 : v.x), v.y < 0 ? 0 : (v.y >= ny ? ny - 1 : v.y),
                  v.z < 0 ? 0 : (v.z >= nz ? nz - 1 : v.z));
}

/* -log(u) for u in (0, 1], the exponential deviate of a uniform.  u = m 2^e
 * with m in [sqrt(1/2), sqrt(2)); log m = 2 atanh(s), s = (m - 1) / (m + 1),
 * |s| < 0.172, by its series to s^11 (truncation below 2e-10 relative). */
CLSIM_INLINE float neg_log_unit(float u)
{
    const uint bits = as_uint(u);
    int e = (int)(bits >> 23) - 127;
    float m = as_float((bits & 0x007FFFFFu) | 0x3F800000u);
    if (m > 1.41421356f) {
        m *= 0.5f;
        e += 1;
    }
    const float s = (m - 1.0f) / (m + 1.0f), s2 = s * s;
    const float lm = 2.0f * s * (1.0f + s2 * (1.0f / 3.0f + s2 * (1.0f / 5.0f + s2 * (1.0f / 7.0f
                     + s2 * (1.0f / 9.0f + s2 * (1.0f / 11.0f))))));
    return -((float)e * 0.69314718055994531f + lm);
}

#endif
