/* Shared by every clsim kernel header. */
#ifndef CLSIM_COMMON_CL
#define CLSIM_COMMON_CL

/* PoCL (the CPU device of the tests) does not inline small helpers on its
 * own; a call per voxel step or per Philox round costs more than the work.
 * Forcing inlining makes the transport kernel about 2x faster there, and
 * GPU compilers inline anyway. */
#define CLSIM_INLINE inline __attribute__((always_inline))

/* PoCL 3.0 also calls fmin, fmax, fabs and dot out of line.  These twins
 * compile to single instructions everywhere; they assume no NaN operands,
 * which the kernels never produce (infinities are fine). */
CLSIM_INLINE float fast_min(float a, float b) { return a < b ? a : b; }
CLSIM_INLINE float fast_max(float a, float b) { return a > b ? a : b; }
CLSIM_INLINE float fast_abs(float a) { return as_float(as_uint(a) & 0x7FFFFFFFu); }
CLSIM_INLINE float fast_dot(float3 a, float3 b) { return a.x * b.x + a.y * b.y + a.z * b.z; }

#endif
