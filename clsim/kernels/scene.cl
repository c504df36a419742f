/* Sparse brick scene traversal (Amanatides & Woo 1987 DDA, two levels).
 * Coordinates are local metres (grid origin at 0).  Empty bricks are crossed
 * in one step; voxels with zero extinction are skipped. */
#ifndef CLSIM_SCENE_CL
#define CLSIM_SCENE_CL

#include "common.cl"

#define B3 (BRICK * BRICK * BRICK)

#ifndef CLSIM_UNIFORM
#define CLSIM_UNIFORM 1
#endif
/* Profiling only (benchmarks/bench_walk_profile.py): 0 replaces a voxel step's pool load
 * by the value (1, 0). */
#ifndef CLSIM_PROF_POOL
#define CLSIM_PROF_POOL 1
#endif

/* Two DDAs share the ray: one over brick cells (far brick planes bt*), which
 * crosses empty and uniform bricks in one step each, and one over the voxels
 * of a brick that holds different values (far voxel planes tm*), entered with
 * the brick's pool pointer and the voxel's offset in it, so that a voxel step
 * is one compare, one add of a constant offset and one load.
 * Scalar fields, not float3/int3: a step updates one axis, and lane inserts
 * and extracts on vectors cost more than the arithmetic on PoCL. */
typedef struct {
    float ox, oy, oz;     /* origin */
    float dx, dy, dz;     /* unit direction */
    float ix, iy, iz;     /* 1/direction (CLSIM_FAR where 0) */
    float h, ih;          /* voxel size and its reciprocal */
    float tmx, tmy, tmz;  /* far plane of the current voxel per axis (in a voxel brick) */
    float btx, bty, btz;  /* far plane of the current brick per axis */
    float t, t_end;
    int vx, vy, vz;       /* current voxel (in a voxel brick; at a brick entry when vok) */
    int sx, sy, sz;       /* step per axis: -1, 0, 1 */
    int cbx, cby, cbz;    /* current brick cell */
    int nbx, nby, nbz;    /* bricks per axis */
    int nx, ny, nz;       /* voxels per axis */
    int inside;           /* 1: walking the voxels of brick `slot`; 0: at a brick's entry */
    int vok;              /* at a brick's entry: (vx, vy, vz) is the entry voxel */
    int eaxis;            /* at a brick's entry without vok: the axis crossed into it */
    int slot;             /* pool slot of the voxel brick */
    int lrow;             /* the voxel's row in it (0 .. B3 - 1) */
    int dlx, dly, dlz;    /* row offset of one step per axis: sx, BRICK sy, BRICK^2 sz */
    size_t row;           /* pool row of the segment walker_next returned last */
    int useg;             /* that segment crossed a uniform brick: its voxels were counted */
    int ubx, uby, ubz;    /* to the brick's exit voxel ue (local: 0..BRICK-1) from brick */
    int uex, uey, uez;    /* origin ub (voxels); walker_stop takes back what lies beyond */
} walker_t;

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
    w->ox = o.x;
    w->oy = o.y;
    w->oz = o.z;
    w->dx = d.x;
    w->dy = d.y;
    w->dz = d.z;
    w->ix = ix;
    w->iy = iy;
    w->iz = iz;
    w->h = h;
    w->ih = 1.0f / h;
    w->t = t0;
    w->t_end = t1;
    w->nx = P->shape[0];
    w->ny = P->shape[1];
    w->nz = P->shape[2];
    w->nbx = P->bshape[0];
    w->nby = P->bshape[1];
    w->nbz = P->bshape[2];
    const int3 v = clamp_index(convert_int3((o + d * t0) * w->ih), w->nx, w->ny, w->nz); /* as local_voxel */
    w->vx = v.x;
    w->vy = v.y;
    w->vz = v.z;
    w->sx = sign_of(d.x);
    w->sy = sign_of(d.y);
    w->sz = sign_of(d.z);
    w->dlx = w->sx;
    w->dly = BRICK * w->sy;
    w->dlz = BRICK * BRICK * w->sz;
    w->cbx = v.x >> BRICK_SHIFT;
    w->cby = v.y >> BRICK_SHIFT;
    w->cbz = v.z >> BRICK_SHIFT;
    const float cell = (float)BRICK * h;
    w->btx = far_plane_t(w->cbx, w->sx, o.x, ix, cell);
    w->bty = far_plane_t(w->cby, w->sy, o.y, iy, cell);
    w->btz = far_plane_t(w->cbz, w->sz, o.z, iz, cell);
    w->inside = 0;
    w->vok = 1;
    w->eaxis = -1;
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

