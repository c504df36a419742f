"""The voxel stage as a pipeline of stages: scans (+ echo classes) -> ground -> grid -> beams -> trace ->
LAD -> undetected echoes -> wood -> Scene.

:func:`voxelize` runs the stages in order (each a function of this module, its
settings a group of :class:`~tlsvox.voxel.settings.VoxelizeSettings`): it takes
registered scans (each with a world-from-scanner
pose), turns every pulse into a beam (:mod:`tlsvox.voxel.pulses`), traces them
through a voxel grid (:mod:`tlsvox.voxel.trace`), estimates leaf area density
(:mod:`tlsvox.voxel.estimators`) and wood (the wood package (:mod:`tlsvox.voxel.wood`)), finds the ground
(:mod:`tlsvox.ground`), and returns a :class:`~voxlidar.scene.Scene` with the
intermediate results for inspection.  :func:`score_lad` (:mod:`tlsvox.voxel.quality`) compares a LAD grid
with a known truth; :func:`memory_plan` (:mod:`tlsvox.voxel.plan`) says what a
grid will cost before it runs.

Examples
--------
>>> import numpy as np
>>> from tlsvox.scan import Scan, PulseTable
>>> rng = np.random.default_rng(0)
>>> d = rng.normal(size=(2000, 3)); d[:, 2] = np.abs(d[:, 2]); d /= np.linalg.norm(d, axis=1)[:, None]
>>> hit = rng.random(2000) < 0.3
>>> scan = Scan(xyz=d[hit] * 3.0, pulse_id=np.nonzero(hit)[0], truth_material=np.ones(hit.sum()),
...             pose=np.eye(4), pulses=PulseTable(d, hit.astype(int)))
>>> res = voxelize([scan], voxel_size=0.5, ground=None, progress=False)
>>> res.scene.n_voxels > 0 and bool(np.all(np.isfinite(res.scene.lad)))
True
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from tlsvox.errors import InputError
from tlsvox.ground import GroundPlane, fit_ground, ground_mask
from tlsvox.scan import AngularGrid, Scan
from tlsvox.voxel.bricks import BRICK, Bricks
from tlsvox.voxel.detection import DetectionModel, Undetected
from tlsvox.voxel.estimators import DENSE_FILLS, Estimator, FillMode, LadEstimate, estimate
from tlsvox.voxel.fills import (
    CALIBRATION_MIN_VOXELS,
    check_calibration_scans,
)
from tlsvox.voxel.giveback import give_back_undetected
from tlsvox.voxel.grid import VoxelGrid
from tlsvox.voxel.plan import (  # noqa: F401
    _ESTIMATE_BYTES,
    DENSE_AUTO_MAX,
    Layout,
    MemoryPlan,
    memory_plan,
    row_bytes,
    undetected_bytes,
)
from tlsvox.voxel.pulses import (
    beams_from_scan,
    kinds_from_material,
    kinds_from_pointclass,
    layer_g_tables,
    outward_g_table,
)
from tlsvox.voxel.quality import LAD_PLAUSIBLE_MAX, LINE_FIT_MIN, OCCLUDED_SHARE_MAX, quality_warnings, score_lad  # noqa: F401
from tlsvox.voxel.settings import VoxelizeSettings
from tlsvox.voxel.trace import Beams, EchoKind, Tracer, VoxelStats, echo_voxels
from tlsvox.voxel.weights import EchoWeights, resolve_rule
from tlsvox.voxel.wood.voxels import WoodEstimate, WoodMethod, estimate_wood
from voxlidar.leaf_orientation import LeafAngle, LeafAzimuth
from voxlidar.scene import Scene

__all__ = ["Checked", "Echoes", "Layout", "MemoryPlan", "Projection", "TraceRun", "VoxelizeResult", "build_scene",
           "check_settings", "estimate", "give_back_undetected", "leaf_projection", "make_beams", "make_grid", "memory_plan",
           "scan_poses", "scene_ground", "score_lad", "undetected_bytes", "voxelize", "world_echoes"]

@dataclass
class VoxelizeResult:
    """What :func:`voxelize` made, and from what."""

    scene: Scene
    grid: VoxelGrid
    stats: VoxelStats | None  #: None for a scene made without beams (tlsvox.voxel.merged.voxelize_occupancy)
    lad: LadEstimate | None  #: None for a scene made without beams
    wood: WoodEstimate
    ground: GroundPlane | None
    scans: list = field(default_factory=list)  #: per-scan info dicts
    timings: dict = field(default_factory=dict)  #: seconds per stage
    coarse: VoxelizeResult | None = None  #: with ``lad_voxel_size``: the coarse run the LAD came from


def _kinds_for(scan: Scan, classes, class_codes: str) -> np.ndarray:
    if classes is None:
        if scan.classification is not None:  # written by tlsvox classify
            return kinds_from_pointclass(scan.classification)
        if scan.truth_material is not None:
            return kinds_from_material(scan.truth_material)
        return np.full(len(scan), EchoKind.LEAF, np.uint8)
    c = np.asarray(classes).reshape(-1)
    if len(c) != len(scan):
        raise InputError(f"classes for scan {scan.name!r} has {len(c)} labels for its {len(scan)} echoes; "
                         "pass one label per echo, in the scan's order")
    if class_codes == "pointclass":
        return kinds_from_pointclass(c)
    if class_codes == "material":
        return kinds_from_material(c)
    raise InputError(f"class_codes={class_codes!r} must be 'pointclass' (tlsvox.classify) or 'material'")


def voxelize(scans, settings: VoxelizeSettings | None = None, *, classes=None, leaf_angle_layers=None,
             tracer: Tracer | None = None, progress: bool = True, plan_only: bool = False,
             **kwargs):
    """Build the voxel scene from registered scans, stage by stage.

    The stages, each a function of this module: :func:`world_echoes` (every
    echo in the world frame, with its kind), :func:`scene_ground`,
    :func:`make_grid`, :func:`leaf_projection` (G per beam or per voxel),
    :func:`make_beams`, then :class:`TraceRun` (the tracer's sums),
    :func:`estimate` and :func:`give_back_undetected` (the echoes under the
    detection threshold), and :func:`build_scene` (wood, the stored voxels,
    the meta).  Their settings come from ``settings``
    (:class:`~tlsvox.voxel.settings.VoxelizeSettings`, grouped by stage), any
    of whose fields a keyword argument replaces (``voxelize(scans,
    voxel_size=0.1)``); ``scene.meta["settings"]`` records them in full.

    Parameters
    ----------
    scans : sequence of Scan
        Each with ``pose`` (world-from-scanner) unless ``scanner_frame``.
    settings : VoxelizeSettings, optional
        Every setting below, grouped (default: the defaults).
    classes : sequence of (N_s,) arrays, optional
        Echo classes per scan (``tlsvox.classify`` labels by default, see
        ``class_codes``).  Default: each scan's ``classification`` (a scan
        written by ``tlsvox classify``), else its ``truth_material``
        (simulated), else every echo counted as a leaf (the result is then
        plant area density).
    voxel_size : float, metres
    class_codes : {"pointclass", "material"}
    leaf_angle : str, dict or LeafAngle
        Leaf inclination model used for G(theta) (default uniform, the paper).
    leaf_angle_layers : LeafAngleMeasurement or sequence of (z_low, z_high, LeafAngle), optional
        Leaf angles per crown layer for the estimators' G(theta) (e.g.
        ``tlsvox.leafangles.measure_leaf_angles(scans).layers``): each voxel
        takes the model of the layer its centre's height lies in (the lowest
        layer below them all, the highest above).  ``leaf_angle`` stays the
        scene's one model (the simulator's) and the detection model's.
    leaf_azimuth : {"uniform", "outward"}
        The leaves' azimuth, stored in the scene for the simulator.
        ``outward`` (leaves facing away from a vertical crown axis through
        ``crown_center``) also enters the estimate: each voxel's G is that of
        outward leaves for the beam crossing it
        (:func:`tlsvox.voxel.pulses.outward_g_table`), not G(theta) of
        azimuthally uniform ones.
    estimator : {"bcmle", "voxlad", "beer_lambert", "contact_frequency"}
    wood : {"count_stretch", "voxlad"}
    wood_percentile : float
        ``count_stretch``: percentile of non-zero counts that maps to 1.
    ground : "ransac", float, GroundPlane or None
        Fit a plane to the lowest echoes, use a given height, or no ground.
    ground_tolerance : float, metres
        Echoes within this height above the plane stop beams as ground, not leaves.
    bounds : (2, 3) float, metres, optional
        Region to voxelise; default the vegetation echoes' bounding box (+
        ``margin``), snapped to multiples of ``voxel_size``.  Given bounds are
        taken as they are: the grid starts at ``bounds[0]`` (less ``margin``)
        and ends at the first voxel face at or past ``bounds[1]``.
    snap : bool
        Snap given ``bounds`` outwards to multiples of ``voxel_size`` (so the
        grids of several runs line up).
    n_min, min_explored, leaf_size, small_voxel_factor, fill
        See :func:`tlsvox.voxel.estimators.estimate_lad`.  ``fill="neighbourhood"``
        (occluded crown voxels take the mean LAD of their nearest seen crown
        voxels) needs the dense layout; ``fill="layer"`` works in both.
        ``fill="calibrated"`` (dense, two or more scans) traces each scan on
        its own and scales the neighbourhood fill by the ratio measured where
        one scan is hidden and the others see
        (:func:`~tlsvox.voxel.estimators.cross_scan_ratio`).
    max_range, angular_grid, socs_rotation
        See :func:`tlsvox.voxel.pulses.beams_from_scan` (real scans without pulse tables);
        ``max_range`` must be positive (metres).
    scanner_frame : bool
        Allow a single scan without a pose: the world is its own frame.
    crown_center : (2,) float, optional
        Default: with ``leaf_azimuth="outward"`` the middle of the leaf echoes'
        extent in x and y (their 0.1 and 99.9 percentiles), else the
        LAD-weighted centroid of the voxels.
    layout : {"auto", "dense", "sparse"}
        How the tracer keeps its sums (:class:`Layout`): ``sparse`` keeps
        full sums only for voxels holding echoes and judges the others' occlusion
        per brick of 8^3 voxels; its scene then stores no echo-free occluded
        voxel (``meta["occluded_bricks"]`` counts them).  ``auto``: dense up to
        1 GiB.
    echo_weights : {"auto", "uniform", "fraction", "threshold"}
        How echoes share their pulse's beam (:mod:`tlsvox.voxel.weights`):
        ``auto`` (default) weights each echo by the share of the beam it
        intercepted when the scan has a ``beam_fraction`` column (simulated
        scans), else ``1/n``.  The rule used per scan is in
        ``scene.meta["echo_weights"]``.
    leaf_reflectance, wood_reflectance : float, optional
        Nominal reflectance of a full hit (``fraction`` from reflectance,
        ``threshold``, and the detection model); default the optics at the
        scanner's wavelength.
    undetected : {"ignore", "model"}
        Leaf hits too weak for the scanner's detection threshold
        (:mod:`tlsvox.voxel.detection`): ``ignore`` (default) counts the
        share of the beam they stopped as travelling on (LAD biased low);
        ``model`` gives each pulse's expected unrecorded interception back
        as leaf echoes where the current estimate puts it, and estimates
        again (``undetected_iterations`` times); its voxels entered by less
        than ``n_min`` pulses' worth of beam weight count as occluded
        (``weighted_count``).  Stated in ``scene.meta["undetected"]``.
    detection_threshold_db : float, optional
        The scanner's detection threshold (dB of a white Lambertian target);
        default the scan's preset (``scan.meta["preset"]["min_reflectance_db"]``).
    leaf_shape : (float, float), metres
        Leaf length and width of the detection model (default 5 x 2.5 cm).
    undetected_iterations : int
        Estimates made with the correction, each from the one before (>= 1).
    tracer : Tracer, optional
        OpenCL tracer to reuse (default: a new one).  Not a setting (nor
        ``classes``, ``leaf_angle_layers``, ``progress``, ``plan_only``): what
        the run is given, not how it runs.
    max_bytes : int, optional
        Memory limit (default: 80 % of what the system has available); the
        plan (:func:`memory_plan`) is checked before tracing.
    progress : bool
        tqdm progress bars.
    lad_voxel_size : float, metres, optional
        Estimate the leaf area density on a grid this much coarser (a whole
        multiple of ``voxel_size``, e.g. 0.1 for 2 cm voxels) and put it on
        the fine voxels (``lad_placement``; :mod:`tlsvox.voxel.coarse`): for
        voxels narrower than two leaves, where the turbid estimators fail.  ``fill`` and
        ``undetected`` then act on the coarse grid (its layout chosen by
        size, ``layout`` is the fine grid's); wood and ground stay fine.  The
        fine grid covers the coarse one's voxels whole (the coarse grid comes
        from ``bounds`` as usual).
        Stated in ``scene.meta["lad_voxel_size"]``; the coarse run is the
        result's ``coarse``.
    lad_placement : {"even", "echoes"}
        With ``lad_voxel_size``: each coarse voxel's LAD on all its fine
        voxels (``even``, default), or its leaf area in proportion to the fine
        voxels' leaf echo weight (``echoes``; it puts the leaves on the
        surfaces the scanners saw, and reads worse against airborne
        waveforms, docs/voxelize.md).
    plan_only : bool
        Stop after the beams and return the :class:`MemoryPlan` (nothing traced).

    Returns
    -------
    VoxelizeResult (or MemoryPlan with ``plan_only``)
    """
    s = VoxelizeSettings.from_kwargs(settings, **kwargs)
    g, m = s.grid, s.model
    if g.lad_voxel_size is None and str(g.lad_placement).lower() != "even":
        raise InputError(f"lad_placement={g.lad_placement!r} needs lad_voxel_size (it says how the coarse grid's LAD "
                         "goes onto the fine one)")
    if g.lad_voxel_size is not None:
        from tlsvox.voxel.coarse import voxelize_coarse_lad

        res = voxelize_coarse_lad(dict(s.to_kwargs(), scans=scans, classes=classes, leaf_angle_layers=leaf_angle_layers,
                                       tracer=tracer, progress=progress, plan_only=plan_only))
        if isinstance(res, VoxelizeResult):
            res.scene.meta["settings"] = s.to_dict()  # the run as asked, not its fine half
        return res
    timings = {}
    t0 = time.perf_counter()
    echoes = world_echoes(scans, classes, s)
    checks = check_settings(echoes.scans, s)
    plane = scene_ground(echoes, s)
    timings["prepare"] = time.perf_counter() - t0

    # grid (and the memory it needs, checked before anything large is made)
    grid = make_grid(echoes, plane, s)
    layout = Layout.parse(g.layout, "layout")
    if layout is Layout.SPARSE and checks.fill in DENSE_FILLS:  # known before the beams are built
        raise InputError(f"fill={checks.fill.value!r} needs the dense layout, but layout='sparse' was given; use "
                         "fill='layer' (per brick layer in the sparse layout), or layout='dense' where memory allows")
    projection = leaf_projection(echoes, grid, checks.leaf_angle, checks.azimuth, m.crown_center, leaf_angle_layers)
    echoes.world = []  # the echoes' world positions: not held through the beams and the trace
    tracer = tracer or Tracer()
    if layout is Layout.DENSE and not plan_only:  # before the beams, when the answer is already known
        grid.check_memory(row_bytes(tracer), max_bytes=g.max_bytes, what="tracing and estimation")

    t1 = time.perf_counter()
    parts: list | None
    parts, infos = make_beams(echoes, checks.leaf_angle, s, progress=progress)
    beams = parts[0] if len(parts) == 1 else Beams.concat(parts)
    per_scan = checks.fill is FillMode.CALIBRATED  # each scan traced on its own: the fill's calibration
    if checks.detection is None and not per_scan:
        parts = None  # the per-scan copies
    timings["pulses"] = time.perf_counter() - t1
    if plan_only:
        return memory_plan(grid, beams, tracer, layout=layout, max_bytes=g.max_bytes, check=False,
                           undetected=checks.undetected, fill=checks.fill, scans=len(echoes.scans))

    run = TraceRun.start(grid, beams, tracer, layout, checks, projection, len(echoes.scans), s, progress=progress)
    if per_scan and checks.detection is None:
        beams = None  # each scan's beams are traced on their own: the joined copy is not needed again
    t2 = time.perf_counter()
    stats, scan_stats = run.sums(beams, parts if per_scan else None)
    timings["trace"] = time.perf_counter() - t2

    t3 = time.perf_counter()
    lad = estimate(stats, checks.estimator, checks.fill, s, scan_stats=scan_stats)
    if checks.weights is EchoWeights.GEOMETRIC:  # the first estimate took 1/n: the rule's rounds
        stats, lad, parts, beams, infos = geometric_rounds(run, echoes, checks, s, lad, per_scan=per_scan,
                                                           progress=progress)
        if checks.detection is None and not per_scan:
            parts = None
    if checks.detection is not None:
        stats, lad, undetected_meta = give_back_undetected(run, parts, beams, stats, lad, checks, projection, s)
    else:
        thr = [(sc.meta.get("preset") or {}).get("min_reflectance_db") for sc in echoes.scans]
        undetected_meta = {"rule": checks.undetected.value, "detection_threshold_db": thr}
    parts = beams = scan_stats = None
    scene, wood_est = build_scene(grid, stats, lad, plane, infos, checks, projection, run.plan, undetected_meta,
                                  s, timings=timings, t_estimate=t3, t_start=t0)
    return VoxelizeResult(scene, grid, stats, lad, wood_est, plane, infos, timings)


@dataclass
class Echoes:
    """The scans' echoes in the world frame (:func:`world_echoes`): one entry per scan."""

    scans: list  #: the Scan objects
    poses: list  #: (4, 4) world-from-scanner
    world: list  #: (N_s, 3) echo positions, metres (emptied once the grid and G are known)
    kinds: list  #: (N_s,) EchoKind codes (the ground stage marks ground echoes OTHER)


