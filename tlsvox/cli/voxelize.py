"""``tlsvox voxelize``: registered scans -> voxel scene (NPZ, optionally AMAPVox .vox).

:func:`register` adds it to the ``tlsvox`` command (``tlsvox/cli/app.py``); :func:`main`
runs it alone (``python -m tlsvox.cli.voxelize``), with the same conventions (:mod:`voxlidar.cli`).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from tlsvox.errors import InputError, TlsvoxError
from voxlidar.cli import number, numbers
from voxlidar.safeio import check_distinct, check_outputs, json_text, staged

DESCRIPTION = """\
Estimate leaf area density per voxel from terrestrial laser scans (VoxLAD).

Every pulse of every scan (also those with no echo) is traced through a voxel
grid; per voxel the estimator turns entering beams, leaf hits and free path
lengths into leaf area density (m2/m3). Scans must be registered (a pose in
each scan's NAME.pose.json sidecar); a single scan may use its own frame with
--scanner-frame. Scans without a pulse table (points only) need their angular
grid (--angular-grid) to rebuild the pulses that left no echo.

Echo classes: the labels 'tlsvox classify' wrote into the scan, else the
scan's truth_material (simulated scans), otherwise every echo counts as plant
material (the result is then plant area density) except ground echoes near
the fitted ground plane. With --qsm, leaf-labelled echoes on the bark of a
fitted cylinder count as wood (in memory; --qsm-keep-labels keeps them leaf).

Echo weights (--echo-weights): how much of its pulse each echo stops. 'auto'
(default) uses the share of the beam the echo intercepted when the scan has a
beam_fraction column (simulated scans), else 1/n ('uniform'); 'fraction'
takes the share from the column or else from apparent reflectance over the
nominal reflectance of a full hit; 'threshold' is the paper's rule (drop
returns under half the nominal leaf reflectance, then 1/n); 'geometric' is
for multi-return scans with neither column nor reflectance: each echo's
expected share of the beam from the scanner's footprint, the leaf size
(--leaf-shape) and the scan's own returns per pulse. The summary states the
rule used per scan (docs/voxelize.md compares them).

Leaf angles (--leaf-angle): a named distribution, or 'measured' from the scans'
leaf echoes (truth material or the leaf class of 'tlsvox classify'): plane fits
at leaf scale, weighted for visibility, corrected for range noise, per crown
layer (docs/voxelize.md, docs/bench/leaf_angles.md for its accuracy).