/* The point at distance t. */
CLSIM_INLINE float3 walker_point(const walker_t *w, float t)
{
    return (float3)(w->ox + w->dx * t, w->oy + w->dy * t, w->oz + w->dz * t);
}

/* Local voxel (0..BRICK-1 per axis) of brick origin `base` holding the point
 * at distance t: the grid voxel of the point, clamped to the grid and to the
 * brick (a point on the brick's far plane belongs to its last voxel). */
CLSIM_INLINE int3 local_voxel(const walker_t *w, float t, int3 base)
{
    /* truncation, not floor: the two differ only below 0, which the clamp maps to 0 alike */
    const int3 g = clamp_index(convert_int3(walker_point(w, t) * w->ih), w->nx, w->ny, w->nz);
    return clamp(g - base, 0, BRICK - 1);
}

/* The walk's voxel at the entry of the current brick, local to it: the voxel
 * the voxel DDA stepped into, else the voxel of the entry point clamped to the
 * brick, with the first layer of voxels along the axis crossed into it. */
CLSIM_INLINE int3 entry_voxel(const walker_t *w, int3 base)
{
    if (w->vok)
        return clamp((int3)(w->vx, w->vy, w->vz) - base, 0, BRICK - 1);
    int3 l = local_voxel(w, w->t, base);
    const int m = BRICK - 1;
    if (w->eaxis == 0)
        l.x = w->sx > 0 ? 0 : m;
    else if (w->eaxis == 1)
        l.y = w->sy > 0 ? 0 : m;
    else if (w->eaxis == 2)
        l.z = w->sz > 0 ? 0 : m;
    return l;
}

/* Voxels crossed along the walk between local voxels a and b of one brick
 * (a straight line in a grid: the voxel planes crossed per axis; signed by
 * the step so that rounding never makes a negative count). */
CLSIM_INLINE uint voxels_between(int3 a, int3 b, int sx, int sy, int sz)
{
    return (uint)(max(0, sx * (b.x - a.x)) + max(0, sy * (b.y - a.y)) + max(0, sz * (b.z - a.z)));
}

/* Step the brick DDA across the nearest far brick plane (capped at t_end). */
CLSIM_INLINE void walker_next_brick(walker_t *w)
{
    const float cell = (float)BRICK * w->h;
    float tb;
    if (w->btx <= w->bty && w->btx <= w->btz) {
        tb = w->btx;
        w->cbx += w->sx;
        w->btx = far_plane_t(w->cbx, w->sx, w->ox, w->ix, cell);
        w->eaxis = 0;
    } else if (w->bty <= w->btz) {
        tb = w->bty;
        w->cby += w->sy;
        w->bty = far_plane_t(w->cby, w->sy, w->oy, w->iy, cell);
        w->eaxis = 1;
    } else {
        tb = w->btz;
        w->cbz += w->sz;
        w->btz = far_plane_t(w->cbz, w->sz, w->oz, w->iz, cell);
        w->eaxis = 2;
    }
    w->t = fast_max(w->t, fast_min(tb, w->t_end));
    w->vok = 0;
}

/* Clip [*t0, *t1] to the slab of local voxels lo..hi (inclusive) of one axis
 * of brick origin `base` (voxels); an axis the ray does not move along keeps
 * the range when its voxel li is inside the slab and empties it otherwise.
 * [*t0, *t1] is already inside the brick. */
