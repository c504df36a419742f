"""Benchmark: leaf angles per crown layer in the estimators' G, on an oak whose layers differ.

The synthetic oak (``make_tree(TreeParams(leaf_angle="planophile"), seed)``,
500 m2 of outward-facing leaves) with the leaves of its upper half (leaf
centre above the crown's middle height) given erectophile normals instead:
same places, same areas, a crown whose leaf angle distribution changes with
height.  Its two VZ-400 scans (true poses, true classes; every echo kept, a
-60 dB detection threshold, so that the detection floor's own loss, which
depends on the leaf angles too, does not hide G's term) are measured by
:func:`tlsvox.leafangles.measure_leaf_angles` (4 layers) and voxelised at 20 cm
(``undetected="ignore"``, ``fill="none"``, outward G per voxel) three ways:

- ``crown``: the whole crown's measured distribution for G (one model);
- ``per layer``: each layer's measured distribution in its voxels
  (``voxelize(leaf_angle_layers=...)``, CLI ``--leaf-angle-by-layer``);
- ``truth``: the true distribution of each half in its voxels (the best a
  per-layer G can do with these scans).

Scored against the mesh: the leaf area of the seen voxels of each half (voxel
centre below or above the switch height) and of the whole crown.  Writes
docs/bench/leaf_angle_layers.md.

    .venv/bin/python benchmarks/bench_leaf_angle_layers.py [--seed 0]

With the scanner's own floor and the detection model (which takes the crown's one distribution, also
in the per-layer runs), written to docs/bench/leaf_angle_layers-detection.md:

    .venv/bin/python benchmarks/bench_leaf_angle_layers.py --threshold-db -20 --undetected model \
        --out docs/bench/leaf_angle_layers-detection.md
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np
from _bench import machine_line, with_leaves, write_page

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_OUT = ROOT / "docs" / "bench" / "leaf_angle_layers.md"


def _shown(path) -> str:
    """``path`` as the page's command gives it: relative to the repository where it lies inside."""
    p = Path(path).resolve()
    return str(p.relative_to(ROOT)) if p.is_relative_to(ROOT) else str(p)