@dataclass
class Checked:
    """The run's settings parsed once, before any work (:func:`check_settings`)."""

    estimator: Estimator
    azimuth: LeafAzimuth
    weights: EchoWeights
    undetected: Undetected
    detection: list | None  #: one DetectionModel per scan with ``undetected="model"``
    fill: FillMode
    wood: WoodMethod
    leaf_angle: LeafAngle


@dataclass
class Projection:
    """Where the tracer reads G from (:func:`leaf_projection`)."""

    outward: tuple | None  #: (G table, crown centre) for outward-facing leaves, else None
    g_tables: tuple | None  #: what the tracer reads (None: each beam's own G)
    g_layer: np.ndarray | None  #: per z-layer of the grid, which leaf-angle layer's table
    layers: list | None  #: [(z_low, LeafAngle)], lowest first
    crown_center: object  #: the given or measured crown centre (None: the LAD centroid, later)


def scan_poses(scans, scanner_frame: bool = False) -> list:
    """Each scan's world-from-scanner pose; refused in one line for a scan without one.

    A single scan without a pose takes its own frame when ``scanner_frame``.
    """
    poses = []
    for sc in scans:
        if sc.pose is not None:
            poses.append(sc.pose)
        elif scanner_frame and len(scans) == 1:
            poses.append(np.eye(4))
        else:
            hint = ("; or for a single scan use its own frame (scanner_frame=True, CLI --scanner-frame)"
                    if len(scans) == 1 else "")
            raise InputError(f"scan {sc.name!r} has no pose (world-from-scanner 4x4): register the scans "
                             f"first (tlsvox register){hint}")
    return poses


