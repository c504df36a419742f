"""NumPy float64 oracle of the photon transport (the kernels' physics, for tests).

Same physics, same Philox streams and the same order of random draws as
``kernels/transport.cl``, vectorised over photons in float64 on a dense
grid.  It is the reference the kernel is tested against, replays single
photons of a kernel run (``photon_ids``), and is the explicit fallback where
no OpenCL device exists:

>>> from clsim.validation import testscenes
>>> from clsim.sensor import Sensor
>>> res = ReferenceSimulator().run(testscenes.ground_only(), Sensor(), photons=64, seed=3,
...                                max_order=1, batches=4)
>>> e, se = res.energy(kind="ground")
>>> bool(abs(e / (Sensor().aperture_area_m2 / 360.0**2 * 0.30 / np.pi) - 1) < 1e-6)
True
"""

from __future__ import annotations

import time

import numpy as np

from voxlidar.scene import Scene

from clsim.transport.bricks import extinction, wood_direction
from clsim.errors import InputError
from clsim.transport.rng import uniforms
from clsim.transport.result import SimulationResult, assemble_result
from clsim.transport.setup import (NG, NTAB, QMC_STEP, STAT_NAMES, TRACE_EVENTS, Detect, Mode, RunSetup,
                                   prepare_run)

__all__ = ["ReferenceSimulator"]

C = 0.299792458
ESCAPE, LEAF, WOOD, GROUND = 0, 1, 2, 3
RR_THRESHOLD, RR_SURVIVE = 0.1, 0.5
LEAF_TRIES = 1024  # proposals for a leaf normal at a real collision (kernels/transport.cl)
_S = {n: i for i, n in enumerate(STAT_NAMES)}
MAX_DENSE_VOXELS = 50_000_000


def _onb(n):
    s = np.where(n[:, 2] >= 0, 1.0, -1.0)  # copysign(1, z); -0.0 -> +1 here, never hit in practice
    a = -1.0 / (s + n[:, 2])
    b = n[:, 0] * n[:, 1] * a
    b1 = np.column_stack([1.0 + s * n[:, 0] ** 2 * a, s * b, -s * n[:, 0]])
    b2 = np.column_stack([b, s + n[:, 1] ** 2 * a, -n[:, 1]])
    return b1, b2


def cosine_dir(m, u1, u2):
    """Cosine-weighted unit directions about unit normals m (n, 3)."""
    b1, b2 = _onb(m)
    r, ph = np.sqrt(u1), 2.0 * np.pi * u2
    v = (r * np.cos(ph))[:, None] * b1 + (r * np.sin(ph))[:, None] * b2 \
        + np.sqrt(np.maximum(0.0, 1.0 - u1))[:, None] * m
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def wood_parts(q, sw, d):
    """Directional wood extinction along unit ``d`` (n, 3): (cylinder part, random-facet part).

    ``q`` (n, 4) holds ``(bark axis, beta)`` per row, or is None (no directions:
    the parts are ``(0, sw)``); ``sw`` (n,) is the direction-averaged extinction.
    The kernel's ``wood_parts`` (docs/method.md, directional wood)."""
    if q is None:
        return np.zeros_like(sw), sw
    c = row_dot(q[:, :3], d)
    sin_psi = np.sqrt(np.maximum(0.0, 1.0 - c * c))
    return sw * q[:, 3] * (4.0 / np.pi) * sin_psi, sw * (1.0 - q[:, 3])


def wood_majorant(q, sw):
    """Largest wood extinction over directions, ``sw (beta 4 / pi + 1 - beta)`` (kernel ``wood_majorant``)."""
    if q is None:
        return sw
    return sw * q[:, 3] * (4.0 / np.pi) + sw * (1.0 - q[:, 3])


