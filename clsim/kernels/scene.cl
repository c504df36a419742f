/* Sparse brick scene traversal (Amanatides & Woo 1987 DDA, two levels).
 * Coordinates are local metres (grid origin at 0).  Empty bricks are crossed
 * in one step; voxels with zero extinction are skipped. */
#ifndef CLSIM_SCENE_CL
#define CLSIM_SCENE_CL

#include "common.cl"

#define B3 (BRICK * BRICK * BRICK)

typedef struct {
    float3 o, d, inv; /* origin, unit direction, 1/direction (inf where 0) */
    float3 tm;        /* distance to the far plane of the current voxel per axis */
    float t, t_end;
    int3 v, step;
    int3 cb;          /* current brick cell */
    int slot;         /* its pool slot; WALK_LOOKUP: look it up before the next step */
    int fresh;        /* tm must be recomputed (start, or after a brick jump) */
} walker_t;

#define WALK_LOOKUP (-2)

CLSIM_INLINE float far_plane_t(int v, int step, float o, float inv, float cell)
{
    if (step == 0)
        return INFINITY;
    return ((float)(v + (step > 0)) * cell - o) * inv;
}

/* Clip [t_start, t_limit] to the grid box; 0 when the ray misses it. */
CLSIM_INLINE int walker_init(walker_t *w, float3 o, float3 d, float t_start, float t_limit,
                       __global const params_t *P)
{
    const float3 L = (float3)(P->shape[0], P->shape[1], P->shape[2]) * P->h;
    float t0 = t_start, t1 = t_limit;
    const float oo[3] = {o.x, o.y, o.z}, dd[3] = {d.x, d.y, d.z}, ll[3] = {L.x, L.y, L.z};
    for (int a = 0; a < 3; ++a) {
        if (dd[a] == 0.0f) {
            if (oo[a] < 0.0f || oo[a] > ll[a])
                return 0;
        } else {
            float ta = (0.0f - oo[a]) / dd[a], tb = (ll[a] - oo[a]) / dd[a];
            t0 = fast_max(t0, fast_min(ta, tb));
            t1 = fast_min(t1, fast_max(ta, tb));
        }
    }
    if (!(t0 < t1))
        return 0;
    w->o = o;
    w->d = d;
    w->inv = (float3)(d.x != 0.0f ? 1.0f / d.x : INFINITY, d.y != 0.0f ? 1.0f / d.y : INFINITY,
                      d.z != 0.0f ? 1.0f / d.z : INFINITY);
    w->t = t0;
    w->t_end = t1;
    const float3 p = (o + d * t0) / P->h;
    w->v = clamp(convert_int3_rtn(p), (int3)(0), (int3)(P->shape[0] - 1, P->shape[1] - 1, P->shape[2] - 1));
    w->step = (int3)(d.x > 0.0f ? 1 : (d.x < 0.0f ? -1 : 0), d.y > 0.0f ? 1 : (d.y < 0.0f ? -1 : 0),
                     d.z > 0.0f ? 1 : (d.z < 0.0f ? -1 : 0));
    w->slot = WALK_LOOKUP;
    w->fresh = 1;
    return 1;
}

CLSIM_INLINE int inside_grid(int3 v, __global const params_t *P)
{
    return v.x >= 0 && v.y >= 0 && v.z >= 0 && v.x < P->shape[0] && v.y < P->shape[1] &&
           v.z < P->shape[2];
}

/* v must be inside the grid (non-negative). */
CLSIM_INLINE int brick_slot(int3 v, __global const params_t *P, __global const int *index)
{
    const int3 b = v >> BRICK_SHIFT;
    return index[b.x + P->bshape[0] * (b.y + P->bshape[1] * b.z)];
}

CLSIM_INLINE float2 voxel_value(int3 v, int slot, __global const float2 *pool)
{
    const int3 l = v & (BRICK - 1);
    return pool[(size_t)slot * B3 + l.x + BRICK * (l.y + BRICK * l.z)];
}

/* Next voxel segment [*ta, *tb] with non-zero extinction; 0 at the end.
 * Inside an occupied brick a step is one DDA advance and one pool load; the
 * brick index is read (and the grid bounds checked) only when the walk
 * enters another brick.  Empty bricks are crossed in one step. */
