"""Beam tracing speed on the real VZ-400i scan (../shared/data), beams per second.

Rebuilds the scan's pulses (returned + empty, ~1.23 M beams), traces them
through a 20 cm grid of the plot ``--repeat`` times per OpenCL device found,
and writes the medians to docs/bench/voxelize.md (section "Tracer").  The
NumPy brute-force reference (every ray against every voxel) is timed on a
small sub-problem for the ratio.

    .venv/bin/python benchmarks/bench_trace.py [--repeat 5] [--voxel-size 0.2]
"""

from __future__ import annotations

import argparse
import os
import platform
import time
from pathlib import Path

import numpy as np
from _bench import write_section

from tlsvox.scan import AngularGrid, Scan
from tlsvox.voxel.grid import VoxelGrid
from tlsvox.voxel.pulses import beams_from_scan, rotation_from_rpy
from tlsvox.voxel.trace import Beams, Tracer, trace_reference

ROOT = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("VOXLIDAR_SHARED_DATA", ROOT.parent / "shared" / "data"))
GRID = AngularGrid(30.0, 0.048, 2082, 0.0, 0.622, 580)
RPY = (1.026, 0.746, -110.019)


def subset(b: Beams, idx) -> Beams:
    cnt = np.diff(b.echo_start)[idx]
    st = np.concatenate([[0], np.cumsum(cnt)])
    e = np.repeat(b.echo_start[idx], cnt) + (np.arange(st[-1]) - np.repeat(st[:-1], cnt))
    return Beams(origin=b.origin[idx], direction=b.direction[idx], echo_start=st, echo_range=b.echo_range[e],
                 echo_weight=b.echo_weight[e], echo_kind=b.echo_kind[e], tail=b.tail[idx],
                 max_range=b.max_range[idx], g=b.g[idx])


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--voxel-size", type=float, default=0.2)
    ap.add_argument("--out", default=str(ROOT / "docs" / "bench" / "voxelize.md"))
    args = ap.parse_args(argv)
    path = DATA / "tls-vz400i-scan" / "tls_scan.laz"
    if not path.exists():
        raise SystemExit(f"{path} not found: set VOXLIDAR_SHARED_DATA")
    scan = Scan.read(path)
    t = time.perf_counter()
    beams, info = beams_from_scan(scan, pose=np.eye(4), angular_grid=GRID, socs_rotation=rotation_from_rpy(*RPY))
    t_pulses = time.perf_counter() - t
    grid = VoxelGrid.from_points(scan.xyz, voxel_size=args.voxel_size)
    from voxlidar.devices import device_report

    rows = []
    for info, verdict in device_report(("tlsvox",)):
        if verdict["tlsvox"] is None:  # broken devices are skipped (clsim devices says why)
            tracer = Tracer(info)
            tracer.trace(grid, subset(beams, np.arange(1000)))  # warm-up (build, first touch)
            times, steps = [], 0
            for _ in range(args.repeat):
                st = tracer.trace(grid, beams)
                times.append(st.seconds)
                steps = st.n_steps
            med = float(np.median(times))
            rows.append((tracer.name, len(beams) / med, steps / med, med))
    # NumPy brute-force reference on a small sub-problem, and the same on OpenCL
    small = VoxelGrid((-2.0, -2.0, -1.0), 0.2, (20, 20, 15))
    sub = subset(beams, np.random.default_rng(0).choice(len(beams), 300, replace=False))
    t = time.perf_counter()
    trace_reference(small, sub)
    t_ref = time.perf_counter() - t
    tr = Tracer()
    tr.trace(small, sub)
    t_cl = np.median([tr.trace(small, sub).seconds for _ in range(5)])
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    lines = [
        f"Real RIEGL VZ-400i scan: {len(scan):,} echoes -> {len(beams):,} beams "
        f"({info['reconstructed']:,} empty pulses rebuilt from the angular grid in {t_pulses:.1f} s, "
        f"line fit {info['line_fit']:.3f}); grid {grid.shape} of {grid.voxel_size} m "
        f"= {grid.n_voxels:,} voxels. Median of {args.repeat} runs, wall time including transfers.",
        "",
        f"Machine: {platform.processor() or platform.machine()}, {os.cpu_count()} logical CPUs, "
        f"load average {load:.1f} at the time of the run (other jobs share the cores).",
        "",
        "| device | beams/s | voxel steps/s | seconds |",
        "|---|---:|---:|---:|",
    ]
    for name, bps, sps, med in rows:
        lines.append(f"| {name} | {bps / 1e6:.2f} M | {sps / 1e6:.1f} M | {med:.2f} |")
    lines += ["", f"NumPy brute-force reference (every ray x every voxel) on 300 beams x {small.n_voxels:,} "
              f"voxels: {t_ref:.2f} s; OpenCL on the same: {t_cl * 1e3:.1f} ms (ratio {t_ref / t_cl:,.0f}x).",
              "", "Command: `.venv/bin/python benchmarks/bench_trace.py`"]
    body = "\n".join(lines)
    write_section(Path(args.out), "Tracer: beams per second on the real scan", body)
    print(body)


if __name__ == "__main__":
    main()