def world_echoes(scans, classes, settings: VoxelizeSettings) -> Echoes:
    """Stage 1: each scan checked, its pose found, its echoes put in the world frame with their kinds."""
    if isinstance(scans, Scan):
        scans = [scans]
    scans = list(scans)
    if not scans:
        raise InputError("scans is empty: pass at least one Scan")
    for sc in scans:
        if not isinstance(sc, Scan):
            raise InputError(f"scans must hold tlsvox Scan objects, got {type(sc).__name__}")
    if classes is not None and len(classes) != len(scans):
        raise InputError(f"classes has {len(classes)} entries for {len(scans)} scans: one array per scan")
    max_range = settings.poses.max_range
    if max_range is not None and not (np.isfinite(max_range) and max_range > 0):
        raise InputError(f"max_range={max_range!r} must be a positive distance in metres (how far empty "
                         "pulses are followed), or None for the scanner's range")
    poses = scan_poses(scans, settings.poses.scanner_frame)
    world = [sc.world_xyz(p) for sc, p in zip(scans, poses)]
    if len(world) > 1:
        boxes = [(w.min(axis=0), w.max(axis=0)) for w in world if len(w)]
        for i in range(1, len(boxes)):
            lo = np.maximum(boxes[0][0], boxes[i][0])
            hi = np.minimum(boxes[0][1], boxes[i][1])
            if np.any(lo > hi):
                raise InputError(
                    f"scan {scans[i].name!r} does not overlap scan {scans[0].name!r} in the world frame "
                    f"(boxes {np.round(boxes[0], 2).tolist()} and {np.round(boxes[i], 2).tolist()}): "
                    "the scans are not co-registered; register them first"
                )
    codes = settings.echoes.class_codes
    kinds = [_kinds_for(sc, None if classes is None else classes[i], codes) for i, sc in enumerate(scans)]
    return Echoes(scans, poses, world, kinds)


