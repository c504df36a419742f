/* Amanatides-Woo voxel traversal of laser beams with echo bookkeeping.
 *
 * Every beam starts at its origin with weight W0 = sum of its echo weights +
 * its tail weight.  Each echo at range r removes its weight (1/n for an n-echo
 * pulse) from the beam; after the last echo the tail weight (the part of the
 * pulse whose echoes were not recorded) carries on to max_range.
 *
 * Per voxel visited (one row of NF doubles, see tlsvox/trace.py FIELDS):
 *   0 count        beams entering
 *   1 n_w          weight entering
 *   2 leaf_w       leaf echo weight inside
 *   3 wood_w       wood echo weight inside
 *   4 other_w      other stopping echoes (ground, targets)
 *   5 path_w       integral of the beam weight along the path inside (free path)
 *   6 path_wg      g * path_w (g = G(theta) of the beam, leaf projection)
 *   7 leaf_zw      sum over leaf echoes of weight * (range - entry)
 *   8 leaf_zwg     g * leaf_zw
 *   9 wood_zw      sum over wood echoes of weight * (range - entry)
 *  10 chord_w      entering weight * potential chord (as if unobstructed)
 *  11 chord2_w     entering weight * chord^2
 *  12..14 dir_w    entering weight * direction
 *  15 leaf_w_g     leaf echo weight / g
 *
 * Sparse layout (-DSPARSE): full rows only for the voxels that hold an echo
 * ("rows", listed by the host), found through bricks of BRICK^3 voxels:
 * brick_start[b] .. brick_start[b + 1] are the rows of brick b, their
 * in-brick indices brick_key[] sorted ascending (binary search).  Every
 * brick keeps NB coarse sums of its own, per beam crossing it:
 *   0 count (beams crossing), 1 visits (voxels entered: the dense count summed),
 *   2 n_w (weight entering), 3 path_w (free path), 4 chord_w, 5 path_wg,
 *   6 visits_w (weight entering each voxel: the dense n_w summed)
 * (3, 4, 5 and 6: the sums of the dense fields over the voxels crossed)
 * which tell the occlusion of the voxels that hold no echo.
 *
 * Compile-time options:
 *   -DNF=16
 *   -DSPARSE        the sparse layout above (dense: one row per grid voxel)
 *   -DUSE_ATOMICS   one shared accumulator of 64-bit fixed-point integers
 *                   (value x fx_scale, chosen by the host so that no sum can
 *                   overflow), native atomic adds (GPU): integer sums are exact,
 *                   so the result does not depend on the order the threads
 *                   arrive in, and an atomic add is one instruction where a
 *                   float64 compare-and-swap loop serialises under contention;
 *                   otherwise each work-item owns a private float64 copy of the
 *                   grid (CPU: no atomics, deterministic sums) and strides over
 *                   the beams.
 */

#pragma OPENCL EXTENSION cl_khr_fp64 : enable
#ifdef USE_ATOMICS
#pragma OPENCL EXTENSION cl_khr_int64_base_atomics : enable
#endif

#ifndef NF
#define NF 16
#endif

#define BRICK_BITS 3
#define BRICK (1 << BRICK_BITS)
#define NB 7

#define KIND_LEAF 1
#define KIND_WOOD 2

#ifdef USE_ATOMICS
#define ADD(p, v) atom_add((__global long *)(p), (long)rint((v) * fx_scale))
#else
#define ADD(p, v) (*(p) += (v))
#endif

/* The beams, the grid and the layout: the kernel's inputs, handed on to the per-beam body
 * as they are (OpenCL C 1.2 has no struct of global pointers) */
#define TRACE_INPUTS \
    __global const double *origin, __global const double *direction, \
    __global const long *echo_start, __global const double *echo_range, \
    __global const double *echo_weight, __global const uchar *echo_kind, \
    __global const double *tail, __global const double *max_range, \
    __global const double *gval, \
    const double lx, const double ly, const double lz, const double h, \
    const int nx, const int ny, const int nz, const double fx_scale, \
    __global const int *brick_start, __global const ushort *brick_key, \
    __global const double *gout, const int gout_nt, const int gout_nc, \
    const double ccx, const double ccy, const int outward, __global const int *g_layer
