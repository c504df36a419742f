"""Run the OpenCL photon transport: :class:`Simulator` and its result.

Examples
--------
>>> from clsim.validation import testscenes
>>> from clsim.sensor import Sensor
>>> sim = Simulator()                      # VOXLIDAR_DEVICE, PYOPENCL_CTX or the best working device
>>> res = sim.run(testscenes.ground_only(), Sensor.preset("ahab-chiroptera-i"),
...               photons=4096, seed=1, max_order=1)
>>> e, se = res.energy(kind="ground")                     # (A / R^2) rho_g / pi
>>> bool(abs(e / (Sensor().aperture_area_m2 / 360.0**2 * 0.30 / np.pi) - 1) < 1e-3)
True
"""

from __future__ import annotations

import time
from importlib import resources

import numpy as np

from clsim.errors import DeviceError, InputError
from clsim.sensor import Sensor
from clsim.transport.bricks import BRICK, BrickGrid, bricks_key, build_bricks, uniform_records
from clsim.transport.result import PulseWaveforms, SimulationResult, assemble_result, digitized
from clsim.transport.rng import split_seed
from clsim.transport.setup import (
    COUNT_STATS,
    FIXED_SCALE,
    NG,
    NTAB,
    STAT_NAMES,
    TRACE_EVENTS,
    InteractionModel,
    PhotonTally,
    RunSetup,
    SceneSetup,
    prepare_run,
    prepare_scene,
)
from voxlidar.devices import DeviceInfo, build_program, choose_device, describe, device_report, open_queue, short_reason
from voxlidar.errors import DeviceError as AnyDeviceError
from voxlidar.scene import Scene

__all__ = ["PhotonTally", "InteractionModel", "PulseWaveforms", "RunSetup", "SceneSetup", "SimulationResult", "Simulator",
           "build_options", "list_devices", "prepare_run", "prepare_scene", "working_devices"]


# -- devices -----------------------------------------------------------------------
def list_devices() -> list[tuple[DeviceInfo, str | None]]:
    """Every OpenCL device found, best first, with None where it runs the
    transport kernel and the reason where it cannot (one build per device,
    cached; see :mod:`voxlidar.devices`)."""
    return [(info, verdict["clsim"]) for info, verdict in device_report(("clsim",))]


def working_devices() -> list[DeviceInfo]:
    """The devices that run the transport kernel, best first."""
    return [info for info, reason in list_devices() if reason is None]


#: Estimator features of the exact mode (docs/method.md, "Variance reduction") and ``uniform``,
#: the exact mode's crossing of uniform bricks in one segment (docs/method.md, "Uniform bricks");
#: all on by default.
FEATURES = ("tight", "leaf_avg", "qmc", "uniform")


def build_options(info: DeviceInfo, mode, detect, *, atomics64: bool | None = None,
                  fast_math: bool = True, wood_dir: bool = False, features: dict | None = None) -> list[str]:
    """``-D`` options of the transport kernel for a device, mode and detection.

    ``wood_dir`` builds the variant that reads each voxel's bark direction
    (scenes with ``wood_beta > 0``); without it the kernel is the
    direction-free one, bit for bit.

    ``-cl-fast-relaxed-math`` is safe: the kernels create no infinity or NaN
    (kernels/common.cl).  64-bit atomics are used where the device has them
    (``atomics64=None``), else two 32-bit atomics with an exact carry.
    ``features`` turns estimator features off (``{"qmc": False}``) to measure
    them; the NumPy oracle implements the defaults only."""
    feats = dict(features or {})
    unknown = sorted(set(feats) - set(FEATURES))
    if unknown:
        raise InputError(f"unknown estimator feature(s) {unknown}; choose from {list(FEATURES)}")
    mode = InteractionModel.parse(mode, "mode")
    detect = PhotonTally.parse(detect, "detect")
    use64 = info.int64_atomics if atomics64 is None else bool(atomics64) and info.int64_atomics
    opts = [f"-DMODE={1 if mode is InteractionModel.PAPER else 0}", f"-DDETECT={1 if detect is PhotonTally.ANALOG else 0}",
            f"-DBRICK={BRICK}", f"-DBRICK_SHIFT={BRICK.bit_length() - 1}", f"-DNTAB={NTAB}", f"-DNG={NG}",
            f"-DTRACE_EVENTS={TRACE_EVENTS}", f"-DWOOD_DIR={int(bool(wood_dir))}"]
    opts += ["-cl-fast-relaxed-math"] if fast_math else ["-cl-mad-enable", "-cl-no-signed-zeros"]
    opts += [f"-DCLSIM_{name.upper()}={int(bool(on))}" for name, on in sorted(feats.items())]
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
    build_program(ctx, src, [inc] + build_options(info, InteractionModel.EXACT, PhotonTally.NEE))
    return None


