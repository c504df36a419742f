/* Sparse brick scene traversal (Amanatides & Woo 1987 DDA, two levels).
 * Coordinates are local metres (grid origin at 0).  Empty bricks are crossed
 * in one step; voxels with zero extinction are skipped. */
#ifndef CLSIM_SCENE_CL
#define CLSIM_SCENE_CL

#include "common.cl"

#define B3 (BRICK * BRICK * BRICK)

/* Scalar fields, not float3/int3: the step updates one axis, and lane
 * inserts and extracts on vectors cost more than the arithmetic on PoCL. */
typedef struct {
    float3 o, d;          /* origin, unit direction */
    float ix, iy, iz;     /* 1/direction (CLSIM_FAR where 0) */
    float tmx, tmy, tmz;  /* distance to the far plane of the current voxel per axis */
    float t, t_end;
    int vx, vy, vz;       /* current voxel */
    int sx, sy, sz;       /* step per axis: -1, 0, 1 */
    int cbx, cby, cbz;    /* current brick cell */
    int slot;             /* its pool slot; WALK_LOOKUP: look it up before the next step */
    int fresh;            /* tm must be recomputed (start, or after a brick jump) */
    size_t row;           /* pool row of the segment walker_next returned last */
    int useg;             /* that segment crossed a uniform brick: its voxels were counted */
    int ubx, uby, ubz;    /* to the brick's exit voxel ue (local: 0..BRICK-1) from brick */
    int uex, uey, uez;    /* origin ub (voxels); walker_stop takes back what lies beyond */
} walker_t;

#define WALK_LOOKUP (-2)

CLSIM_INLINE float far_plane_t(int v, int step, float o, float inv, float cell)
{
    if (step == 0)
        return CLSIM_FAR;
    return ((float)(v + (step > 0)) * cell - o) * inv;
}

/* Clip [t_start, t_limit] to the grid box; 0 when the ray misses it.
 * Three divisions (the reciprocals), the rest multiplications. */
