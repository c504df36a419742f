"""Host-side set-up of a transport run: kernel parameters, the sparse scene, the seed (no OpenCL).

:func:`prepare_run` checks every argument where it enters and packs what the
kernel reads into :data:`PARAMS_DTYPE` (the C struct of ``kernels/params.cl``);
the same :class:`RunSetup` feeds the OpenCL launcher
(:class:`~clsim.transport.simulator.Simulator`) and the NumPy oracle.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from clsim.digitize import fine_edges
from clsim.errors import InputError
from clsim.sensor import C_M_PER_NS, Sensor
from clsim.transport.bricks import BrickGrid, build_bricks
from clsim.transport.rng import philox4x32_10, split_seed
from voxlidar.choices import Choice
from voxlidar.scene import Scene

NTAB = 4097


NG = 1025


TRACE_EVENTS = 16


FIXED_SCALE = 2.0**32


STAT_NAMES = ("escaped_up", "escaped_down", "absorbed", "truncated", "rr_killed", "rr_added",
              "ground_direct", "outside_window", "detections", "voxel_steps", "events",
              "shadow_rays", "walk_steps")


#: stats that are counts, not weights
COUNT_STATS = ("detections", "voxel_steps", "events", "shadow_rays", "walk_steps")


PARAMS_DTYPE = np.dtype([
    ("sensor", "<f4", 3), ("axis", "<f4", 3), ("e1", "<f4", 3), ("e2", "<f4", 3),
    ("beam_sigma", "<f4"), ("tan2_fov", "<f4"), ("virt_r2", "<f4"), ("norm_nee", "<f4"),
    ("norm_analog", "<f4"), ("h", "<f4"), ("shape", "<i4", 3), ("bshape", "<i4", 3),
    ("ground_z", "<f4"), ("has_ground", "<i4"), ("leaf_R", "<f4"), ("leaf_T", "<f4"),
    ("wood_R", "<f4"), ("wood_T", "<f4"), ("ground_R", "<f4"), ("crown_c", "<f4", 2),
    ("outward", "<i4"), ("ds", "<f4"), ("t0_ns", "<f4"), ("dt_ns", "<f4"), ("nbins", "<i4"),
    ("max_order", "<i4"), ("n_batches", "<i4"), ("n_trace", "<i4"), ("hotspot", "<i4"),
    ("leaf_avg", "<i4"), ("qmc", "<u4"), ("skip_first", "<i4"),
])

#: Step of the golden-ratio lattice of first free paths (kernels/transport.cl QMC_STEP):
#: round(2^32 / phi).
QMC_STEP = 2654435769


def qmc_shift(seed: int) -> int:
    """The lattice's random shift for a run's seed: the first word of Philox block
    (2^32 - 1, 2^32 - 1, 2^32 - 1, 1), a counter no photon stream uses (their last
    word is 0)."""
    lo, hi = split_seed(seed)
    return int(philox4x32_10((0xFFFFFFFF, 0xFFFFFFFF, 0xFFFFFFFF, 1), (lo, hi))[0])


class InteractionModel(str, Choice):
    """Where photons interact: ``exact`` free flight with thinning, or the ``paper``'s fixed step
    (``Simulator.run(mode=...)``, ``clsim simulate --mode``)."""

    EXACT = "exact"
    PAPER = "paper"


class PhotonTally(str, Choice):
    """How photons are counted into the waveform: ``nee`` next-event estimation (every scattering event
    sends its expected return to the receiver), or ``analog`` (only photons that fly through the aperture)
    (``Simulator.run(detect=...)``, ``clsim simulate --detect``)."""

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
    mode: InteractionModel
    detect: PhotonTally
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


@dataclass
class SceneSetup:
    """What a run needs from the scene alone, built once for many pulses (:func:`prepare_scene`)."""

    scene: Scene
    wavelength_nm: float
    leaf_off: bool
    optics: dict  # material -> (R, T) at the wavelength
    bricks: BrickGrid
    ppf: np.ndarray
    gtab: np.ndarray
    flags: list

    def matches(self, scene: Scene, wavelength_nm: float, leaf_off: bool) -> bool:
        """Whether this set-up was built for ``scene`` (the same object), the wavelength and ``leaf_off``."""
        return scene is self.scene and float(wavelength_nm) == self.wavelength_nm and bool(leaf_off) == self.leaf_off


@functools.lru_cache(maxsize=16)
def leaf_tables(leaf_angle) -> tuple[np.ndarray, np.ndarray]:
    """The kernel's leaf angle tables of a (frozen, hashable) LeafAngle: the inverse CDF of the
    leaf zenith on NTAB points of [0, 1] and G on NG points of cos(theta) in [0, 1], float64,
    read-only (computed once per distribution: tens of milliseconds)."""
    ppf = leaf_angle.ppf(np.linspace(0.0, 1.0, NTAB)).astype(np.float64)
    gtab = np.asarray(leaf_angle.G(np.arccos(np.linspace(0.0, 1.0, NG))), dtype=np.float64)
    ppf.flags.writeable = False
    gtab.flags.writeable = False
    return ppf, gtab


def _check_scene(scene) -> None:
    """One line unless ``scene`` is a Scene or brings its own bricks (a :class:`clsim.scenes.PlotScene`)."""
    if not isinstance(scene, Scene) and not callable(getattr(scene, "brick_grid", None)):
        raise InputError(f"scene must be a voxlidar.scene.Scene (Scene.load(path)) or a clsim.scenes.PlotScene, "
                         f"got {type(scene).__name__}")


def prepare_scene(scene: Scene, *, wavelength_nm: float, leaf_off: bool = False,
                  bricks: BrickGrid | None = None) -> SceneSetup:
    """The scene's part of :func:`prepare_run`: optics at the wavelength (checked),
    the bricks, the leaf angle tables (inverse CDF and G).

    ``bricks``: ones already built for this scene and ``leaf_off`` (a cache;
    :class:`~clsim.transport.simulator.Simulator` keeps the last scene's,
    keyed on :func:`~clsim.transport.bricks.bricks_key`)."""
    _check_scene(scene)
    wl = float(wavelength_nm)
    optics = {}
    for mat in ("leaf", "bark", "ground"):
        r, t = scene.optics(mat, wl)
        if min(r, t) < 0 or r + t > 1 + 1e-9:
            raise InputError(
                f"scene optics of {mat} at {wl:g} nm: R={r}, T={t}; need R, T >= 0 and R + T <= 1. "
                f"Fix scene.materials[{mat!r}][{str(int(round(wl)))!r}]"
            )
        optics[mat] = (r, t)
    # a plot of many trees brings its own bricks (shared between the instances of a tree)
    if bricks is None:
        bricks = (scene.brick_grid(leaf_off=leaf_off) if hasattr(scene, "brick_grid")
                  else build_bricks(scene, leaf_off=leaf_off))
    flags = []
    if bricks.flags.get("wood_probability_capped"):
        flags.append(f"wood probability 1 capped at 1-1e-6 in {bricks.flags['wood_probability_capped']} voxels")
    ppf, gtab = leaf_tables(scene.leaf_angle)
    return SceneSetup(scene=scene, wavelength_nm=wl, leaf_off=bool(leaf_off), optics=optics, bricks=bricks,
                      ppf=ppf, gtab=gtab, flags=flags)


def _int_arg(name, value, lo, hi):
    try:
        v = int(value)
    except (TypeError, ValueError) as err:
        raise InputError(f"{name} must be an integer in [{lo}, {hi}], got {value!r}") from err
    if v != value or not lo <= v <= hi:
        raise InputError(f"{name} must be an integer in [{lo}, {hi}], got {value!r}")
    return v


def scene_params(r, scene_setup: SceneSetup, sensor: Sensor) -> None:
    """Fill the fields of a :data:`PARAMS_DTYPE` record ``r`` that the scene and the beam fix (grid,
    bricks, ground, optics, leaf azimuths, divergence and field of view), for every kernel that reads
    the medium (the photon walk, the deterministic first order)."""
    scene, lo, ground = scene_setup.scene, scene_setup.scene.origin, scene_setup.scene.ground_z
    r["beam_sigma"] = 0.5e-3 * sensor.divergence_mrad
    r["tan2_fov"] = math.tan(1e-3 * sensor.fov_mrad) ** 2
    r["h"] = scene.voxel_size
    r["shape"] = scene.shape
    r["bshape"] = scene_setup.bricks.brick_shape
    r["ground_z"] = 0.0 if ground is None else ground - lo[2]
    r["has_ground"] = ground is not None
    r["leaf_R"], r["leaf_T"] = scene_setup.optics["leaf"]
    r["wood_R"], r["wood_T"] = scene_setup.optics["bark"]
    r["ground_R"] = scene_setup.optics["ground"][0]
    r["crown_c"] = scene.crown_center - lo[:2]
    r["outward"] = scene.leaf_azimuth == "outward"
    # the averaged next-event weight is exact for spherical leaf angles with uniform azimuths
    r["leaf_avg"] = scene.leaf_angle.kind.value == "spherical" and scene.leaf_azimuth != "outward"


def prepare_run(scene: Scene, sensor: Sensor, *, photons: int, seed: int, mode="exact",
                detect="nee", max_order: int = 3, leaf_off: bool = False, batches: int = 16,
                bin_ns: float = 0.05, step_m: float = 0.02, target=None, trace: int = 0,
                hotspot: bool = False, scene_setup: SceneSetup | None = None,
                bricks: BrickGrid | None = None) -> RunSetup:
    """Check the inputs and build the run's parameters (see :meth:`clsim.transport.simulator.Simulator.run`).

    ``scene_setup`` (from :func:`prepare_scene`) skips rebuilding what depends
    only on the scene, the wavelength and ``leaf_off`` (bricks, leaf angle
    tables, optics): a survey runs many pulses over one scene.  ``bricks``
    (without ``scene_setup``) reuses bricks built for this scene and
    ``leaf_off`` (:func:`prepare_scene`)."""
    _check_scene(scene)
    if not isinstance(sensor, Sensor):
        raise InputError(f"sensor must be a clsim.Sensor (Sensor.preset(name)), got {type(sensor).__name__}")
    mode = InteractionModel.parse(mode, "mode")
    detect = PhotonTally.parse(detect, "detect")
    photons = _int_arg("photons", photons, 1, 2**40)
    max_order = _int_arg("max_order", max_order, 1, 64)
    batches = _int_arg("batches", batches, 1, 4096)
    trace = _int_arg("trace", trace, 0, 100_000)
    split_seed(seed)
    if not (np.isfinite(bin_ns) and 0.001 <= bin_ns <= 1.0):
        raise InputError(f"bin_ns must lie in [0.001, 1] ns, got {bin_ns!r}")
    if not (np.isfinite(step_m) and 1e-4 <= step_m <= scene.voxel_size * 10):
        raise InputError(f"step_m (paper-mode step) must lie in [1e-4, 10 voxels] m, got {step_m!r}")
    if scene_setup is None:
        scene_setup = prepare_scene(scene, wavelength_nm=sensor.wavelength_nm, leaf_off=leaf_off, bricks=bricks)
    elif not isinstance(scene_setup, SceneSetup) or not scene_setup.matches(scene, sensor.wavelength_nm, leaf_off):
        raise InputError("scene_setup was prepared for another scene, wavelength or leaf_off; "
                         "fix: prepare_scene(scene, wavelength_nm=sensor.wavelength_nm, leaf_off=leaf_off)")
    optics, bricks = scene_setup.optics, scene_setup.bricks
    flags = list(scene_setup.flags)

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
    scene_params(r, scene_setup, sensor)
    r["virt_r2"] = (0.5 * sensor.virtual_aperture_m) ** 2
    r["norm_nee"] = R_ref**2
    r["norm_analog"] = R_ref**2 / sensor.virtual_aperture_area_m2
    r["ds"] = step_m
    r["t0_ns"] = edges[0]
    r["dt_ns"] = bin_ns
    r["nbins"] = len(edges) - 1
    r["max_order"] = max_order
    r["n_batches"] = batches
    r["n_trace"] = trace
    r["hotspot"] = bool(hotspot)
    r["qmc"] = qmc_shift(seed)

    ppf, gtab = scene_setup.ppf, scene_setup.gtab
    if sensor.fov_mrad < sensor.divergence_mrad:
        flags.append(f"receiver FOV ({sensor.fov_mrad} mrad) is narrower than the beam divergence "
                     f"({sensor.divergence_mrad} mrad): part of the footprint is not seen")
    if hotspot and detect is PhotonTally.ANALOG:
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
                   leaf_azimuth=scene.leaf_azimuth, ground_z=ground, meta=scene.meta,
                   wood_directional=bricks.wdir is not None),
    )
    return RunSetup(scene=scene, sensor=sensor, mode=mode, detect=detect, photons=photons,
                    seed=int(seed), max_order=max_order, batches=batches, leaf_off=bool(leaf_off),
                    params=rec, bricks=bricks, ppf=ppf, gtab=gtab, edges_ns=edges, range_ref_m=R_ref,
                    flags=flags, settings=settings, trace=trace)
