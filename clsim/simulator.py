"""Run the OpenCL photon transport: :class:`Simulator` and its result.

Examples
--------
>>> from clsim import testscenes
>>> from clsim.sensor import Sensor
>>> sim = Simulator()                      # VOXLIDAR_DEVICE, PYOPENCL_CTX or the best working device
>>> res = sim.run(testscenes.ground_only(), Sensor.preset("ahab-chiroptera-i"),
...               photons=4096, seed=1, max_order=1)
>>> e, se = res.energy(kind="ground")                     # (A / R^2) rho_g / pi
>>> bool(abs(e / (Sensor().aperture_area_m2 / 360.0**2 * 0.30 / np.pi) - 1) < 1e-3)
True
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

import numpy as np
from tlsvox.scene import Scene, atomic_write
from voxlidar.devices import (DeviceInfo, build_program, choose_device, describe, device_report,
                              open_queue, short_reason)
from voxlidar.errors import DeviceError as AnyDeviceError
from voxlidar.safeio import json_text

from .bricks import BRICK, BrickGrid, build_bricks
from .choices import Choice
from .errors import DeviceError, InputError
from .rng import split_seed
from .sensor import C_M_PER_NS, Sensor
from .waveform import digitize, fine_edges

__all__ = ["Simulator", "SimulationResult", "Mode", "Detect", "RunSetup", "prepare_run",
           "PARAMS_DTYPE", "STAT_NAMES", "build_options", "list_devices", "working_devices"]

NTAB = 4097
NG = 1025
TRACE_EVENTS = 16
FIXED_SCALE = 2.0**32
STAT_NAMES = ("escaped_up", "escaped_down", "absorbed", "truncated", "rr_killed", "rr_added",
              "ground_direct", "outside_window", "detections", "voxel_steps", "events",
              "shadow_rays")
#: stats that are counts, not weights
COUNT_STATS = ("detections", "voxel_steps", "events", "shadow_rays")

PARAMS_DTYPE = np.dtype([
    ("sensor", "<f4", 3), ("axis", "<f4", 3), ("e1", "<f4", 3), ("e2", "<f4", 3),
    ("beam_sigma", "<f4"), ("tan2_fov", "<f4"), ("virt_r2", "<f4"), ("norm_nee", "<f4"),
    ("norm_analog", "<f4"), ("h", "<f4"), ("shape", "<i4", 3), ("bshape", "<i4", 3),
    ("ground_z", "<f4"), ("has_ground", "<i4"), ("leaf_R", "<f4"), ("leaf_T", "<f4"),
    ("wood_R", "<f4"), ("wood_T", "<f4"), ("ground_R", "<f4"), ("crown_c", "<f4", 2),
    ("outward", "<i4"), ("ds", "<f4"), ("t0_ns", "<f4"), ("dt_ns", "<f4"), ("nbins", "<i4"),
    ("max_order", "<i4"), ("n_batches", "<i4"), ("n_trace", "<i4"), ("hotspot", "<i4"),
])


class Mode(Choice):
    """Interaction model: ``exact`` free flight with thinning, or the ``paper``'s fixed step."""

    EXACT = "exact"
    PAPER = "paper"


class Detect(Choice):
    """Detection: ``nee`` next-event estimation, or ``analog`` photons through the aperture."""

    NEE = "nee"
    ANALOG = "analog"


def _onb(n):
    """Duff et al. (2017) orthonormal basis, float64 (same formula as geometry.cl)."""
    s = math.copysign(1.0, n[2])
    a = -1.0 / (s + n[2])
    b = n[0] * n[1] * a
    return (np.array([1.0 + s * n[0] * n[0] * a, s * b, -s * n[0]]),
            np.array([b, s + n[1] * n[1] * a, -n[1]]))


@dataclass
class RunSetup:
    """Everything a transport needs for one run (shared by kernel and oracle)."""

    scene: Scene
    sensor: Sensor
    mode: Mode
    detect: Detect
    photons: int
    seed: int
    max_order: int
    batches: int
    leaf_off: bool
    params: np.ndarray  # one record of PARAMS_DTYPE
    bricks: BrickGrid
    ppf: np.ndarray  # (NTAB,) float64 leaf zenith inverse CDF
    gtab: np.ndarray  # (NG,) float64 G(theta) at |cos theta| = linspace(0, 1, NG)
    edges_ns: np.ndarray
    range_ref_m: float
    flags: list
    settings: dict
    trace: int = 0

    @property
    def p(self):
        return self.params[0]


