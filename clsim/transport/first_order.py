"""The deterministic first order: single scattering integrated along the beam, for a batch of pulses.

The Monte Carlo kernel estimates the order-1 return by sampling free paths; its
expectation for a fixed beam direction is an integral along the ray that can be
done exactly, voxel by voxel (docs/method.md, "Deterministic first order").  Over
a fixed set of beam samples (:func:`beam_samples`: a sunflower spiral of equal
weights through the Gaussian beam) that integral is free of Monte Carlo noise:
the same pulses give the same bits on a device, whatever the seed.  One kernel
launch computes every pulse of a batch (kernels/first_order.cl); a second
convolves with the pulse and samples at the digitiser's rate on the device, so
that only the digitised waveforms are read back.

:func:`first_order_reference` is its NumPy float64 oracle, and
:meth:`clsim.Simulator.run_pulses` (``first_order="deterministic"``) its entry
point.

Examples
--------
>>> s = beam_samples(19)
>>> s.shape, round(float(s[:, 2].sum()), 12)
((19, 3), 1.0)
"""

from __future__ import annotations

import functools
import math
import time
from dataclasses import dataclass
from importlib import resources

import numpy as np

from clsim.digitize import pulse_kernel
from clsim.errors import DeviceError, InputError
from clsim.sensor import C_M_PER_NS, Sensor
from clsim.transport.bricks import extinction, wood_direction
from clsim.transport.setup import NG, PARAMS_DTYPE, SceneSetup, scene_params
from voxlidar.devices import build_program, short_reason

__all__ = ["PULSE_FIELDS", "FirstOrderGrid", "FirstOrderRunner", "beam_samples", "check_first_order",
           "first_order_reference", "leaf_cos2", "pulse_grid", "window_ns"]

#: floats per pulse record of the kernel (kernels/first_order.cl PULSE_STRIDE): sensor (3),
#: beam axis (3), e1 (3), e2 (3), the fine grid's first edge (ns), the pulse's fine bins, 2 unused
PULSE_FIELDS = 16
#: the golden angle, radians: consecutive sunflower samples turn by it
GOLDEN_ANGLE = math.pi * (3.0 - math.sqrt(5.0))


def beam_samples(n: int) -> np.ndarray:
    """``n`` directions through a circular Gaussian beam, equal weights: (n, 3) of (a, b, w).

    Sample ``i`` leaves along ``axis + beam_sigma (a e1 + b e2)`` (the Monte Carlo
    kernel's mapping of its two uniforms), with ``a, b`` at radius
    ``sqrt(-2 ln(1 - (i + 1/2) / n))`` (the middle of its equal share of the
    Rayleigh-distributed radius) and azimuth ``i`` golden angles: a sunflower
    spiral (Vogel 1979), even over the disc for any ``n``.  ``w = 1/n``."""
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or not 1 <= int(n) <= 100_000:
        raise InputError(f"beam samples must be an integer in [1, 100000], got {n!r}")
    i = np.arange(int(n), dtype=np.float64)
    r = np.sqrt(-2.0 * np.log1p(-(i + 0.5) / n))
    phi = i * GOLDEN_ANGLE
    return np.column_stack([r * np.cos(phi), r * np.sin(phi), np.full(int(n), 1.0 / n)])


def leaf_cos2(ppf) -> float:
    """E[cos^2 theta_l] of the leaf zenith whose inverse CDF is ``ppf`` (NTAB points on [0, 1]),
    as the kernel samples it (linear between the points; trapezoid rule)."""
    c2 = np.cos(np.asarray(ppf, dtype=np.float64)) ** 2
    return float(0.5 * (c2[:-1] + c2[1:]).mean())


@functools.lru_cache(maxsize=16)
def _outward_tables_cached(ppf_bytes: bytes) -> np.ndarray:
    theta = np.frombuffer(ppf_bytes, dtype=np.float64)
    beta = np.linspace(-np.pi, np.pi, NG)
    wts = np.full(len(theta), 1.0)
    wts[[0, -1]] = 0.5
    wts /= wts.sum()
    sn = np.sin(theta[None, :] + beta[:, None])
    tab = np.concatenate([np.abs(sn) @ wts, (sn * sn) @ wts])
    tab.flags.writeable = False
    return tab