CLSIM_INLINE void clip_box_axis(int s, int li, int lo, int hi, int base, float o, float inv, float h,
                                float *t0, float *t1)
{
    if (lo == 0 && hi == BRICK - 1)
        return; /* the box spans the brick along this axis: the brick's own planes clip */
    if (s == 0) {
        if (li < lo || li > hi)
            *t1 = *t0;
        return;
    }
    const float pa = ((float)(base + lo) * h - o) * inv, pb = ((float)(base + hi + 1) * h - o) * inv;
    *t0 = fast_max(*t0, fast_min(pa, pb));
    *t1 = fast_min(*t1, fast_max(pa, pb));
}

/* The walk stops at distance t_stop inside the segment walker_next returned
 * last (a collision, a cut-off transmittance): a uniform-brick segment
 * counted its voxels to the brick's exit, so the voxels beyond t_stop are
 * taken back and voxel_steps counts the voxels reached, as the
 * voxel-by-voxel walk does (it counts the voxel where it stops). */
CLSIM_INLINE void walker_stop(walker_t *w, float t_stop, uint2 *steps)
{
    if (!w->useg)
        return;
    const int3 base = (int3)(w->ubx, w->uby, w->ubz);
    const int3 ls = local_voxel(w, t_stop, base);
    steps->x -= voxels_between(ls, (int3)(w->uex, w->uey, w->uez), w->sx, w->sy, w->sz);
    w->useg = 0;
}

/* Next voxel segment [*ta, *tb] with non-zero extinction; 0 at the end.
 * Inside a brick of different values a step is one DDA advance and one pool
 * load; the brick index is read only when the walk enters another brick.
 * Empty bricks are crossed in one step.  A uniform brick (boxes[slot].x >= 0:
 * its non-empty voxels fill one box with one value, .y and .z; uniform_records
 * in clsim/transport/bricks.py)
 * is crossed as one segment, the ray clipped to the box, with the values of
 * the box's first voxel (CLSIM_UNIFORM).
 * steps->x counts voxels as the voxel-by-voxel walk does (an empty brick 1,
 * an occupied brick each voxel visited; a uniform brick the voxels the ray
 * crosses in it, less those walker_stop takes back), steps->y the walk's
 * steps (a voxel, an empty brick, a uniform brick). */
