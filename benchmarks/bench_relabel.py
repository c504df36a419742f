"""Bark the classifier missed: leaf-classed echoes on the fitted cylinders relabelled wood.

The default synthetic oak (``make_tree(seed=1)``, the demo's) and its two
simulated VZ-400 scans, registered, classified and voxelised by
``tlsvox.pipeline.scene_from_scans`` at 20 cm with the demo's settings
(``undetected="model"``, ``fill="neighbourhood"``), once with
``qsm_relabel=True`` (the default) and once with ``False``.  Per scan: the
echoes moved and their truth materials, the leaf and wood precision and recall
against the truth; per run: the leaf area in all voxels and in the voxels not
flagged occluded against the mesh's (as the demo scores it).

Writes docs/bench/relabel.md.

    .venv/bin/python benchmarks/bench_relabel.py            # about 4-5 min on 2 cores
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np
from _bench import machine_line, write_page

ROOT = Path(__file__).resolve().parents[1]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=1, help="the oak's seed (default 1, the demo's)")
    ap.add_argument("--voxel-size", type=float, default=0.2)
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "bench" / "relabel.md")
    args = ap.parse_args(argv)

    from tlsvox.classify import PointClass, score
    from tlsvox.pipeline import scene_from_scans
    from tlsvox.truth.scanner import ScannerPreset, paper_scan_poses, simulate_scan
    from tlsvox.truth.synthetic import TreeParams, make_tree
    from tlsvox.voxel.quality import score_seen
    from voxlidar.materials import Material

    load0 = os.getloadavg()
    t_start = time.perf_counter()
    tree = make_tree(TreeParams(), seed=args.seed)
    preset = ScannerPreset.riegl_vz400()
    poses = paper_scan_poses(tree)

    def scans():  # fresh scans each run: the pipeline sets their poses
        return [simulate_scan(tree, pose=p, preset=preset, seed=args.seed + i, scan_id=i + 1, name=f"scan{i + 1}",
                              progress=False) for i, p in enumerate(poses)]

    runs = {}
    for relabel in (False, True):
        ss = scans()
        t0 = time.perf_counter()
        pr = scene_from_scans(ss, voxel_size=args.voxel_size, progress=False, qsm_relabel=relabel,
                              voxelize_kwargs={"undetected": "model", "fill": "neighbourhood"})
        seconds = time.perf_counter() - t0
        sc = pr.scene
        truth = tree.leaf_area_per_voxel(origin=sc.origin, voxel_size=sc.voxel_size, shape=sc.shape)
        vol = sc.voxel_size**3
        all_, vis = score_seen(sc.dense("lad"), sc.dense("occluded"), truth / vol, voxel_volume=vol)
        per_scan = []
        for s, c in zip(ss, pr.classifications):
            q = score(c.labels, s.truth_material)
            per_scan.append((s, c, q))
        runs[relabel] = (pr, all_, vis, per_scan, seconds)

    # what moved: the labels of the two runs, echo by echo (the same scans, the same classifier)
    moved_rows = []
    for (s, c0, _), (_, c1, _) in zip(runs[False][3], runs[True][3]):
        m = (c0.labels == PointClass.LEAF) & (c1.labels == PointClass.WOOD)
        tm = s.truth_material[m]
        n = int(m.sum())
        bark = int(np.count_nonzero(tm == Material.BARK))
        leaf = int(np.count_nonzero(tm == Material.LEAF))
        moved_rows.append(f"| {s.name} | {n:,} | {bark:,} ({100 * bark / max(n, 1):.1f} %) | {leaf:,} | "
                          f"{n - bark - leaf:,} |")
    minutes = (time.perf_counter() - t_start) / 60
    cyl = runs[True][0].cylinders
    lines = [
        "# Bark the classifier missed: leaf echoes on the fitted cylinders relabelled wood",
        "",
        f"Command: `.venv/bin/python benchmarks/bench_relabel.py --seed {args.seed}` ({minutes:.1f} min). "
        + machine_line(load0, os.getloadavg()),
        "",
        f"The synthetic oak of seed {args.seed}{' (the demo' + chr(39) + 's)' if args.seed == 1 else ''}, its two "
        "simulated VZ-400 scans, "
        f"`scene_from_scans` at {100 * args.voxel_size:.0f} cm with `undetected=\"model\"`, "
        f"`fill=\"neighbourhood\"` (the demo's settings), `qsm_relabel` off and on; {len(cyl)} cylinders fitted. "
        "A leaf-classed echo within max(3 sigma, 1 cm) of a trusted cylinder's side is relabelled wood "
        "(`tlsvox.voxel.wood.qsm.bark_echoes`).",
        "",
        "## The echoes moved, against the truth",
        "",
        "| scan | leaf echoes relabelled wood | of them bark | leaf | other |",
        "|---|---|---|---|---|",
        *moved_rows,
        "",
        "## Classification against the truth",
        "",
        "| scan | relabel | leaf precision | leaf recall | wood precision | wood recall |",
        "|---|---|---|---|---|---|",
    ]
    for relabel in (False, True):
        for s, c, q in runs[relabel][3]:
            lines.append(f"| {s.name} | {'on' if relabel else 'off'} | {q.precision['leaf']:.3f} | "
                         f"{q.recall['leaf']:.3f} | {q.precision['wood']:.3f} | {q.recall['wood']:.3f} |")
    lines += ["", "## Leaf area against the mesh", "",
              "| relabel | all voxels (m2) | error | voxels not flagged occluded (m2) | true there (m2) | error | "
              "pipeline time |", "|---|---|---|---|---|---|---|"]
    for relabel in (False, True):
        _, a, v, _, secs = runs[relabel]
        lines.append(f"| {'on' if relabel else 'off'} | {a['total_area']:.1f} | {100 * a['area_error']:+.1f} % | "
                     f"{v['total_area']:.1f} | {v['true_area']:.1f} | {100 * v['area_error']:+.1f} % | {secs:.0f} s |")
    lines += ["", "Reading: docs/voxelize.md, *Bark the classifier missed*."]
    write_page(args.out, lines, echo=True)


if __name__ == "__main__":
    main()