def outward_tables(ppf) -> np.ndarray:
    """(2 NG,) float64: E|sin(theta + beta)| then E[sin^2(theta + beta)] over the leaf zenith theta
    whose inverse CDF is ``ppf``, at NG values of beta in [-pi, pi] (kernels/first_order.cl
    ``outward_leaf``; the trapezoid rule over the table, as :func:`leaf_cos2`)."""
    return _outward_tables_cached(np.ascontiguousarray(ppf, dtype=np.float64).tobytes())


def _onb_rows(n):
    """Duff et al. (2017) orthonormal bases of unit rows n (the kernel set-up's formula)."""
    s = np.where(n[:, 2] >= 0, 1.0, -1.0)
    a = -1.0 / (s + n[:, 2])
    b = n[:, 0] * n[:, 1] * a
    e1 = np.column_stack([1.0 + s * n[:, 0] ** 2 * a, s * b, -s * n[:, 0]])
    e2 = np.column_stack([b, s + n[:, 1] ** 2 * a, -n[:, 1]])
    return e1, e2


@dataclass
class FirstOrderGrid:
    """The time grids of a batch of pulses: fine bins ``k`` to a digitiser sample, aligned on its clock.

    Sample ``s`` of pulse ``p`` is at ``t0_ns[p] + s / sampling_ghz``, the centre of its fine
    bin ``k s``; the fine grid of pulse ``p`` starts at ``t0_ns[p] - dt_ns / 2``."""

    records: np.ndarray   # (N, PULSE_FIELDS) float32, the kernel's pulse records (local metres)
    t0_ns: np.ndarray     # (N,) float64, time of each pulse's first sample
    n_samples: np.ndarray  # (N,) int64, samples of each pulse
    k: int                # fine bins per sample
    dt_ns: float          # fine bin, ns
    nbins: int            # fine bins per pulse (the batch's longest)

    @property
    def fine_start_ns(self) -> np.ndarray:
        return self.t0_ns - 0.5 * self.dt_ns


def window_ns(lo, hi, ground, S, target, pulse_fwhm_ns: float, max_order: int = 1):
    """(t_start, t_end) ns of each pulse's record: from the nearest point of the scene box (or the
    ground) to its farthest corner (or the pulse's ground target), two pulse widths each side, and
    for ``max_order > 1`` the box's diagonal of wandering after the farthest point
    (:func:`clsim.transport.setup.prepare_run`'s window, for many pulses at once)."""
    lo, hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    S = np.asarray(S, dtype=np.float64)
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    near = np.linalg.norm(np.maximum(np.maximum(lo - S, 0.0), S - hi), axis=1)
    far = np.linalg.norm(corners[None, :, :] - S[:, None, :], axis=2).max(axis=1)
    if ground is not None:
        near = np.minimum(near, S[:, 2] - ground)
        far = np.maximum(far, np.linalg.norm(np.asarray(target, dtype=np.float64) - S, axis=1))
    t_start = 2.0 * near / C_M_PER_NS - 2.0 * pulse_fwhm_ns
    t_end = 2.0 * far / C_M_PER_NS + 2.0 * pulse_fwhm_ns
    if max_order > 1:
        t_end = t_end + 2.0 * float(np.linalg.norm(hi - lo)) / C_M_PER_NS
    return t_start, t_end