def check_settings(scans, settings: VoxelizeSettings) -> Checked:
    """Every choice of the settings parsed, and the inputs the echo weights need checked, before any work."""
    m, u = settings.model, settings.undetected
    est = Estimator.parse(m.estimator, "estimator")
    azimuth = LeafAzimuth.parse(m.leaf_azimuth, "leaf_azimuth")
    weights = EchoWeights.parse(settings.echoes.echo_weights, "echo_weights")
    for sc in scans:
        resolve_rule(weights, sc)  # the inputs the rule needs, checked before any work
    undetected = Undetected.parse(u.undetected, "undetected")
    detection = None
    if undetected is Undetected.MODEL:
        shape = np.asarray(u.leaf_shape, dtype=np.float64).reshape(-1)
        if shape.shape != (2,):
            raise InputError(f"leaf_shape={u.leaf_shape!r} must be (length, width) in metres, e.g. (0.05, 0.025)")
        if int(u.undetected_iterations) < 1:
            raise InputError(f"undetected_iterations={u.undetected_iterations!r} must be an integer >= 1, e.g. 2")
        detection = [DetectionModel.for_scan(sc, threshold_db=u.detection_threshold_db,
                                             leaf_reflectance=settings.echoes.leaf_reflectance,
                                             leaf_length=shape[0], leaf_width=shape[1]) for sc in scans]
    fill = FillMode.parse(m.fill, "fill")
    if fill is FillMode.CALIBRATED:
        check_calibration_scans(len(scans))
    return Checked(est, azimuth, weights, undetected, detection, fill, WoodMethod.parse(m.wood, "wood"),
                   LeafAngle.from_dict(m.leaf_angle))