CLSIM_INLINE int walker_init(walker_t *w, float3 o, float3 d, float t_start, float t_limit,
                             __global const params_t *P)
{
    const float h = P->h;
    const float ix = safe_inv(d.x), iy = safe_inv(d.y), iz = safe_inv(d.z);
    const float oo[3] = {o.x, o.y, o.z}, dd[3] = {d.x, d.y, d.z}, ii[3] = {ix, iy, iz};
    float t0 = t_start, t1 = t_limit;
    for (int a = 0; a < 3; ++a) {
        const float len = (float)P->shape[a] * h;
        if (fast_abs(dd[a]) < CLSIM_TINY) {
            if (oo[a] < 0.0f || oo[a] > len)
                return 0;
        } else {
            const float ta = -oo[a] * ii[a], tb = (len - oo[a]) * ii[a];
            t0 = fast_max(t0, fast_min(ta, tb));
            t1 = fast_min(t1, fast_max(ta, tb));
        }
    }
    if (!(t0 < t1))
        return 0;
    w->o = o;
    w->d = d;
    w->ix = ix;
    w->iy = iy;
    w->iz = iz;
    w->t = t0;
    w->t_end = t1;
    const float ih = 1.0f / h;
    const int3 v = clamp_index(convert_int3_rtn((o + d * t0) * ih), P->shape[0], P->shape[1], P->shape[2]);
    w->vx = v.x;
    w->vy = v.y;
    w->vz = v.z;
    w->sx = sign_of(d.x);
    w->sy = sign_of(d.y);
    w->sz = sign_of(d.z);
    w->slot = WALK_LOOKUP;
    w->fresh = 1;
    w->useg = 0;
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

/* Pool row of voxel v in brick slot `slot` (also the row of the wood directions). */
CLSIM_INLINE size_t voxel_row(int3 v, int slot)
{
    const int3 l = v & (BRICK - 1);
    return (size_t)slot * B3 + l.x + BRICK * (l.y + BRICK * l.z);
}

CLSIM_INLINE float2 voxel_value(int3 v, int slot, __global const float2 *pool)
{
    return pool[voxel_row(v, slot)];
}

/* Index along one axis after an empty-brick jump: the float32 position, but
 * never behind the current voxel (rounding could otherwise bounce the walk
 * between two bricks forever); on the exit axis, the neighbour's first voxel. */
CLSIM_INLINE int jump_index(int p, int v, int s, int c, int exit_axis)
{
    if (exit_axis)
        return (c + s) * BRICK + (s > 0 ? 0 : BRICK - 1);
    return s > 0 ? (p > v ? p : v) : (s < 0 ? (p < v ? p : v) : v);
}

#ifndef CLSIM_UNIFORM
#define CLSIM_UNIFORM 1
#endif

/* Leave brick cell c (the walk's voxel v lies in it): the walk moves to the
 * brick's exit (capped at t_end) and to the first voxel of the neighbour
 * along the exit axis. */
CLSIM_INLINE void walker_leave_brick(walker_t *w, int3 v, int3 c, __global const params_t *P)
{
    const float h = P->h;
    const float cell = (float)BRICK * h;
    const float fx = far_plane_t(c.x, w->sx, w->o.x, w->ix, cell);
    const float fy = far_plane_t(c.y, w->sy, w->o.y, w->iy, cell);
    const float fz = far_plane_t(c.z, w->sz, w->o.z, w->iz, cell);
    const int ax = (fx <= fy && fx <= fz) ? 0 : (fy <= fz ? 1 : 2);
    const float t_b = fast_min(fast_min(fx, fast_min(fy, fz)), w->t_end);
    w->t = fast_max(w->t, t_b);
    const int3 p = clamp_index(convert_int3_rtn((w->o + w->d * t_b) / h), P->shape[0], P->shape[1],
                               P->shape[2]);
    w->vx = jump_index(p.x, v.x, w->sx, c.x, ax == 0);
    w->vy = jump_index(p.y, v.y, w->sy, c.y, ax == 1);
    w->vz = jump_index(p.z, v.z, w->sz, c.z, ax == 2);
    w->fresh = 1;
}

/* Clip [*t0, *t1] to the slab of local voxels lo..hi (inclusive) of one axis
 * of brick origin `base` (voxels); an axis the ray does not move along keeps
 * the range when its voxel li is inside the slab and empties it otherwise. */
CLSIM_INLINE void clip_box_axis(int s, int li, int lo, int hi, int base, float o, float inv, float h,
                                float *t0, float *t1)
{
    if (s == 0) {
        if (li < lo || li > hi)
            *t1 = *t0;
        return;
    }
    const float pa = ((float)(base + lo) * h - o) * inv, pb = ((float)(base + hi + 1) * h - o) * inv;
    *t0 = fast_max(*t0, fast_min(pa, pb));
    *t1 = fast_min(*t1, fast_max(pa, pb));
}

/* Local voxel (0..BRICK-1 per axis) of brick origin `base` holding the point
 * at distance t: the grid voxel of the point, clamped to the grid and to the
 * brick (a point on the brick's far plane belongs to its last voxel). */
CLSIM_INLINE int3 local_voxel(const walker_t *w, float t, int3 base, __global const params_t *P)
{
    const int3 g = clamp_index(convert_int3_rtn((w->o + w->d * t) * (1.0f / P->h)), P->shape[0],
                               P->shape[1], P->shape[2]);
    return clamp(g - base, 0, BRICK - 1);
}

/* Voxels crossed along the walk between local voxels a and b of one brick
 * (a straight line in a grid: 1 + the voxel planes crossed per axis; signed
 * by the step so that rounding never makes a negative count). */
CLSIM_INLINE uint voxels_between(int3 a, int3 b, int sx, int sy, int sz)
{
    return (uint)(max(0, sx * (b.x - a.x)) + max(0, sy * (b.y - a.y)) + max(0, sz * (b.z - a.z)));
}

/* The walk stops at distance t_stop inside the segment walker_next returned
 * last (a collision, a cut-off transmittance): a uniform-brick segment
 * counted its voxels to the brick's exit, so the voxels beyond t_stop are
 * taken back and voxel_steps counts the voxels reached, as the
 * voxel-by-voxel walk does (it counts the voxel where it stops). */
CLSIM_INLINE void walker_stop(walker_t *w, float t_stop, __global const params_t *P, uint2 *steps)
{
    if (!w->useg)
        return;
    const int3 base = (int3)(w->ubx, w->uby, w->ubz);
    const int3 ls = local_voxel(w, t_stop, base, P);
    steps->x -= voxels_between(ls, (int3)(w->uex, w->uey, w->uez), w->sx, w->sy, w->sz);
    w->useg = 0;
}

/* Next voxel segment [*ta, *tb] with non-zero extinction; 0 at the end.
 * Inside an occupied brick a step is one DDA advance and one pool load; the
 * brick index is read (and the grid bounds checked) only when the walk
 * enters another brick.  Empty bricks are crossed in one step.  A uniform
 * brick (boxes[slot] >= 0: its non-empty voxels fill one box with one value;
 * clsim/transport/bricks.py) is crossed as one segment, the ray clipped to
 * the box, with the values of the box's first voxel (CLSIM_UNIFORM).
 * steps->x counts voxels as the voxel-by-voxel walk does (an empty brick 1,
 * an occupied brick each voxel visited; a uniform brick the voxels the ray
 * crosses in it, less those walker_stop takes back), steps->y the walk's
 * steps (a voxel, an empty brick, a uniform brick). */
CLSIM_INLINE int walker_next(walker_t *w, __global const params_t *P, __global const int *index,
                             __global const int *boxes, __global const float2 *pool, float *ta,
                             float *tb, float2 *val, uint2 *steps)
{
    const float h = P->h;
    /* safety net: a ray enters at most (nx + ny + nz) / BRICK + 3 bricks */
    int budget = (P->shape[0] + P->shape[1] + P->shape[2]) / BRICK + 8;
    const int sx = w->sx, sy = w->sy, sz = w->sz;
    w->useg = 0;
    while (w->t < w->t_end) {
        if (w->slot == WALK_LOOKUP) {
            const int3 v = (int3)(w->vx, w->vy, w->vz);
            if (--budget < 0 || !inside_grid(v, P)) {
                w->t = w->t_end;
                return 0;
            }
            const int3 c = v >> BRICK_SHIFT;
            const int slot = brick_slot(v, P, index);
            if (slot < 0) {
                /* jump over the empty brick: enter the neighbour along the exit axis */
                *steps += (uint2)(1u, 1u);
                walker_leave_brick(w, v, c, P);
                continue;
            }
#if CLSIM_UNIFORM
            const int box = boxes[slot];
            if (box >= 0) {
                /* one segment through the brick's box, then on to the next brick; the
                 * voxels of the brick the walk crosses (to its exit or t_end) are counted */
                const int m = BRICK - 1;
                const int3 lo = (int3)(box, box >> BRICK_SHIFT, box >> (2 * BRICK_SHIFT)) & m;
                const int3 hi = (int3)(box >> (3 * BRICK_SHIFT), box >> (4 * BRICK_SHIFT),
                                       box >> (5 * BRICK_SHIFT)) & m;
                const int3 base = c << BRICK_SHIFT;
                float t0 = w->t;
                walker_leave_brick(w, v, c, P);
                float t1 = w->t;
                const int3 le = local_voxel(w, t1, base, P);
                *steps += (uint2)(1u + voxels_between(v & m, le, sx, sy, sz), 1u);
                clip_box_axis(sx, v.x & m, lo.x, hi.x, base.x, w->o.x, w->ix, h, &t0, &t1);
                clip_box_axis(sy, v.y & m, lo.y, hi.y, base.y, w->o.y, w->iy, h, &t0, &t1);
                clip_box_axis(sz, v.z & m, lo.z, hi.z, base.z, w->o.z, w->iz, h, &t0, &t1);
                if (t1 > t0) {
                    const size_t row = voxel_row(base + lo, slot);
                    *ta = t0;
                    *tb = t1;
                    *val = pool[row];
                    w->row = row;
                    w->useg = 1;
                    w->ubx = base.x;
                    w->uby = base.y;
                    w->ubz = base.z;
                    w->uex = le.x;
                    w->uey = le.y;
                    w->uez = le.z;
                    return 1;
                }
                continue;
            }
#endif
            w->cbx = c.x;
            w->cby = c.y;
            w->cbz = c.z;
            w->slot = slot;
            if (w->fresh) {
                w->tmx = far_plane_t(v.x, sx, w->o.x, w->ix, h);
                w->tmy = far_plane_t(v.y, sy, w->o.y, w->iy, h);
                w->tmz = far_plane_t(v.z, sz, w->o.z, w->iz, h);
                w->fresh = 0;
            }
        }
        *steps += (uint2)(1u, 1u);
        const size_t row = voxel_row((int3)(w->vx, w->vy, w->vz), w->slot);
        const float2 e = pool[row];
        const float t_a = w->t;
        int leave;
        float t_b;
        if (w->tmx <= w->tmy && w->tmx <= w->tmz) {
            t_b = w->tmx;
            w->vx += sx;
            w->tmx = far_plane_t(w->vx, sx, w->o.x, w->ix, h);
            leave = (w->vx >> BRICK_SHIFT) != w->cbx;
        } else if (w->tmy <= w->tmz) {
            t_b = w->tmy;
            w->vy += sy;
            w->tmy = far_plane_t(w->vy, sy, w->o.y, w->iy, h);
            leave = (w->vy >> BRICK_SHIFT) != w->cby;
        } else {
            t_b = w->tmz;
            w->vz += sz;
            w->tmz = far_plane_t(w->vz, sz, w->o.z, w->iz, h);
            leave = (w->vz >> BRICK_SHIFT) != w->cbz;
        }
        if (leave)
            w->slot = WALK_LOOKUP;
        t_b = fast_min(t_b, w->t_end);
        w->t = fast_max(t_a, t_b);
        if (e.x + e.y > 0.0f && t_b > t_a) {
            *ta = t_a;
            *tb = t_b;
            *val = e;
            w->row = row;
            return 1;
        }
    }
    return 0;
}

/* Extinction at a point (paper mode) and its pool row *row; sets *skip_t to the
 * exit of an empty brick. */
CLSIM_INLINE float2 point_value(float3 x, __global const params_t *P, __global const int *index,
                          __global const float2 *pool, float3 o, float3 d, float *skip_t, size_t *row)
{
    const int3 v = convert_int3_rtn(x / P->h);
    *skip_t = -1.0f;
    *row = 0;
    if (!inside_grid(v, P))
        return (float2)(0.0f);
    const int slot = brick_slot(v, P, index);
    if (slot < 0) {
        const int3 c = v >> BRICK_SHIFT;
        const float cell = (float)BRICK * P->h;
        *skip_t = fast_min(far_plane_t(c.x, sign_of(d.x), o.x, safe_inv(d.x), cell),
                           fast_min(far_plane_t(c.y, sign_of(d.y), o.y, safe_inv(d.y), cell),
                                    far_plane_t(c.z, sign_of(d.z), o.z, safe_inv(d.z), cell)));
        return (float2)(0.0f);
    }
    *row = voxel_row(v, slot);
    return pool[*row];
}

#endif