def pulse_grid(scene, pulses, sensor: Sensor, *, bin_ns: float = 0.05) -> FirstOrderGrid:
    """The pulses' geometry and time grids (vectorised; :func:`clsim.transport.setup.prepare_run`'s
    window for ``max_order=1``: the scene box and the ground, two pulse widths each side).

    ``bin_ns`` is the finest bin wanted: the grid's is ``1 / (k sampling_ghz)`` with ``k`` the
    smallest integer that makes it no coarser."""
    if not (np.isfinite(bin_ns) and 0.001 <= bin_ns <= 1.0):
        raise InputError(f"bin_ns must lie in [0.001, 1] ns, got {bin_ns!r}")
    lo = np.asarray(scene.origin, dtype=np.float64)
    hi = lo + scene.voxel_size * np.asarray(scene.shape)
    ground = scene.ground_z
    S = np.asarray(pulses.position, dtype=np.float64)
    axis = np.asarray(pulses.direction, dtype=np.float64)
    axis = axis / np.linalg.norm(axis, axis=1, keepdims=True)
    top = max(hi[2], ground if ground is not None else -np.inf)
    if len(S) and S[:, 2].min() <= top:
        raise InputError(f"a pulse is fired from z = {S[:, 2].min():.2f} m, not above the scene (top {top:.2f} m); "
                         "raise the flight's altitude")
    t_start, t_end = window_ns(lo, hi, ground, S, pulses.target, sensor.pulse_fwhm_ns)
    period = 1.0 / sensor.sampling_ghz
    k = max(1, int(math.ceil(period / bin_ns - 1e-9)))
    dt = period / k
    t0 = np.floor(t_start / period) * period
    n_s = (np.floor((t_end - t0) / period) + 1).astype(np.int64)
    e1, e2 = _onb_rows(axis)
    rec = np.zeros((len(S), PULSE_FIELDS), dtype=np.float32)
    rec[:, 0:3] = S - lo
    rec[:, 3:6] = axis
    rec[:, 6:9] = e1
    rec[:, 9:12] = e2
    rec[:, 12] = t0 - 0.5 * dt
    rec[:, 13] = k * (n_s + 1)
    nbins = int(k * (n_s.max() + 1)) if len(S) else k
    return FirstOrderGrid(records=rec, t0_ns=t0, n_samples=n_s, k=k, dt_ns=dt, nbins=nbins)


def _params(scene_setup: SceneSetup, sensor: Sensor, grid: FirstOrderGrid, hotspot: bool) -> np.ndarray:
    """The kernel's shared parameters (:data:`~clsim.transport.setup.PARAMS_DTYPE`) of a batch."""
    rec = np.zeros(1, dtype=PARAMS_DTYPE)
    r = rec[0]
    scene_params(r, scene_setup, sensor)
    r["dt_ns"] = grid.dt_ns
    r["nbins"] = grid.nbins
    r["max_order"] = 1
    r["n_batches"] = 1
    r["hotspot"] = bool(hotspot)
    return rec


def check_first_order(mode="exact", detect="nee") -> None:
    """One line unless the deterministic first order applies: the exact mode's medium and
    next-event detection."""
    if str(getattr(mode, "value", mode)) != "exact":
        raise InputError("the deterministic first order integrates the exact mode's medium; "
                         "fix: mode='exact', or first_order='mc' for the paper's steps")
    if str(getattr(detect, "value", detect)) != "nee":
        raise InputError("the deterministic first order is the next-event estimate's expectation; "
                         "fix: detect='nee', or first_order='mc' for analog detection")