def scene_ground(echoes: Echoes, settings: VoxelizeSettings) -> GroundPlane | None:
    """Stage 2: the ground plane (fitted, given or none); echoes within ``ground_tolerance`` above it stop
    beams as ground (their kind becomes OTHER), not as leaves."""
    ground = settings.ground.ground
    plane = None
    if isinstance(ground, GroundPlane):
        plane = ground
    elif isinstance(ground, dict):  # a GroundPlane given through the settings
        plane = GroundPlane(**{k: tuple(v) if isinstance(v, list | tuple) else v for k, v in ground.items()})
    elif isinstance(ground, str):
        if ground.lower() == "ransac":
            plane = fit_ground(np.vstack([w[k != EchoKind.IGNORE] for w, k in zip(echoes.world, echoes.kinds)]))
        elif ground.lower() != "none":
            raise InputError(f"ground={ground!r} must be 'ransac', 'none', a height in metres or a GroundPlane")
    elif ground is not None:
        plane = GroundPlane.horizontal(float(ground))
    if plane is not None:
        for w, k in zip(echoes.world, echoes.kinds):
            k[ground_mask(w, plane, tolerance=settings.ground.ground_tolerance) & (k == EchoKind.LEAF)] = EchoKind.OTHER
    return plane


def make_grid(echoes: Echoes, plane: GroundPlane | None, settings: VoxelizeSettings) -> VoxelGrid:
    """Stage 3: the voxel grid, over the given bounds or the vegetation echoes' box (down to the ground)."""
    g = settings.grid
    voxel_size, world, kinds = g.voxel_size, echoes.world, echoes.kinds
    if g.bounds is None:
        # the vegetation's box: ground and targets may reach far beyond the trees
        veg = [w[(k == EchoKind.LEAF) | (k == EchoKind.WOOD)] for w, k in zip(world, kinds)]
        pts = np.vstack(veg)
        if len(pts) == 0:
            raise InputError("the scans have no leaf or wood echoes to size the grid from (every echo near the fitted "
                             "ground counts as ground): give the region, bounds= (CLI --bounds "
                             "xmin,ymin,zmin,xmax,ymax,zmax), or --ground none when the scan holds no ground")
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        if plane is not None:
            lo[2] = max(lo[2], plane.z_center - voxel_size)
        span = float(np.max(hi - lo))
        if voxel_size > span:
            raise InputError(f"voxel_size={voxel_size:g} m is larger than the vegetation the scans saw ({span:.3g} m "
                             "across): one voxel would hold it all and its LAD would mean nothing; use a voxel size "
                             "well below the crown size (the paper: 0.02-0.5 m)")
        return VoxelGrid.from_bounds(lo, hi, voxel_size=voxel_size, margin=g.margin)
    b = np.asarray(g.bounds, dtype=np.float64)
    if b.shape != (2, 3):
        raise InputError(f"bounds must be [[xmin, ymin, zmin], [xmax, ymax, zmax]], got shape {b.shape}")
    vxyz = np.vstack([w[(k == EchoKind.LEAF) | (k == EchoKind.WOOD)] for w, k in zip(world, kinds)])
    inside = np.all((vxyz >= b[0]) & (vxyz <= b[1]), axis=1) if len(vxyz) else np.zeros(0, bool)
    if len(vxyz) and not inside.any():
        raise InputError(f"bounds {b.tolist()} hold none of the {len(vxyz):,} leaf and wood echoes (they lie within "
                         f"{vxyz.min(axis=0).round(2).tolist() if len(vxyz) else '-'} .. "
                         f"{vxyz.max(axis=0).round(2).tolist() if len(vxyz) else '-'}); check the frame and the "
                         "numbers")
    return VoxelGrid.from_bounds(b[0], b[1], voxel_size=voxel_size, margin=g.margin, snap=bool(g.snap))