def layered_oak(seed: int, lower: str, upper: str):
    """The oak with ``lower`` leaf normals below the crown's middle height and ``upper`` above it."""
    from tlsvox.truth.synthetic import TreeParams, make_tree
    from voxlidar.leaf_orientation import LeafAngle, sample_leaf_normals

    tree = make_tree(TreeParams(leaf_angle=lower), seed=seed)
    p = tree.params
    c = tree.leaf_centers
    z_mid = float(p.crown_center[2])
    up = c[:, 2] >= z_mid
    rng = np.random.default_rng(seed + 1000)
    normals = tree.leaf_normals.copy()
    normals[up] = sample_leaf_normals(int(up.sum()), LeafAngle(upper), rng, azimuth=p.leaf_azimuth,
                                      positions=c[up], crown_center=np.asarray(p.crown_center)[:2])
    return with_leaves(tree, c, normals, rng), z_mid


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--lower", default="planophile")
    ap.add_argument("--upper", default="erectophile")
    ap.add_argument("--threshold-db", type=float, default=-60.0,
                    help="the scanner's detection threshold (the VZ-400 preset: -20 dB)")
    ap.add_argument("--undetected", default="ignore", choices=("ignore", "model"),
                    help="voxelize's undetected rule: 'model' gives back the interception a threshold above the "
                         "floor leaves unrecorded (with the crown's leaf angles)")
    ap.add_argument("--out", default=str(DEFAULT_OUT))
    args = ap.parse_args(argv)
    from tlsvox.leafangles import measure_leaf_angles
    from tlsvox.truth.scanner import ScannerPreset, paper_scan_poses, simulate_scan
    from tlsvox.voxel.stages import voxelize
    from tlsvox.voxel.trace import Tracer
    from voxlidar.leaf_orientation import LeafAngle

    load0 = os.getloadavg()
    t_all = time.perf_counter()
    tree, z_mid = layered_oak(args.seed, args.lower, args.upper)
    preset = ScannerPreset.riegl_vz400(min_reflectance_db=args.threshold_db)
    scans = [simulate_scan(tree, pose=pose, preset=preset, seed=10 + i, scan_id=i, progress=False)
             for i, pose in enumerate(paper_scan_poses(tree))]
    for s in scans:
        s.pose = s.pose_true
    t0 = time.perf_counter()
    m = measure_leaf_angles(scans, layers=4)
    t_measure = time.perf_counter() - t0
    incl = np.degrees(np.arccos(np.abs(tree.leaf_normals[:, 2])))
    zc = tree.leaf_centers[:, 2]
    layer_rows = []
    for k, lay in enumerate(m.layers):
        z0, z1 = lay.z_range
        sel = (zc >= z0 if k else np.ones(len(zc), bool)) & (zc < z1 if k < len(m.layers) - 1 else True)
        layer_rows.append((k + 1, z0, z1, float(incl[sel].mean()), float(np.degrees(lay.mean_inclination)),
                           float((zc[sel] >= z_mid).mean())))
    truth_layers = [(-1e3, z_mid, LeafAngle(args.lower)), (z_mid, 1e3, LeafAngle(args.upper))]
    tracer = Tracer()
    kw = dict(voxel_size=0.2, leaf_azimuth="outward", ground=0.0, layout="dense", progress=False, tracer=tracer,
              undetected=args.undetected)
    runs = {}
    for name, extra in (("crown", {}), ("per layer", {"leaf_angle_layers": m}),
                        ("truth", {"leaf_angle_layers": truth_layers})):
        t0 = time.perf_counter()
        res = voxelize(scans, leaf_angle=m.leaf_angle, **kw, **extra)
        g = res.grid
        truth = tree.leaf_area_per_voxel(origin=g.lower, voxel_size=g.voxel_size, shape=g.shape)
        seen = ~res.lad.occluded
        est = res.lad.lad * g.voxel_volume
        upper = (g.lower[2] + (np.arange(g.shape[2]) + 0.5) * g.voxel_size >= z_mid)[None, None, :]
        scores = {}
        for part, where in (("lower half", seen & ~upper), ("upper half", seen & upper), ("crown", seen)):
            t = float(truth[where].sum())
            scores[part] = (float(est[where].sum()), t)
        runs[name] = (scores, time.perf_counter() - t0)
        print(name, {k: f"{100 * (e / t - 1):+.1f} %" for k, (e, t) in scores.items()}, flush=True)
    lines = [f"## Leaf angles per crown layer in the estimators' G (an oak whose layers differ, seed {args.seed})", "",
             f"Command: `.venv/bin/python benchmarks/bench_leaf_angle_layers.py --seed {args.seed} --threshold-db "
             f"{args.threshold_db:g}"
             + ("" if args.undetected == "ignore" else f" --undetected {args.undetected}")
             + ("" if Path(args.out).resolve() == DEFAULT_OUT.resolve() else f" --out {_shown(args.out)}") + "` "
             f"({(time.perf_counter() - t_all) / 60:.1f} min). " + machine_line(load0) + " "
             f"The synthetic oak with {args.lower} leaves below its crown's middle height ({z_mid:.2f} m) and "
             f"{args.upper} leaves above (same places and areas, outward azimuths); two VZ-400 scans keeping "
             f"echoes down to {args.threshold_db:g} dB, true poses "
             f"and classes; 20 cm voxels, `undetected='{args.undetected}'`, no fill, outward G per voxel. Leaf angles "
             f"measured with `measure_leaf_angles(scans, layers=4)` ({t_measure:.0f} s).", "",
             "| layer | z (m) | share of its leaves above the switch | true mean inclination (deg) | measured (deg) |",
             "|---|---|---|---|---|"]
    for k, z0, z1, true_mean, got, share in layer_rows:
        lines.append(f"| {k} | {z0:.2f}-{z1:.2f} | {100 * share:.0f} % | {true_mean:.1f} | {got:.1f} |")
    lines += ["", f"Crown: measured {np.degrees(m.crown.mean_inclination):.1f} deg for a true "
              f"{incl.mean():.1f} deg.", "",
              "Leaf area of the seen voxels against the mesh:", "",
              "| G from | lower half | upper half | crown | voxelize time |", "|---|---|---|---|---|"]
    for name, (scores, sec) in runs.items():
        cells = [f"{e:.1f} of {t:.1f} m2 ({100 * (e / t - 1):+.1f} %)" for e, t in scores.values()]
        lines.append(f"| {name} | " + " | ".join(cells) + f" | {sec:.0f} s |")
    lines += ["", "`crown`: the whole crown's measured distribution; `per layer`: each measured layer's in its "
              "voxels (`leaf_angle_layers=`); `truth`: each half's true distribution in its voxels.", ""]
    write_page(args.out, lines)


if __name__ == "__main__":
    main()
