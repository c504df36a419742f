"""Benchmark: survey pulses per second against waveform agreement with the explicit mesh, first order.

The shared case of the HELIOS++ comparison (docs/bench/first_order.md): the synthetic oak of
seed 1 (``make_tree(TreeParams(), seed=1)``), its exact-LAD twin at ``--voxel`` m for clsim and its
own triangles for the judge; one 20 m line at 600 m and 60 m/s, a rotating polygon over +-1 deg at
100 lines/s and ``--pulse-rate`` Hz (10 kHz: 3,334 pulses), 0.25 mrad half-angle beam, 4 ns pulse,
1 GHz sampling (the RIEGL LMS-Q680i preset with those changes).  Single scattering, the hot spot on
(explicit leaves return along their free incoming path).

- **Judge**: :class:`clsim.validation.meshref.MeshReferenceSimulator` on ``--judge`` pulses of the
  line whose targets lie nearest the crown centre (``--mesh-photons`` photons each, order 1), its
  waveforms cached under out/bench_cache.  Score: the median over those pulses of the Pearson r
  between a method's waveform and the mesh's, on their common sample clock.
- **Methods**: the deterministic first order (``first_order="deterministic"``) with 1 .. 271 beam
  samples, and the Monte Carlo first order at 100 .. 10,000 photons per pulse.
- **Speed**: :meth:`clsim.Simulator.run_pulses` over the line (Monte Carlo: its first
  ``--mc-pulses``), the scene prepared and uploaded once; medians of ``--repeats``, methods taking
  turns.  **End to end**: ``clsim survey`` as a user runs it (start-up, scene load, simulation,
  batch files, LAS 1.4 with waveform packets), on the line and on one of 10x its pulses, wall
  seconds and peak memory of the process.

    flock /tmp/voxlidar-bench.lock .venv/bin/python benchmarks/bench_first_order.py
    .venv/bin/python benchmarks/bench_first_order.py --quick
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from _bench import machine_line, write_page

ROOT = Path(__file__).resolve().parents[1]
CACHE = ROOT / "out" / "bench_cache"


def log(msg):
    print(f"[{time.strftime('%H:%M:%S')}] {msg}", flush=True)


def shared_case(voxel: float, pulse_rate: float):
    """(tree or None, twin path, sensor, pulses) of the shared case; the twin cached."""
    from clsim.sensor import Sensor
    from clsim.survey import ScanPattern, Trajectory, survey_pulses

    CACHE.mkdir(parents=True, exist_ok=True)
    twin = CACHE / f"oak1_twin_{voxel:g}.npz"
    tree = None
    if not twin.is_file():
        from tlsvox.truth.synthetic import TreeParams, make_tree

        tree = make_tree(TreeParams(), seed=1)
        tree.truth_scene(voxel).save(twin)
    sensor = Sensor.preset("riegl-lms-q680i").replace(divergence_mrad=0.5, pulse_fwhm_ns=4.0, sampling_ghz=1.0)
    pattern = ScanPattern.preset("riegl-lms-q680i", pulse_rate_hz=pulse_rate, scan_rate_hz=100.0, fov_deg=2.0)
    from voxlidar.scene import Scene

    sc = Scene.load(twin)
    cx, cy = float(sc.crown_center[0]), float(sc.crown_center[1])
    traj = Trajectory.line((cx - 10.0, cy), (cx + 10.0, cy), altitude_m=600.0, speed_mps=60.0)
    pulses = survey_pulses(traj, pattern, sensor, ground=float(sc.ground_z or 0.0), seed=1)
    return tree, twin, sc, sensor, pulses, traj


def judge_pulses(sc, pulses, n: int):
    """Indices of ``n`` pulses nearest the crown centre, spread over distinct scan lines."""
    return nearest_spread(np.linalg.norm(pulses.target[:, :2] - np.asarray(sc.crown_center[:2]), axis=1), n)


def nearest_spread(distance, n: int, gap: int = 20) -> list[int]:
    """The ``n`` pulses of least ``distance``, no two within ``gap`` pulses of each other (so on
    distinct scan lines), in pulse order."""
    picked: list[int] = []
    for i in np.argsort(distance):
        if all(abs(int(i) - j) > gap for j in picked):
            picked.append(int(i))
        if len(picked) == n:
            break
    return sorted(picked)


def mesh_waveforms(idx, twin_path, sc, sensor, pulses, photons: int, voxel: float, tag: str = "first_order"):
    """The mesh reference's order-1 waveforms (time, waveform) of pulses ``idx``, cached (``tag``
    names the pulses' origin in the cache file's name)."""
    from clsim.validation.meshref import MeshReferenceSimulator

    path = CACHE / f"meshref_{tag}_{voxel:g}_{len(pulses)}_{photons}_{'-'.join(map(str, idx))}.npz"
    if path.is_file():
        z = np.load(path, allow_pickle=False)
        return [(z[f"t{i}"], z[f"w{i}"]) for i in range(len(idx))], float(z["seconds"])
    from tlsvox.truth.synthetic import TreeParams, make_tree

    tree = make_tree(TreeParams(), seed=1)
    ref = MeshReferenceSimulator()
    out, t0 = {}, time.perf_counter()
    for k, i in enumerate(idx):
        r = ref.run(tree, pulses.sensor(i, sensor), photons=photons, seed=7, max_order=1, target=pulses.target[i],
                    twin=sc)
        out[f"t{k}"], out[f"w{k}"] = r.time_ns, r.waveform
        log(f"mesh pulse {i}: {time.perf_counter() - t0:.0f} s")
    seconds = time.perf_counter() - t0
    np.savez(path, seconds=seconds, **out)
    return [(out[f"t{k}"], out[f"w{k}"]) for k in range(len(idx))], seconds


def pearson_on_clock(ta, a, tb, b, period: float) -> float:
    """Pearson r of two waveforms on one sample clock, over the span of both."""
    off = int(round((tb[0] - ta[0]) / period))
    lo, hi = min(0, off), max(len(a), off + len(b))
    x, y = np.zeros(hi - lo), np.zeros(hi - lo)
    x[-lo:-lo + len(a)] = a
    y[off - lo:off - lo + len(b)] = b
    return float(np.corrcoef(x, y)[0, 1])


def scores(wf, idx, judge, period):
    rs = []
    for k, i in enumerate(idx):
        t = wf.t0_ns[i] + period * np.arange(wf.n_samples[i])
        rs.append(pearson_on_clock(t, wf.waveform[i, :wf.n_samples[i]], judge[k][0], judge[k][1], period))
    return float(np.median(rs)), float(min(rs))


def end_to_end(twin, pulse_rate, args_extra, tmp) -> tuple[float, float, int]:
    """``clsim survey`` on the line: wall seconds, peak resident MiB of the process, pulses."""
    out = Path(tmp) / f"sv{time.monotonic_ns()}"
    cmd = [str(ROOT / ".venv" / "bin" / "clsim"), "survey", str(twin), "-o", str(out), "--start=-10,0", "--end",
           "10,0", "--altitude", "600", "--speed", "60", "--pulse-rate", f"{pulse_rate:g}", "--scan-rate", "100",
           "--fov", "2", "--max-order", "1", "--hotspot", "--workers", "0", "-q", "--batch-size", "4096",
           *args_extra]
    t0 = time.perf_counter()
    proc = subprocess.run(["/usr/bin/time", "-f", "%M", *cmd], capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise SystemExit(f"clsim survey failed: {proc.stderr.strip().splitlines()[-1:]}")
    peak_kib = int(proc.stderr.strip().splitlines()[-1])
    import json

    n = json.loads((out / "survey.json").read_text())["count"]
    return wall, peak_kib / 1024.0, n


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--voxel", type=float, default=0.1)
    ap.add_argument("--pulse-rate", type=float, default=10_000.0)
    ap.add_argument("--judge", type=int, default=6)
    ap.add_argument("--mesh-photons", type=int, default=200_000)
    ap.add_argument("--mc-pulses", type=int, default=200)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--quick", action="store_true", help="fewer settings and repeats, a check")
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "bench" / "first_order.md")
    args = ap.parse_args(argv)
    samples = (1, 19) if args.quick else (1, 3, 7, 19, 61, 271)
    photons = (100,) if args.quick else (100, 1000, 10_000)
    repeats = 1 if args.quick else args.repeats
    load0 = os.getloadavg()

    from clsim.transport.simulator import Simulator

    t = time.perf_counter()
    _, twin, sc, sensor, pulses, _ = shared_case(args.voxel, args.pulse_rate)
    log(f"scene {twin.name}: {sc.n_voxels:,} voxels, {len(pulses):,} pulses ({time.perf_counter() - t:.1f} s)")
    idx = judge_pulses(sc, pulses, args.judge)
    judge, mesh_s = mesh_waveforms(idx, twin, sc, sensor, pulses, args.mesh_photons, args.voxel)
    period = 1.0 / sensor.sampling_ghz
    sim = Simulator()
    bin_ns = sensor.pulse_fwhm_ns / 16
    methods = [(f"deterministic, {n} beam sample{'s' if n > 1 else ''}",
                dict(first_order="deterministic", beam_samples=n, photons=1, bin_ns=bin_ns), pulses)
               for n in samples]
    methods += [(f"Monte Carlo, {p:,} photons", dict(photons=p), pulses[:args.mc_pulses]) for p in photons]
    times = {name: [] for name, _, _ in methods}
    acc = {}
    for name, kw, ps in methods:  # warm: builds, and the accuracy on the judged pulses
        wf = sim.run_pulses(sc, pulses[np.asarray(idx)], sensor, max_order=1, hotspot=True, **kw)
        acc[name] = scores(wf, range(len(idx)), judge, period)
    for _ in range(repeats):
        for name, kw, ps in methods:
            t0 = time.perf_counter()
            sim.run_pulses(sc, ps, sensor, max_order=1, hotspot=True, **kw)
            times[name].append((time.perf_counter() - t0) / len(ps))
    rows = []
    for name, _, ps in methods:
        per = statistics.median(times[name])
        rows.append((name, 1.0 / per, *acc[name], len(ps)))
        log(f"{name}: {1.0 / per:,.0f} pulses/s, median r {acc[name][0]:.3f} (min {acc[name][1]:.3f})")
    e2e = []
    with tempfile.TemporaryDirectory() as tmp:
        for rate in (args.pulse_rate, 10 * args.pulse_rate):
            for n in ((1, 19) if not args.quick else (19,)):
                wall, peak, count = end_to_end(twin, rate, ["--first-order", "deterministic", "--beam-samples",
                                                            str(n)], tmp)
                e2e.append((f"deterministic, {n} beam sample{'s' if n > 1 else ''}", count, wall, count / wall, peak))
                log(f"end to end {count:,} pulses, {n} samples: {wall:.1f} s, {count / wall:,.0f} pulses/s, "
                    f"{peak:.0f} MiB")
    load1 = os.getloadavg()
    cmd = " ".join(["python", "benchmarks/bench_first_order.py", *(argv if argv is not None else sys.argv[1:])])
    lines = [
        "# First order: survey speed against agreement with the explicit mesh",
        "",
        f"`{cmd}`; {platform.processor() or platform.machine()}, {os.cpu_count()} cores, device "
        f"{sim.device_name}; {machine_line(load0, load1)}",
        "",
        f"The shared case: the synthetic oak of seed 1, its exact-LAD twin at {args.voxel:g} m "
        f"({sc.n_voxels:,} voxels) for clsim; one 20 m line at 600 m and 60 m/s, polygon over +-1 deg at 100 "
        f"lines/s and {args.pulse_rate:,.0f} Hz ({len(pulses):,} pulses), 0.25 mrad half-angle beam, 4 ns pulse, "
        "1 GHz sampling; single scattering with the hot spot (the return retraces the free incoming path). "
        f"Judge: clsim's explicit-mesh reference (the tree's own triangles, {args.mesh_photons:,} photons, order 1) "
        f"on the {len(idx)} pulses of the line nearest the crown centre (pulses {', '.join(map(str, idx))}; "
        f"{mesh_s:.0f} s for the mesh runs, cached); r: Pearson correlation of the waveforms on their common "
        "sample clock, median (and worst) over those pulses.",
        "",
        "**Simulation**: `Simulator.run_pulses` over the line (the Monte Carlo rows over its first "
        f"{args.mc_pulses} pulses), the scene prepared and uploaded once, medians of {repeats}; the deterministic "
        f"rows on fine bins of {bin_ns:g} ns (a 16th of the pulse width; their bins hold exact integrals).",
        "",
        "| method | pulses/s | median r vs mesh | worst r | pulses timed |",
        "| --- | --- | --- | --- | --- |",
    ]
    lines += [f"| {n} | {r:,.0f} | {m:.3f} | {w:.3f} | {c:,} |" for n, r, m, w, c in rows]
    lines += ["", "**End to end**: `clsim survey ... --max-order 1 --hotspot --first-order deterministic "
              "--beam-samples N --workers 0 --batch-size 4096` as a user runs it: start-up, scene load, simulation, "
              "batch files, LAS 1.4 with waveform packets and the decomposed points; wall time and the process's "
              "peak resident memory.", "",
              "| method | pulses | wall s | pulses/s | peak MiB |", "| --- | --- | --- | --- | --- |"]
    lines += [f"| {n} | {c:,} | {w:.1f} | {r:,.0f} | {p:.0f} |" for n, c, w, r, p in e2e]
    write_page(args.out, lines, echo=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