Airborne full-waveform files (a NEON record folder, a LAS 1.3/1.4 file with
waveform packets) are voxelised too: each pulse is a beam from the sensor,
its echoes from the waveforms (or the file's discrete returns) weighted by
their energy against a full hit's (or 1/n), the voxels' sums pooled over a
footprint of neighbouring pulses, Beer-Lambert by default. Every echo counts
as vegetation (plant area density), the ground too unless --ground ransac or
a height makes its echoes stop the beams as ground (docs/replay.md, scenes
from airborne data).

Output: the scene NPZ (docs/formats.md) and, with --vox, an AMAPVox .vox file.
"""

EPILOG = """\
examples:
  tlsvox voxelize scan0.laz scan1.laz --voxel-size 0.2 --leaf-angle uniform --estimator bcmle -o scene.npz
  tlsvox voxelize tls_scan.laz --scanner-frame --angular-grid 30,0.048,2082,0,0.622,580 \\
  --scanner-rpy 1.026,0.746,-110.019 --voxel-size 0.2 -o plot.npz --vox plot.vox
  tlsvox voxelize neon-harvard-waveforms/ --voxel-size 0.5 -o neon.npz
"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Options of the voxelize subcommand."""
    from tlsvox.voxel.detection import Undetected
    from tlsvox.voxel.estimators import Estimator, FillMode
    from tlsvox.voxel.stages import Layout
    from tlsvox.voxel.weights import EchoWeights
    from tlsvox.voxel.wood.voxels import WoodMethod
    from voxlidar.leaf_orientation import LeafAngleKind, LeafAzimuth

    p.add_argument("scans", nargs="+", metavar="SCAN",
                   help="LAS/LAZ scans (with .pose.json / .pulses.npz sidecars), or pulse-grouped text exports "
                        "(x y z time return_index return_count, miss rows for empty pulses: .txt/.csv/.asc); or "
                        "one airborne full-waveform file: a NEON record folder or a LAS file with waveform packets")
    p.add_argument("-o", "--output", required=True, help="scene file to write (.npz)")
    p.add_argument("--vox", help="also write an AMAPVox .vox file")
    p.add_argument("--profile", metavar="PICTURE",
                   help="also draw the LAD profile: mean LAD of the seen voxels and the occluded share against "
                        "height (.png, .pdf, .svg, .jpg)")
    p.add_argument("--profile-radius", type=number(lo=0, lo_open=True, unit="m"), metavar="METRES",
                   help="the profile over the voxel columns within this distance of the crown centre (default: "
                        "the whole grid)")
    p.add_argument("--device", default=None, help="OpenCL device: 'platform:device', 'cpu', 'gpu' or a "
                   "name part (default: VOXLIDAR_DEVICE, else PYOPENCL_CTX, else the best working "
                   "device; `clsim devices` lists them)")
    p.add_argument("--strict", action="store_true",
                   help="fail (exit 2, nothing written) when a quality gate warns: LAD above 20 m2/m3, "
                        "more than half the voxels occluded, or a poor angular-grid fit")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bars or summary")
    p.add_argument("--config", metavar="FILE",
                   help="settings from a TOML file (groups [grid], [model], [ground], [echoes], [undetected], "
                        "[poses], as the option groups below) or from a scene .npz a run wrote (its meta records "
                        "them): repeats that run; a flag given on the command line wins")
    p.add_argument("--write-config", metavar="FILE", help="also write this run's settings as TOML (for --config)")
    p.add_argument("--plan", action="store_true",
                   help="print what the grid will cost in memory for each layout, and exit (writes nothing)")
    grid = p.add_argument_group("the grid ([grid] in --config)")
    grid.add_argument("--voxel-size", type=float, default=0.2, help="voxel edge in metres (default 0.2)")
    grid.add_argument("--bounds", type=numbers(6),
                      help="xmin,ymin,zmin,xmax,ymax,zmax of the region (default: the vegetation's box); the "
                           "grid starts exactly at the minimum corner")
    grid.add_argument("--snap", action="store_true",
                      help="snap --bounds outwards to multiples of the voxel size (grids of runs line up)")
    grid.add_argument("--layout", default="auto", choices=[m.value for m in Layout],
                      help="tracer memory: sums for every voxel (dense), or only for voxels holding echoes "
                           "plus coarse sums per 8^3 brick (sparse; small voxels); default auto: dense up to 1 GiB")
    grid.add_argument("--lad-voxel-size", type=float, default=None, metavar="METRES",
                      help="estimate the LAD on a grid this much coarser (a whole multiple of --voxel-size, e.g. "
                           "0.1 for 0.02 voxels; the estimators need voxels wider than the leaves) and put it on the "
                           "fine grid, which keeps the wood and ground at --voxel-size (docs/voxelize.md, "
                           "leaf-scale voxels)")
    grid.add_argument("--lad-placement", default="even", choices=["even", "echoes"],
                      help="with --lad-voxel-size: every fine voxel takes its coarse voxel's LAD (even, default), "
                           "or its leaf area shared by the fine voxels' leaf echo weight (echoes)")
    ground = p.add_argument_group("the ground ([ground] in --config)")
    ground.add_argument("--ground", default=None,
                      help="'ransac' (fit the lowest echoes; the default for scans), 'none' (the default for "
                           "airborne files, whose records often end above the ground: every echo is then "
                           "vegetation), or a ground height in metres")
    ground.add_argument("--ground-tolerance", type=float, default=0.15, metavar="METRES",
                        help="echoes this far above the ground plane stop beams as ground, not leaves (default 0.15)")
    model = p.add_argument_group("the leaf and wood model ([model] in --config)")
    steps = p.add_argument_group("steps before the voxels: leaf angles measured, cylinders fitted to the wood")
    model.add_argument("--leaf-angle", default=None, choices=[k.value for k in LeafAngleKind] + ["measured"],
                       help="leaf inclination distribution for G(theta) (default uniform, the paper; the "
                            "summary and the scene say which was used); 'measured': from the leaf echoes' plane "
                            "fits (tlsvox.leafangles), a beta distribution fitted to the whole crown, the per-layer "
                            "histograms kept in the scene's meta")
    steps.add_argument("--leaf-angle-layers", type=int, default=4,
                       help="crown layers of --leaf-angle measured (default 4)")
    steps.add_argument("--leaf-angle-by-layer", action="store_true",
                       help="with --leaf-angle measured: each crown layer's own distribution gives G(theta) in "
                            "its voxels (the scene keeps the whole crown's for the simulator)")
    model.add_argument("--leaf-azimuth", default="uniform", choices=[a.value for a in LeafAzimuth],
                       help="leaf normal azimuths: any (default), or facing away from the crown axis, which then "
                            "gives each voxel the G of outward leaves for each beam (and the simulator uses it)")
    model.add_argument("--estimator", default=None, choices=[e.value for e in Estimator],
                       help="LAD estimator (default bcmle, Pimont et al. 2018; airborne files: beer_lambert, exact "
                            "with energy echo weights)")
    model.add_argument("--wood", default="count_stretch", choices=[w.value for w in WoodMethod],
                       help="wood model (default count_stretch, the paper)")
    steps.add_argument("--qsm", action="store_true",
                       help="fit cylinders to the wood echoes (classified scans, or truth material) and fill solid "
                            "wood voxels from them; wood echoes no cylinder explains stay turbid wood "
                            "(docs/voxelize.md, solid wood from fitted cylinders; tlsvox.pipeline does it by default); "
                            "leaf-classed echoes on a cylinder's bark are counted as wood (see --qsm-keep-labels)")
    steps.add_argument("--qsm-keep-labels", action="store_true",
                       help="with --qsm: keep the scans' leaf labels on the fitted cylinders' bark (by default "
                            "the leaf echoes of classified scans there count as wood; truth materials are kept; "
                            "the files are never changed)")
    model.add_argument("--fill", default="none", choices=[f.value for f in FillMode],
                       help="occluded voxels: leave at 0, fill with their height layer's mean, with the mean "
                            "of the nearest seen crown voxels (neighbourhood; dense layout), or with that mean "
                            "times the ratio the scans measure where one hides what another sees (calibrated; "
                            "dense layout, two or more scans)")
    model.add_argument("--n-min", type=int, default=None,
                       help="beams a voxel needs (else occluded; default 5; airborne files: 1 pooled beam)")
    model.add_argument("--min-explored", type=float, default=0.05,
                       help="explored depth fraction a voxel needs (else occluded; default 0.05)")
    model.add_argument("--leaf-size", type=float, default=0.05, help="leaf size in metres for the large-leaf flag")
    model.add_argument("--small-voxel-factor", type=float, default=1.0,
                       help="multiply every LAD (the paper used 0.95; default 1)")
    weights = p.add_argument_group("echo weights: how echoes share their pulse ([echoes] in --config)")
    weights.add_argument("--echo-weights", default="auto", choices=[w.value for w in EchoWeights],
                         help="how echoes share their pulse: auto (default: fraction with a beam_fraction column, "
                              "else uniform), uniform (1/n), fraction (intercepted share), threshold (the paper), "
                              "geometric (the expected share from the beam's footprint: no reflectance needed)")
    weights.add_argument("--leaf-reflectance", type=float,
                         help="nominal leaf reflectance of a full hit (fraction from reflectance, threshold); "
                              "default the leaf optics at the scanner's wavelength")
    weights.add_argument("--wood-reflectance", type=float, help="nominal bark reflectance of a full hit (fraction)")
    missed = p.add_argument_group("leaf hits under the detection threshold ([undetected] in --config)")
    missed.add_argument("--undetected", default="ignore", choices=[u.value for u in Undetected],
                        help="leaf hits under the scanner's detection threshold: ignore (default; LAD biased low) or "
                             "model (give the expected unrecorded interception back; docs/voxelize.md)")
    missed.add_argument("--leaf-shape", default="0.05,0.025", type=numbers(2, what="length,width in metres",
                                                                   example="0.05,0.025"),
                        help="leaf length,width in metres for --undetected model and --echo-weights geometric "
                             "(default 0.05,0.025)")
    missed.add_argument("--detection-threshold-db", type=float,
                        help="the scanner's detection threshold, dB of a white target (default: the scan's preset; "
                             "the RIEGL VZ-400: -20)")
    inputs = p.add_argument_group("what the scans are given: poses, the scanner's position in text files")
    inputs.add_argument("--transforms", metavar="JSON",
                        help="poses from 'tlsvox register' (its .transforms.json); they replace the "
                             ".pose.json sidecars, matched by scan name")
    inputs.add_argument("--scan-origin", type=numbers(3),
                        help="x,y,z of the scanner in the coordinates of a pulse-grouped text file or of a LAS "
                             "file without a pose (HELIOS++'s world coordinates) (default 0,0,0)")
    poses = p.add_argument_group("scans without a pose, and the empty pulses of scans without a pulse table "
                                 "([poses] in --config)")
    poses.add_argument("--scanner-frame", action="store_true",
                       help="a single scan without pose: use its own frame as the world")
    poses.add_argument("--angular-grid", type=numbers(6),
                       help="zenith0,zstep,nzenith,azimuth0,astep,nazimuth (degrees) to rebuild empty pulses")
    poses.add_argument("--scanner-rpy", type=numbers(3),
                       help="roll,pitch,yaw (degrees) of the scanner's own frame in the scan's frame")
    poses.add_argument("--max-range", type=float, help="follow empty pulses this far (metres)")
    merged = p.add_argument_group("merged point clouds without pulses (one registered cloud, or one file per scan "
                                  "position without its pulse table; tlsvox.voxel.merged)")
    merged.add_argument("--scan-positions", metavar="POSITIONS",
                        help="where the scanner stood, in the cloud's coordinates: x,y,z;x,y,z or a text file of x y z "
                             "lines (the beams are rebuilt from each position to its points and the empty pulses "
                             "estimated), or 'unknown' (no beams: leaf area from the cells holding leaf points, "
                             "occlusion not corrected); a list that starts with a minus sign goes after '=': "
                             "--scan-positions=-3.5,-19.7,1.7;9.1,4.2,1.7")
    merged.add_argument("--angular-step", type=numbers(1, 2, what="degrees", example="0.04 or 0.048,0.622"),
                        help="with --scan-positions: the scanner's angular step in degrees, one value or "
                             "zenith,azimuth (default: estimated from the cloud)")
    merged.add_argument("--assign", choices=["auto", "source-id", "nearest"], default="auto",
                        help="with --scan-positions: which position each point was seen from: one file per position "
                             "or the LAS point_source_id (auto, when their count matches), else the nearest position")
    merged.add_argument("--occupancy-cell", type=number(lo=0, lo_open=True, unit="m"), metavar="METRES",
                        help="with --scan-positions unknown: the fine cell whose occupancy counts (default: the leaf "
                             "points' spacing, at least 0.01 m)")
    air = p.add_argument_group("airborne full-waveform files (NEON record folders, LAS with waveform packets)")
    air.add_argument("--airborne-echoes", default="waveform", choices=["waveform", "returns"],
                     help="echoes from the waveforms' template decomposition (default) or the LAS file's own "
                          "discrete returns; --echo-weights uniform gives each 1/n of its pulse, else its energy "
                          "over a full hit's")
    air.add_argument("--beams-per-footprint", type=float, default=3.0,
                     help="each voxel's sums are pooled over a horizontal Gaussian holding this many pulses "
                          "(default 3)")
    air.add_argument("--no-hotspot", action="store_true",
                     help="the echoes' light came back through the canopy independently (two-way attenuation: a "
                          "target behind transmittance T returns T^2 of a full hit), not through the gap it went "
                          "down (the small-footprint hot spot, the default)")
    air.add_argument("--divergence-mrad", type=float, default=None,
                     help="beam divergence half angle at 1/e^2, mrad (not in the files; default: NEON 0.25; LAS: "
                          "the clsim preset a clsim survey file names, else 0.11 as a Leica ALS50-II)")


def register(subparsers) -> argparse.ArgumentParser:
    """Add ``voxelize`` to a ``tlsvox`` subparsers object; returns its parser."""
    p = subparsers.add_parser("voxelize", help="scans -> voxel LAD scene (VoxLAD)", description=DESCRIPTION,
                              epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_arguments(p)
    p.set_defaults(func=run)
    return p


def apply_transforms(scans, path) -> None:
    """Set each scan's pose from a ``tlsvox register`` transforms JSON (by scan name)."""
    from tlsvox.register import read_transforms

    path = Path(path)
    if not path.is_file():
        raise InputError(f"--transforms {path} does not exist; 'tlsvox register ... -o merged.laz' "
                          "writes merged.transforms.json")
    try:
        poses = read_transforms(path)
    except (ValueError, KeyError, TypeError) as err:
        raise InputError(f"--transforms {path} is not a tlsvox registration JSON ({err}); "
                          "write it with 'tlsvox register'") from None
    missing = [s.name for s in scans if s.name not in poses]
    if missing:
        raise InputError(f"--transforms {path} has no pose for scan(s) {missing}; it holds "
                          f"{sorted(poses)}. Register these scans together, or name the files alike")
    for s in scans:
        pose = poses[s.name]
        if pose.shape != (4, 4) or not np.all(np.isfinite(pose)):
            raise InputError(f"--transforms {path}: the pose of {s.name!r} is not a finite 4x4 matrix")
        s.pose = pose


def read_scan(path, scan_id: int, origin=None):
    """One scan file: LAS/LAZ with its sidecars, or a pulse-grouped text export (``origin`` = the scanner there)."""
    from tlsvox.readers import ScanFormat, read_any, scan_format
    from tlsvox.scan import Scan

    path = Path(path)
    if not path.is_file():
        raise InputError(f"scan file {str(path)!r} does not exist" if not path.exists() else
                         f"{str(path)!r} is not a file (a directory?); give the scan files themselves")
    fmt = scan_format(path)
    if fmt in (ScanFormat.LAS, ScanFormat.LAZ):
        return Scan.read(path, scan_id=scan_id, origin=origin)
    if fmt is not ScanFormat.PULSES:
        raise InputError(f"{path}: voxelize needs pulses (LAS/LAZ with a pulse table or return numbers, or "
                         f"pulse-grouped text), not a bare {fmt.value.upper()} point cloud")
    return read_any(path, scan_id=scan_id, origin=origin, min_points=1)


def run(args) -> int:
    """Handler: voxelise ``args.scans`` and write ``args.output``; returns the exit code."""
    from tlsvox.cli.airborne import airborne_kind, run_airborne
    from tlsvox.scan import AngularGrid, sidecar_paths
    from tlsvox.voxel.amapvox import write_vox
    from tlsvox.voxel.pulses import rotation_from_rpy
    from tlsvox.voxel.stages import voxelize
    from tlsvox.voxel.trace import Tracer

    if any(airborne_kind(path) for path in args.scans):
        return run_airborne(args, _defaults())
    explicit = {k for k, v in _defaults().items() if getattr(args, k, v) != v}  # before the defaults below
    config = _config_settings(args)  # settings of --config the command line does not set
    args.estimator = args.estimator or "bcmle"
    args.ground = args.ground or "ransac"
    args.n_min = 5 if args.n_min is None else args.n_min
    if args.bounds is not None and not np.all(np.reshape(args.bounds, (2, 3))[1] > np.reshape(args.bounds, (2, 3))[0]):
        raise InputError(f"--bounds {args.bounds}: give xmin,ymin,zmin,xmax,ymax,zmax with each max above its min")
    check_distinct("scan", args.scans)
    check_outputs([("scan", p) for path in args.scans for p in (path, *sidecar_paths(path))]
                  + [("--transforms", args.transforms), ("--config", args.config)],
                  [("-o", args.output), ("--vox", args.vox), ("--write-config", args.write_config),
                   ("--profile", args.profile)])
    from voxlidar.safeio import check_figure_path

    check_figure_path("--profile", args.profile)
    if args.profile_radius is not None and args.profile is None:
        raise InputError("--profile-radius needs --profile PICTURE (it says what the profile covers)")
    if Path(args.output).suffix.lower() != ".npz":
        raise InputError(f"-o {args.output} must end in .npz (the scene file); --vox PATH adds an AMAPVox .vox")
    if args.vox is not None and Path(args.vox).suffix.lower() != ".vox":
        raise InputError(f"--vox {args.vox} must end in .vox")
    merged_parts = None
    if args.scan_positions is not None:
        scans, merged_parts = _merged_scans(args, explicit)
        if merged_parts is None:
            return _run_occupancy(args, scans[0])
    else:
        for flag, given in (("--angular-step", args.angular_step), ("--occupancy-cell", args.occupancy_cell),
                            ("--assign", args.assign != "auto")):
            if given:
                raise InputError(f"{flag} is for merged clouds without pulses: give --scan-positions too")
        scans = [read_scan(path, i, args.scan_origin) for i, path in enumerate(args.scans)]
    if args.transforms:
        apply_transforms(scans, args.transforms)
    ground = _ground_arg(args.ground)
    grid = None
    if args.angular_grid:
        z0, dz, nz, a0, da, na = args.angular_grid
        grid = AngularGrid(z0, dz, int(nz), a0, da, int(na))
    rot = rotation_from_rpy(*args.scanner_rpy) if args.scanner_rpy else None
    bounds = None if args.bounds is None else np.reshape(args.bounds, (2, 3))
    options = dict(voxel_size=args.voxel_size, estimator=args.estimator, snap=args.snap, layout=args.layout,
                   leaf_azimuth=args.leaf_azimuth, wood=args.wood, fill=args.fill, n_min=args.n_min,
                   min_explored=args.min_explored, leaf_size=args.leaf_size,
                   small_voxel_factor=args.small_voxel_factor, ground=ground, bounds=bounds,
                   scanner_frame=args.scanner_frame, angular_grid=grid, socs_rotation=rot, max_range=args.max_range,
                   progress=not args.quiet, echo_weights=args.echo_weights, leaf_reflectance=args.leaf_reflectance,
                   wood_reflectance=args.wood_reflectance, undetected=args.undetected,
                   detection_threshold_db=args.detection_threshold_db, leaf_shape=args.leaf_shape,
                   ground_tolerance=args.ground_tolerance, tracer=Tracer(args.device) if args.device else None)
    options.update(config)  # the config's settings that no flag sets, and those no flag was given for
    if args.lad_voxel_size is not None:
        from tlsvox.voxel.coarse import ratio_of

        ratio_of(args.voxel_size, args.lad_voxel_size)  # before any fitting or measuring
        options.update(lad_voxel_size=args.lad_voxel_size, lad_placement=args.lad_placement)
    elif args.lad_placement != "even":
        raise InputError("--lad-placement needs --lad-voxel-size (it says how the coarse LAD is put on the fine grid)")
    if args.leaf_angle_by_layer and args.leaf_angle != "measured":  # before any fitting or measuring
        raise InputError("--leaf-angle-by-layer needs --leaf-angle measured (the layers' distributions come from "
                         "the scans)")
    if args.qsm_keep_labels and not args.qsm:
        raise InputError("--qsm-keep-labels needs --qsm (it keeps the leaf labels on the fitted cylinders' bark)")
    if args.plan:  # the same run's plan (the leaf angle model does not change what it holds)
        print(voxelize(scans, plan_only=True, **options).describe())
        return 0
    qsm = model = None
    relabelled = 0
    if args.qsm:  # before the leaf angles are measured: they read the leaf labels
        from tlsvox.classify import PointClass
        from tlsvox.voxel.wood.qsm import bark_echoes, fit_cylinders, wood_points

        model = fit_cylinders(wood_points(scans))
        if not args.qsm_keep_labels:  # classified scans only (in memory; the input files are not touched)
            classified = [s for s in scans if s.classification is not None]
            for s, bark in zip(classified, bark_echoes(classified, model)):
                s.classification = np.where(bark, np.uint8(PointClass.WOOD), s.classification).astype(
                    s.classification.dtype)
                relabelled += int(bark.sum())
    measured = None
    from_config = options.pop("leaf_angle", "uniform")  # a --config's leaf-angle table, if it gave one
    leaf_angle = args.leaf_angle or from_config
    if args.leaf_angle == "measured":
        from tlsvox.leafangles import measure_leaf_angles
        from tlsvox.voxel.stages import scan_poses

        if args.leaf_angle_layers < 1:
            raise InputError(f"--leaf-angle-layers {args.leaf_angle_layers} must be >= 1 (e.g. 4)")
        scan_poses(scans, args.scanner_frame)  # refuse a scan without a pose before the long measurement
        measured = measure_leaf_angles(scans, layers=args.leaf_angle_layers)
        leaf_angle = measured.leaf_angle
    res = voxelize(scans, leaf_angle=leaf_angle, leaf_angle_layers=measured if args.leaf_angle_by_layer else None,
                   **options)
    if args.qsm:
        from tlsvox.voxel.wood.qsm import apply_cylinders, wood_points

        wood = wood_points(scans)
        if not len(wood):
            res.scene.meta["warnings"].append("--qsm: the scans have no wood echoes (classify them with tlsvox "
                                              "classify); no cylinders were fitted")
        res.scene, qsm = apply_cylinders(res.scene, model, wood)
        qsm["leaf_echoes_relabelled_wood"] = relabelled
        res.scene.meta.setdefault("qsm", {**model.summary(), **qsm})["leaf_echoes_relabelled_wood"] = relabelled
    if merged_parts is not None:
        from tlsvox.voxel.merged import merged_warnings

        res.scene.meta["merged"] = [sc.meta["merged"] for sc in scans]
        res.scene.meta["warnings"].extend(merged_warnings(scans))
    for w in res.scene.meta["warnings"]:
        print(f"tlsvox voxelize: warning: {w}", file=sys.stderr)
    if args.strict and res.scene.meta["warnings"]:
        raise TlsvoxError(f"{len(res.scene.meta['warnings'])} quality warning(s) with --strict; "
                          "nothing was written (drop --strict to keep the result)")
    if measured is not None:
        res.scene.meta["leaf_angle_measured"] = measured.to_dict()
    with staged([args.output, args.vox, args.write_config]) as tmp:  # the scene, its .vox and settings: all or none
        res.scene.save(tmp[args.output])
        if args.vox:
            write_vox(res.scene, tmp[args.vox])
        if args.write_config:
            from tlsvox.voxel.settings import VoxelizeSettings

            Path(tmp[args.write_config]).write_text(VoxelizeSettings.from_dict(res.scene.meta["settings"]).to_toml(),
                                                    encoding="utf-8")
    if args.profile:
        _draw_profile(res.scene, args)
    if not args.quiet:
        s = res.scene
        summary = {"output": str(args.output), "grid": list(res.grid.shape), "voxel_size": s.voxel_size,
                   "voxels_stored": s.n_voxels, "leaf_area_m2": round(s.total_leaf_area(), 3),
                   "leaf_angle": s.leaf_angle.to_dict() | ({} if args.leaf_angle else {"note": "the default; "
                                                                            "set it with --leaf-angle"})
                   | ({} if measured is None else {"measured": {
                       "method": measured.method.value,
                       "mean_inclination_deg": round(float(np.degrees(measured.crown.mean_inclination)), 1),
                       "layers_mean_inclination_deg": [round(float(np.degrees(lay.mean_inclination)), 1)
                                                       for lay in measured.layers]}}),
                   "layout": s.meta["layout"], "grid_origin": [round(v, 6) for v in res.grid.origin],
                   "estimator": s.meta["estimator"], "echo_weights": s.meta["echo_weights"],
                   "undetected": {k: v for k, v in s.meta["undetected"].items() if k != "models"},
                   "flags": s.meta["flags"], "beams": s.meta["beams"],
                   **({} if "lad_voxel_size" not in s.meta else {"lad_voxel_size": {
                       k: s.meta["lad_voxel_size"][k] for k in ("size", "placement", "rule", "flags")}}),
                   **({} if qsm is None else {"qsm": s.meta.get("qsm", qsm)}),
                   **({} if merged_parts is None else {"merged": [
                       {k: m[k] for k in ("position", "assigned", "points", "returned_pulses", "empty_pulses",
                                          "expected_from", "coverage_p90")} for m in s.meta["merged"]]}),
                   "seconds": {k: round(v, 2) for k, v in res.timings.items()}}
        print(json_text(summary, indent=1))
    return 0


#: flags that rebuild or stand in for pulses, refused beside --scan-positions (they say where pulses come from)
_POSITION_CONFLICTS = (("transforms", "--transforms"), ("scan_origin", "--scan-origin"),
                       ("scanner_frame", "--scanner-frame"), ("angular_grid", "--angular-grid"),
                       ("scanner_rpy", "--scanner-rpy"))
#: flags of the beam estimators, refused with --scan-positions unknown (there are no beams)
_BEAM_ONLY = (("estimator", "--estimator"), ("fill", "--fill"), ("echo_weights", "--echo-weights"),
              ("undetected", "--undetected"), ("lad_voxel_size", "--lad-voxel-size"), ("n_min", "--n-min"),
              ("max_range", "--max-range"), ("qsm", "--qsm"), ("plan", "--plan"))


def _merged_scans(args, explicit: set):
    """--scan-positions: the files as one merged world-frame cloud, split into one scan per position
    with its pulses rebuilt (returns scans, the parts), or with 'unknown' ([merged], None)."""
    from tlsvox.voxel.merged import read_merged, split_by_positions

    for dest, flag in _POSITION_CONFLICTS:
        if dest in explicit:
            raise InputError(f"{flag} does not go with --scan-positions: the positions say where the beams start "
                             "(a merged cloud is taken in its own coordinates)")
    unknown = str(args.scan_positions).strip().lower() == "unknown"
    if unknown:
        for dest, flag in _BEAM_ONLY + (("angular_step", "--angular-step"),):
            if dest in explicit:
                raise InputError(f"{flag} needs beams; with --scan-positions unknown there are none (give the "
                                 "positions, x,y,z;x,y,z, to rebuild them)")
        if args.leaf_angle == "measured":
            raise InputError("--leaf-angle measured needs the scan positions (it models each scanner's view); give "
                             "them, or name a distribution (e.g. --leaf-angle spherical)")
    elif args.occupancy_cell is not None:
        raise InputError("--occupancy-cell is for --scan-positions unknown (the estimate without beams)")
    merged, source = read_merged(args.scans)
    if unknown:
        return [merged], None
    parts = split_by_positions(merged, args.scan_positions, source_id=source, assign=args.assign,
                               step=args.angular_step, progress=not args.quiet)
    return parts, parts


def _ground_arg(value) -> str | float | None:
    """--ground as voxelize takes it: 'ransac', None for 'none', or a height in metres."""
    if value in ("ransac", "none"):
        return None if value == "none" else value
    try:
        return float(value)
    except ValueError:
        raise InputError(f"--ground={value!r} must be 'ransac', 'none' or a height in metres") from None


def _draw_profile(scene, args) -> None:
    """--profile: the scene's LAD profile picture (tlsvox.voxel.profile)."""
    from tlsvox.voxel.profile import lad_profile, lad_profile_figure

    prof = lad_profile(scene, radius=args.profile_radius)
    where = "the whole grid" if args.profile_radius is None else f"within {args.profile_radius:g} m of the crown centre"
    names = ", ".join(Path(p).name for p in args.scans[:3]) + (" ..." if len(args.scans) > 3 else "")
    est = scene.meta.get("estimator", "")
    lad_profile_figure({f"{est}, {scene.voxel_size:g} m voxels": prof}, args.profile,
                       title=f"LAD profile: {names}",
                       caption=f"tlsvox voxelize -> {Path(args.output).name}; {where}; heights "
                               + ("above the ground plane" if prof.above_ground else "in the grid's z"))
    if not args.quiet:
        print(f"tlsvox voxelize: profile written to {args.profile}", file=sys.stderr)


def _run_occupancy(args, merged) -> int:
    """--scan-positions unknown: the occupancy scene (tlsvox.voxel.merged.voxelize_occupancy)."""
    from tlsvox.voxel.amapvox import write_vox
    from tlsvox.voxel.merged import voxelize_occupancy

    ground = _ground_arg(args.ground)
    bounds = None if args.bounds is None else np.reshape(args.bounds, (2, 3))
    leaf_angle = args.leaf_angle or "uniform"
    res = voxelize_occupancy(merged, cell=args.occupancy_cell, voxel_size=args.voxel_size, ground=ground,
                             bounds=bounds, snap=args.snap, leaf_angle=leaf_angle, wood=args.wood,
                             ground_tolerance=args.ground_tolerance, leaf_azimuth=args.leaf_azimuth)
    for w in res.scene.meta["warnings"]:
        print(f"tlsvox voxelize: warning: {w}", file=sys.stderr)
    if args.strict and res.scene.meta["warnings"]:
        raise TlsvoxError(f"{len(res.scene.meta['warnings'])} quality warning(s) with --strict; "
                          "nothing was written (drop --strict to keep the result)")
    with staged([args.output, args.vox]) as tmp:
        res.scene.save(tmp[args.output])
        if args.vox:
            write_vox(res.scene, tmp[args.vox])
    if args.profile:
        _draw_profile(res.scene, args)
    if not args.quiet:
        s = res.scene
        print(json_text({"output": str(args.output), "grid": list(res.grid.shape), "voxel_size": s.voxel_size,
                         "voxels_stored": s.n_voxels, "leaf_area_m2": round(s.total_leaf_area(), 3),
                         "estimator": "occupancy", "occupancy": s.meta["occupancy"],
                         "leaf_angle": s.leaf_angle.to_dict(), "seconds": round(res.timings["total"], 2)}, indent=1))
    return 0


#: settings whose command-line flag gives them in another form (dest: how --config's value becomes it)
_CLI_FORM = {
    "bounds": lambda v: None if v is None else [float(x) for row in v for x in row],
    "angular_grid": lambda v: None if v is None else [v[k] for k in ("zenith_start_deg", "zenith_step_deg", "n_zenith",
                                                                   "azimuth_start_deg", "azimuth_step_deg",
                                                                   "n_azimuth")],
    "ground": lambda v: "none" if v is None else v if isinstance(v, str) else str(v),
    "leaf_shape": lambda v: [float(x) for x in v],
}


def _config_settings(args) -> dict:
    """The settings of ``--config`` (a TOML file or a scene NPZ) that the command line does not give.

    A setting with a flag is put on ``args`` where the flag was left at its default; the others (no
    flag, or a form no flag takes: a leaf-angle table, a rotation matrix, a given ground plane) are
    returned as voxelize keywords.
    """
    if not args.config:
        return {}
    from tlsvox.voxel.settings import VoxelizeSettings

    kwargs = VoxelizeSettings.read(args.config).to_kwargs()
    defaults = _defaults()
    out = {}
    for name, value in kwargs.items():
        dest = "scanner_rpy" if name == "socs_rotation" else name
        if dest in defaults and getattr(args, dest) != defaults[dest]:
            continue  # the command line wins
        if name == "socs_rotation" or (name == "leaf_angle" and not isinstance(value, str)) or (
                name == "ground" and isinstance(value, dict)) or dest not in defaults:
            out[name] = value
        else:
            setattr(args, dest, _CLI_FORM.get(name, lambda v: v)(value))
    return out


def _defaults() -> dict:
    """The options' defaults, to tell which ones a run set."""
    p = argparse.ArgumentParser()
    add_arguments(p)
    return vars(p.parse_args(["scan", "-o", "scene.npz"]))


def main(argv=None) -> int:
    """Run ``voxelize`` alone: ``python -m tlsvox.cli.voxelize SCAN... -o scene.npz``."""
    from tlsvox.cli.app import main as tlsvox_main

    return tlsvox_main(["voxelize", *(sys.argv[1:] if argv is None else argv)])


if __name__ == "__main__":
    sys.exit(main())
