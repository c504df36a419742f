"""``tlsvox georegister``: place a TLS cloud in the airborne frame (yaw search + ICP).

The library side is :mod:`tlsvox.register.georegister`.  ``clsim georegister``
is the same command (kept for old scripts).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from tlsvox.errors import InputError, RegistrationError
from voxlidar.cli import number
from voxlidar.safeio import check_outputs, json_text

__all__ = ["cmd_georegister", "register"]


def register(subparsers) -> None:
    """Add ``georegister`` to an argparse subparsers object."""
    geo = subparsers.add_parser(
        "georegister", help="place a TLS cloud in the airborne frame (ICP + yaw search)",
        description="Register SOURCE (TLS cloud, its own frame) to TARGET (airborne cloud) "
                    "with a restricted yaw search and point-to-plane ICP; write the 4x4 "
                    "source->target transform and its fitness as JSON.")
    geo.add_argument("source", type=Path, help="TLS cloud (.las/.laz/.ply/.pcd/.xyz/.npy)")
    geo.add_argument("target", type=Path, help="airborne cloud (same formats)")
    geo.add_argument("-o", "--output", type=Path, required=True, help="transform (.json)")
    geo.add_argument("--init", default=None,
                     help="initial guess 'tx,ty,tz,yaw_deg' (source->target) or a JSON file "
                          "with a 'transform' 4x4; default: centroids and lowest points")
    geo.add_argument("--yaw-range", type=number(lo=0, hi=180, unit="degrees"), default=30.0,
                     help="+- degrees searched (30)")
    geo.add_argument("--yaw-step", type=number(lo=0, lo_open=True, unit="degrees"), default=5.0,
                     help="degrees between trials (5)")
    geo.add_argument("--voxel-size", type=number(lo=0, lo_open=True, unit="m"), default=0.2,
                     help="fine voxel size, m (0.2)")
    geo.add_argument("--min-fitness", type=number(lo=0, hi=1), default=0.3,
                     help="least accepted fitness: the share of airborne points with a TLS point within the "
                          "final distance (0.3); below it the command fails and writes nothing")
    geo.add_argument("--strict", action="store_true",
                     help="also fail when the best yaw lies at the edge of the searched range")
    geo.add_argument("--output-cloud", type=Path,
                     help="also write SOURCE transformed into the target frame (.ply/.npy/.xyz)")
    geo.set_defaults(func=cmd_georegister)


def _read_cloud(path: Path) -> np.ndarray:
    path = Path(path)
    if not path.is_file():
        raise InputError(f"point cloud {str(path)!r} does not exist")
    suffix = path.suffix.lower()
    if suffix in (".las", ".laz"):
        import laspy

        las = laspy.read(path)
        return np.column_stack([las.x, las.y, las.z]).astype(np.float64)
    if suffix == ".npy":
        return np.load(path).astype(np.float64)
    if suffix in (".ply", ".pcd", ".xyz", ".pts"):
        import open3d as o3d

        pc = o3d.io.read_point_cloud(str(path))
        return np.asarray(pc.points, dtype=np.float64)
    raise InputError(f"{path.name}: unknown point cloud type {suffix!r}; use .las, .laz, "
                     ".ply, .pcd, .xyz or .npy")


def _parse_init(value) -> np.ndarray | None:
    if value is None:
        return None
    p = Path(value)
    if p.suffix.lower() == ".json":
        if not p.is_file():
            raise InputError(f"--init {p} does not exist; give 'tx,ty,tz,yaw_deg' or a JSON file with 'transform'")
        try:
            m = np.asarray(json.loads(p.read_text())["transform"], dtype=np.float64)
        except (json.JSONDecodeError, KeyError, TypeError, ValueError) as err:
            raise InputError(f"--init {p}: not a JSON file with a 4x4 'transform' ({type(err).__name__}: {err})") \
                from None
        if m.shape != (4, 4):
            raise InputError(f"--init {p}: 'transform' must be 4x4, got shape {m.shape}")
        return m
    try:
        tx, ty, tz, yaw = (float(v) for v in str(value).split(","))
    except ValueError as err:
        raise InputError(f"--init must be 'tx,ty,tz,yaw_deg' or a JSON file with 'transform'; "
                         f"got {value!r}") from err
    from tlsvox.register.georegister import yaw_matrix

    m = yaw_matrix(yaw)
    m[:3, 3] = [tx, ty, tz]
    return m


def cmd_georegister(args) -> int:
    from tlsvox.register.georegister import georegister, transform_points
    from voxlidar.safeio import atomic_write

    check_outputs([("source", args.source), ("target", args.target)],
                  [("-o", args.output), ("--output-cloud", args.output_cloud)])
    if args.output_cloud is not None and args.output_cloud.suffix.lower() not in (".npy", ".ply", ".pcd", ".xyz"):
        raise InputError(f"--output-cloud must be .npy, .ply, .pcd or .xyz; got {args.output_cloud.suffix!r}")
    init = _parse_init(args.init)
    src = _read_cloud(args.source)
    tgt = _read_cloud(args.target)
    res = georegister(src, tgt, init=init, yaw_range_deg=args.yaw_range,
                      yaw_step_deg=args.yaw_step, voxel_size=args.voxel_size)
    if res.fitness < args.min_fitness:
        raise RegistrationError(f"georegistration failed: fitness {res.fitness:.3f} is below --min-fitness "
                                f"{args.min_fitness:g} (inlier RMSE {res.inlier_rmse:.3f} m, yaw offset "
                                f"{res.yaw_offset_deg:+.1f} deg); nothing was written: check that the clouds "
                                "overlap, give a closer --init, or widen --yaw-range")
    if args.yaw_range > 0 and abs(abs(res.yaw_offset_deg) - args.yaw_range) < 0.5 * args.yaw_step:
        msg = (f"the best yaw offset {res.yaw_offset_deg:+.1f} deg lies at the edge of the searched "
               f"+-{args.yaw_range:g} deg: the true yaw may lie beyond it; widen --yaw-range")
        if args.strict:
            raise RegistrationError(f"{msg}; nothing was written (--strict)")
        print(f"warning: {msg}", file=sys.stderr)
    doc = dict(transform=res.transform.tolist(), fitness=res.fitness,
               inlier_rmse_m=res.inlier_rmse, yaw_offset_deg=res.yaw_offset_deg,
               yaw_trials=res.trials, source=str(args.source), target=str(args.target))
    atomic_write(args.output, lambda tmp: Path(tmp).write_text(json_text(doc, indent=2)))
    print(f"fitness {res.fitness:.3f}, inlier RMSE {res.inlier_rmse:.3f} m, yaw offset "
          f"{res.yaw_offset_deg:+.1f} deg -> {args.output}")
    if args.output_cloud is not None:
        moved = transform_points(res.transform, src)
        suffix = args.output_cloud.suffix.lower()
        if suffix == ".npy":
            atomic_write(args.output_cloud, lambda tmp: np.save(tmp, moved))
        elif suffix in (".ply", ".pcd", ".xyz"):
            import open3d as o3d

            pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(moved))
            atomic_write(args.output_cloud,
                         lambda tmp: o3d.io.write_point_cloud(str(tmp), pc))
        else:
            raise InputError(f"--output-cloud must be .npy, .ply, .pcd or .xyz; got {suffix!r}")
    return 0
