"""tlsvox: terrestrial laser scans -> voxel model of a tree.

Sub-commands build the synthetic truth world (tree, scan), look at files
(view), and run the pipeline stages.  Run ``tlsvox COMMAND --help`` for each.

Examples:
  tlsvox tree -o out/oak.ply --seed 1
  tlsvox scan out/oak.json --position 0,-20,1.7 --yaw 37 -o out/scan1.laz
  tlsvox view out/scan1.laz --color reflectance --screenshot out/scan1.png
"""

from __future__ import annotations

import argparse
import math
import os
import sys
from pathlib import Path

from tlsvox.cli import georegister, register, voxelize
from tlsvox.errors import TlsvoxError
from voxlidar.cli import Parser, number, numbers, run, with_debug
from voxlidar.errors import InputError
from voxlidar.safeio import check_figure_path, check_outputs
from voxlidar.versions import show_versions

#: picture formats of ``tlsvox view --screenshot`` (Open3D renders a bitmap)
SCREENSHOT_FORMATS = ("png", "jpg", "jpeg")
#: what ``tlsvox view`` reads: scans, and the point clouds and meshes Open3D reads
VIEW_SUFFIXES = (".npz", ".vox", ".las", ".laz", ".ply", ".pcd", ".xyz", ".xyzn", ".xyzrgb", ".pts", ".obj", ".stl", ".off",
                 ".gltf", ".glb")

def _cmd_tree(args) -> int:
    from tlsvox.truth.synthetic import TreeParams, make_tree

    params = TreeParams(height=args.height, total_leaf_area=args.leaf_area, leaf_angle=args.leaf_angle,
                        leaf_azimuth=args.leaf_azimuth, crown_radius=args.crown_radius)
    out = Path(args.output)
    if out.suffix.lower() != ".ply":
        raise InputError(f"-o {out} must end in .ply (the mesh; its truth JSON is written beside it)")
    check_outputs([], [("-o", out), ("-o (truth JSON)", out.with_suffix(".json"))])
    tree = make_tree(params, seed=args.seed)
    ply, meta = tree.save(args.output)
    summary = tree.truth_summary()
    print(f"wrote {ply} ({len(tree.triangles):,} triangles) and {meta}")
    print(f"leaf area {summary['leaf_area_m2']:.2f} m2 in {summary['n_leaves']:,} leaves; "
          f"crown mean LAD {summary['crown_mean_lad_m2_m3']:.3f} m2/m3; "
          f"LAI over crown projection {summary['lai_over_crown_projection']:.2f}")
    return 0


def _cmd_scan(args) -> int:
    from tlsvox.scan import sidecar_paths
    from tlsvox.truth.scanner import ScannerPreset, ScanPose, paper_scan_poses, simulate_scan
    from tlsvox.truth.synthetic import load_tree

    tree_json = Path(args.tree)
    tree_json = tree_json if tree_json.suffix.lower() == ".json" else tree_json.with_suffix(".json")
    out = Path(args.output)
    if out.suffix.lower() not in (".las", ".laz"):
        raise InputError(f"scan output {str(out)!r} must end in .las or .laz")
    step = args.step if args.step is not None else 0.06
    pulses = (360.0 / step) * (180.0 / step)
    if pulses > 5e8:
        raise InputError(f"--step {step:g} degrees would fire about {pulses:.2g} pulses per scan (the RIEGL VZ-400 "
                         f"fires 1.8e7 at 0.06); use a step of at least {math.sqrt(360 * 180 / 5e8):.3f} degrees")
    stems = ([out.with_name(f"{out.stem}{i + 1}{out.suffix}") for i in range(2)] if args.paper_pair else [out])
    check_outputs([("tree", args.tree), ("tree", tree_json), ("tree", tree_json.with_suffix(".ply"))],
                  [("-o", p) for t in stems for p in (t, *sidecar_paths(t))])
    tree = load_tree(args.tree)
    overrides = {}
    if args.step is not None:
        overrides.update(zenith_step_deg=args.step, azimuth_step_deg=args.step)
    preset = ScannerPreset.load(args.preset, **overrides)
    if args.paper_pair:
        poses = paper_scan_poses(tree)
        out = Path(args.output)
        targets = [out.with_name(f"{out.stem}{i + 1}{out.suffix}") for i in range(len(poses))]
    else:
        poses = [ScanPose(position=tuple(args.position), yaw_deg=args.yaw, pitch_deg=args.pitch,
                          roll_deg=args.roll)]
        targets = [Path(args.output)]
    for i, (pose, path) in enumerate(zip(poses, targets)):
        scan = simulate_scan(tree, pose=pose, preset=preset, seed=args.seed + i, scan_id=args.scan_id + i,
                             name=path.stem, progress=not args.quiet)
        scan.write(path)
        gaps = int((scan.pulses.n_echoes == 0).sum())
        print(f"wrote {path}: {len(scan):,} echoes from {len(scan.pulses):,} pulses "
              f"({gaps:,} without echo); true pose in {path.with_suffix('').name}.pose.json")
    return 0