class FirstOrderRunner:
    """The deterministic first order on a :class:`~clsim.transport.simulator.Simulator`'s device
    (its context, queue and uploaded scene)."""

    def __init__(self, simulator):
        self.sim = simulator
        self._programs = {}

    def program(self, wood_dir: bool):
        if wood_dir not in self._programs:
            from clsim.transport.simulator import build_options

            kdir = resources.files("clsim") / "kernels"
            src = (kdir / "first_order.cl").read_text()
            opts = [f"-I{kdir}"] + [o for o in build_options(self.sim.info, "exact", "nee", wood_dir=wood_dir,
                                                             fast_math=self.sim.fast_math)
                                    if not o.startswith(("-DMODE", "-DDETECT", "-DTRACE"))]
            t0 = time.perf_counter()
            try:
                prg = build_program(self.sim.context, src, opts)
            except self.sim._cl.Error as err:
                raise DeviceError(f"the first-order kernel does not build on {self.sim.device_name}: "
                                  f"{short_reason(err)}; fix: --first-order mc, or another device") from err
            self.sim.build_seconds += time.perf_counter() - t0
            self._programs[wood_dir] = (self.sim._cl.Kernel(prg, "first_order"),
                                        self.sim._cl.Kernel(prg, "digitize_rows"))
        return self._programs[wood_dir]

    def run(self, scene_setup: SceneSetup, grid: FirstOrderGrid, sensor: Sensor, samples, *,
            hotspot: bool = False, fine: bool = False):
        """The batch's digitised order-1 waveforms ``(N, S)`` (received power per emitted energy per
        ns, S the longest), the energies ``(N,)``, what fell outside the fine grid ``(N,)`` and the
        kernel seconds; with ``fine`` also the fine energies ``(N, 2, F)`` (vegetation, ground)."""
        cl = self.sim._cl
        ctx, q = self.sim.context, self.sim.queue
        mf = cl.mem_flags
        bufs = self.sim._scene_buffers(_ShimSetup(scene_setup))
        k_fo, k_dig = self.program(scene_setup.bricks.wdir is not None)
        n, F = len(grid.records), grid.nbins
        S = int(grid.n_samples.max()) if n else 0
        area = sensor.aperture_area_m2
        smp = np.zeros((len(samples), 4), dtype=np.float32)
        smp[:, :3] = samples
        taps, lag0 = pulse_kernel(grid.dt_ns, sensor.pulse_fwhm_ns)
        params = _params(scene_setup, sensor, grid, hotspot)
        try:
            pb = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=params)
            recb = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=np.ascontiguousarray(grid.records))
            sb = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=smp)
            tb = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=taps.astype(np.float32))
            otb = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR,
                            hostbuf=outward_tables(scene_setup.ppf).astype(np.float32))
            fb = cl.Buffer(ctx, mf.READ_WRITE, size=max(4, n * 2 * F * 4))
            ob = cl.Buffer(ctx, mf.WRITE_ONLY, size=max(4, n * 4))
            wb = cl.Buffer(ctx, mf.WRITE_ONLY, size=max(4, n * S * 4))
            eb = cl.Buffer(ctx, mf.WRITE_ONLY, size=max(4, n * 4))
        except cl.Error as err:
            raise DeviceError(f"cannot allocate the first order's {n * 2 * F * 4 / 2**20:.0f} MiB of fine bins on "
                              f"{self.sim.device_name}: {short_reason(err)}; fix: a smaller --batch-size") from err
        wave = np.zeros((n, S), dtype=np.float32)
        energy = np.zeros(n, dtype=np.float32)
        out = np.zeros(n, dtype=np.float32)
        fine_h = np.zeros((n, 2, F), dtype=np.float32) if fine else None
        t0 = time.perf_counter()
        if n:
            try:
                k_fo(q, (n,), None, pb, bufs["index"], bufs["boxes"], bufs["pool"], bufs["ppf"], bufs["gtab"],
                     bufs["wdir"], recb, sb, np.uint32(len(smp)), np.float32(leaf_cos2(scene_setup.ppf)), otb,
                     fb, ob, np.uint32(n))
                k_dig(q, (n,), None, pb, fb, tb, np.int32(len(taps)), np.int32(lag0), np.int32(grid.k),
                      np.int32(S), wb, eb, np.uint32(n))
                cl.enqueue_copy(q, wave, wb)
                cl.enqueue_copy(q, energy, eb)
                cl.enqueue_copy(q, out, ob)
                if fine:
                    cl.enqueue_copy(q, fine_h, fb)
                q.finish()
            except cl.Error as err:
                raise DeviceError(f"first-order kernel failed on {self.sim.device_name}: {err}") from err
        elapsed = time.perf_counter() - t0
        res: tuple = (wave.astype(np.float64) * area, energy.astype(np.float64) * area,
                      out.astype(np.float64) * area, elapsed)
        if fine_h is not None:
            res += (fine_h.astype(np.float64) * area,)
        return res


class _ShimSetup:
    """What :meth:`Simulator._scene_buffers` reads of a run set-up, from a scene set-up."""

    def __init__(self, scene_setup: SceneSetup):
        self.bricks, self.ppf, self.gtab = scene_setup.bricks, scene_setup.ppf, scene_setup.gtab