def _int_arg(name, value, lo, hi):
    try:
        v = int(value)
    except (TypeError, ValueError) as err:
        raise InputError(f"{name} must be an integer in [{lo}, {hi}], got {value!r}") from err
    if v != value or not lo <= v <= hi:
        raise InputError(f"{name} must be an integer in [{lo}, {hi}], got {value!r}")
    return v


def prepare_run(scene: Scene, sensor: Sensor, *, photons: int, seed: int, mode="exact",
                detect="nee", max_order: int = 3, leaf_off: bool = False, batches: int = 16,
                bin_ns: float = 0.05, step_m: float = 0.02, target=None, trace: int = 0,
                hotspot: bool = False) -> RunSetup:
    """Check the inputs and build the run's parameters (see :meth:`Simulator.run`)."""
    if not isinstance(scene, Scene):
        raise InputError(f"scene must be a tlsvox.scene.Scene (Scene.load(path)), got {type(scene).__name__}")
    if not isinstance(sensor, Sensor):
        raise InputError(f"sensor must be a clsim.Sensor (Sensor.preset(name)), got {type(sensor).__name__}")
    mode = Mode.parse(mode, "mode")
    detect = Detect.parse(detect, "detect")
    photons = _int_arg("photons", photons, 1, 2**40)
    max_order = _int_arg("max_order", max_order, 1, 64)
    batches = _int_arg("batches", batches, 1, 4096)
    trace = _int_arg("trace", trace, 0, 100_000)
    split_seed(seed)
    if not (np.isfinite(bin_ns) and 0.001 <= bin_ns <= 1.0):
        raise InputError(f"bin_ns must lie in [0.001, 1] ns, got {bin_ns!r}")
    if not (np.isfinite(step_m) and 1e-4 <= step_m <= scene.voxel_size * 10):
        raise InputError(f"step_m (paper-mode step) must lie in [1e-4, 10 voxels] m, got {step_m!r}")
    flags = []
    wl = sensor.wavelength_nm
    optics = {}
    for mat in ("leaf", "bark", "ground"):
        r, t = scene.optics(mat, wl)
        if min(r, t) < 0 or r + t > 1 + 1e-9:
            raise InputError(
                f"scene optics of {mat} at {wl:g} nm: R={r}, T={t}; need R, T >= 0 and R + T <= 1. "
                f"Fix scene.materials[{mat!r}][{str(int(round(wl)))!r}]"
            )
        optics[mat] = (r, t)
    bricks = build_bricks(scene, leaf_off=leaf_off)
    if bricks.flags.get("wood_probability_capped"):
        flags.append(f"wood probability 1 capped at 1-1e-6 in {bricks.flags['wood_probability_capped']} voxels")

    lo = scene.origin
    hi = scene.origin + scene.voxel_size * np.asarray(scene.shape)
    ground = scene.ground_z
    if target is None:
        target = np.array([0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1]), lo[2] if ground is None else ground])
    else:
        t = np.asarray(target, dtype=np.float64).ravel()
        if t.size == 2:
            t = np.append(t, lo[2] if ground is None else ground)
        if t.shape != (3,) or not np.all(np.isfinite(t)):
            raise InputError(f"target must be (x, y) or (x, y, z) in metres, got {target!r}")
        target = t
    S = sensor.position(target)
    top = max(hi[2], ground if ground is not None else -np.inf)
    if S[2] <= top:
        raise InputError(
            f"the sensor is at z = {S[2]:.2f} m, not above the scene (top {top:.2f} m, "
            f"ground {ground}); raise altitude_m (now {sensor.altitude_m}) or lower off_nadir_deg"
        )
    axis = sensor.beam_axis()
    e1, e2 = _onb(axis)
    R_ref = sensor.range_m

    # time window: nearest point of the box .. farthest corner / ground + wandering
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    near = np.linalg.norm(np.maximum(np.maximum(lo - S, 0.0), S - hi))
    far = np.linalg.norm(corners - S, axis=1).max()
    if ground is not None:
        near = min(near, (S[2] - ground))
        far = max(far, np.linalg.norm(target - S) + 0.0)
    diag = float(np.linalg.norm(hi - lo))
    t_start = 2.0 * near / C_M_PER_NS - 2.0 * sensor.pulse_fwhm_ns
    t_end = 2.0 * far / C_M_PER_NS + (2.0 * diag if max_order > 1 else 0.0) / C_M_PER_NS \
        + 2.0 * sensor.pulse_fwhm_ns
    t_start = math.floor(t_start / bin_ns) * bin_ns
    edges = fine_edges(t_start, t_end, bin_ns)

    rec = np.zeros(1, dtype=PARAMS_DTYPE)
    r = rec[0]
    r["sensor"] = S - lo
    r["axis"] = axis
    r["e1"] = e1
    r["e2"] = e2
    r["beam_sigma"] = 0.5e-3 * sensor.divergence_mrad
    r["tan2_fov"] = math.tan(1e-3 * sensor.fov_mrad) ** 2
    r["virt_r2"] = (0.5 * sensor.virtual_aperture_m) ** 2
    r["norm_nee"] = R_ref**2
    r["norm_analog"] = R_ref**2 / sensor.virtual_aperture_area_m2
    r["h"] = scene.voxel_size
    r["shape"] = scene.shape
    r["bshape"] = bricks.brick_shape
    r["ground_z"] = 0.0 if ground is None else ground - lo[2]
    r["has_ground"] = ground is not None
    r["leaf_R"], r["leaf_T"] = optics["leaf"]
    r["wood_R"], r["wood_T"] = optics["bark"]
    r["ground_R"] = optics["ground"][0]
    r["crown_c"] = scene.crown_center - lo[:2]
    r["outward"] = scene.leaf_azimuth == "outward"
    r["ds"] = step_m
    r["t0_ns"] = edges[0]
    r["dt_ns"] = bin_ns
    r["nbins"] = len(edges) - 1
    r["max_order"] = max_order
    r["n_batches"] = batches
    r["n_trace"] = trace
    r["hotspot"] = bool(hotspot)

    ppf = scene.leaf_angle.ppf(np.linspace(0.0, 1.0, NTAB)).astype(np.float64)
    gtab = np.asarray(scene.leaf_angle.G(np.arccos(np.linspace(0.0, 1.0, NG))), dtype=np.float64)
    if sensor.fov_mrad < sensor.divergence_mrad:
        flags.append(f"receiver FOV ({sensor.fov_mrad} mrad) is narrower than the beam divergence "
                     f"({sensor.divergence_mrad} mrad): part of the footprint is not seen")
    if hotspot and detect is Detect.ANALOG:
        flags.append("hotspot applies to next-event estimation only; analog detection keeps the "
                     "turbid (independent) return path")
    if photons < batches:
        flags.append(f"photons ({photons}) < batches ({batches}): standard errors use fewer batches")
    settings = dict(
        mode=mode.value, detect=detect.value, photons=photons, seed=int(seed), max_order=max_order,
        hotspot=bool(hotspot),
        leaf_off=bool(leaf_off), batches=batches, bin_ns=bin_ns, step_m=step_m,
        sensor=sensor.to_dict(), target=target.tolist(), sensor_position=S.tolist(),
        range_ref_m=R_ref, optics={k: list(v) for k, v in optics.items()},
        scene=dict(origin=lo.tolist(), voxel_size=scene.voxel_size, shape=list(scene.shape),
                   n_voxels=scene.n_voxels, leaf_angle=scene.leaf_angle.to_dict(),
                   leaf_azimuth=scene.leaf_azimuth, ground_z=ground, meta=scene.meta),
    )
    return RunSetup(scene=scene, sensor=sensor, mode=mode, detect=detect, photons=photons,
                    seed=int(seed), max_order=max_order, batches=batches, leaf_off=bool(leaf_off),
                    params=rec, bricks=bricks, ppf=ppf, gtab=gtab, edges_ns=edges, range_ref_m=R_ref,
                    flags=flags, settings=settings, trace=trace)