#define TRACE_INPUT_NAMES \
    origin, direction, echo_start, echo_range, echo_weight, echo_kind, tail, max_range, gval, \
    lx, ly, lz, h, nx, ny, nz, fx_scale, brick_start, brick_key, gout, gout_nt, gout_nc, ccx, ccy, outward, \
    g_layer

inline void trace_one(const long b, TRACE_INPUTS,
                      __global double *acc, __global double *bacc, __global ulong *steps)
{
    const double ox = origin[3 * b], oy = origin[3 * b + 1], oz = origin[3 * b + 2];
    const double dx = direction[3 * b], dy = direction[3 * b + 1], dz = direction[3 * b + 2];
    const long e0 = echo_start[b], e1 = echo_start[b + 1];
    const double g = gval[b];
    /* max_range bounds the tail only: a beam stopped by its last echo is
     * followed to the end of that echo's voxel (its potential chord) */
    const double tmaxr = tail[b] > 0.0 ? max_range[b] : INFINITY;

    double w = tail[b];
    for (long e = e0; e < e1; ++e) w += echo_weight[e];
    if (w <= 0.0) return;

    /* slab intersection with the grid box */
    const double ux = lx + nx * h, uy = ly + ny * h, uz = lz + nz * h;
    double t0 = 0.0, t1 = tmaxr;
    double o[3] = {ox, oy, oz}, d[3] = {dx, dy, dz}, lo[3] = {lx, ly, lz}, hi[3] = {ux, uy, uz};
    for (int a = 0; a < 3; ++a) {
        if (d[a] != 0.0) {
            double inv = 1.0 / d[a];
            double ta = (lo[a] - o[a]) * inv, tb = (hi[a] - o[a]) * inv;
            if (ta > tb) { double tmp = ta; ta = tb; tb = tmp; }
            t0 = fmax(t0, ta);
            t1 = fmin(t1, tb);
        } else if (o[a] < lo[a] || o[a] >= hi[a]) {
            return;
        }
    }
    if (!(t0 < t1)) return;

    /* echoes before the grid take their weight away first */
    long e = e0;
    while (e < e1 && echo_range[e] < t0) { w -= echo_weight[e]; ++e; }
    if (w <= 1e-12) return;

    /* starting voxel, from the midpoint-safe entry position */
    const double n[3] = {nx, ny, nz};
    int ijk[3], step[3];
    double tnext[3], tdelta[3];
    for (int a = 0; a < 3; ++a) {
        double p = o[a] + d[a] * t0;
        int i = (int)floor((p - lo[a]) / h);
        if (i < 0) i = 0;
        if (i >= (int)n[a]) i = (int)n[a] - 1;
        /* a ray entering through the face at this axis' upper boundary */
        ijk[a] = i;
        if (d[a] > 0.0) {
            step[a] = 1;
            tnext[a] = (lo[a] + (i + 1) * h - o[a]) / d[a];
            tdelta[a] = h / d[a];
        } else if (d[a] < 0.0) {
            step[a] = -1;
            tnext[a] = (lo[a] + i * h - o[a]) / d[a];
            tdelta[a] = -h / d[a];
        } else {
            step[a] = 0;
            tnext[a] = INFINITY;
            tdelta[a] = INFINITY;
        }
    }

    /* outward-facing leaves: G depends on the beam's zenith and on the cosine c of the
     * angle between its horizontal direction and the voxel's outward direction from the
     * crown axis; gout is G on a (gout_nt zenith rows over [0, pi]) x (gout_nc c over
     * [-1, 1]) table, interpolated bilinearly (the per-beam g where c is undefined).
     * outward & 2: one such table per crown layer (leaf angles per layer), stacked, the
     * layer of each voxel z index in g_layer, each row ending in the layer's azimuth-
     * averaged G (read where c is undefined) */
    const double dh = sqrt(dx * dx + dy * dy);
    int t_i = 0;
    double t_f = 0.0;
    if (outward) {
        const double u = acos(clamp(dz, -1.0, 1.0)) / 3.14159265358979323846 * (gout_nt - 1);
        t_i = min((int)floor(u), gout_nt - 2);
        t_f = u - t_i;
    }

    double t = t0;
    ulong nsteps = 0;
#ifdef SPARSE
    const int bny = (ny + BRICK - 1) >> BRICK_BITS, bnz = (nz + BRICK - 1) >> BRICK_BITS;
    long brick = -1;
    double b_w = 0.0, b_path = 0.0, b_chord = 0.0, b_visits = 0.0, b_pathg = 0.0, b_visits_w = 0.0;
#endif
    while (t < t1 && w > 1e-12) {
        int a = 0;
        if (tnext[1] < tnext[a]) a = 1;
        if (tnext[2] < tnext[a]) a = 2;
        double tex = fmin(tnext[a], t1);
        double chord = tex - t;
        if (chord > 1e-12 * h) {
#ifdef SPARSE
            const long vb = ((long)(ijk[0] >> BRICK_BITS) * bny + (ijk[1] >> BRICK_BITS)) * bnz
                            + (ijk[2] >> BRICK_BITS);
            if (vb != brick) {
                if (brick >= 0) {
                    __global double *brow = bacc + brick * NB;
                    ADD(brow + 0, 1.0); ADD(brow + 1, b_visits); ADD(brow + 2, b_w); ADD(brow + 3, b_path);
                    ADD(brow + 4, b_chord); ADD(brow + 5, b_pathg); ADD(brow + 6, b_visits_w);
                }
                brick = vb;
                b_w = w; b_path = 0.0; b_chord = 0.0; b_visits = 0.0; b_pathg = 0.0; b_visits_w = 0.0;
            }
            /* this voxel's row, if it holds an echo: binary search in its brick */
            const ushort key = (ushort)((((ijk[0] & (BRICK - 1)) << BRICK_BITS | (ijk[1] & (BRICK - 1)))
                                         << BRICK_BITS) | (ijk[2] & (BRICK - 1)));
            int lo_r = brick_start[vb], hi_r = brick_start[vb + 1];
            while (lo_r < hi_r) {
                const int mid = (lo_r + hi_r) >> 1;
                if (brick_key[mid] < key) lo_r = mid + 1; else hi_r = mid;
            }
            __global double *row = (lo_r < brick_start[vb + 1] && brick_key[lo_r] == key)
                                   ? acc + (long)lo_r * NF : 0;
#else
            const long v = ((long)ijk[0] * ny + ijk[1]) * nz + ijk[2];
            __global double *row = acc + v * NF;
#endif
            double gv = g;
            if (outward) {
                double v = 0.0;
                int defined = 0;
                if (dh > 1e-9) {
                    const double rx = lx + (ijk[0] + 0.5) * h - ccx, ry = ly + (ijk[1] + 0.5) * h - ccy;
                    const double rr = sqrt(rx * rx + ry * ry);
                    if (rr > 1e-9) {
                        v = (clamp((rx * dx + ry * dy) / (rr * dh), -1.0, 1.0) + 1.0) * 0.5 * (gout_nc - 1);
                        defined = 1;
                    }
                }
                /* per layer (outward & 2): each row holds gout_nc columns in c and then the layer's
                 * azimuth-averaged G, read where c is undefined (the per-beam g of the one-table mode) */
                const int stride = (outward & 2) ? gout_nc + 1 : gout_nc;
                __global const double *r0 = gout + ((long)((outward & 2) ? g_layer[ijk[2]] : 0) * gout_nt + t_i)
                                                   * stride;
                __global const double *r1 = r0 + stride;
                if (defined) {
                    const int c_i = min((int)floor(v), gout_nc - 2);
                    const double c_f = v - c_i;
                    gv = fmax((1.0 - t_f) * ((1.0 - c_f) * r0[c_i] + c_f * r0[c_i + 1])
                              + t_f * ((1.0 - c_f) * r1[c_i] + c_f * r1[c_i + 1]), 1e-6);
                } else if (outward & 2) {
                    gv = fmax((1.0 - t_f) * r0[gout_nc] + t_f * r1[gout_nc], 1e-6);
                }
            }
            const double w_in = w;
            double tp = t, path = 0.0, lz_ = 0.0, wz_ = 0.0, lw = 0.0, ww = 0.0, ow = 0.0;
            /* echoes in [t, tex); the last segment also takes an echo at t1 */
            const double tcut = (tex >= t1) ? nextafter(t1, (double)INFINITY) : tex;
            while (e < e1 && echo_range[e] < tcut) {
                const double r = echo_range[e], we = echo_weight[e];
                path += w * (r - tp);
                tp = r;
                w -= we;
                const uchar k = echo_kind[e];
                if (k == KIND_LEAF) { lw += we; lz_ += we * (r - t); }
                else if (k == KIND_WOOD) { ww += we; wz_ += we * (r - t); }
                else { ow += we; }
                ++e;
            }
            if (w < 1e-12) w = 0.0;
            path += w * (tex - tp);
#ifdef SPARSE
            b_path += path;
            b_chord += w_in * chord;
            b_pathg += gv * path;
            b_visits += 1.0;
            b_visits_w += w_in;
            if (row) {
#else
            {
#endif
            ADD(row + 0, 1.0);
            ADD(row + 1, w_in);
            if (lw > 0.0) { ADD(row + 2, lw); ADD(row + 7, lz_); ADD(row + 8, gv * lz_); ADD(row + 15, lw / gv); }
            if (ww > 0.0) { ADD(row + 3, ww); ADD(row + 9, wz_); }
            if (ow > 0.0) ADD(row + 4, ow);
            ADD(row + 5, path);
            ADD(row + 6, gv * path);
            ADD(row + 10, w_in * chord);
            ADD(row + 11, w_in * chord * chord);
            ADD(row + 12, w_in * dx);
            ADD(row + 13, w_in * dy);
            ADD(row + 14, w_in * dz);
            }
            ++nsteps;
        }
        t = tnext[a];
        ijk[a] += step[a];
        if (ijk[a] < 0 || ijk[a] >= (int)n[a]) break;
        tnext[a] += tdelta[a];
    }
#ifdef SPARSE
    if (brick >= 0) {
        __global double *brow = bacc + brick * NB;
        ADD(brow + 0, 1.0); ADD(brow + 1, b_visits); ADD(brow + 2, b_w); ADD(brow + 3, b_path);
        ADD(brow + 4, b_chord); ADD(brow + 5, b_pathg); ADD(brow + 6, b_visits_w);
    }
#endif
#ifdef USE_ATOMICS
    atom_add(steps, nsteps);
#else
    *steps += nsteps;
#endif
}

__kernel void trace_beams(
    const long b_begin, const long b_end, TRACE_INPUTS, const long n_rows, const long n_bricks,
    __global double *acc, __global double *bacc, __global ulong *steps)
{
#ifdef USE_ATOMICS
    const long b = b_begin + get_global_id(0);
    if (b >= b_end) return;
    trace_one(b, TRACE_INPUT_NAMES, acc, bacc, steps);
#else
    const long c = get_global_id(0);
    const long nc = get_global_size(0);
    /* n_rows: the grid's voxels (dense) or the listed rows (sparse) */
    __global double *mine = acc + c * n_rows * NF;
    __global double *bmine = bacc + c * n_bricks * NB;
    for (long b = b_begin + c; b < b_end; b += nc)
        trace_one(b, TRACE_INPUT_NAMES, mine, bmine, steps + c);
#endif
}