def _scene_items(path: Path, color: str):
    """Voxels of a scene file as a coloured mesh: LAD (log scale) or wood, with its colour scale."""
    import numpy as np

    from tlsvox.render import colormap, voxel_mesh

    if path.suffix.lower() == ".vox":
        from tlsvox.voxel.amapvox import read_vox

        scene = read_vox(path)
    else:
        from voxlidar.scene import Scene

        scene = Scene.load(path)
    c = scene.centers()
    if color == "wood":
        sel = scene.wood > 0.05
        cols = colormap(scene.wood[sel], vmin=0.0, vmax=1.0, name="copper_r")
        bar = ("copper_r", 0.0, 1.0, "wood probability" if scene.wood_kind == "probability" else "wood")
    else:
        sel = scene.lad > 0
        cols = colormap(np.log10(scene.lad[sel]), vmin=-1.0, vmax=1.2, name="viridis")
        bar = ("viridis", -1.0, 1.2, "log10 LAD (m²/m³)")
    if not sel.any():
        raise InputError(f"{path}: no voxel has {'wood' if color == 'wood' else 'leaves'} to show")
    title = (f"{path.name}: {int(sel.sum()):,} voxels of {scene.voxel_size * 100:g} cm, "
             f"leaf area {scene.total_leaf_area():,.1f} m²")
    directional = (int(np.count_nonzero((scene.wood_beta[sel] > 0) | scene.wood_solid[sel])) if color == "wood"
                   else 0)
    if directional:  # the colour is the amount; the bark's axis (wood_axis) would need glyphs
        title += f"; the bark directions of {directional:,} voxels (wood_axis) are not drawn"
    return [voxel_mesh(c[sel], scene.voxel_size, cols)], c[sel], (title, bar)