@dataclass
class SimulationResult:
    """A simulated waveform with its Monte Carlo statistics.

    Attributes
    ----------
    time_ns : (S,) float64
        Sample times after emission, ns, at the sensor's sampling rate.
    waveform : (S,) float64
        Received power, fraction of the emitted energy per ns (all orders).
    by_order : (K, S) float64
        ``waveform`` split by scattering order (row 0: single scattering).
    fine_edges_ns : (F+1,) float64
        Edges of the fine time bins.
    fine : (K, 2, F) float64
        Energy per fine bin (fraction of emitted energy) by order and by the
        material of the last scattering (0 vegetation, 1 ground), before the
        pulse convolution.
    fine_batches : (B, K, 2, F) float64
        The same per batch (photon id modulo B), each normalised by its own
        photon count; the spread gives standard errors.
    batch_photons : (B,) int
    stats : dict of (B,) float64
        Per-batch photon fates (weights per launched photon; counts for
        ``detections``, ``voxel_steps``, ``events``, ``shadow_rays``).
    settings : dict
    flags : list of str
        Things a user should know about this result.
    traces : (P, 16, 4) float32 or None
        First events (x, y, z in world metres, type) of the first P photons;
        type -2 launch, 0 escape, 1 leaf, 2 wood, 3 ground, -1 absorbed, -9 unused.
    elapsed_s : float
    """

    time_ns: np.ndarray
    waveform: np.ndarray
    by_order: np.ndarray
    fine_edges_ns: np.ndarray
    fine: np.ndarray
    fine_batches: np.ndarray
    batch_photons: np.ndarray
    stats: dict
    settings: dict
    flags: list = field(default_factory=list)
    traces: np.ndarray | None = None
    elapsed_s: float = 0.0

    _KINDS = {None: slice(None), "vegetation": 0, "ground": 1}

    def _batch_values(self, values):
        """(B,) per-photon estimates -> (mean, standard error)."""
        v = np.asarray(values, dtype=np.float64)
        n = self.batch_photons
        ok = n > 0
        mean = float(np.sum(v[ok] * n[ok]) / n[ok].sum())
        se = float(np.std(v[ok], ddof=1) / math.sqrt(ok.sum())) if ok.sum() > 1 else math.nan
        return mean, se

    def energy(self, order=None, kind=None) -> tuple[float, float]:
        """Received energy (fraction of emitted) and its standard error.

        Parameters
        ----------
        order : int or None
            Scattering order (1 = single); None for all.
        kind : {"vegetation", "ground", None}
            Material of the last scattering event; None for both.
        """
        if kind not in self._KINDS:
            raise InputError(f"kind={kind!r} must be one of vegetation, ground, None")
        fb = self.fine_batches
        if order is not None:
            if not 1 <= order <= fb.shape[1]:
                raise InputError(f"order={order!r} must lie in 1..{fb.shape[1]}")
            fb = fb[:, order - 1 : order]
        per = fb[:, :, self._KINDS[kind]].reshape(fb.shape[0], -1).sum(axis=1)
        return self._batch_values(per)

    def stat(self, name: str) -> tuple[float, float]:
        """A photon-fate statistic per launched photon (or total count) and its standard error."""
        if name not in self.stats:
            raise InputError(f"stat {name!r} unknown; have {sorted(self.stats)}")
        if name in COUNT_STATS:
            return float(np.sum(self.stats[name])), math.nan
        return self._batch_values(self.stats[name])

    @property
    def photons_per_second(self) -> float:
        return self.settings["photons"] / self.elapsed_s if self.elapsed_s > 0 else math.nan

    def save(self, path) -> Path:
        """Write ``time_ns``, ``waveform``, ``by_order``, the fine histograms and settings as NPZ."""
        arrays = dict(time_ns=self.time_ns, waveform=self.waveform, by_order=self.by_order,
                      fine_edges_ns=self.fine_edges_ns, fine=self.fine,
                      batch_photons=self.batch_photons,
                      settings=np.str_(json_text(self.settings)),
                      flags=np.str_(json_text(self.flags)),
                      **{f"stat_{k}": v for k, v in self.stats.items()})
        if self.traces is not None:
            arrays["traces"] = self.traces

        def write(tmp):
            with open(tmp, "wb") as fh:
                np.savez_compressed(fh, **arrays)

        return atomic_write(path, write)


