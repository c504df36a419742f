"""Both kernels on every OpenCL device of this machine, side by side; writes a table per runtime.

    .venv/bin/python benchmarks/bench_devices.py                 # docs/bench/devices-<machine>.md
    .venv/bin/python benchmarks/bench_devices.py --quick         # smaller runs (about a minute)

1. clsim transport (``clsim bench``'s routine): photons/s and voxel steps/s on
   the benchmark layer (10 m x 10 m x 2 m, 0.1 m voxels, LAD 1, ground;
   ``ahab-chiroptera-i`` at nadir, ``max_order=3``) for exact+nee,
   exact+analog and paper+nee.  Devices and variants take turns run by run;
   medians of ``--repeats`` runs with the range.  A GPU gets ``--gpu-factor``
   times more photons per run, so that a run lasts long enough to time.
2. tlsvox tracer: beams/s and voxel steps/s for a synthetic scan (one
   scanner position 1.7 m above the ground, beams into a 30 m x 30 m x 20 m
   grid of 0.2 m voxels, half of them ending in a leaf echo), the same beams
   on every device; medians of ``--repeats`` runs, transfers included.
3. Build and launch choices of the transport on each CPU device, side by side:
   ``-cl-fast-relaxed-math`` or not, and one photon per work-group (the
   default on CPUs) or the runtime's own work-group size.
Broken devices are listed with their reason and skipped.  The load average
is logged before and after.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import time
from pathlib import Path

import numpy as np

from clsim.cli.simulate import device_benchmark
from tlsvox.voxel.grid import VoxelGrid
from tlsvox.voxel.trace import Beams, Tracer
from voxlidar.devices import device_report, state_text

ROOT = Path(__file__).resolve().parents[1]


def synthetic_scan(n: int, seed: int = 0) -> tuple[VoxelGrid, Beams]:
    """(grid, beams): n beams from (0, 0, 1.7) over the upper hemisphere and 30 degrees below."""
    rng = np.random.default_rng(seed)
    grid = VoxelGrid((-15.0, -15.0, 0.0), 0.2, (150, 150, 100))
    az = rng.uniform(0, 2 * np.pi, n)
    zen = np.arccos(rng.uniform(-0.5, 1.0, n))
    d = np.column_stack([np.sin(zen) * np.cos(az), np.sin(zen) * np.sin(az), np.cos(zen)])
    hit = np.where(rng.random(n) < 0.5, rng.uniform(1.0, 25.0, n), np.inf)
    return grid, Beams.from_rays(np.array([0.0, 0.0, 1.7]), d, hit_range=hit, max_range=60.0)


def bench_tracer(devices, n_beams: int, repeats: int) -> list[dict]:
    grid, beams = synthetic_scan(n_beams)
    tracers = [Tracer(info) for info in devices]
    for tr in tracers:
        tr.trace(grid, beams)  # warm-up: build, first touch
    times = {i: [] for i in range(len(tracers))}
    steps = {}
    for _ in range(repeats):
        for i, tr in enumerate(tracers):
            st = tr.trace(grid, beams)
            times[i].append(st.seconds)
            steps[i] = st.n_steps
    rows = []
    for i, tr in enumerate(tracers):
        med = statistics.median(times[i])
        rows.append(dict(key=tr.info.key, device=tr.info.label, runtime=tr.info.runtime, kind=tr.info.kind,
                         mode=tr.name.split("(")[-1].rstrip(")"), beams=len(beams), seconds=med,
                         beams_per_s=len(beams) / med, steps_per_s=steps[i] / med,
                         range_s=(min(times[i]), max(times[i]))))
    return rows


def bench_choices(devices, photons: int, repeats: int) -> list[dict]:
    """exact + nee photons/s for fast math on/off x work-group size 1 / runtime's choice."""
    from clsim.cli.simulate import benchmark_scene
    from clsim.transport.simulator import Simulator

    scene, sensor = benchmark_scene()
    runs = []
    for info in devices:
        for fast in (True, False):
            sim = Simulator(device=info, fast_math=fast)
            for ls in ((1,), None):
                runs.append((info, fast, ls, sim))
    times = {i: [] for i in range(len(runs))}
    for i, (_, _, ls, sim) in enumerate(runs):
        sim.local_size = ls
        sim.run(scene, sensor, photons=2000, seed=0)  # build
    for r in range(repeats):
        for i, (_, _, ls, sim) in enumerate(runs):
            sim.local_size = ls
            res = sim.run(scene, sensor, photons=photons, seed=r + 1, max_order=3)
            times[i].append((res.elapsed_s, res.stat("voxel_steps")[0]))
    rows = []
    for i, (info, fast, ls, _) in enumerate(runs):
        med = statistics.median(t for t, _ in times[i])
        steps = statistics.median(s / t for t, s in times[i])
        rows.append(dict(key=info.key, runtime=info.runtime, fast_math=fast,
                         local_size="1" if ls else "runtime's choice", photons_per_s=photons / med,
                         steps_per_s=steps))
    return rows


