"""The NumPy oracle's walk: free flights and transmittance through the voxel scene.

Float64 twin of the walkers of ``kernels/transport.cl`` (``flight``,
``transmittance``) over the scene of ``kernels/scene.cl``, on a dense grid:
delta tracking for free flights and ratio tracking (or the optical depth)
for shadow rays in exact mode; the paper's fixed steps otherwise.  Same
order of random draws as the kernel.  :mod:`clsim.transport.reference`
follows photons with it.
"""

from __future__ import annotations

import numpy as np

from clsim.errors import InputError
from clsim.transport.bricks import extinction, wood_direction
from clsim.transport.reference_geometry import cosine_dir, row_dot, wood_majorant, wood_normal, wood_parts
from clsim.transport.rng import uniforms
from clsim.transport.setup import NG, NTAB, InteractionModel, RunSetup
from voxlidar.scene import Scene

__all__ = ["ESCAPE", "GROUND", "LEAF", "RR_SURVIVE", "RR_THRESHOLD", "WOOD", "SceneWalker"]

ESCAPE, LEAF, WOOD, GROUND = 0, 1, 2, 3
RR_THRESHOLD, RR_SURVIVE = 0.1, 0.5
LEAF_TRIES = 1024  # proposals for a leaf normal at a real collision (kernels/transport.cl)
MAX_DENSE_VOXELS = 50_000_000


class SceneWalker:
    """The scene on a dense float64 grid, walked by rows of photons.

    Owns what a walk needs: the extinction and wood directions per voxel, the
    ground, the leaf angles, the mode, and the photons' Philox streams
    (``pid``, ``ctr``, set by the caller before a walk).  ``steps`` counts
    voxel visits.
    """

    def __init__(self, setup: RunSetup):
        self.s = setup
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
        self.ground = float(sc.ground_z - sc.origin[2]) if sc.ground_z is not None else None
        self.cc = sc.crown_center - sc.origin[:2]
        self.outward = sc.leaf_azimuth == "outward"
        self.spherical = bool(setup.p["leaf_avg"])  # spherical leaf angles, uniform azimuths
        self.ds = float(setup.p["ds"])
        self.exact = setup.mode is InteractionModel.EXACT
        self.steps = 0

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
        and a leaf's normal is drawn after the collision, from p(n) |n . d| / G(d)
        (:meth:`rejection_normals`).  ``u_first`` replaces the first uniform of the free path (lattice points
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
        """Leaf normals at real leaf collisions ``leaf`` from p(n) |n . d| / G(d).

        Spherical leaf angles (``self.spherical``, the run's ``leaf_avg``): the density is
        |n . d| / pi on the upper hemisphere, the cosine law about -d folded onto it, drawn
        directly from bb.z, bb.w (unfolded: the caller uses only the side facing -d, as the
        kernel's ``leaf_normal_seen``).  Otherwise by rejection: the first proposal is ``nl``
        with acceptance uniform bb.y sig / sigma_leaf, then fresh blocks (y: acceptance, z, w:
        the normal)."""
        nl = nl.copy()
        j = np.nonzero(leaf)[0]
        if self.spherical:
            nl[j] = cosine_dir(-d[ic[j]], bb[j, 2], bb[j, 3])
            return nl
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
        if self.spherical:  # spherical leaf angles: G = 1/2 (the kernel's g_of)
            return np.full(np.shape(mu), 0.5)
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