def assemble_result(setup: RunSetup, hist, stats, traces, elapsed: float, device: str) -> SimulationResult:
    """Turn raw tallies into a :class:`SimulationResult`.

    ``hist`` (B, K, 2, F) and ``stats`` (B, NSTAT) are in tally units: NEE in
    units of A / R_ref^2 per launched photon, weights per launched photon.
    """
    B = setup.batches
    n_b = np.array([setup.photons // B + (b < setup.photons % B) for b in range(B)], dtype=np.int64)
    scale = setup.sensor.aperture_area_m2 / setup.range_ref_m**2
    with np.errstate(invalid="ignore", divide="ignore"):
        inv = np.where(n_b > 0, 1.0 / np.maximum(n_b, 1), 0.0)
    fine_b = hist * scale * inv[:, None, None, None]
    fine = hist.sum(axis=0) * scale / setup.photons
    st = {}
    for i, name in enumerate(STAT_NAMES):
        v = stats[:, i].astype(np.float64)
        st[name] = v if name in COUNT_STATS else v * inv
    st["outside_window"] = st["outside_window"] * scale
    time_ns, by_order = digitize(setup.edges_ns, fine.sum(axis=1), sampling_ghz=setup.sensor.sampling_ghz,
                                 pulse_fwhm_ns=setup.sensor.pulse_fwhm_ns)
    flags = list(setup.flags)
    res = SimulationResult(time_ns=time_ns, waveform=by_order.sum(axis=0), by_order=by_order,
                           fine_edges_ns=setup.edges_ns, fine=fine, fine_batches=fine_b,
                           batch_photons=n_b, stats=st, settings=dict(setup.settings, device=device),
                           flags=flags, traces=traces, elapsed_s=elapsed)
    trunc, _ = res.stat("truncated")
    if trunc > 0.01:
        flags.append(f"{100 * trunc:.1f} % of the launched energy was still travelling at max_order="
                     f"{setup.max_order}; raise max_order for the higher orders")
    outside = float(np.sum(st["outside_window"] * n_b)) / setup.photons
    total = float(fine.sum())
    if outside > 1e-3 * max(total, 1e-300):
        flags.append(f"{outside:.3g} of received energy fell outside the time window")
    if B < 2 or (n_b > 0).sum() < 2:
        flags.append("fewer than 2 batches with photons: no standard errors (NaN)")
    if total == 0.0:
        flags.append("no energy reached the receiver")
    return res


# -- devices -----------------------------------------------------------------------
def list_devices() -> list[tuple[DeviceInfo, str | None]]:
    """Every OpenCL device found, best first, with None where it runs the
    transport kernel and the reason where it cannot (one build per device,
    cached; see :mod:`voxlidar.devices`)."""
    return [(info, verdict["clsim"]) for info, verdict in device_report(("clsim",))]


def working_devices() -> list[DeviceInfo]:
    """The devices that run the transport kernel, best first."""
    return [info for info, reason in list_devices() if reason is None]


def build_options(info: DeviceInfo, mode, detect, *, atomics64: bool | None = None,
                  fast_math: bool = True) -> list[str]:
    """``-D`` options of the transport kernel for a device, mode and detection.

    ``-cl-fast-relaxed-math`` is safe: the kernels create no infinity or NaN
    (kernels/common.cl).  64-bit atomics are used where the device has them
    (``atomics64=None``), else two 32-bit atomics with an exact carry."""
    mode = Mode.parse(mode, "mode")
    detect = Detect.parse(detect, "detect")
    use64 = info.int64_atomics if atomics64 is None else bool(atomics64) and info.int64_atomics
    opts = [f"-DMODE={1 if mode is Mode.PAPER else 0}", f"-DDETECT={1 if detect is Detect.ANALOG else 0}",
            f"-DBRICK={BRICK}", f"-DBRICK_SHIFT={BRICK.bit_length() - 1}", f"-DNTAB={NTAB}", f"-DNG={NG}",
            f"-DTRACE_EVENTS={TRACE_EVENTS}"]
    opts += ["-cl-fast-relaxed-math"] if fast_math else ["-cl-mad-enable", "-cl-no-signed-zeros"]
    if use64:
        opts.append("-DCLSIM_ATOM64")
    if info.runtime.startswith("PoCL"):
        opts.append("-DCLSIM_CLANG_BUILTINS")  # PoCL compiles with clang (kernels/common.cl)
    return opts


def _kernel_source() -> tuple[str, str]:
    kdir = resources.files("clsim") / "kernels"
    return (kdir / "transport.cl").read_text(), f"-I{kdir}"


def probe_build(device) -> str | None:
    """Build the transport kernel (exact, nee) on a ``pyopencl.Device``; the
    device layer's probe.  Raises on a build failure."""
    import pyopencl as cl

    info = describe(device)
    src, inc = _kernel_source()
    ctx = cl.Context([device])
    build_program(ctx, src, [inc] + build_options(info, Mode.EXACT, Detect.NEE))
    return None


class Simulator:
    """Owns an OpenCL context, queue and the built transport programs.

    Parameters
    ----------
    device : voxlidar.devices.DeviceInfo, pyopencl.Device, str or None
        ``"0:1"`` (platform:device), ``"cpu"``, ``"gpu"``, a name fragment,
        or None for ``VOXLIDAR_DEVICE`` / ``PYOPENCL_CTX`` / the best working
        device (:func:`voxlidar.devices.choose_device`).  Never prompts.
    atomics64 : bool or None
        Use 64-bit atomics where the device has them (None, True) or the
        exact two-word fallback (False; for tests).
    fast_math : bool
        Build with ``-cl-fast-relaxed-math`` (default; safe, the kernels make
        no infinity or NaN) or with only ``-cl-mad-enable`` (benchmarks).

    Raises
    ------
    DeviceError
        One line when no device can build the transport kernel, naming the
        devices, the reasons and the fix (and the NumPy fallback).
    """

    def __init__(self, device=None, *, atomics64: bool | None = None, fast_math: bool = True):
        try:
            import pyopencl as cl
        except ImportError as err:
            raise DeviceError("pyopencl is not installed; fix: pip install pyopencl, or run the NumPy "
                              "oracle clsim.transport_ref.ReferenceSimulator() (slow)") from err
        self._cl = cl
        try:
            self.info = choose_device(device, kernels=("clsim",))
        except AnyDeviceError as err:
            raise DeviceError(f"{err} (the NumPy oracle clsim.transport_ref.ReferenceSimulator() "
                              "needs no device)") from None
        self.device = self.info.device
        self.atomics64 = atomics64
        self.fast_math = bool(fast_math)
        try:
            self.context, self.queue = open_queue(self.info)
        except AnyDeviceError as err:
            raise DeviceError(str(err)) from None
        self._programs = {}
        self.build_seconds = 0.0
        # Work-group size of the launches.  On CPU runtimes one photon per work-group
        # (measured against the runtime's own choice: Intel's runtime x2.6, PoCL 3.1
        # +9 %, PoCL 3.0 -2 %; docs/benchmarks.md): photons diverge, so a group gains
        # nothing from running in lock step.  GPUs: the runtime's choice.
        self.local_size = None if self.info.is_gpu else (1,)

    @property
    def device_name(self) -> str:
        return self.info.label

    def program(self, mode: Mode, detect: Detect):
        """(program, kernel) built for a mode and detection (cached per Simulator)."""
        key = (Mode.parse(mode, "mode"), Detect.parse(detect, "detect"))
        if key not in self._programs:
            src, inc = _kernel_source()
            opts = [inc] + build_options(self.info, key[0], key[1], atomics64=self.atomics64,
                                         fast_math=self.fast_math)
            t0 = time.perf_counter()
            try:
                prg = build_program(self.context, src, opts)
            except self._cl.Error as err:
                raise DeviceError(f"the transport kernel does not build on {self.device_name}: "
                                  f"{short_reason(err)}; fix: choose another device (clsim devices)") from err
            self.build_seconds += time.perf_counter() - t0
            self._programs[key] = (prg, self._cl.Kernel(prg, "simulate"))
        return self._programs[key]

    def run(self, scene: Scene, sensor: Sensor, *, photons: int, seed: int, mode="exact",
            detect="nee", max_order: int = 3, leaf_off: bool = False, batches: int = 16,
            bin_ns: float = 0.05, step_m: float = 0.02, target=None, trace: int = 0,
            chunk: int = 1 << 20, progress: bool = False, hotspot: bool = False) -> SimulationResult:
        """Simulate one pulse of ``sensor`` over ``scene``.

        Parameters
        ----------
        scene : tlsvox.scene.Scene
        sensor : Sensor
        photons : int
            Photons launched (each carries 1/photons of the pulse energy).
        seed : int
            RNG seed; same seed and device give an identical result.
        mode : {"exact", "paper"}
            Interaction model (docs/method.md).
        detect : {"nee", "analog"}
            Detection: next-event estimation, or counting photons through the
            enlarged virtual aperture.
        max_order : int
            Highest scattering order simulated and recorded.
        leaf_off : bool
            Drop the leaves (wood and ground only).
        batches : int
            Photons are split into this many batches (photon id modulo
            batches) for standard errors.
        bin_ns : float
            Fine time bin, ns.
        step_m : float
            Step of the paper model, m.
        target : (2,) or (3,) float, optional
            Where the beam axis meets the ground (default: grid centre).
        trace : int
            Record the first events of this many photons.
        chunk : int
            Photons per kernel launch.
        progress : bool
            Show a tqdm progress bar.
        hotspot : bool
            Correlated return for single scattering: with a monostatic sensor
            the return path of an order-1 event retraces the incoming one,
            which was free, so its transmittance is 1 (exact for explicit
            leaves; a turbid medium would apply exp(-tau) twice).  Higher
            orders return independently.  See docs/method.md.
        """
        setup = prepare_run(scene, sensor, photons=photons, seed=seed, mode=mode, detect=detect,
                            max_order=max_order, leaf_off=leaf_off, batches=batches, bin_ns=bin_ns,
                            step_m=step_m, target=target, trace=trace, hotspot=hotspot)
        return self.run_setup(setup, chunk=chunk, progress=progress)

    def run_setup(self, setup: RunSetup, *, chunk: int = 1 << 20, progress: bool = False) -> SimulationResult:
        cl = self._cl
        _, kern = self.program(setup.mode, setup.detect)
        ctx, q = self.context, self.queue
        mf = cl.mem_flags
        p = setup.p
        B, K, F = setup.batches, setup.max_order, int(p["nbins"])
        g = setup.bricks
        pool = g.pool if len(g.pool) else np.zeros((1, 2), np.float32)
        bufs = dict(
            params=cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=setup.params),
            index=cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=g.index),
            pool=cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=np.ascontiguousarray(pool)),
            ppf=cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=setup.ppf.astype(np.float32)),
            gtab=cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=setup.gtab.astype(np.float32)),
        )
        hist = np.zeros(B * K * 2 * F, dtype=np.uint64)
        stats = np.zeros(B * len(STAT_NAMES), dtype=np.uint64)
        traces = np.full((max(setup.trace, 1) * TRACE_EVENTS, 4), np.nan, dtype=np.float32)
        traces[:, 3] = -9
        try:
            hist_buf = cl.Buffer(ctx, mf.READ_WRITE | mf.COPY_HOST_PTR, hostbuf=hist)
        except cl.Error as err:
            raise DeviceError(f"cannot allocate the {hist.nbytes / 2**20:.0f} MiB histogram on "
                              f"{self.device_name}; lower batches, max_order or raise bin_ns") from err
        stats_buf = cl.Buffer(ctx, mf.READ_WRITE | mf.COPY_HOST_PTR, hostbuf=stats)
        trace_buf = cl.Buffer(ctx, mf.READ_WRITE | mf.COPY_HOST_PTR, hostbuf=traces)
        lo, hi = split_seed(setup.seed)
        key = np.array([lo, hi], dtype=np.uint32).view(cl.cltypes.uint2)[0]
        chunk = max(1, int(chunk))
        bar = None
        if progress:
            from tqdm import tqdm

            bar = tqdm(total=setup.photons, unit="photon", unit_scale=True, desc="clsim")
        t0 = time.perf_counter()
        try:
            for start in range(0, setup.photons, chunk):
                n = min(chunk, setup.photons - start)
                kern(q, (n,), self.local_size, bufs["params"], bufs["index"], bufs["pool"], bufs["ppf"],
                     bufs["gtab"], hist_buf, stats_buf, trace_buf, key, np.uint64(start), np.uint32(n))
                if bar is not None:
                    q.finish()
                    bar.update(n)
            cl.enqueue_copy(q, hist, hist_buf)
            cl.enqueue_copy(q, stats, stats_buf)
            cl.enqueue_copy(q, traces, trace_buf)
            q.finish()
        except cl.Error as err:
            raise DeviceError(f"transport kernel failed on {self.device_name}: {err}") from err
        finally:
            if bar is not None:
                bar.close()
        elapsed = time.perf_counter() - t0
        stats = stats.reshape(B, len(STAT_NAMES)).astype(np.float64)
        weight_cols = [i for i, n in enumerate(STAT_NAMES) if n not in COUNT_STATS]
        stats[:, weight_cols] /= FIXED_SCALE
        tr = None
        if setup.trace:
            tr = traces.reshape(setup.trace, TRACE_EVENTS, 4).copy()
            tr[..., :3] += setup.scene.origin.astype(np.float32)
        return assemble_result(setup, hist.reshape(B, K, 2, F).astype(np.float64) / FIXED_SCALE,
                               stats, tr, elapsed, self.device_name)