def wood_normal(q, d, cyl, u1, u2):
    """Normals of wood elements hit from ``d``, facing ``-d``, weighted by ``|n . d|``.

    Rows with ``cyl`` lie on the cylinder part, perpendicular to the bark axis
    (``n = -cos(phi) u + sin(phi) a x u``, ``sin(phi) = 2 u1 - 1``); the rest are
    random facets, cosine-weighted about ``-d`` (kernel ``wood_normal``)."""
    n = cosine_dir(-d, u1, u2)
    if q is None or not np.any(cyl):
        return n
    a = q[:, :3]
    p = d - a * row_dot(a, d)[:, None]
    l2 = row_dot(p, p)
    use = cyl & (l2 > 1e-12)
    if use.any():
        u = p[use] / np.sqrt(l2[use])[:, None]
        s = 2.0 * u1[use] - 1.0
        c = np.sqrt(np.maximum(0.0, 1.0 - s * s))
        n[use] = s[:, None] * np.cross(a[use], u) - c[:, None] * u
    return n


def row_dot(a, b):
    """Row-wise dot products of two (n, 3) arrays."""
    return np.einsum("ij,ij->i", a, b)


def receiver_view(sensor, axis, tan2_fov, x, m, R, T):
    """Next-event geometry of scattering points ``x`` (n, 3) with incident-side normals ``m``.

    Returns ``(r, drx, cosr, c, f, ok)``: distance to the receiver, unit direction to it,
    that direction's cosine on the beam axis, ``m . drx``, the bi-Lambertian BSDF value
    towards the receiver, and the mask of points that scatter towards a receiver that
    sees them (``f > 0`` and inside the field of view)."""
    to = sensor - x
    r = np.linalg.norm(to, axis=1)
    drx = to / r[:, None]
    cosr = -row_dot(drx, np.broadcast_to(axis, drx.shape))
    c = row_dot(m, drx)
    f = np.where(c > 0, R * c / np.pi, -T * c / np.pi)
    ok = (f > 0) & in_fov(-to, axis, tan2_fov)
    return r, drx, cosr, c, f, ok


def leaf_avg_f(d, w, R, T):
    """Next-event weight (1/sr) of a leaf event averaged over the leaf normals of a spherical
    leaf-angle distribution with uniform azimuths, incoming unit ``d``, outgoing unit ``w``
    (rows): Ross's area scattering phase function over pi G (G = 1/2); docs/method.md.

    >>> z = np.array([[0.0, 0.0, 1.0]])
    >>> bool(np.isclose(leaf_avg_f(-z, z, 0.437, 0.478)[0], 2 * 0.437 / (3 * np.pi)))
    True
    """
    c = np.clip(row_dot(d, w), -1.0, 1.0)
    beta = np.arccos(c)
    return ((R + T) * (np.sqrt(1.0 - c * c) - beta * c) / (3.0 * np.pi) + T * c / 3.0) * (2.0 / np.pi)


def lattice_unit(shift, pid, step):
    """Coordinate of photons ``pid`` on the seed-shifted Kronecker lattice, as the kernel's
    uniform in (0, 1): ((shift + pid step) mod 2^32 >> 9 + 1/2) 2^-23."""
    x = (np.uint64(shift) + (np.asarray(pid, np.uint64) & np.uint64(0xFFFFFFFF)) * np.uint64(step)) \
        & np.uint64(0xFFFFFFFF)
    return ((x >> np.uint64(9)).astype(np.float64) + 0.5) * 2.0**-23


def in_fov(v, axis, tan2_fov):
    """Rows of v (sensor -> point) inside the field of view around unit ``axis``.

    Tested on the offset from the axis, as the kernel does (a cosine near 1
    is too coarse in float32)."""
    along = v @ axis
    off = v - along[:, None] * axis
    return (along > 0) & (row_dot(off, off) <= tan2_fov * along**2)