CLSIM_INLINE int walker_next(walker_t *w, __global const params_t *P, __global const int *index,
                             __global const int4 *boxes, __global const float2 *pool, float *ta,
                             float *tb, float2 *val, uint2 *steps)
{
    const int sx = w->sx, sy = w->sy, sz = w->sz;
    const int m = BRICK - 1;
    w->useg = 0;
    for (;;) {
        if (!w->inside) {
            /* at a brick's entry */
            if (!(w->t < w->t_end) || (uint)w->cbx >= (uint)w->nbx || (uint)w->cby >= (uint)w->nby ||
                (uint)w->cbz >= (uint)w->nbz) {
                w->t = w->t_end;
                return 0;
            }
            const int slot = index[w->cbx + w->nbx * (w->cby + w->nby * w->cbz)];
            if (slot < 0) {
                *steps += (uint2)(1u, 1u);
                walker_next_brick(w);
                continue;
            }
            const int3 base = (int3)(w->cbx, w->cby, w->cbz) << BRICK_SHIFT;
            const int3 l = entry_voxel(w, base);
#if CLSIM_UNIFORM
            const int4 rec = boxes[slot];
            const int box = rec.x;
            if (box >= 0) {
                /* one segment through the brick's box, then on to the next brick; the
                 * voxels of the brick the walk crosses (to its exit or t_end) are counted */
                const int3 lo = (int3)(box, box >> BRICK_SHIFT, box >> (2 * BRICK_SHIFT)) & m;
                const int3 hi = (int3)(box >> (3 * BRICK_SHIFT), box >> (4 * BRICK_SHIFT),
                                       box >> (5 * BRICK_SHIFT)) & m;
                float t0 = w->t;
                walker_next_brick(w);
                float t1 = w->t;
                const int3 le = local_voxel(w, t1, base);
                *steps += (uint2)(1u + voxels_between(l, le, sx, sy, sz), 1u);
                /* the next brick's entry voxel: the exit voxel's neighbour across the exit axis */
                w->vx = base.x + le.x + (w->eaxis == 0 ? sx : 0);
                w->vy = base.y + le.y + (w->eaxis == 1 ? sy : 0);
                w->vz = base.z + le.z + (w->eaxis == 2 ? sz : 0);
                w->vok = 1;
                const float h = w->h;
                clip_box_axis(sx, l.x, lo.x, hi.x, base.x, w->ox, w->ix, h, &t0, &t1);
                clip_box_axis(sy, l.y, lo.y, hi.y, base.y, w->oy, w->iy, h, &t0, &t1);
                clip_box_axis(sz, l.z, lo.z, hi.z, base.z, w->oz, w->iz, h, &t0, &t1);
                if (t1 > t0) {
                    const size_t row = (size_t)slot * B3 + lo.x + BRICK * (lo.y + BRICK * lo.z);
                    *ta = t0;
                    *tb = t1;
                    *val = (float2)(as_float(rec.y), as_float(rec.z)); /* = pool[row] */
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
            /* enter the voxel DDA of the brick */
            w->vx = base.x + l.x;
            w->vy = base.y + l.y;
            w->vz = base.z + l.z;
            w->slot = slot;
            w->lrow = l.x + BRICK * (l.y + BRICK * l.z);
            const float h = w->h;
            w->tmx = far_plane_t(w->vx, sx, w->ox, w->ix, h);
            w->tmy = far_plane_t(w->vy, sy, w->oy, w->iy, h);
            w->tmz = far_plane_t(w->vz, sz, w->oz, w->iz, h);
            w->inside = 1;
        }
        /* one voxel of the brick: load, step the voxel DDA, and on leaving the
         * brick step the brick DDA along the same axis (the entry voxel is known) */
        __global const float2 *bp = pool + (size_t)w->slot * B3;
        const float h = w->h;
        for (;;) {
            if (!(w->t < w->t_end)) {
                w->inside = 0;
                return 0;
            }
            *steps += (uint2)(1u, 1u);
            const int lrow = w->lrow;
#if CLSIM_PROF_POOL
            const float2 e = bp[lrow];
#else
            const float2 e = (float2)(1.0f, 0.0f);
#endif
            const float t_a = w->t;
            float t_b;
            int leave;
            if (w->tmx <= w->tmy && w->tmx <= w->tmz) {
                t_b = w->tmx;
                w->vx += sx;
                w->lrow += w->dlx;
                w->tmx = far_plane_t(w->vx, sx, w->ox, w->ix, h);
                leave = (w->vx >> BRICK_SHIFT) != w->cbx;
                if (leave) {
                    w->cbx += sx;
                    w->btx = far_plane_t(w->cbx, sx, w->ox, w->ix, (float)BRICK * h);
                }
            } else if (w->tmy <= w->tmz) {
                t_b = w->tmy;
                w->vy += sy;
                w->lrow += w->dly;
                w->tmy = far_plane_t(w->vy, sy, w->oy, w->iy, h);
                leave = (w->vy >> BRICK_SHIFT) != w->cby;
                if (leave) {
                    w->cby += sy;
                    w->bty = far_plane_t(w->cby, sy, w->oy, w->iy, (float)BRICK * h);
                }
            } else {
                t_b = w->tmz;
                w->vz += sz;
                w->lrow += w->dlz;
                w->tmz = far_plane_t(w->vz, sz, w->oz, w->iz, h);
                leave = (w->vz >> BRICK_SHIFT) != w->cbz;
                if (leave) {
                    w->cbz += sz;
                    w->btz = far_plane_t(w->cbz, sz, w->oz, w->iz, (float)BRICK * h);
                }
            }
            t_b = fast_min(t_b, w->t_end);
            w->t = fast_max(t_a, t_b);
            if (leave) {
                w->inside = 0;
                w->vok = 1;
            }
            if (e.x + e.y > 0.0f && t_b > t_a) {
                *ta = t_a;
                *tb = t_b;
                *val = e;
                w->row = (size_t)w->slot * B3 + lrow;
                return 1;
            }
            if (leave)
                break;
        }
    }
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
