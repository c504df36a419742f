"""``clsim pick``: an Open3D window on a voxel scene; the pulses aimed at the picked voxels.

The scene's voxels show as points coloured by LAD.  Shift + left click picks
voxels (Open3D's editing visualiser); closing the window simulates a nadir
pulse aimed at each picked voxel (its x, y) and writes one picture: the scene
with the picks marked, beside their waveforms against height above ground,
and, with ``-o``, the waveforms as one NPZ (as ``clsim simulate --targets``).

``--pick-voxel I ...`` picks by voxel index instead of by mouse and closes the
window after ``--seconds`` (scripts, and the test under ``xvfb-run``).
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

import numpy as np

from clsim.errors import InputError
from voxlidar.cli import number
from voxlidar.safeio import check_figure_path, check_outputs, staged

__all__ = ["cmd_pick", "register"]

#: most pulses one session simulates (one panel each in the picture)
MAX_PICKS = 6


def register(subparsers) -> None:
    """Add ``pick`` to a ``clsim`` subparsers object."""
    p = subparsers.add_parser(
        "pick", help="pick voxels of a scene in an Open3D window; simulate the pulses aimed there",
        description=__doc__, formatter_class=__import__("argparse").RawDescriptionHelpFormatter)
    p.add_argument("scene", help="scene file (.npz from tlsvox voxelize, or AMAPVox .vox)")
    p.add_argument("--plot", required=True, metavar="PATH",
                   help="the picture: the scene with the picks beside their waveforms (.png, .pdf, .svg, .jpg)")
    p.add_argument("-o", "--output", default=None, help="also the waveforms, one NPZ (.npz)")
    p.add_argument("--pick-voxel", type=number(int, lo=0), nargs="+", default=None, metavar="I",
                   help="pick these voxels (indices into the scene's non-empty voxels) instead of by mouse")
    p.add_argument("--seconds", type=number(lo=0, lo_open=True), default=1.0,
                   help="with --pick-voxel: how long the window stays open (1)")
    p.add_argument("--screenshot", default=None, metavar="PNG", help="with --pick-voxel: the window as a PNG")
    p.add_argument("--photons", type=number(int, lo=1000), default=200_000, help="photons per pulse (200000)")
    p.add_argument("--seed", type=number(int, lo=0), default=1)
    p.add_argument("--sensor", default="ahab-chiroptera-i", help="sensor preset name or TOML path")
    p.add_argument("--device", default=None, help="OpenCL device (default: the best working one)")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_pick)


def _load_scene(path: Path):
    from voxlidar.safeio import file_kind

    if path.suffix.lower() == ".vox" or file_kind(path) == "vox":
        from tlsvox.voxel.amapvox import read_vox

        return read_vox(path)
    from voxlidar.scene import Scene

    return Scene.load(path)


def _window(points, colors, picks, seconds, screenshot):
    """Show the points; return the picked indices (by mouse, or ``picks`` after ``seconds``)."""
    import open3d as o3d

    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    pc.colors = o3d.utility.Vector3dVector(colors)
    vis = o3d.visualization.VisualizerWithEditing()
    if not vis.create_window(window_name="clsim pick: shift + left click picks voxels; close to simulate",
                             width=1000, height=800):
        raise InputError("Open3D could not open a window; under no display run it as "
                         "`xvfb-run -a clsim pick ...` with --pick-voxel")
    vis.add_geometry(pc)
    if picks is None:
        vis.run()  # until the user closes the window
        chosen = list(vis.get_picked_points())
    else:
        t0 = time.monotonic()
        while time.monotonic() - t0 < seconds:
            vis.poll_events()
            vis.update_renderer()
        if screenshot:
            vis.capture_screen_image(str(screenshot), do_render=True)
        chosen = list(picks)
    vis.destroy_window()
    return chosen


def cmd_pick(args) -> int:
    """Handler of ``clsim pick``."""
    from clsim.sensor import Sensor
    from clsim.transport.result import save_results
    from tlsvox.render import colormap

    scene_path = Path(args.scene)
    if not scene_path.is_file():
        raise InputError(f"scene file {scene_path} does not exist")
    if args.output is not None and Path(args.output).suffix.lower() != ".npz":
        raise InputError(f"-o {args.output} must end in .npz")
    check_outputs([("scene", scene_path)], [("--plot", args.plot), ("-o", args.output),
                                             ("--screenshot", args.screenshot)])
    check_figure_path("--plot", args.plot)
    check_figure_path("--screenshot", args.screenshot, formats=("png",))
    if args.screenshot and args.pick_voxel is None:
        raise InputError("--screenshot goes with --pick-voxel (a mouse session has no fixed moment to capture)")
    if sys.platform.startswith("linux") and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        raise InputError("no display to open a window on (DISPLAY is not set); fix: run it under a virtual "
                         "display, `xvfb-run -a clsim pick SCENE --pick-voxel I ...`, or look at the scene with "
                         "`tlsvox view SCENE --screenshot scene.png`")
    scene = _load_scene(scene_path)
    leafy = np.flatnonzero(scene.lad > 0)
    if leafy.size == 0:
        raise InputError(f"{scene_path}: the scene has no leaf voxel to pick")
    if args.pick_voxel is not None:
        bad = [i for i in args.pick_voxel if i >= leafy.size]
        if bad:
            raise InputError(f"--pick-voxel {bad}: the scene has {leafy.size:,} leaf voxels (0-{leafy.size - 1})")
    centres = scene.centers()[leafy]
    colors = colormap(np.log10(scene.lad[leafy]), vmin=-1.0, vmax=1.2, name="viridis")
    chosen = _window(centres, colors, args.pick_voxel, args.seconds, args.screenshot)[:MAX_PICKS]
    if not chosen:
        print("no voxel picked (shift + left click picks one); nothing simulated")
        return 0
    sensor = Sensor.preset(args.sensor)
    from clsim.figures import plot_picks
    from clsim.transport.simulator import Simulator

    sim = Simulator(device=args.device)
    targets = [(float(centres[i, 0]), float(centres[i, 1])) for i in chosen]
    results = [sim.run(scene, sensor, photons=args.photons, seed=args.seed, max_order=3, target=t,
                       progress=not args.quiet) for t in targets]
    with staged([args.plot, args.output]) as tmp:
        plot_picks(tmp[args.plot], scene, centres, colors, chosen, results, sensor, photons=args.photons,
                   seed=args.seed, name=Path(args.scene).name)
        if args.output:
            save_results(results, targets, tmp[args.output])
    for i, t, r in zip(chosen, targets, results):
        e, se = r.energy()
        print(f"voxel {i} at x={t[0]:.2f} m, y={t[1]:.2f} m: received energy {e:.4g} +- {se:.2g}")
    print(f"wrote {args.plot}" + (f" and {args.output}" if args.output else ""))
    return 0