class _Transport:
    def __init__(self, setup: RunSetup):
        self.s = setup
        p = setup.p
        sc = setup.scene
        if not isinstance(sc, Scene):           # a clsim.scenes.PlotScene: its copied scene, same values
            sc = sc.to_scene()
        if int(np.prod(sc.shape)) > MAX_DENSE_VOXELS:
            raise InputError(
                f"the NumPy oracle uses a dense grid; shape {sc.shape} has more than "
                f"{MAX_DENSE_VOXELS} voxels. Use the OpenCL Simulator for large scenes"
            )
        lad, sw, _ = extinction(sc, leaf_off=setup.leaf_off)
        self.ext = np.zeros(tuple(sc.shape) + (2,))
        i, j, k = sc.ijk.T
        self.ext[i, j, k, 0] = lad
        self.ext[i, j, k, 1] = sw
        wd = wood_direction(sc)
        self.wdir = None
        if wd is not None:  # float32 as on the device
            self.wdir = np.zeros(tuple(sc.shape) + (4,))
            self.wdir[..., 2] = 1.0
            self.wdir[i, j, k] = wd.astype(np.float32)
        self.shape = np.asarray(sc.shape)
        self.h = sc.voxel_size
        self.L = self.shape * self.h
        f = lambda name: np.asarray(p[name], dtype=np.float64)  # noqa: E731
        self.sensor, self.axis, self.e1, self.e2 = (f(n) for n in ("sensor", "axis", "e1", "e2"))
        self.ground = float(sc.ground_z - sc.origin[2]) if sc.ground_z is not None else None
        opt = setup.settings["optics"]
        self.RT = {LEAF: tuple(opt["leaf"]), WOOD: tuple(opt["bark"]), GROUND: (opt["ground"][0], 0.0)}
        self.cc = sc.crown_center - sc.origin[:2]
        self.outward = sc.leaf_azimuth == "outward"
        self.ds = float(p["ds"])
        self.tan2_fov = float(np.tan(1e-3 * setup.sensor.fov_mrad)) ** 2
        self.sigma = 0.5e-3 * setup.sensor.divergence_mrad
        self.virt_r2 = (0.5 * setup.sensor.virtual_aperture_m) ** 2
        self.norm_nee = setup.range_ref_m**2
        self.norm_analog = setup.range_ref_m**2 / setup.sensor.virtual_aperture_area_m2
        self.edges = setup.edges_ns
        self.exact = setup.mode is Mode.EXACT
        self.nee = setup.detect is Detect.NEE
        self.hotspot = bool(setup.p["hotspot"])
        self.leaf_avg = bool(setup.p["leaf_avg"])
        self.qmc = int(setup.p["qmc"])
        B, K, F = setup.batches, setup.max_order, len(self.edges) - 1
        self.hist = np.zeros((B, K, 2, F))
        self.stats = np.zeros((B, len(STAT_NAMES)))
        self.traces = np.full((max(setup.trace, 1), TRACE_EVENTS, 4), np.nan)
        self.traces[..., 3] = -9

    # -- random numbers ---------------------------------------------------------------
    def draw(self, idx):
        u = uniforms(self.pid[idx], self.ctr[idx], seed=self.s.seed)
        self.ctr[idx] += 1
        return u

    def leaf_normal(self, ut, uaz, x):
        s = ut * (NTAB - 1)
        i = np.minimum(s.astype(np.int64), NTAB - 2)
        f = s - i
        t = self.s.ppf[i] * (1 - f) + self.s.ppf[i + 1] * f
        ph = np.arctan2(x[:, 1] - self.cc[1], x[:, 0] - self.cc[0]) if self.outward else 2 * np.pi * uaz
        st = np.sin(t)
        return np.column_stack([st * np.cos(ph), st * np.sin(ph), np.cos(t)])

    # -- geometry ------------------------------------------------------------------------
    def clip(self, o, d, t_lim):
        t0 = np.zeros(len(o))
        t1 = t_lim.copy()
        ok = np.ones(len(o), bool)
        with np.errstate(divide="ignore", invalid="ignore"):
            for a in range(3):
                zero = d[:, a] == 0
                ok &= ~(zero & ((o[:, a] < 0) | (o[:, a] > self.L[a])))
                ta = (0.0 - o[:, a]) / d[:, a]
                tb = (self.L[a] - o[:, a]) / d[:, a]
                t0 = np.where(zero, t0, np.maximum(t0, np.minimum(ta, tb)))
                t1 = np.where(zero, t1, np.minimum(t1, np.maximum(ta, tb)))
        return ok & (t0 < t1), t0, t1

    def ground_t(self, o, d):
        if self.ground is None:
            return np.full(len(o), np.inf)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.maximum(0.0, (self.ground - o[:, 2]) / d[:, 2])
        return np.where(d[:, 2] < 0, t, np.inf)

    def value(self, v):
        inside = np.all((v >= 0) & (v < self.shape), axis=1)
        vc = np.clip(v, 0, self.shape - 1)
        e = self.ext[vc[:, 0], vc[:, 1], vc[:, 2]]
        return np.where(inside[:, None], e, 0.0), inside

    def wood_dir(self, v):
        """(axis, beta) of voxels v (inside the grid), or None for a scene without directions."""
        if self.wdir is None:
            return None
        return self.wdir[v[:, 0], v[:, 1], v[:, 2]]

    # -- free flight / transmittance -------------------------------------------------
    def walk(self, o, d, t_lim, idx, shadow, u_first=None):
        """Exact: delta tracking (flight) or ratio tracking (shadow).  Paper: fixed steps.

        With uniform leaf azimuths a flight's majorant is the extinction LAD G(d) + sigma_wood
        and a leaf's normal is drawn after the collision, from p(n) |n . d| / G(d) by
        rejection.  ``u_first`` replaces the first uniform of the free path (lattice points
        of first flights).  Returns (event, t, normal) for flights, T for shadow rays."""
        if shadow and self.exact and not self.outward:
            return self.optical_depth_transmittance(o, d, t_lim)
        n = len(o)
        ev = np.full(n, ESCAPE)
        tev = np.full(n, np.inf)
        nrm = np.zeros((n, 3))
        T = np.ones(n)
        hit, t0, t1 = self.clip(o, d, t_lim)
        if self.exact:
            b = self.draw(idx)
            if u_first is not None:
                b[:, 0] = u_first
            tau = -np.log(b[:, 0])
            tight = not shadow and not self.outward
            gl = self.g_of(d[:, 2]) if tight else np.ones(n)
        act = np.nonzero(hit)[0]
        if self.exact:
            v = np.clip(np.floor((o[act] + d[act] * t0[act, None]) / self.h).astype(np.int64), 0, self.shape - 1)
            vox = np.zeros((n, 3), np.int64)
            vox[act] = v
            step = np.sign(d).astype(np.int64)
            t = t0.copy()
            while act.size:
                vi = vox[act]
                e, inside = self.value(vi)
                self.steps += act.size
                act, vi, e = act[inside], vi[inside], e[inside]
                if not act.size:
                    break
                oa, da, sa = o[act], d[act], step[act]
                with np.errstate(divide="ignore", invalid="ignore"):
                    plane = (vi + (sa > 0)) * self.h
                    tf = np.where(sa == 0, np.inf, (plane - oa) / da)
                ax = np.argmin(tf, axis=1)
                tb = np.minimum(tf[np.arange(act.size), ax], t1[act])
                ta = t[act]
                q = self.wood_dir(vi)
                sig = e[:, 0] * gl[act] + wood_majorant(q, e[:, 1])
                opt = sig * np.maximum(tb - ta, 0.0)
                coll = (sig > 0) & (tb > ta) & (opt > tau[act])
                # segments without collision: advance
                nc = ~coll
                ia = act[nc]
                tau[ia] -= opt[nc]
                t[ia] = np.maximum(t[ia], tb[nc])
                vox[ia, ax[nc]] += sa[nc, ax[nc]]
                done = np.zeros(act.size, bool)
                done[nc] = t[ia] >= t1[ia]
                # tentative collisions
                ic = act[coll]
                if ic.size:
                    sg, ec = sig[coll], e[coll]
                    qc = None if q is None else q[coll]
                    tc = ta[coll] + tau[ic] / sg
                    x = o[ic] + d[ic] * tc[:, None]
                    bb = b[ic]
                    nl = self.leaf_normal(bb[:, 2], bb[:, 3], x)
                    cosn = np.abs(row_dot(nl, d[ic]))
                    wc, wr = wood_parts(qc, ec[:, 1], d[ic])
                    if shadow:
                        T[ic] *= 1.0 - (ec[:, 0] * cosn + wc + wr) / sg
                        low = T[ic] < RR_THRESHOLD
                        surv = bb[:, 1] * RR_SURVIVE < T[ic]
                        T[ic] = np.where(low, np.where(surv, RR_SURVIVE, 0.0), T[ic])
                        stop = low & ~surv
                    else:
                        sl = ec[:, 0] * gl[ic]
                        y = bb[:, 1] * sg - sl
                        in_wood = y >= 0
                        wood = in_wood if q is None else in_wood & (y < wc + wr)
                        if tight:
                            leaf = ~in_wood
                            nl = self.rejection_normals(nl, bb, sg, sl, leaf, ic, idx, x, d)
                        else:
                            leaf = ~in_wood & (bb[:, 1] * sg < ec[:, 0] * cosn)
                        stop = wood | leaf
                        ev[ic[wood]] = WOOD
                        nrm[ic[wood]] = wood_normal(None if qc is None else qc[wood], d[ic[wood]],
                                                    (y < wc)[wood], bb[wood, 2], bb[wood, 3])
                        ev[ic[leaf]] = LEAF
                        nrm[ic[leaf]] = nl[leaf]
                        tev[ic[stop]] = tc[stop]
                    cont = ic[~stop]
                    if cont.size:
                        b[cont] = self.draw(idx[cont])
                        tau[cont] = -np.log(b[cont, 0])
                        t[cont] = tc[~stop]
                    done[coll] = stop
                act = act[~done]
        else:
            ds = self.ds
            k = np.maximum(1, np.ceil(t0 / ds)).astype(np.int64)
            while act.size:
                tk = k[act] * ds
                act = act[tk < t1[act]]
                if not act.size:
                    break
                tk = k[act] * ds
                x = o[act] + d[act] * tk[:, None]
                vx = np.floor(x / self.h).astype(np.int64)
                e, _ = self.value(vx)
                self.steps += act.size
                nz = (e[:, 0] + e[:, 1]) > 0
                stop = np.zeros(act.size, bool)
                if nz.any():
                    iz = act[nz]
                    ez, xz = e[nz], x[nz]
                    qz = self.wood_dir(vx[nz])  # non-zero voxels lie inside the grid
                    wc, wr = wood_parts(qz, ez[:, 1], d[iz])
                    bb = self.draw(idx[iz])
                    nl = self.leaf_normal(bb[:, 2], bb[:, 3], xz)
                    pl = np.minimum(1.0, ez[:, 0] * np.abs(row_dot(nl, d[iz])) * ds)
                    pw = -np.expm1(-(wc + wr) * ds)
                    if shadow:
                        T[iz] *= (1.0 - pl) * np.exp(-(wc + wr) * ds)
                        low = T[iz] < RR_THRESHOLD
                        surv = bb[:, 1] * RR_SURVIVE < T[iz]
                        T[iz] = np.where(low, np.where(surv, RR_SURVIVE, 0.0), T[iz])
                        st = low & ~surv
                    else:
                        leaf = bb[:, 0] < pl
                        wood = ~leaf & (bb[:, 1] < pw)
                        ev[iz[leaf]] = LEAF
                        nrm[iz[leaf]] = nl[leaf]
                        if wood.any():
                            iw = iz[wood]
                            b2 = self.draw(idx[iw])
                            ev[iw] = WOOD
                            cyl = b2[:, 1] * (wc + wr)[wood] < wc[wood]
                            nrm[iw] = wood_normal(None if qz is None else qz[wood], d[iw], cyl,
                                                  b2[:, 2], b2[:, 3])
                        st = leaf | wood
                        tev[iz[st]] = tk[nz][st]
                    stop[nz] = st
                k[act] += 1
                act = act[~stop]
        if shadow:
            return T
        gt = self.ground_t(o, d)
        g = (ev == ESCAPE) & np.isfinite(gt)
        ev[g] = GROUND
        tev[g] = gt[g]
        nrm[g] = (0.0, 0.0, 1.0)
        return ev, tev, nrm

    def rejection_normals(self, nl, bb, sg, sl, leaf, ic, idx, x, d):
        """Leaf normals at real leaf collisions ``leaf`` from p(n) |n . d| / G(d): the first
        proposal is ``nl`` with acceptance uniform bb.y sig / sigma_leaf, then fresh blocks
        (y: acceptance, z, w: the normal)."""
        nl = nl.copy()
        j = np.nonzero(leaf)[0]
        with np.errstate(divide="ignore", invalid="ignore"):
            u = bb[j, 1] * sg[j] / sl[j]
        pend = j[u >= np.abs(row_dot(nl[j], d[ic[j]]))]
        for _ in range(LEAF_TRIES):
            if not pend.size:
                break
            bj = self.draw(idx[ic[pend]])
            nl[pend] = self.leaf_normal(bj[:, 2], bj[:, 3], x[pend])
            pend = pend[bj[:, 1] >= np.abs(row_dot(nl[pend], d[ic[pend]]))]
        return nl

    def g_of(self, mu):
        s = np.minimum(np.abs(mu), 1.0) * (NG - 1)
        i = np.minimum(s.astype(np.int64), NG - 2)
        f = s - i
        return self.s.gtab[i] * (1 - f) + self.s.gtab[i + 1] * f

    def optical_depth_transmittance(self, o, d, t_lim):
        """exp(-sum (LAD G(d) + sigma_wood) l) voxel by voxel (uniform leaf azimuths)."""
        n = len(o)
        od = np.zeros(n)
        hit, t0, t1 = self.clip(o, d, t_lim)
        act = np.nonzero(hit)[0]
        gd = self.g_of(d[:, 2])
        vox = np.zeros((n, 3), np.int64)
        vox[act] = np.clip(np.floor((o[act] + d[act] * t0[act, None]) / self.h).astype(np.int64), 0,
                           self.shape - 1)
        step = np.sign(d).astype(np.int64)
        t = t0.copy()
        while act.size:
            e, inside = self.value(vox[act])
            self.steps += act.size
            act, e = act[inside], e[inside]
            if not act.size:
                break
            vi, sa = vox[act], step[act]
            with np.errstate(divide="ignore", invalid="ignore"):
                tf = np.where(sa == 0, np.inf, ((vi + (sa > 0)) * self.h - o[act]) / d[act])
            ax = np.argmin(tf, axis=1)
            tb = np.minimum(tf[np.arange(act.size), ax], t1[act])
            wc, wr = wood_parts(self.wood_dir(vi), e[:, 1], d[act])
            od[act] += (e[:, 0] * gd[act] + wc + wr) * np.maximum(tb - t[act], 0.0)
            t[act] = np.maximum(t[act], tb)
            vox[act, ax] += sa[np.arange(act.size), ax]
            act = act[(t[act] < t1[act]) & (od[act] <= 40.0)]
        return np.where(od > 40.0, 0.0, np.exp(-od))

    # -- tallies ---------------------------------------------------------------------------
    def add_stat(self, name, idx, values):
        np.add.at(self.stats[:, _S[name]], self.batch[idx], values)

    def tally(self, idx, order, kind, t_ns, value):
        s = (t_ns - self.edges[0]) / (self.edges[1] - self.edges[0])
        F = len(self.edges) - 1
        ok = (s >= 0) & (s < F)
        b = self.batch[idx]
        np.add.at(self.hist, (b[ok], order[ok] - 1, kind[ok], s[ok].astype(np.int64)), value[ok])
        np.add.at(self.stats[:, _S["outside_window"]], b[~ok], value[~ok])

    def record(self, idx, k, x, typ):
        if k >= TRACE_EVENTS:
            return
        sel = self.pid[idx] < self.s.trace
        if sel.any():
            rows = self.pid[idx[sel]].astype(np.int64)
            self.traces[rows, k, :3] = x[sel]
            self.traces[rows, k, 3] = typ[sel] if np.ndim(typ) else typ

    # -- one chunk of photons --------------------------------------------------------------
    def simulate(self, pids):
        n = len(pids)
        self.pid = np.asarray(pids, dtype=np.uint64)
        self.ctr = np.zeros(n, np.uint64)
        self.batch = (self.pid % np.uint64(self.s.batches)).astype(np.int64)
        K = self.s.max_order
        allp = np.arange(n)
        b0 = self.draw(allp)
        # the seed-shifted golden-ratio lattice of first free paths (exact mode)
        u_first = lattice_unit(self.qmc, self.pid, QMC_STEP) if self.exact else None
        rr = self.sigma * np.sqrt(-2.0 * np.log(b0[:, 0]))
        ph = 2.0 * np.pi * b0[:, 1]
        d = self.axis + (rr * np.cos(ph))[:, None] * self.e1 + (rr * np.sin(ph))[:, None] * self.e2
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        x = np.tile(self.sensor, (n, 1))
        L = np.zeros(n)
        w = np.ones(n)
        last = np.full(n, LEAF)
        self.record(allp, 0, x, -2)
        alive = allp
        k = 0
        while alive.size:
            k += 1
            a = alive
            ev, t, nrm = self.walk(x[a], d[a], self.ground_t(x[a], d[a]), a, shadow=False,
                                   u_first=u_first if k == 1 and u_first is not None else None)
            esc = ev == ESCAPE
            ie = a[esc]
            up = d[ie, 2] >= 0
            self.add_stat("escaped_up", ie[up], w[ie[up]])
            self.add_stat("escaped_down", ie[~up], w[ie[~up]])
            self.record(ie, k, x[ie] + d[ie] * 10.0, ESCAPE)
            if not self.nee and k >= 2 and ie.size:
                self.analog(ie, x, d, L, w, last, k - 1)
            a, ev, t, nrm = a[~esc], ev[~esc], t[~esc], nrm[~esc]
            x[a] += d[a] * t[:, None]
            L[a] += t
            self.events += a.size
            self.record(a, k, x[a], ev)
            if k == 1:
                gd = ev == GROUND
                self.add_stat("ground_direct", a[gd], w[a[gd]])
            if k > K:
                self.add_stat("truncated", a, w[a])
                break
            last[a] = ev
            R = np.choose(ev - 1, [self.RT[LEAF][0], self.RT[WOOD][0], self.RT[GROUND][0]])
            T = np.choose(ev - 1, [self.RT[LEAF][1], self.RT[WOOD][1], 0.0])
            m = nrm.copy()
            lf = ev == LEAF
            flip = row_dot(nrm[lf], d[a[lf]]) > 0
            m[np.nonzero(lf)[0][flip]] *= -1.0
            if self.nee:
                self.nee_event(a, x, d, L, w, ev, m, R, T, k)
                if k == K:
                    self.add_stat("truncated", a, w[a])
                    break
            s = self.draw(a)
            alb = R + T
            if self.exact:
                dead = alb <= 0
                self.add_stat("absorbed", a[dead], w[a[dead]])
                reflect = s[:, 0] * alb < R
                self.add_stat("absorbed", a[~dead], w[a[~dead]] * (1.0 - alb[~dead]))
                w[a] *= alb
                low = ~dead & (w[a] < RR_THRESHOLD)
                surv = low & (s[:, 3] * RR_SURVIVE < w[a])
                kill = low & ~surv
                self.add_stat("rr_added", a[surv], RR_SURVIVE - w[a[surv]])
                w[a[surv]] = RR_SURVIVE
                self.add_stat("rr_killed", a[kill], w[a[kill]])
                keep = ~dead & ~kill
            else:
                absorb = s[:, 0] >= alb
                self.add_stat("absorbed", a[absorb], w[a[absorb]])
                self.record(a[absorb], k + 1, x[a[absorb]], -1)
                reflect = s[:, 0] < R
                keep = ~absorb
            mm = np.where(reflect[:, None], m, -m)
            a, s, mm = a[keep], s[keep], mm[keep]
            if a.size:
                d[a] = cosine_dir(mm, s[:, 1], s[:, 2])
            alive = a

    def nee_event(self, a, x, d, L, w, ev, m, R, T, k):
        r, drx, cosr, _, f, ok = receiver_view(self.sensor, self.axis, self.tan2_fov, x[a], m, R, T)
        if self.leaf_avg:  # leaf events: the weight averaged over the leaf normals
            lf = ev == LEAF
            f = np.where(lf, leaf_avg_f(d[a], drx, R, T), f)
            ok = (f > 0) & in_fov(x[a] - self.sensor, self.axis, self.tan2_fov)
        if not ok.any():
            return
        i = a[ok]
        self.shadow += i.size
        if self.hotspot and k == 1:
            Tr = np.ones(i.size)  # the return retraces the free incoming path
        else:
            Tr = self.walk(x[i], drx[ok], r[ok], i, shadow=True)
        val = w[i] * f[ok] * Tr * cosr[ok] * self.norm_nee / r[ok] ** 2
        pos = Tr > 0
        kind = (ev[ok] == GROUND).astype(np.int64)
        self.tally(i[pos], np.full(pos.sum(), k), kind[pos], (L[i] + r[ok])[pos] / C, val[pos])

    def analog(self, ie, x, d, L, w, last, order):
        axis = np.broadcast_to(self.axis, (ie.size, 3))
        den = row_dot(d[ie], axis)
        sx = x[ie] - self.sensor
        along = row_dot(sx, axis)
        ok = (den < 0) & in_fov(sx, self.axis, self.tan2_fov)
        with np.errstate(divide="ignore", invalid="ignore"):
            s = -along / den
        q = x[ie] + d[ie] * s[:, None] - self.sensor
        ok &= row_dot(q, q) <= self.virt_r2
        i = ie[ok]
        self.add_stat("detections", i, 1.0)
        kind = (last[i] == GROUND).astype(np.int64)
        self.tally(i, np.full(i.size, order), kind, (L[i] + s[ok]) / C, w[i] * self.norm_analog)