# -- the NumPy float64 oracle ------------------------------------------------------------
def _segments(shape, h, o, d, t_lim):
    """Voxel segments (ta, tb, (i, j, k)) of the ray o + t d, 0 <= t <= t_lim, through a grid of
    ``shape`` voxels of size ``h`` at the origin (Amanatides & Woo), float64."""
    L = np.asarray(shape) * h
    t0, t1 = 0.0, float(t_lim)
    for a in range(3):
        if abs(d[a]) < 1e-20:
            if not 0.0 <= o[a] <= L[a]:
                return
        else:
            ta, tb = (0.0 - o[a]) / d[a], (L[a] - o[a]) / d[a]
            t0, t1 = max(t0, min(ta, tb)), min(t1, max(ta, tb))
    if not t0 < t1:
        return
    v = np.clip(np.floor((o + d * t0) / h).astype(np.int64), 0, np.asarray(shape) - 1)
    step = np.sign(d).astype(np.int64)
    t = t0
    while t < t1 and np.all((v >= 0) & (v < shape)):
        with np.errstate(divide="ignore"):
            tf = np.where(step == 0, np.inf, ((v + (step > 0)) * h - o) / np.where(d == 0, 1.0, d))
        ax = int(np.argmin(tf))
        tb = min(float(tf[ax]), t1)
        if tb > t:
            yield t, tb, tuple(v)
        t = max(t, tb)
        v[ax] += step[ax]


def _wood_parts(q, sw, d, R_w):
    """The wood's (cylinder, facet) extinction along d and the cylinder part's backscatter per unit
    extinction (kernels/first_order.cl ``wood_back``), float64; ``q`` the voxel's (axis, beta)."""
    if q is None or sw <= 0:
        return np.array([0.0, sw]), 0.0
    ca = abs(q[:3] @ d)
    sp = math.sqrt(max(0.0, 1 - ca * ca))
    if q[3] < 0:
        cap = -1 - q[3]
        end, side = cap * ca, (1 - cap) * sp / np.pi
        fc = (end * R_w * ca / np.pi + side * R_w * sp / 4) / (end + side) if end + side > 0 else 0.0
        return np.array([sw, 0.0]), fc
    return np.array([sw * q[3] * 4 / np.pi * sp, sw * (1 - q[3])]), R_w * sp / 4


def _outward_direct(theta, wts, rel, d):
    """(G, E[(n . d)^2]) of outward-facing leaves at ``rel`` (from the crown centre), straight from
    the zenith table ``theta`` with trapezoid weights ``wts`` (no beta table)."""
    rr = math.hypot(rel[0], rel[1])
    cp, sp = (rel[0] / rr, rel[1] / rr) if rr > 0 else (1.0, 0.0)
    nd = np.sin(theta) * (d[0] * cp + d[1] * sp) + np.cos(theta) * d[2]
    return float(wts @ np.abs(nd)), float(wts @ nd**2)


def _deposit_exact(h, n_bins, ta, tb, k, amp, s0, bins_per_m):
    """amp exp(-k (s - ta)) / s^2 over [ta, tb] into the bins of h, each bin's piece by a 9-point
    trapezoid rule (the kernel: exactly in the exponential, 1 / s^2 at the piece's middle)."""
    first = math.floor((ta - s0) * bins_per_m)
    edges = np.clip(s0 + np.arange(first, math.floor((tb - s0) * bins_per_m) + 2) / bins_per_m, ta, tb)
    sm = np.linspace(0, 1, 9)
    for bi, (x0, x1) in enumerate(zip(edges[:-1], edges[1:])):
        if x1 > x0 and 0 <= first + bi < n_bins:
            ss = x0 + (x1 - x0) * sm
            f = amp * np.exp(-k * (ss - ta)) / ss**2
            h[first + bi] += float(np.sum(0.5 * (f[1:] + f[:-1])) * (x1 - x0) / 8)