def leaf_projection(echoes: Echoes, grid: VoxelGrid, la: LeafAngle, azimuth: LeafAzimuth, crown_center=None,
                    leaf_angle_layers=None) -> Projection:
    """Stage 4: where the tracer reads each beam's G from: the beam's own G(theta) (uniform leaf azimuths),
    G of outward-facing leaves per voxel, or per crown layer (``leaf_angle_layers``)."""
    layers = _leaf_angle_layers(leaf_angle_layers)
    outward = None
    if azimuth is LeafAzimuth.OUTWARD:  # G per voxel, from the beam's angle to the leaves' outward direction
        if crown_center is None:
            leaves = np.vstack([w[k == EchoKind.LEAF, :2] for w, k in zip(echoes.world, echoes.kinds)])
            # the middle of the leaves' extent: the scans see the near side of the crown best, so the
            # echoes' mean lies off the axis towards the scanners
            crown_center = (0.5 * (np.percentile(leaves, 0.1, axis=0) + np.percentile(leaves, 99.9, axis=0))
                            if len(leaves) else 0.5 * (grid.lower + grid.upper)[:2])
        outward = (outward_g_table(la), np.asarray(crown_center, dtype=np.float64).reshape(2))
    g_tables, g_layer = outward, None  # what the tracer reads G from (None: each beam's g)
    if layers is not None:
        cuts = np.array([z for z, _ in layers[1:]])  # each layer's lower bound above the first
        g_layer = np.searchsorted(cuts, grid.lower[2] + (np.arange(grid.shape[2]) + 0.5) * grid.voxel_size,
                                  side="right").astype(np.int32)
        g_tables = (layer_g_tables([m for _, m in layers], outward=outward is not None),
                    outward[1] if outward is not None else np.zeros(2))
    return Projection(outward, g_tables, g_layer, layers, crown_center)


def make_beams(echoes: Echoes, la: LeafAngle, settings: VoxelizeSettings, *, progress: bool = False, lad_field=None):
    """Stage 5: every pulse of every scan as a beam with its echoes and their weights.

    ``lad_field`` (:class:`~tlsvox.voxel.footprint.LadField`) is the
    ``geometric`` rule's leaf area density (:func:`geometric_rounds`).
    Returns the per-scan :class:`~tlsvox.voxel.beams.Beams` and their info dicts.
    """
    p, e = settings.poses, settings.echoes
    weights = EchoWeights.parse(e.echo_weights, "echo_weights")
    angular = None if p.angular_grid is None else AngularGrid(**p.angular_grid)
    rotation = None if p.socs_rotation is None else np.asarray(p.socs_rotation, dtype=np.float64)
    parts, infos = [], []
    it = list(zip(echoes.scans, echoes.poses, echoes.kinds))
    if progress:
        from tqdm.auto import tqdm

        it = tqdm(it, desc="pulses", unit="scan", leave=False)
    for sc, pose, k in it:
        part, info = beams_from_scan(sc, kinds=k, pose=pose, leaf_angle=la, max_range=p.max_range,
                                     angular_grid=angular, socs_rotation=rotation, echo_weights=weights,
                                     leaf_reflectance=e.leaf_reflectance, wood_reflectance=e.wood_reflectance,
                                     leaf_shape=tuple(settings.undetected.leaf_shape), lad_field=lad_field)
        parts.append(part)
        infos.append(info)
    return parts, infos


#: estimates made with the geometric echo weights, each from the one before (the first takes 1/n)
GEOMETRIC_ROUNDS = 2


def geometric_rounds(run, echoes: Echoes, checks, settings: VoxelizeSettings, lad, *, per_scan: bool,
                     progress: bool = False, rounds: int | None = None):
    """The ``geometric`` echo weights' rounds: weights from the estimate's leaf area density, traced and
    estimated again, ``rounds`` times (:mod:`tlsvox.voxel.footprint`).

    Returns the last round's sums, estimate, per-scan beams, joined beams and info dicts.
    """
    from tlsvox.voxel.footprint import LadField

    rounds = GEOMETRIC_ROUNDS if rounds is None else rounds
    for _ in range(rounds):
        dense = lad.lad
        if lad.rows is not None:  # sparse rows onto the grid (echo-free voxels: no leaves)
            dense = np.zeros(run.grid.shape, np.float32)
            dense[tuple(lad.rows.ijk.T)] = lad.lad
        field = LadField(np.asarray(run.grid.lower, dtype=np.float64), float(run.grid.voxel_size),
                         np.nan_to_num(np.asarray(dense, dtype=np.float64)))
        parts, infos = make_beams(echoes, checks.leaf_angle, settings, progress=progress, lad_field=field)
        beams = parts[0] if len(parts) == 1 else Beams.concat(parts)
        stats, scan_stats = run.sums(beams, parts if per_scan else None)
        lad = estimate(stats, checks.estimator, checks.fill, settings, scan_stats=scan_stats)
    for info in infos:
        info["echo_weights_rounds"] = rounds
    return stats, lad, parts, beams, infos