def _cmd_view(args) -> int:
    import numpy as np

    from tlsvox.render import colormap, reflectance_colors, render
    from tlsvox.scan import sidecar_paths

    path = Path(args.file)
    sidecars = sidecar_paths(path) if path.suffix.lower() in (".las", ".laz") else ()
    check_outputs([("file", p) for p in (path, *sidecars)], [("--screenshot", args.screenshot)])
    check_figure_path("--screenshot", args.screenshot, formats=SCREENSHOT_FORMATS)
    if not args.screenshot and sys.platform.startswith("linux") and not (
            os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        raise TlsvoxError(f"no display to open a window on (DISPLAY is not set); fix: "
                          f"tlsvox view {path} --screenshot {path.with_suffix('').name}.png renders a picture "
                          "headless")
    if path.suffix.lower() not in VIEW_SUFFIXES:
        raise InputError(f"{path}: unknown file type {path.suffix!r}; view reads {', '.join(VIEW_SUFFIXES)}")
    if path.suffix.lower() in (".npz", ".vox"):
        items, xyz, legend = _scene_items(path, args.color)
        geoms = items
    elif path.suffix.lower() in (".las", ".laz"):
        from tlsvox.scan import Scan

        scan = Scan.read(path)
        pose = scan.pose if scan.pose is not None else scan.pose_true
        xyz = scan.world_xyz(pose) if (pose is not None and not args.scanner_frame) else scan.xyz
        if args.color in ("lad", "wood"):
            raise InputError(f"--color {args.color} is for scene files (.npz, .vox); a scan takes reflectance or "
                             "material")
        if args.color == "material":
            if scan.truth_material is None:
                raise TlsvoxError(f"{path} has no truth_material; use --color reflectance")
            palette = np.array([[0.5, 0.5, 0.5], [0.2, 0.6, 0.15], [0.5, 0.3, 0.1], [0.7, 0.7, 0.6], [1, 0, 1]])
            colors = palette[np.clip(scan.truth_material, 0, 4)]
            legend = (f"{path.name}: {len(xyz):,} echoes, colour: material "
                      "(green leaf, brown bark, beige ground, magenta target)", None)
        elif scan.reflectance_db is not None:
            colors = reflectance_colors(scan.reflectance_db)
            legend = (f"{path.name}: {len(xyz):,} echoes", ("inferno", -20.0, 0.0, "apparent reflectance (dB)"))
        elif scan.intensity is not None:
            colors = colormap(scan.intensity, name="gray")
            lo, hi = float(np.min(scan.intensity)), float(np.max(scan.intensity))
            legend = (f"{path.name}: {len(xyz):,} echoes", ("gray", lo, hi, "intensity (counts)"))
        else:
            colors = colormap(xyz[:, 2])
            legend = (f"{path.name}: {len(xyz):,} echoes",
                      ("viridis", float(xyz[:, 2].min()), float(xyz[:, 2].max()), "height z (m)"))
        items = [(xyz, colors)]
        import open3d as o3d

        geoms = [o3d.geometry.PointCloud(o3d.utility.Vector3dVector(xyz))]
        geoms[0].colors = o3d.utility.Vector3dVector(colors)
    else:
        import open3d as o3d

        mesh = o3d.io.read_triangle_mesh(str(path))
        if len(mesh.triangles):
            mesh.compute_vertex_normals()
            geoms = [mesh]
        else:
            geoms = [o3d.io.read_point_cloud(str(path))]
        if not len(geoms[0].vertices if hasattr(geoms[0], "vertices") else geoms[0].points):
            raise TlsvoxError(f"{path}: Open3D read no points or triangles from it")
        items = geoms
        xyz = np.asarray(geoms[0].vertices if hasattr(geoms[0], "vertices") else geoms[0].points)
        legend = (f"{path.name}: {len(xyz):,} {'vertices' if hasattr(geoms[0], 'vertices') else 'points'}", None)
    if args.screenshot:
        lo, hi = xyz.min(axis=0), xyz.max(axis=0)
        center = 0.5 * (lo + hi)
        radius = float(np.linalg.norm(hi - lo))
        eye = center + np.array([0.0, -1.1 * radius, 0.25 * radius])
        title, colorbar = legend
        used = render(items, args.screenshot, eye=eye, center=center, point_size=args.point_size, title=title,
                      colorbar=colorbar)
        print(f"wrote {args.screenshot} ({used})")
        return 0
    import open3d as o3d

    o3d.visualization.draw_geometries(geoms, window_name=f"tlsvox view {path.name}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    from voxlidar.leaf_orientation import LeafAzimuth

    parser = with_debug(Parser(prog="tlsvox", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter))
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    p = sub.add_parser("tree", help="build the synthetic oak: mesh PLY + truth JSON",
                       description="Build the seeded procedural tree; write NAME.ply (mesh coloured by "
                                   "material) and NAME.json (parameters, seed and truth metadata).")
    p.add_argument("-o", "--output", required=True, help="output mesh, e.g. out/oak.ply")
    p.add_argument("--seed", type=number(int, lo=0), default=1, help="random seed (default 1)")
    p.add_argument("--height", type=float, default=13.6, help="tree height, m (default 13.6)")
    p.add_argument("--crown-radius", type=float, default=6.0, help="crown radius, m (default 6)")
    p.add_argument("--leaf-area", type=float, default=500.0, help="total one-sided leaf area, m2 (default 500)")
    p.add_argument("--leaf-angle", default="uniform", help="leaf inclination distribution (default uniform)")
    p.add_argument("--leaf-azimuth", default="outward", choices=[a.value for a in LeafAzimuth])
    p.set_defaults(func=_cmd_tree)

    p = sub.add_parser("scan", help="simulate a terrestrial scan of a synthetic tree",
                       description="Scan the tree of TREE.json (from `tlsvox tree`) with a simulated "
                                   "scanner. Writes SCAN.las/laz (point format 6, scanner frame), "
                                   "SCAN.pulses.npz (every pulse) and SCAN.pose.json (true pose).")
    p.add_argument("tree", help="tree metadata JSON (or its PLY) written by `tlsvox tree`")
    p.add_argument("-o", "--output", required=True, help="output .las or .laz")
    p.add_argument("--preset", default="riegl-vz400", help="scanner preset name or TOML path")
    p.add_argument("--position", type=numbers(3, what="X,Y,Z in metres", example="0,-20,1.7"),
                   default=(0.0, -20.0, 1.7), metavar="X,Y,Z",
                   help="scanner position, metres (default 0,-20,1.7), e.g. --position -5,0,1.7")
    p.add_argument("--yaw", type=number(), default=0.0, help="scanner yaw, degrees")
    p.add_argument("--pitch", type=number(lo=-90, hi=90), default=0.0, help="scanner pitch (tilt), degrees")
    p.add_argument("--roll", type=number(lo=-90, hi=90), default=0.0, help="scanner roll (tilt), degrees")
    p.add_argument("--step", type=number(lo=0, lo_open=True, unit="degrees"), default=None,
                   help="angular step, degrees (overrides the preset)")
    p.add_argument("--paper-pair", action="store_true",
                   help="scan from the paper's two positions; writes NAME1 and NAME2")
    p.add_argument("--seed", type=number(int, lo=0), default=1)
    p.add_argument("--scan-id", type=number(int, lo=0, hi=65534), default=1,
                   help="scan id (the LAS point source id), 0-65534")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=_cmd_scan)

    p = sub.add_parser("view", help="look at a scan, a mesh or a voxel scene (Open3D window or a picture)",
                       description="Open an Open3D window on a LAS/LAZ scan, PLY/PCD/XYZ cloud or mesh, or a voxel "
                                   "scene (.npz, .vox: voxels by LAD or wood); with --screenshot, render headless "
                                   "to a picture with a title and a colour scale instead.")
    p.add_argument("file")
    p.add_argument("--color", choices=["reflectance", "material", "lad", "wood"], default=None,
                   help="scans: reflectance (default) or material; scenes (.npz, .vox): lad (default) or wood")
    p.add_argument("--scanner-frame", action="store_true", help="do not apply the scan's pose")
    p.add_argument("--screenshot", help="write a picture (.png or .jpg) instead of opening a window")
    p.add_argument("--point-size", type=number(lo=0, lo_open=True, unit="pixels"), default=2.0)
    p.set_defaults(func=_cmd_view)

    p = sub.add_parser("versions", help="print package versions and OpenCL devices (for bug reports)")
    p.set_defaults(func=lambda args: show_versions() or 0)

    register.register(sub)
    voxelize.register(sub)
    georegister.register(sub)
    return parser


def main(argv=None) -> int:
    """Entry point of the ``tlsvox`` command (exit codes: :mod:`voxlidar.cli`)."""
    return run("tlsvox", build_parser(), argv)


if __name__ == "__main__":
    sys.exit(main())
