"""``clsim simulate | devices | bench``: the command-line face of the simulator.

``register(subparsers)`` adds the three commands to an argparse parser; each
handler takes the parsed namespace and returns an exit status, so tests call
them in-process.

Examples
--------
>>> from clsim.cli.app import build_parser
>>> a = build_parser().parse_args(["simulate", "scene.npz", "--photons", "1000", "-o", "wf.npz"])
>>> a.mode, a.detect, a.max_order, a.sensor
('exact', 'nee', 3, 'ahab-chiroptera-i')
"""

from __future__ import annotations

import argparse
import statistics
import sys
from pathlib import Path

import numpy as np

from clsim.errors import InputError
from clsim.sensor import Sensor, list_presets
from clsim.transport.simulator import InteractionModel, PhotonTally
from voxlidar.cli import number, numbers
from voxlidar.safeio import check_figure_path, check_outputs, staged

__all__ = ["register", "cmd_simulate", "cmd_devices", "cmd_bench", "device_benchmark",
           "benchmark_scene"]


def register(subparsers) -> None:
    """Add ``simulate``, ``devices`` and ``bench`` to an argparse subparsers object."""
    p = subparsers.add_parser(
        "simulate", help="simulate a full waveform over a voxel scene",
        description="Monte Carlo photon transport of one airborne LiDAR pulse through a voxel "
                    "scene (NPZ, docs/formats.md); writes time_ns, waveform, by_order (orders x "
                    "samples), the fine histograms and the run's settings to an NPZ file.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument("scene", help="scene file: .npz written by tlsvox or clsim.validation.testscenes, a plot of many "
                                 "trees (clsim.scenes.PlotScene.save), or an AMAPVox "
                                 ".vox (its PadBVTotal as LAD; no wood, no ground)")
    p.add_argument("--target", default=None, metavar="X,Y[,Z]",
                   type=numbers(2, 3, what="X,Y or X,Y,Z in metres", example="1.5,-2"),
                   help="where the beam axis meets the ground, metres in the scene's frame "
                        "(default: the centre of the grid at ground level), e.g. --target -1.5,2")
    p.add_argument("--targets", default=None, metavar="CSV",
                   help="a file of targets, one X,Y[,Z] per row (a header row allowed): one pulse each, "
                        "all in one NPZ (arrays with a leading target axis)")
    p.add_argument("--sensor", default="ahab-chiroptera-i",
                   help=f"preset name ({', '.join(list_presets())}) or a .toml file")
    p.add_argument("--photons", type=int, default=1_000_000, help="photons launched")
    p.add_argument("--max-hours", type=number(lo=0, lo_open=True, unit="hours"), default=MAX_HOURS,
                   help=f"refuse a run estimated (by a pilot run) to take longer ({MAX_HOURS:g})")
    p.add_argument("--seed", type=int, default=1, help="random seed (same seed, same device: same output)")
    p.add_argument("-o", "--output", required=True, help="output waveform file (.npz)")
    p.add_argument("--mode", choices=[m.value for m in InteractionModel], default="exact",
                   help="interaction model: exact free flight, or the paper's fixed 2 cm step")
    p.add_argument("--detect", choices=[d.value for d in PhotonTally], default="nee",
                   help="next-event estimation, or analog counting through the virtual aperture")
    p.add_argument("--max-order", type=int, default=3, help="highest scattering order")
    p.add_argument("--leaf-off", action="store_true", help="drop the leaves (wood and ground only)")
    p.add_argument("--hotspot", action="store_true",
                   help="single-scattering returns retrace their free incoming path (transmittance 1), "
                        "as explicit leaves do with a monostatic sensor; default: turbid, independent "
                        "return (the paper's model). NEE only")
    p.add_argument("--off-nadir", type=float, default=None, help="override the off-nadir angle, degrees")
    p.add_argument("--fov", type=float, default=None, help="override the receiver FOV half angle, mrad")
    p.add_argument("--batches", type=int, default=16, help="batches for standard errors")
    p.add_argument("--trace", type=int, default=0, help="record the first events of this many photons")
    p.add_argument("--plot", default=None, metavar="PATH", help="also write a waveform plot")
    p.add_argument("--trace-plot", default=None, metavar="PATH",
                   help="also draw the traced photon paths over the scene (needs --trace N)")
    p.add_argument("--device", default=None, help="OpenCL device: 'platform:device', 'cpu', 'gpu' or a "
                   "name part (default: VOXLIDAR_DEVICE, else PYOPENCL_CTX, else the best working "
                   "device; `clsim devices` lists them)")
    p.add_argument("--reference", action="store_true",
                   help="run the NumPy float64 oracle instead of OpenCL (slow; no device needed)")
    p.add_argument("--progress", action="store_true", help=argparse.SUPPRESS)  # the default now; kept for old scripts
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    p.add_argument("--strict", action="store_true",
                   help="refuse a scene written with quality warnings (tlsvox voxelize records them; they are "
                        "repeated here either way)")
    p.set_defaults(func=cmd_simulate)

    d = subparsers.add_parser("devices", help="list OpenCL devices and whether each works",
                              description="List every OpenCL device found, best first, with its "
                                          "state: each device builds the project's kernels once "
                                          "(clsim transport, tlsvox tracer; cached), and a device "
                                          "that cannot is shown as broken with the reason from its "
                                          "build log. The device marked '*' is the one commands use.")
    d.set_defaults(func=cmd_devices)

    b = subparsers.add_parser("bench", help="photons/s and voxel steps/s on every device",
                              description="Run the transport benchmark on every working OpenCL "
                                          "device side by side (devices take turns run by run; "
                                          "broken devices are skipped) and print a table (medians "
                                          "of --repeats runs).",
                              formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    b.add_argument("--photons", type=number(int, lo=1), default=200_000)
    b.add_argument("--repeats", type=number(int, lo=1), default=3)
    b.set_defaults(func=cmd_bench)



#: longest run `clsim simulate` starts without --max-hours
MAX_HOURS = 2.0


def _check_duration(sim, scene, sensor, kw, args) -> None:
    """Time a pilot run of large requests; refuse one that would outlast --max-hours.

    A run of 10^12 photons would otherwise start, silently, for days."""
    n = kw["photons"]
    if not isinstance(n, int) or n <= 20_000_000:
        return
    pilot = dict(kw, photons=200_000, progress=False, trace=0)
    res = sim.run(scene, sensor, **pilot)
    rate = 200_000 / max(res.elapsed_s, 1e-9)
    hours = n / rate / 3600.0
    if hours > args.max_hours:
        raise InputError(f"--photons {n:,} would take about {hours:,.1f} h on {sim.device_name} "
                         f"(a pilot run measured {rate:,.0f} photons/s); lower --photons or raise "
                         f"--max-hours (now {args.max_hours:g})")
    if not args.quiet:
        print(f"{n:,} photons: about {hours * 60:,.0f} min on {sim.device_name}", file=sys.stderr)


def read_targets(path) -> list:
    """Targets from a CSV file: one ``X,Y`` or ``X,Y,Z`` (metres) per row; a header row is allowed."""
    import csv

    path = Path(path)
    if not path.is_file():
        raise InputError(f"--targets {path} does not exist; give a CSV with one X,Y[,Z] per row")
    out = []
    with open(path, newline="") as fh:
        for n, row in enumerate(csv.reader(fh), start=1):
            cells = [c.strip() for c in row if c.strip()]
            if not cells:
                continue
            try:
                values = tuple(float(c) for c in cells)
            except ValueError:
                if n == 1:
                    continue  # header
                raise InputError(f"--targets {path.name}, row {n}: {row!r} is not X,Y[,Z] in metres") from None
            if len(values) not in (2, 3) or not all(np.isfinite(values)):
                raise InputError(f"--targets {path.name}, row {n}: {row!r} is not X,Y[,Z] in metres")
            out.append(values)
    if not out:
        raise InputError(f"--targets {path.name} holds no target; one X,Y[,Z] per row")
    return out


def cmd_simulate(args) -> int:
    """Handler of ``clsim simulate``."""
    from voxlidar.scene import Scene

    if Path(args.output).suffix.lower() != ".npz":
        raise InputError(f"-o {args.output} must end in .npz (the waveform file is NumPy NPZ)")
    check_outputs([("scene", args.scene), ("--targets", args.targets)],
                  [("-o", args.output), ("--plot", args.plot), ("--trace-plot", args.trace_plot)])
    check_figure_path("--plot", args.plot)
    check_figure_path("--trace-plot", args.trace_plot)
    if args.trace_plot and not args.trace:
        raise InputError("--trace-plot needs --trace N (the number of photons to draw)")
    target = args.target
    targets = None
    if args.targets is not None:
        if args.target is not None or args.trace_plot:
            raise InputError("--targets runs one pulse per row: drop --target and --trace-plot")
        targets = read_targets(args.targets)

    from clsim.scenes import load_scene, repeat_scene_warnings

    scene = load_scene(args.scene)
    repeat_scene_warnings("clsim simulate", args.scene, scene, strict=args.strict)
    over = {}
    if args.off_nadir is not None:
        over["off_nadir_deg"] = args.off_nadir
    if args.fov is not None:
        over["fov_mrad"] = args.fov
    sensor = Sensor.preset(args.sensor, **over)
    if args.reference:
        from clsim.transport.reference import ReferenceSimulator

        sim = ReferenceSimulator()
    else:
        from clsim.transport.simulator import Simulator

        sim = Simulator(device=args.device)
    kw = dict(photons=args.photons, seed=args.seed, mode=args.mode, detect=args.detect,
              max_order=args.max_order, leaf_off=args.leaf_off, batches=args.batches,
              trace=args.trace, hotspot=args.hotspot, target=target)
    if targets is not None:
        return _simulate_targets(sim, scene, sensor, kw, targets, args)
    if not args.reference:
        kw["progress"] = not args.quiet
        _check_duration(sim, scene, sensor, kw, args)
    res = sim.run(scene, sensor, **kw)
    from clsim.figures import plot_result, plot_traces

    with staged([args.output, args.plot, args.trace_plot]) as tmp:  # all three or none
        res.save(tmp[args.output])
        if args.plot:
            plot_result(res, tmp[args.plot])
        if args.trace_plot:
            plot_traces(res, scene if isinstance(scene, Scene) else scene.to_scene(), tmp[args.trace_plot])
    e, se = res.energy()
    print(f"{args.photons:,} photons in {res.elapsed_s:.2f} s on {res.settings['device']}: "
          f"received energy {e:.4g} +- {se:.2g} of the emitted pulse; wrote {args.output}")
    for f in res.flags:
        print(f"note: {f}")
    return 0


def _simulate_targets(sim, scene, sensor, kw, targets, args) -> int:
    """One pulse per target, the same photons and seed for each; one NPZ (and one picture)."""
    from tqdm.auto import tqdm

    from clsim.figures import plot_waveforms
    from clsim.transport.result import save_results

    results = []
    for t in tqdm(targets, desc="targets", unit="pulse", disable=args.quiet or len(targets) < 2):
        results.append(sim.run(scene, sensor, **dict(kw, target=t)))
    with staged([args.output, args.plot]) as tmp:
        save_results(results, targets, tmp[args.output])
        if args.plot:
            curves = [(",".join(f"{v:g}" for v in t), r) for t, r in zip(targets, results)][:12]
            plot_waveforms(curves, tmp[args.plot], height_axis=False,
                           title=f"{len(targets)} pulses, {args.photons:,} photons each (legend: target X,Y m)")
    print(f"{len(targets)} pulses of {args.photons:,} photons on {results[0].settings['device']}; wrote {args.output}")
    return 0


def cmd_devices(args) -> int:
    """Handler of ``clsim devices``: every device with its state; exit 1 when none works."""
    from voxlidar.devices import FIX_NO_DEVICE, choose_device, device_report, state_text, unloadable_runtimes
    from voxlidar.errors import DeviceError as AnyDeviceError

    report = device_report(("clsim", "tlsvox"))
    for lib, why in unloadable_runtimes():
        print(f"! {lib} is installed but does not load ({why}); fix: reinstall it with its dependencies "
              "(`make setup`, or pip install \"intel-opencl-rt\" \"intel-cmplr-lib-rt\")", file=sys.stderr)
    if not report:
        print(f"no OpenCL device found; fix: {FIX_NO_DEVICE}", file=sys.stderr)
        return 1
    chosen, errors = {}, []
    for stage in ("clsim", "tlsvox"):
        try:
            chosen[stage] = choose_device(kernels=(stage,), devices=[info for info, _ in report]).key
        except AnyDeviceError as err:
            errors.append(str(err))
    for info, verdict in report:
        mark = "*" if info.key in chosen.values() else " "
        print(f"{mark} {info.key}  {info.label}  [{info.runtime}, {info.kind}, {info.compute_units} compute "
              f"units, {info.global_mem_bytes / 2**30:.1f} GiB, {'fp64' if info.fp64 else 'no fp64'}, "
              f"{'int64 atomics' if info.int64_atomics else 'no int64 atomics'}]  {state_text(verdict)}")
    for stage, key in chosen.items():
        print(f"* {stage} uses {key} (override: --device, VOXLIDAR_DEVICE or PYOPENCL_CTX)")
    if errors:
        print("clsim devices: error: " + "; ".join(dict.fromkeys(errors)), file=sys.stderr)
        return 1
    return 0


def benchmark_scene():
    """(scene, sensor) of the device benchmark: a 10 m x 10 m x 2 m layer of 0.1 m voxels."""
    from clsim.validation.testscenes import homogeneous_layer

    scene = homogeneous_layer(lad=1.0, thickness=2.0, base_height=2.0, width=10.0, voxel_size=0.1)
    return scene, Sensor.preset("ahab-chiroptera-i")


def device_benchmark(*, photons: int = 200_000, repeats: int = 3, devices=None) -> list[dict]:
    """photons/s, voxel steps/s and walk steps/s (medians) for each working device and transport variant.

    Variants: exact+nee, exact+analog, paper+nee, and exact+nee walking voxel
    by voxel through uniform bricks (``uniform`` False: the walk before uniform
    bricks were crossed in one segment; docs/method.md).  Voxel steps count the
    voxels crossed, walk steps what the walker did (a segment through a uniform
    brick is one walk step and many voxel steps).  Devices and variants take
    turns run by run, so that a slow spell of a shared machine falls on all of
    them alike; broken devices are skipped (``clsim devices`` says why)."""
    from clsim.transport.simulator import Simulator, working_devices

    scene, sensor = benchmark_scene()
    variants = (("exact", "nee", photons, True), ("exact", "analog", photons, True),
                ("paper", "nee", max(1, photons // 10), True), ("exact", "nee", photons, False))
    devs = working_devices() if devices is None else devices
    sims = [{uni: Simulator(device=dev, features=None if uni else {"uniform": False}) for uni in (True, False)}
            for dev in devs]
    for sim in sims:
        for mode, detect, _, uni in variants:
            sim[uni].run(scene, sensor, photons=2000, seed=0, mode=mode, detect=detect)  # build
    el = {(i, v): [] for i in range(len(sims)) for v in variants}
    steps = {k: [] for k in el}
    walks = {k: [] for k in el}
    for r in range(repeats):
        for i, sim in enumerate(sims):
            for v in variants:
                mode, detect, n, uni = v
                res = sim[uni].run(scene, sensor, photons=n, seed=r + 1, mode=mode, detect=detect, max_order=3)
                el[i, v].append(res.elapsed_s)
                steps[i, v].append(res.stat("voxel_steps")[0] / res.elapsed_s)
                walks[i, v].append(res.stat("walk_steps")[0] / res.elapsed_s)
    rows = []
    for (i, v), times in el.items():
        mode, detect, n, uni = v
        sim = sims[i][uni]
        rows.append(dict(device=sim.device_name, runtime=sim.info.runtime, key=sim.info.key, kind=sim.info.kind,
                         mode=mode, detect=detect, uniform=uni, photons=n, photons_per_s=n / statistics.median(times),
                         steps_per_s=statistics.median(steps[i, v]),
                         steps_per_s_range=(min(steps[i, v]), max(steps[i, v])),
                         walk_steps_per_s=statistics.median(walks[i, v])))
    return rows


def cmd_bench(args) -> int:
    """Handler of ``clsim bench``."""
    rows = device_benchmark(photons=args.photons, repeats=args.repeats)
    if not rows:
        from voxlidar.devices import FIX_NO_DEVICE

        print(f"no working OpenCL device (clsim devices says why); fix: {FIX_NO_DEVICE}", file=sys.stderr)
        return 1
    print(f"{'device':44s} {'runtime':22s} {'mode':6s} {'detect':7s} {'uniform':7s} {'photons/s':>12s} "
          f"{'voxel steps/s':>14s} {'walk steps/s':>14s}")
    for r in rows:
        print(f"{r['key'] + ' ' + r['device']:44.44s} {r['runtime']:22.22s} {r['mode']:6s} {r['detect']:7s} "
              f"{'yes' if r['uniform'] else 'no':7s} {r['photons_per_s']:12,.0f} {r['steps_per_s'] / 1e6:12,.1f} M "
              f"{r['walk_steps_per_s'] / 1e6:12,.1f} M")
    return 0
