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

/* Portability: the kernels never create an infinity or a NaN, so they are
 * correct under -cl-fast-relaxed-math (which lets a compiler assume both
 * away) on every conformant implementation.  "No boundary" and "no hit" are
 * the finite distance CLSIM_FAR, and a direction component below
 * CLSIM_TINY counts as zero, so reciprocals stay far below CLSIM_FAR. */
#define CLSIM_FAR 1.0e30f
#define CLSIM_TINY 1.0e-20f

/* PoCL 3.0 also calls fmin, fmax, fabs and dot out of line.  These twins
 * compile to single instructions everywhere; they assume no NaN operands,
 * which the kernels never produce. */
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
/* 1/x, or CLSIM_FAR for |x| < CLSIM_TINY (an axis the ray does not move along) */
CLSIM_INLINE float safe_inv(float x) { return fast_abs(x) >= CLSIM_TINY ? 1.0f / x : CLSIM_FAR; }
CLSIM_INLINE int sign_of(float x) { return x >= CLSIM_TINY ? 1 : (x <= -CLSIM_TINY ? -1 : 0); }

/* 64-bit unsigned atomic add.  With cl_khr_int64_base_atomics (the host
 * defines CLSIM_ATOM64) one atom_add; otherwise two 32-bit atomic_adds with
 * the carry of the low word counted once, so the sum stays exact. */
#ifdef CLSIM_ATOM64
#pragma OPENCL EXTENSION cl_khr_int64_base_atomics : enable
CLSIM_INLINE void add_u64(__global ulong *p, ulong v) { atom_add(p, v); }
#else
CLSIM_INLINE void add_u64(__global ulong *p, ulong v)
{
    volatile __global uint *w = (volatile __global uint *)p;
#ifdef __ENDIAN_LITTLE__
    volatile __global uint *lo = w, *hi = w + 1;
#else
    volatile __global uint *lo = w + 1, *hi = w;
#endif
    const uint vlo = (uint)v, vhi = (uint)(v >> 32);
    const uint old = atomic_add(lo, vlo);
    const uint carry = (uint)(old + vlo < old);
    if (vhi + carry)
        atomic_add(hi, vhi + carry);
}
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