@dataclass
class TraceRun:
    """Stage 6: the tracer's set-up for one grid (the memory plan, the sparse rows, G), and its sums."""

    grid: VoxelGrid
    tracer: Tracer
    plan: MemoryPlan
    rows: Bricks | None  #: the sparse layout's rows (None: dense)
    recorded: np.ndarray | None  #: flat voxels of the recorded echoes (sparse runs with the detection model)
    projection: Projection
    max_bytes: int | None
    progress: bool = False

    @classmethod
    def start(cls, grid, beams, tracer, layout, checks: Checked, projection: Projection, n_scans: int,
              settings: VoxelizeSettings, *, progress: bool = False) -> TraceRun:
        """The memory plan (checked), the layout it chose and, when sparse, the rows of voxels holding echoes."""
        max_bytes = settings.grid.max_bytes
        voxels = echo_voxels(grid, beams)
        plan = memory_plan(grid, beams, tracer, layout=layout, voxels=voxels, max_bytes=max_bytes,
                           undetected=checks.undetected, fill=checks.fill, scans=n_scans)
        if plan.layout is Layout.SPARSE and checks.fill in DENSE_FILLS:
            raise InputError(f"fill={checks.fill.value!r} needs the dense layout, but this run is sparse "
                             f"({plan.describe()}); use fill='layer' (per brick layer in the sparse layout), a larger "
                             "voxel_size, or layout='dense' where memory allows")
        rows = Bricks.from_ijk(grid, voxels) if plan.layout is Layout.SPARSE else None
        # the sparse rounds of the detection model list the recorded echoes' voxels again, and the given-back ones
        recorded = grid.flat(voxels) if checks.detection is not None and rows is not None else None
        return cls(grid, tracer, plan, rows, recorded, projection, max_bytes, progress)

    def sums(self, joined, separate=None):
        """The sums of ``joined``, and each scan's (``separate``) when the fill calibrates on them."""
        budget = None if self.max_bytes is None else self.max_bytes - self.plan.beams
        kw = dict(rows=self.rows, outward=self.projection.g_tables, g_layer=self.projection.g_layer,
                  progress=self.progress, max_bytes=budget)
        if separate is None:
            return self.tracer.trace(self.grid, joined, **kw), None
        own = [self.tracer.trace(self.grid, b, **kw) for b in separate]
        return sum(own[1:], own[0]), own


def build_scene(grid, stats, lad, plane, infos, checks: Checked, projection: Projection, plan: MemoryPlan,
                undetected_meta: dict, settings: VoxelizeSettings, *, timings=None, t_estimate=None, t_start=None):
    """Stage 9: wood per voxel, the voxels a scene stores (none below the ground), the crown centre, the
    quality warnings and the meta (the settings in full among them).  Returns the Scene and the wood."""
    m = settings.model
    timings = {} if timings is None else timings
    wood_est = estimate_wood(stats, method=checks.wood, percentile=m.wood_percentile, n_min=m.n_min)
    ijk, lad_v, wood_v, occ_v, std_v = _stored_voxels(grid, lad, wood_est, plane)
    if projection.crown_center is None:
        cc = (grid.centers(ijk)[:, :2] * lad_v[:, None]).sum(axis=0) / lad_v.sum() if lad_v.sum() > 0 else np.zeros(2)
    else:
        cc = np.asarray(projection.crown_center, dtype=np.float64).reshape(2)
    now = time.perf_counter()
    if t_estimate is not None:
        timings["estimate"] = now - t_estimate
    if t_start is not None:
        timings["total"] = now - t_start
    warnings = quality_warnings(lad_v, occ_v, infos)
    calibration = lad.options.get("fill_calibration")
    if calibration is not None and not calibration["calibrated"]:
        warnings.append(f"fill='calibrated' found {calibration['voxels']} voxels that one scan sees and the others "
                        f"hide (it needs {CALIBRATION_MIN_VOXELS}): the occluded voxels took the neighbourhood "
                        "mean unscaled (ratio 1); scans from more different positions give it voxels to measure on")
    leaf_size = m.leaf_size
    if leaf_size is not None and grid.voxel_size < 2.0 * leaf_size:
        suggest = grid.voxel_size * int(np.ceil(2.0 * leaf_size / grid.voxel_size - 1e-9))
        warnings.append(f"voxels of {grid.voxel_size:g} m are narrower than two leaves ({leaf_size:g} m each): the "
                        "turbid estimators lose most of the leaf area in them (docs/voxelize.md, leaf-scale "
                        f"voxels); estimate the LAD on a coarser grid with lad_voxel_size={suggest:g} "
                        f"(CLI --lad-voxel-size {suggest:g})")
    la, layers = checks.leaf_angle, projection.layers
    meta = {
        "estimator": checks.estimator.value, "options": lad.options, "flags": lad.counts(),
        "wood_method": checks.wood.value, "wood_scale": wood_est.scale, "scans": infos, "timings": timings,
        "tracer": stats.device, "beams": stats.n_beams, "voxel_steps": stats.n_steps, "warnings": warnings,
        "leaf_angle": la.to_dict(), "layout": plan.layout.value,
        "leaf_angle_layers": None if layers is None else [
            {"z_low": None if not np.isfinite(z) else float(z), "leaf_angle": lm.to_dict()} for z, lm in layers],
        "memory_plan": plan.describe(),
        "echo_weights": [i["echo_weights"] for i in infos], "undetected": undetected_meta,
        "ground": None if plane is None else {"coefficients": list(plane.coefficients),
                                              "tilt_deg": plane.tilt_deg, "inlier_rmse": plane.inlier_rmse},
        "settings": settings.to_dict(),
    }
    if stats.sparse:
        meta["occluded_bricks"] = {"brick_voxels": BRICK, "occluded": int(lad.brick_occluded.sum()),
                                   "total": int(lad.brick_occluded.size)}
    scene = Scene(origin=grid.lower, voxel_size=grid.voxel_size, shape=grid.shape, ijk=ijk, lad=lad_v,
                  wood=wood_v, wood_kind=wood_est.kind, occluded=occ_v, lad_std=std_v, leaf_angle=la,
                  leaf_azimuth=checks.azimuth.value, crown_center=cc,
                  ground_z=None if plane is None else plane.z_center, meta=meta)
    return scene, wood_est


