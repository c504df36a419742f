"""Benchmark: TLS scanner simulator throughput (pulses/s, sub-rays/s).

Scans the default synthetic oak from the paper's ~20 m position with 1, 7 and
19 sub-rays per pulse, side by side in one run, and reports the median of
several runs.  Writes a Markdown table to docs/bench/scanner.md.

    .venv/bin/python benchmarks/bench_scanner.py [--runs 3] [--step 0.12]
"""

from __future__ import annotations

import argparse
import os
import platform
import time
from pathlib import Path

import numpy as np
from _bench import write_page

from tlsvox.truth.scanner import ScannerPreset, paper_scan_poses, simulate_scan
from tlsvox.truth.synthetic import make_tree

ROOT = Path(__file__).resolve().parents[1]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--step", type=float, default=0.12, help="angular step, degrees")
    ap.add_argument("--out", default=str(ROOT / "docs" / "bench" / "scanner.md"))
    args = ap.parse_args(argv)

    t0 = time.perf_counter()
    tree = make_tree(seed=1)
    t_tree = time.perf_counter() - t0
    pose = paper_scan_poses(tree)[0]
    t0 = time.perf_counter()
    tree.raycasting_scene()  # Embree BVH, built once per tree and cached
    t_bvh = time.perf_counter() - t0
    rows = []
    for n_sub in (1, 7, 19):
        preset = ScannerPreset.riegl_vz400(n_subrays=n_sub, zenith_step_deg=args.step, azimuth_step_deg=args.step)
        times = []
        for run in range(args.runs):
            t0 = time.perf_counter()
            scan = simulate_scan(tree, pose=pose, preset=preset, seed=run, progress=False)
            times.append(time.perf_counter() - t0)
        med = float(np.median(times))
        n_p = len(scan.pulses)
        rows.append((n_sub, n_p, len(scan), med, n_p / med, n_p * n_sub / med))
        print(f"{n_sub:2d} sub-rays: {n_p:,} pulses, {len(scan):,} echoes, median {med:.2f} s "
              f"-> {n_p / med:,.0f} pulses/s, {n_p * n_sub / med:,.0f} sub-rays/s")
    lines = [
        "## TLS scanner simulator",
        "",
        f"Default oak ({len(tree.triangles):,} triangles, generated in {t_tree:.1f} s, Embree BVH built in "
        f"{t_bvh:.1f} s, not counted below), scan from the paper's ~20 m position, angular step {args.step} deg, median of {args.runs} runs. "
        f"Machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores.",
        "",
        f"Command: `.venv/bin/python benchmarks/bench_scanner.py --runs {args.runs} --step {args.step}`",
        "",
        "| sub-rays / pulse | pulses | echoes | median time (s) | pulses/s | sub-rays/s | ratio to 1 sub-ray |",
        "|---:|---:|---:|---:|---:|---:|---:|",
    ]
    base = rows[0][3]
    for n_sub, n_p, n_e, med, pps, sps in rows:
        lines.append(f"| {n_sub} | {n_p:,} | {n_e:,} | {med:.2f} | {pps:,.0f} | {sps:,.0f} | {med / base:.2f}x |")
    out = Path(args.out)
    write_page(out, lines)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