class ReferenceSimulator:
    """Same interface as :class:`clsim.Simulator`, NumPy float64 (slow, exact arithmetic)."""

    device_name = "NumPy float64 reference"

    def run(self, scene, sensor, *, photons: int, seed: int, mode="exact", detect="nee",
            max_order: int = 3, leaf_off: bool = False, batches: int = 16, bin_ns: float = 0.05,
            step_m: float = 0.02, target=None, trace: int = 0, chunk: int = 1 << 16,
            photon_ids=None, hotspot: bool = False) -> SimulationResult:
        """See :meth:`clsim.Simulator.run`.  ``photon_ids`` replays chosen photons only."""
        setup = prepare_run(scene, sensor, photons=photons, seed=seed, mode=mode, detect=detect,
                            max_order=max_order, leaf_off=leaf_off, batches=batches, bin_ns=bin_ns,
                            step_m=step_m, target=target, trace=trace, hotspot=hotspot)
        return self.run_setup(setup, chunk=chunk, photon_ids=photon_ids)

    def run_setup(self, setup: RunSetup, *, chunk: int = 1 << 16, photon_ids=None) -> SimulationResult:
        tr = _Transport(setup)
        tr.steps = tr.events = tr.shadow = 0
        ids = np.arange(setup.photons, dtype=np.uint64) if photon_ids is None \
            else np.asarray(photon_ids, dtype=np.uint64).ravel()
        t0 = time.perf_counter()
        for start in range(0, ids.size, chunk):
            tr.simulate(ids[start : start + chunk])
        elapsed = time.perf_counter() - t0
        tr.stats[0, _S["voxel_steps"]] += tr.steps
        tr.stats[0, _S["walk_steps"]] += tr.steps  # the oracle walks voxel by voxel
        tr.stats[0, _S["events"]] += tr.events
        tr.stats[0, _S["shadow_rays"]] += tr.shadow
        traces = None
        if setup.trace:
            traces = tr.traces.astype(np.float32)
            traces[..., :3] += setup.scene.origin.astype(np.float32)
        return assemble_result(setup, tr.hist, tr.stats, traces, elapsed, self.device_name)