def _leaf_angle_layers(given):
    """``leaf_angle_layers`` as [(z_low, LeafAngle), ...] from the lowest layer up (the first z_low
    -inf), or None.  Only the lower bounds count: each layer reaches up to the next one's (z_high is
    read for the shape of the rows, and the highest layer takes everything above)."""
    if given is None:
        return None
    items = getattr(given, "layers", given)  # a LeafAngleMeasurement
    try:
        items = list(items)
    except TypeError as err:
        raise InputError("leaf_angle_layers must be a LeafAngleMeasurement (tlsvox.leafangles) or a list of "
                         "(z_low, z_high, LeafAngle), lowest layer first") from err
    out = []
    for item in items:
        if hasattr(item, "z_range") and hasattr(item, "leaf_angle"):  # a LayerLeafAngles
            z0, z1, model = float(item.z_range[0]), float(item.z_range[1]), item.leaf_angle
        else:
            try:
                z0, z1, model = item
                z0, z1 = float(z0), float(z1)
            except (TypeError, ValueError) as err:
                raise InputError(f"leaf_angle_layers: {item!r} is not (z_low, z_high, LeafAngle)") from err
            model = LeafAngle.from_dict(model)  # its own error names the valid models
        out.append((z0, z1, model))
    if not out:
        raise InputError("leaf_angle_layers is empty: give at least one layer, or leave it out")
    lows = [z0 for z0, _, _ in out]
    if not all(np.isfinite(lows)) or any(b <= a for a, b in zip(lows, lows[1:])):
        raise InputError(f"leaf_angle_layers must go up in height (lower bounds {lows}); lowest layer first")
    return [(-np.inf if k == 0 else z0, m) for k, (z0, _, m) in enumerate(out)]


def below_ground(grid, ijk, plane) -> np.ndarray:
    """(K,) bool: the voxels ``ijk`` whose top lies at or below the ground plane's centre height
    (a scene stores no leaf area or occlusion there)."""
    return grid.lower[2] + (np.asarray(ijk)[:, 2] + 1) * grid.voxel_size <= plane.z_center


def _stored_voxels(grid, lad: LadEstimate, wood: WoodEstimate, plane):
    """The voxels a scene stores (LAD, wood or occluded), nothing below the ground plane.

    Returns ijk (K, 3), lad, wood, occluded, lad_std (K,).
    """
    if lad.rows is None:
        ijk = np.argwhere((lad.lad > 0) | (wood.value > 0) | lad.occluded)
        sel = tuple(ijk.T)
        values, wood_v, occluded, std = lad.lad[sel], wood.value[sel], lad.occluded[sel], lad.lad_std[sel]
    else:  # sparse: the rows, then the echo-free voxels the fill gave a value
        extra = lad.extra_ijk if lad.extra_ijk is not None else np.zeros((0, 3), np.int64)
        ijk = np.vstack([lad.rows.ijk, extra])
        pad = np.zeros(len(extra))
        values = np.concatenate([lad.lad, pad if lad.extra_lad is None else lad.extra_lad])
        wood_v = np.concatenate([wood.value, pad])
        occluded = np.concatenate([lad.occluded, np.ones(len(extra), bool)])
        std = np.concatenate([lad.lad_std, pad])
    if plane is not None:
        below = below_ground(grid, ijk, plane)
        values = np.where(below, 0.0, values)
        occluded = occluded & ~below
    keep = (values > 0) | (wood_v > 0) | occluded
    return ijk[keep], values[keep], wood_v[keep], occluded[keep], std[keep]