def first_order_reference(scene_setup: SceneSetup, grid: FirstOrderGrid, sensor: Sensor, samples, *,
                          hotspot: bool = False) -> np.ndarray:
    """The fine energies ``(N, 2, F)`` of :class:`FirstOrderRunner` in float64 on a dense grid: the
    same integral, computed independently of the device (tests compare the two)."""
    scene = scene_setup.scene
    scene = scene.to_scene() if hasattr(scene, "to_scene") else scene
    lad, sw, _ = extinction(scene, leaf_off=scene_setup.leaf_off)
    shape = tuple(int(s) for s in scene.shape)
    ext = np.zeros(shape + (2,))
    i, j, k = scene.ijk.T
    ext[i, j, k, 0], ext[i, j, k, 1] = lad, sw
    wd = wood_direction(scene)
    wdir = None
    if wd is not None:
        wdir = np.zeros(shape + (4,))
        wdir[i, j, k] = wd.astype(np.float32)
    p = _params(scene_setup, sensor, grid, hotspot)[0]
    c2 = leaf_cos2(scene_setup.ppf)
    gtab = np.asarray(scene_setup.gtab, dtype=np.float64)
    spherical = bool(p["leaf_avg"])
    R_l, R_w, R_g = float(p["leaf_R"]), float(p["wood_R"]), float(p["ground_R"])
    m = 1.0 if hotspot else 2.0
    h, F = float(scene.voxel_size), grid.nbins
    tan2 = float(p["tan2_fov"])
    ground = float(p["ground_z"]) if p["has_ground"] else None
    out = np.zeros((len(grid.records), 2, F))
    sig_b = float(p["beam_sigma"])
    outward, cc = bool(p["outward"]), np.asarray(p["crown_c"], dtype=np.float64)
    theta = np.asarray(scene_setup.ppf, dtype=np.float64)
    wts = np.full(len(theta), 1.0 / (len(theta) - 1))
    wts[[0, -1]] *= 0.5
    for n, rec in enumerate(grid.records.astype(np.float64)):
        o, axis, e1, e2 = rec[0:3], rec[3:6], rec[6:9], rec[9:12]
        s0 = 0.5 * C_M_PER_NS * rec[12]
        n_bins = int(rec[13])         # the pulse's own window
        bins_per_m = 2.0 / (C_M_PER_NS * grid.dt_ns)
        for a, b, w in np.asarray(samples, dtype=np.float64):
            d = axis + sig_b * (a * e1 + b * e2)
            d /= np.linalg.norm(d)
            along = d @ axis
            if not (along > 0 and np.sum((d - along * axis) ** 2) <= tan2 * along**2):
                continue
            wgt = w * along
            mu = min(abs(d[2]), 1.0)
            gd = 0.5 if spherical else float(np.interp(mu, np.linspace(0, 1, NG), gtab))
            back = R_l / (3 * np.pi) if spherical else R_l / np.pi * (mu**2 * c2 + (1 - mu**2) * (1 - c2) / 2)
            tg = np.inf if ground is None or d[2] >= 0 else max(0.0, (ground - o[2]) / d[2])
            od = 0.0
            for ta, tb, v in _segments(shape, h, o, d, tg):
                lad_v, sw_v = ext[v]
                parts, fc = _wood_parts(None if wdir is None else wdir[v], sw_v, d, R_w)
                pieces = max(1, math.ceil((tb - ta) / h)) if outward and lad_v > 0 else 1
                for a0 in range(pieces):
                    pa, pb = ta + (tb - ta) * a0 / pieces, ta + (tb - ta) * (a0 + 1) / pieces
                    gl, bl = gd, back
                    if outward:
                        gl, q2 = _outward_direct(theta, wts, o + d * 0.5 * (pa + pb) - np.append(cc, 0.0), d)
                        bl = R_l / np.pi * q2
                    sig = lad_v * gl + parts.sum()
                    phi = lad_v * bl + parts[1] * R_w * 2 / (3 * np.pi) + parts[0] * fc
                    if phi > 0 and sig > 0:
                        _deposit_exact(out[n, 0], n_bins, pa, pb, m * sig, wgt * phi * math.exp(-m * od), s0, bins_per_m)
                    od += sig * (pb - pa)
                if od > 40:
                    break
            if np.isfinite(tg) and od <= 40:
                idx = int(math.floor((tg - s0) * bins_per_m))
                if 0 <= idx < n_bins:
                    out[n, 1, idx] += wgt * R_g / np.pi * (-d[2]) * math.exp(-m * od) / tg**2
    return out * sensor.aperture_area_m2