CLSIM_INLINE int walker_next(walker_t *w, __global const params_t *P, __global const int *index,
                       __global const float2 *pool, float *ta, float *tb, float2 *val,
                       uint *steps)
{
    const float h = P->h;
    /* safety net: a ray enters at most (nx + ny + nz) / BRICK + 3 bricks */
    int budget = (P->shape[0] + P->shape[1] + P->shape[2]) / BRICK + 8;
    const int3 s = w->step;
    while (w->t < w->t_end) {
        if (w->slot == WALK_LOOKUP) {
            if (--budget < 0 || !inside_grid(w->v, P)) {
                w->t = w->t_end;
                return 0;
            }
            const int3 v = w->v;
            const int3 c = v >> BRICK_SHIFT;
            const int slot = index[c.x + P->bshape[0] * (c.y + P->bshape[1] * c.z)];
            if (slot < 0) {
                /* jump over the empty brick: enter the neighbour along the exit axis */
                *steps += 1u;
                const float cell = (float)BRICK * h;
                const float fx = far_plane_t(c.x, s.x, w->o.x, w->inv.x, cell);
                const float fy = far_plane_t(c.y, s.y, w->o.y, w->inv.y, cell);
                const float fz = far_plane_t(c.z, s.z, w->o.z, w->inv.z, cell);
                const int ax = (fx <= fy && fx <= fz) ? 0 : (fy <= fz ? 1 : 2);
                const float t_b = fast_min(fast_min(fx, fast_min(fy, fz)), w->t_end);
                w->t = fast_max(w->t, t_b);
                const float3 p = (w->o + w->d * t_b) / h;
                int3 nv = clamp(convert_int3_rtn(p), (int3)(0), (int3)(P->shape[0] - 1, P->shape[1] - 1, P->shape[2] - 1));
                /* float32 rounding of p must never move the walk backwards (it could
                 * bounce between two bricks forever): indices only move along the ray */
                nv = select(nv, max(nv, v), s > 0);
                nv = select(nv, min(nv, v), s < 0);
                nv = select(nv, v, s == 0);
                if (ax == 0) nv.x = (c.x + s.x) * BRICK + (s.x > 0 ? 0 : BRICK - 1);
                else if (ax == 1) nv.y = (c.y + s.y) * BRICK + (s.y > 0 ? 0 : BRICK - 1);
                else nv.z = (c.z + s.z) * BRICK + (s.z > 0 ? 0 : BRICK - 1);
                w->v = nv;
                w->fresh = 1;
                continue;
            }
            w->cb = c;
            w->slot = slot;
            if (w->fresh) {
                w->tm = (float3)(far_plane_t(v.x, s.x, w->o.x, w->inv.x, h),
                                 far_plane_t(v.y, s.y, w->o.y, w->inv.y, h),
                                 far_plane_t(v.z, s.z, w->o.z, w->inv.z, h));
                w->fresh = 0;
            }
        }
        *steps += 1u;
        const int3 v = w->v;
        const float2 e = voxel_value(v, w->slot, pool);
        const float3 tm = w->tm;
        const float t_a = w->t;
        int leave;
        float t_b;
        if (tm.x <= tm.y && tm.x <= tm.z) {
            t_b = tm.x;
            w->v.x += s.x;
            w->tm.x = far_plane_t(w->v.x, s.x, w->o.x, w->inv.x, h);
            leave = (w->v.x >> BRICK_SHIFT) != w->cb.x;
        } else if (tm.y <= tm.z) {
            t_b = tm.y;
            w->v.y += s.y;
            w->tm.y = far_plane_t(w->v.y, s.y, w->o.y, w->inv.y, h);
            leave = (w->v.y >> BRICK_SHIFT) != w->cb.y;
        } else {
            t_b = tm.z;
            w->v.z += s.z;
            w->tm.z = far_plane_t(w->v.z, s.z, w->o.z, w->inv.z, h);
            leave = (w->v.z >> BRICK_SHIFT) != w->cb.z;
        }
        if (leave)
            w->slot = WALK_LOOKUP;
        t_b = fast_min(t_b, w->t_end);
        w->t = fast_max(t_a, t_b);
        if (e.x + e.y > 0.0f && t_b > t_a) {
            *ta = t_a;
            *tb = t_b;
            *val = e;
            return 1;
        }
    }
    return 0;
}

/* Extinction at a point (paper mode); sets *skip_t to the exit of an empty brick. */
CLSIM_INLINE float2 point_value(float3 x, __global const params_t *P, __global const int *index,
                          __global const float2 *pool, float3 o, float3 d, float *skip_t)
{
    const int3 v = convert_int3_rtn(x / P->h);
    *skip_t = -1.0f;
    if (!inside_grid(v, P))
        return (float2)(0.0f);
    const int slot = brick_slot(v, P, index);
    if (slot < 0) {
        const int3 c = v >> BRICK_SHIFT;
        const float cell = (float)BRICK * P->h;
        const float3 inv = 1.0f / d;
        const int3 s = (int3)(d.x > 0.0f ? 1 : (d.x < 0.0f ? -1 : 0), d.y > 0.0f ? 1 : (d.y < 0.0f ? -1 : 0),
                              d.z > 0.0f ? 1 : (d.z < 0.0f ? -1 : 0));
        *skip_t = fast_min(far_plane_t(c.x, s.x, o.x, inv.x, cell),
                       fast_min(far_plane_t(c.y, s.y, o.y, inv.y, cell), far_plane_t(c.z, s.z, o.z, inv.z, cell)));
        return (float2)(0.0f);
    }
    return voxel_value(v, slot, pool);
}

#endif