def markdown(report, clsim_rows, trace_rows, args, load0, load1, wall, choice_rows=()) -> list[str]:
    host = f"{platform.processor() or platform.machine()}, {os.cpu_count()} logical CPUs"
    lines = [f"# OpenCL devices side by side: {args.machine}", "",
             f"Command: `python benchmarks/bench_devices.py --machine {args.machine}"
             + (" --quick" if args.quick else "") + f"` ({time.strftime('%Y-%m-%d')}, {wall:.0f} s). "
             f"Host: {host}. Load average before {load0:.2f}, after {load1:.2f}.", "",
             "## Devices found", "", "| key | device | runtime | kind | state |", "|---|---|---|---|---|"]
    for info, verdict in report:
        lines.append(f"| {info.key} | {info.name} | {info.runtime} | {info.kind} | {state_text(verdict)} |")
    lines += ["", "## clsim transport, per runtime", "",
              "Benchmark layer (10 x 10 x 2 m, 0.1 m voxels, LAD 1, ground), `max_order=3`; medians of "
              f"{args.repeats} runs, devices and variants taking turns. Voxel steps count the voxels the walk "
              "reaches, shadow rays included (the same count with and without uniform bricks), walk steps "
              "what the walker does (a voxel, an empty brick, a segment); `uniform` no: the voxel-by-voxel walk "
              "(docs/method.md, \"Uniform bricks\").", ""]
    for runtime in dict.fromkeys(r["runtime"] for r in clsim_rows):
        lines += [f"### {runtime}", "", "| device | mode | detect | uniform | photons per run | photons/s | "
                  "voxel steps/s (median) | range | walk steps/s |", "|---|---|---|---|---:|---:|---:|---|---:|"]
        for r in (r for r in clsim_rows if r["runtime"] == runtime):
            lo, hi = r["steps_per_s_range"]
            lines.append(f"| {r['key']} {r['device']} | {r['mode']} | {r['detect']} | "
                         f"{'yes' if r.get('uniform', True) else 'no'} | {r['photons']:,} | "
                         f"{r['photons_per_s']:,.0f} | {r['steps_per_s'] / 1e6:,.1f} M | {lo / 1e6:,.1f}-{hi / 1e6:,.1f} M | "
                         f"{r.get('walk_steps_per_s', r['steps_per_s']) / 1e6:,.1f} M |")
        lines.append("")
    lines += ["## tlsvox tracer, per runtime", "",
              f"Synthetic scan: {trace_rows[0]['beams']:,} beams into 150 x 150 x 100 voxels of 0.2 m "
              f"(float64); medians of {args.repeats} runs, transfers included." if trace_rows else "No device runs the tracer.", "",
              "| device | runtime | accumulation | beams/s | voxel steps/s | median s (range) |", "|---|---|---|---:|---:|---|"]
    for r in trace_rows:
        lines.append(f"| {r['key']} {r['device']} | {r['runtime']} | {r['mode']} | {r['beams_per_s']:,.0f} | "
                     f"{r['steps_per_s'] / 1e6:,.1f} M | {r['seconds']:.3f} ({r['range_s'][0]:.3f}-{r['range_s'][1]:.3f}) |")
    if choice_rows:
        lines += ["", "## Build and launch choices (CPU devices, exact + nee)", "",
                  f"{args.photons:,} photons per run; medians of {args.repeats} runs, all variants taking turns.", "",
                  "| device | runtime | -cl-fast-relaxed-math | work-group size | photons/s | voxel steps/s |",
                  "|---|---|---|---|---:|---:|"]
        for r in choice_rows:
            lines.append(f"| {r['key']} | {r['runtime']} | {'yes' if r['fast_math'] else 'no'} | {r['local_size']} | "
                         f"{r['photons_per_s']:,.0f} | {r['steps_per_s'] / 1e6:,.1f} M |")
    return lines + [""]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--machine", default=platform.node() or "this-machine",
                    help="name of the machine in the title and file name")
    ap.add_argument("--out", default=None, help="markdown file (default docs/bench/devices-MACHINE.md)")
    ap.add_argument("--photons", type=int, default=1_000_000, help="photons per run on a CPU device")
    ap.add_argument("--gpu-factor", type=int, default=20, help="photons per run on a GPU, as a multiple")
    ap.add_argument("--beams", type=int, default=1_000_000)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--no-choices", action="store_true", help="skip section 3")
    args = ap.parse_args(argv)
    if args.quick:
        args.photons, args.beams, args.repeats = 200_000, 200_000, 3
    load0 = os.getloadavg()[0]
    t0 = time.perf_counter()
    report = device_report(("clsim", "tlsvox"))
    for info, verdict in report:
        print(f"{info.key} {info.label} [{info.runtime}]: {verdict}")
    cl_ok = [i for i, v in report if v["clsim"] is None]
    tr_ok = [i for i, v in report if v["tlsvox"] is None]
    clsim_rows = []
    cpus, gpus = [i for i in cl_ok if not i.is_gpu], [i for i in cl_ok if i.is_gpu]
    if cpus:
        clsim_rows += device_benchmark(photons=args.photons, repeats=args.repeats, devices=cpus)
    if gpus:
        clsim_rows += device_benchmark(photons=args.photons * args.gpu_factor, repeats=args.repeats, devices=gpus)
    for r in clsim_rows:
        print(f"clsim {r['key']} {r['runtime']:22s} {r['mode']:5s} {r['detect']:6s} uniform={r['uniform']!s:5s} "
              f"{r['photons_per_s']:14,.0f} photons/s {r['steps_per_s'] / 1e6:10,.1f} M steps/s "
              f"{r['walk_steps_per_s'] / 1e6:10,.1f} M walk steps/s")
    trace_rows = bench_tracer(tr_ok, args.beams, args.repeats) if tr_ok else []
    for r in trace_rows:
        print(f"tracer {r['key']} {r['runtime']:22s} {r['mode']:18s} {r['beams_per_s']:14,.0f} beams/s "
              f"{r['steps_per_s'] / 1e6:10,.1f} M steps/s")
    choice_rows = bench_choices(cpus, args.photons, args.repeats) if cpus and not args.no_choices else []
    for r in choice_rows:
        print(f"choice {r['key']} {r['runtime']:22s} fast={r['fast_math']!s:5s} wg={r['local_size']:16s} "
              f"{r['steps_per_s'] / 1e6:10,.1f} M steps/s")
    load1 = os.getloadavg()[0]
    lines = markdown(report, clsim_rows, trace_rows, args, load0, load1, time.perf_counter() - t0, choice_rows)
    out = Path(args.out) if args.out else ROOT / "docs" / "bench" / f"devices-{args.machine}.md"
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(out.name + ".tmp")
    tmp.write_text("\n".join(lines))
    os.replace(tmp, out)
    js = out.with_suffix(".json")
    js.write_text(json.dumps(dict(clsim=clsim_rows, tracer=trace_rows, choices=choice_rows), indent=1, default=str))
    print(f"wrote {out} and {js.name}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