def _add_on_clock(a, ta: float, b, tb: float, period: float):
    """The sum of two waveforms sampled on one clock (first samples at ``ta``, ``tb``, multiples of
    ``period`` apart), over the span of both: (samples, first sample time)."""
    off = int(round((tb - ta) / period))
    lo, hi = min(0, off), max(len(a), off + len(b))
    out = np.zeros(hi - lo)
    out[-lo:-lo + len(a)] += a
    out[off - lo:off - lo + len(b)] += b
    return out, ta + lo * period


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
    features : dict, optional
        Estimator features to turn off, e.g. ``{"qmc": False}`` (benchmarks
        measure each; names in :data:`FEATURES`).  Default: all on.

    Attributes
    ----------
    photons_per_item : int
        Photons one work item runs: 16 on a CPU (the statistics' atomics are
        added once per item), 1 on a GPU.  The result does not depend on it,
        bit for bit.

    Raises
    ------
    DeviceError
        One line when no device can build the transport kernel, naming the
        devices, the reasons and the fix (and the NumPy fallback).
    """

    def __init__(self, device=None, *, atomics64: bool | None = None, fast_math: bool = True,
                 features: dict | None = None):
        try:
            import pyopencl as cl
        except ImportError as err:
            raise DeviceError("pyopencl is not installed; fix: pip install pyopencl, or run the NumPy "
                              "oracle clsim.transport.reference.ReferenceSimulator() (slow)") from err
        self._cl = cl
        try:
            self.info = choose_device(device, kernels=("clsim",))
        except AnyDeviceError as err:
            raise DeviceError(f"{err} (the NumPy oracle clsim.transport.reference.ReferenceSimulator() "
                              "needs no device)") from None
        self.device = self.info.device
        self.atomics64 = atomics64
        self.fast_math = bool(fast_math)
        self.features = dict(features or {})
        build_options(self.info, InteractionModel.EXACT, PhotonTally.NEE, features=self.features)  # checks the names
        try:
            self.context, self.queue = open_queue(self.info)
        except AnyDeviceError as err:
            raise DeviceError(str(err)) from None
        self._programs = {}
        self.build_seconds = 0.0
        # the last scene's bricks, keyed on bricks_key: repeated runs over one scene skip the build
        self._bricks_cache: tuple | None = None
        # Work-group size of the launches.  On CPU runtimes one photon per work-group
        # (measured against the runtime's own choice: Intel's runtime x2.6, PoCL 3.1
        # +9 %, PoCL 3.0 -2 %; docs/benchmarks.md): photons diverge, so a group gains
        # nothing from running in lock step.  GPUs: the runtime's choice.
        self.local_size = None if self.info.is_gpu else (1,)
        # Photons per work item: on CPU runtimes several, so that the statistics' atomics, which
        # contend between the cores, are added once per work item instead of once per photon
        # (docs/method.md, section 7); GPUs: one (their atomics are cheap, their items many).
        self.photons_per_item = 1 if self.info.is_gpu else 16
        # the device copies of the last scene uploaded, with the host arrays they were
        # made from (bricks, leaf tables): runs over one scene upload it once
        self._uploaded: tuple | None = None

    @property
    def device_name(self) -> str:
        return self.info.label

    def program(self, mode: InteractionModel, detect: PhotonTally, wood_dir: bool = False):
        """(program, kernel) built for a mode, detection and wood model (cached per Simulator)."""
        key = (InteractionModel.parse(mode, "mode"), PhotonTally.parse(detect, "detect"), bool(wood_dir))
        if key not in self._programs:
            src, inc = _kernel_source()
            opts = [inc] + build_options(self.info, key[0], key[1], atomics64=self.atomics64,
                                         fast_math=self.fast_math, wood_dir=key[2], features=self.features)
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
            chunk: int = 1 << 20, progress: bool = False, hotspot: bool = False,
            scene_setup: SceneSetup | None = None) -> SimulationResult:
        """Simulate one pulse of ``sensor`` over ``scene``.

        Parameters
        ----------
        scene : voxlidar.scene.Scene
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
        scene_setup : SceneSetup, optional
            The scene prepared once by :func:`~clsim.transport.setup.prepare_scene`
            for many runs over it: its bricks and tables are not rebuilt, and they
            are uploaded to the device once (this Simulator keeps the device copies
            of the last scene it ran).  The result is bit for bit the same.  A
            SceneSetup is a snapshot: prepare it again after changing the scene's
            arrays in place.
        """
        setup = prepare_run(scene, sensor, photons=photons, seed=seed, mode=mode, detect=detect,
                            max_order=max_order, leaf_off=leaf_off, batches=batches, bin_ns=bin_ns,
                            step_m=step_m, target=target, trace=trace, hotspot=hotspot,
                            scene_setup=scene_setup,
                            bricks=None if scene_setup is not None else self._cached_bricks(scene, leaf_off))
        return self.run_setup(setup, chunk=chunk, progress=progress)

    def _cached_bricks(self, scene, leaf_off) -> BrickGrid | None:
        """The bricks of a :class:`~voxlidar.scene.Scene`, reused while its
        :func:`~clsim.transport.bricks.bricks_key` stays the same (None for
        anything else: a plot keeps its own, and prepare_run checks the rest)."""
        if not isinstance(scene, Scene) or not isinstance(leaf_off, (bool, np.bool_)):
            return None
        key = bricks_key(scene, leaf_off=bool(leaf_off))
        if self._bricks_cache is None or self._bricks_cache[0] != key:
            self._bricks_cache = (key, build_bricks(scene, leaf_off=bool(leaf_off)))
        return self._bricks_cache[1]

    def run_pulses(self, scene: Scene, pulses, base: Sensor, *, photons: int, mode="exact", detect="nee",
                   max_order: int = 3, leaf_off: bool = False, batches: int = 1, bin_ns: float = 0.05,
                   step_m: float = 0.02, hotspot: bool = False, chunk: int = 1 << 20,
                   progress: bool = False, scene_setup: SceneSetup | None = None,
                   first_order: str = "mc", beam_samples: int = 19) -> PulseWaveforms:
        """Simulate every pulse of a survey over one scene: the waveforms in the sensor's samples.

        Pulse ``i`` is ``base`` placed by ``pulses.sensor(i, base)``, aimed at
        ``pulses.target[i]`` and seeded with ``pulses.seed[i]``: its waveform is
        bit for bit the ``waveform`` of :meth:`run` with those arguments (and
        the same ``batches``).  What depends on the scene alone (bricks, leaf
        angle tables, optics; :func:`~clsim.transport.setup.prepare_scene`) is
        built and uploaded to the device once.

        Parameters
        ----------
        scene : voxlidar.scene.Scene
        pulses : clsim.survey.Pulses
        base : Sensor
            The instrument; its angles and altitude are replaced per pulse.
        photons : int
            Photons per pulse.
        batches : int
            Photon batches per pulse (see :meth:`run`); 1 by default since a
            survey keeps no per-pulse standard errors, and the tallies are
            ``batches`` times smaller.
        scene_setup : SceneSetup, optional
            Reuse one built by :func:`~clsim.transport.setup.prepare_scene` (a
            worker running many batches over the same scene).
        mode, detect, max_order, leaf_off, bin_ns, step_m, hotspot, chunk
            As :meth:`run`.
        progress : bool
            A tqdm bar over the pulses.
        first_order : {"mc", "deterministic"}
            How the single-scattering return is computed: by the photons (``"mc"``), or integrated
            along ``beam_samples`` fixed directions through the beam, every pulse of the call in
            one kernel launch and digitised on the device (``"deterministic"``;
            :mod:`clsim.transport.first_order`, docs/method.md): no Monte Carlo noise, and with
            ``max_order=1`` no photons at all (``photons`` is then unused).  Higher orders stay
            Monte Carlo.  Needs ``mode="exact"`` and ``detect="nee"``.
        beam_samples : int
            Directions through the beam of the deterministic first order (a sunflower spiral of
            equal weights; :func:`~clsim.transport.first_order.beam_samples`).

        Returns
        -------
        PulseWaveforms
        """
        from clsim.survey import Pulses

        if not isinstance(pulses, Pulses):
            raise InputError(f"pulses must be clsim.survey.Pulses (survey_pulses(...)), got {type(pulses).__name__}")
        if not isinstance(base, Sensor):
            raise InputError(f"base must be a clsim.Sensor (Sensor.preset(name)), got {type(base).__name__}")
        if first_order not in ("mc", "deterministic"):
            raise InputError(f"first_order must be 'mc' or 'deterministic', got {first_order!r}")
        if scene_setup is None:
            scene_setup = prepare_scene(scene, wavelength_nm=base.wavelength_nm, leaf_off=leaf_off,
                                        bricks=self._cached_bricks(scene, leaf_off))
        if first_order == "deterministic":
            return self._run_pulses_first_order(scene, pulses, base, scene_setup, photons=photons, mode=mode,
                                                detect=detect, max_order=max_order, batches=batches,
                                                bin_ns=bin_ns, step_m=step_m, hotspot=hotspot, chunk=chunk,
                                                progress=progress, beam_samples=beam_samples)
        n = len(pulses)
        rows, t0, energy = [], np.zeros(n), np.zeros(n)
        bufs, bar, kernel_s = None, None, 0.0
        if progress:
            from tqdm import tqdm

            bar = tqdm(total=n, unit="pulse", desc="clsim")
        try:
            for i in range(n):
                setup = prepare_run(scene, pulses.sensor(i, base), photons=photons, seed=int(pulses.seed[i]),
                                    mode=mode, detect=detect, max_order=max_order, leaf_off=leaf_off,
                                    batches=batches, bin_ns=bin_ns, step_m=step_m, target=pulses.target[i],
                                    hotspot=hotspot, scene_setup=scene_setup)
                if bufs is None:
                    bufs = self._scene_buffers(setup)
                hist, _, _, elapsed = self._launch(setup, bufs, chunk=chunk, hist_only=True)
                kernel_s += elapsed
                time_ns, by_order, fine = digitized(setup, hist.astype(np.float64) / FIXED_SCALE)
                rows.append(by_order.sum(axis=0))
                t0[i] = time_ns[0]
                energy[i] = fine.sum()
                if bar is not None:
                    bar.update(1)
        finally:
            if bar is not None:
                bar.close()
        return PulseWaveforms.from_rows(pulses.index, rows, t0_ns=t0, bin_ns=1.0 / base.sampling_ghz,
                                        energy=energy, kernel_s=kernel_s)

    def _run_pulses_first_order(self, scene, pulses, base: Sensor, scene_setup: SceneSetup, *, photons, mode,
                                detect, max_order, batches, bin_ns, step_m, hotspot, chunk, progress,
                                beam_samples) -> PulseWaveforms:
        """:meth:`run_pulses` with the deterministic first order: one launch for the order-1
        waveforms of all the pulses; orders 2 and up by the photons, pulse by pulse, their order-1
        tallies skipped, added on the same sample clock."""
        from clsim.transport import first_order as fo

        fo.check_first_order(mode=mode, detect=detect)
        samples = fo.beam_samples(beam_samples)
        if getattr(self, "_first_order", None) is None:
            self._first_order = fo.FirstOrderRunner(self)
        grid = fo.pulse_grid(scene, pulses, base, bin_ns=bin_ns)
        wave, energy, _, kernel_s = self._first_order.run(scene_setup, grid, base, samples, hotspot=hotspot)
        period = 1.0 / base.sampling_ghz
        rows = [wave[i, :grid.n_samples[i]] for i in range(len(pulses))]
        t0 = grid.t0_ns.copy()
        if max_order > 1:
            bufs = None
            for i in range(len(pulses)):
                setup = prepare_run(scene, pulses.sensor(i, base), photons=photons, seed=int(pulses.seed[i]),
                                    mode=mode, detect=detect, max_order=max_order, batches=batches,
                                    bin_ns=bin_ns, step_m=step_m, target=pulses.target[i], hotspot=hotspot,
                                    scene_setup=scene_setup, leaf_off=scene_setup.leaf_off)
                setup.params[0]["skip_first"] = 1
                bufs = bufs or self._scene_buffers(setup)
                hist, _, _, elapsed = self._launch(setup, bufs, chunk=chunk, hist_only=True)
                kernel_s += elapsed
                time_ns, by_order, fine = digitized(setup, hist.astype(np.float64) / FIXED_SCALE)
                energy[i] += fine.sum()
                rows[i], t0[i] = _add_on_clock(rows[i], t0[i], by_order.sum(axis=0), time_ns[0], period)
        return PulseWaveforms.from_rows(pulses.index, rows, t0_ns=t0, bin_ns=period, energy=energy,
                                        kernel_s=kernel_s)

    def _scene_buffers(self, setup: RunSetup) -> dict:
        """Device copies of what the kernel reads from the scene (sparse bricks, their uniform
        boxes, leaf angle tables); the last scene's are kept while its bricks and tables are
        the same objects (kept bricks, a SceneSetup, cached leaf tables), array by array."""
        g = setup.bricks
        host = (g, g.index, g.boxes, g.pool, g.wdir, setup.ppf, setup.gtab)
        if self._uploaded is not None and all(a is b for a, b in zip(self._uploaded[0], host)):
            return self._uploaded[1]
        self._uploaded = None  # release the previous scene's copies first
        bufs = self._upload(setup)
        self._uploaded = (host, bufs)
        return bufs

    def _upload(self, setup: RunSetup) -> dict:
        cl = self._cl
        mf = cl.mem_flags
        g = setup.bricks
        pool = g.pool if len(g.pool) else np.zeros((1, 2), np.float32)
        try:
            bufs = dict(
                index=cl.Buffer(self.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=g.index),
                boxes=cl.Buffer(self.context, mf.READ_ONLY | mf.COPY_HOST_PTR,
                                hostbuf=uniform_records(g.pool, g.boxes, brick=g.brick) if len(g.boxes)
                                else np.array([[-1, 0, 0, 0]], np.int32)),
                pool=cl.Buffer(self.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=np.ascontiguousarray(pool)),
                ppf=cl.Buffer(self.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=setup.ppf.astype(np.float32)),
                gtab=cl.Buffer(self.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=setup.gtab.astype(np.float32)),
                wdir=cl.Buffer(self.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=np.ascontiguousarray(
                    g.wdir if g.wdir is not None else np.zeros((1, 4), np.float32))),
            )
        except cl.Error as err:
            raise DeviceError(f"cannot upload the scene ({g.nbytes / 2**20:.0f} MiB of bricks) to "
                              f"{self.device_name}: {short_reason(err)}") from err
        return bufs

    def run_setup(self, setup: RunSetup, *, chunk: int = 1 << 20, progress: bool = False) -> SimulationResult:
        """Run a :func:`prepare_run` set-up."""
        B = setup.batches
        hist, stats, traces, elapsed = self._launch(setup, self._scene_buffers(setup), chunk=chunk,
                                                    progress=progress)
        stats = stats.reshape(B, len(STAT_NAMES)).astype(np.float64)
        weight_cols = [i for i, n in enumerate(STAT_NAMES) if n not in COUNT_STATS]
        stats[:, weight_cols] /= FIXED_SCALE
        tr = None
        if setup.trace:
            tr = traces.reshape(setup.trace, TRACE_EVENTS, 4).copy()
            tr[..., :3] += setup.scene.origin.astype(np.float32)
        return assemble_result(setup, hist.astype(np.float64) / FIXED_SCALE, stats, tr, elapsed,
                               self.device_name)

    def _work_items(self, n: int, batches: int) -> int:
        """Work items of a launch of ``n`` photons: one per photon on a GPU; on a CPU about
        :attr:`photons_per_item` photons each, the count a multiple of ``batches`` so that each
        item's photons (``gid``, ``gid + items``, ...) share a batch and its statistics take one
        set of atomics (kernels/transport.cl, ``simulate``)."""
        if self.photons_per_item <= 1:
            return n
        items = -(-n // self.photons_per_item)
        return -(-items // batches) * batches

    def _launch(self, setup: RunSetup, bufs: dict, *, chunk: int = 1 << 20, progress: bool = False,
                hist_only: bool = False):
        """Run the kernel over the scene buffers ``bufs`` (:meth:`_scene_buffers`): the raw tallies
        ``hist`` (B, K, 2, F) uint64, ``stats``, ``traces`` (not read back with ``hist_only``)
        and the seconds the kernel took."""
        cl = self._cl
        _, kern = self.program(setup.mode, setup.detect, setup.bricks.wdir is not None)
        ctx, q = self.context, self.queue
        mf = cl.mem_flags
        p = setup.p
        B, K, F = setup.batches, setup.max_order, int(p["nbins"])
        bufs = dict(bufs, params=cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=setup.params))
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
                items = self._work_items(n, B)
                kern(q, (items,), self.local_size, bufs["params"], bufs["index"], bufs["boxes"], bufs["pool"],
                     bufs["ppf"], bufs["gtab"], bufs["wdir"], hist_buf, stats_buf, trace_buf, key,
                     np.uint64(start), np.uint32(n))
                if bar is not None:
                    q.finish()
                    bar.update(n)
            cl.enqueue_copy(q, hist, hist_buf, is_blocking=not hist_only)
            if not hist_only:
                cl.enqueue_copy(q, stats, stats_buf)
                cl.enqueue_copy(q, traces, trace_buf)
            q.finish()
        except cl.Error as err:
            raise DeviceError(f"transport kernel failed on {self.device_name}: {err}") from err
        finally:
            if bar is not None:
                bar.close()
        return hist.reshape(B, K, 2, F), stats, traces, time.perf_counter() - t0
