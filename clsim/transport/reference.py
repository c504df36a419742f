"""NumPy float64 oracle of the photon transport (the kernels' physics, for tests).

Same physics, same Philox streams and the same order of random draws as
``kernels/transport.cl``, vectorised over photons in float64 on a dense
grid.  It is the reference the kernel is tested against, replays single
photons of a kernel run (``photon_ids``), and is the explicit fallback where
no OpenCL device exists.  Its parts: the geometry
(:mod:`clsim.transport.reference_geometry`), the walk through the scene
(:mod:`clsim.transport.reference_walk`), and here the photon histories
(scattering, next-event estimation, tallies):

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

from clsim.transport.reference_geometry import (
    beam_directions,
    cosine_dir,
    in_fov,
    lattice_unit,
    leaf_avg_f,
    receiver_view,
    row_dot,
)
from clsim.transport.reference_walk import ESCAPE, GROUND, LEAF, RR_SURVIVE, RR_THRESHOLD, WOOD, SceneWalker
from clsim.transport.result import SimulationResult, assemble_result
from clsim.transport.setup import QMC_STEP, STAT_NAMES, TRACE_EVENTS, PhotonTally, RunSetup, prepare_run

__all__ = ["ReferenceSimulator"]

C = 0.299792458
_S = {n: i for i, n in enumerate(STAT_NAMES)}


class _Transport(SceneWalker):
    """Photon histories over a :class:`SceneWalker`: scattering, next events, tallies."""

    def __init__(self, setup: RunSetup):
        super().__init__(setup)
        p = setup.p
        f = lambda name: np.asarray(p[name], dtype=np.float64)  # noqa: E731
        self.sensor, self.axis, self.e1, self.e2 = (f(n) for n in ("sensor", "axis", "e1", "e2"))
        opt = setup.settings["optics"]
        self.RT = {LEAF: tuple(opt["leaf"]), WOOD: tuple(opt["bark"]), GROUND: (opt["ground"][0], 0.0)}
        self.tan2_fov = float(np.tan(1e-3 * setup.sensor.fov_mrad)) ** 2
        self.sigma = 0.5e-3 * setup.sensor.divergence_mrad
        self.virt_r2 = (0.5 * setup.sensor.virtual_aperture_m) ** 2
        self.norm_nee = setup.range_ref_m**2
        self.norm_analog = setup.range_ref_m**2 / setup.sensor.virtual_aperture_area_m2
        self.edges = setup.edges_ns
        self.nee = setup.detect is PhotonTally.NEE
        self.hotspot = bool(setup.p["hotspot"])
        self.skip_first = bool(setup.p["skip_first"])
        self.leaf_avg = bool(setup.p["leaf_avg"])
        self.qmc = int(setup.p["qmc"])
        B, K, F = setup.batches, setup.max_order, len(self.edges) - 1
        self.hist = np.zeros((B, K, 2, F))
        self.stats = np.zeros((B, len(STAT_NAMES)))
        self.traces = np.full((max(setup.trace, 1), TRACE_EVENTS, 4), np.nan)
        self.traces[..., 3] = -9
        self.events = self.shadow = 0

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
        d = beam_directions(self.axis, self.e1, self.e2, self.sigma, b0[:, 0], b0[:, 1])
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
        if not ok.any() or (k == 1 and self.skip_first):
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
