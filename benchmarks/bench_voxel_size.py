"""LAD error and run time versus voxel size, per estimator, on the synthetic oak.

Two simulated scans of the procedural oak (true poses, truth materials as the
echo classes) are voxelised at 5, 10, 20 and 40 cm.  Every estimator reads
the same traced statistics.  Scored against the mesh's exact leaf area per
voxel: total leaf area error (all voxels, and only where the scans see),
per-voxel RMSE and bias in non-occluded voxels.  Writes a table to
docs/bench/voxelize.md and a chart to docs/img/voxel_size.png.

    .venv/bin/python benchmarks/bench_voxel_size.py [--sizes 0.05,0.1,0.2,0.4] [--max-gib 6]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
from _bench import write_section

from tlsvox.errors import InputError
from tlsvox.voxel.estimators import Estimator, estimate_lad
from tlsvox.voxel.stages import score_lad, voxelize
from tlsvox.voxel.trace import Tracer

ROOT = Path(__file__).resolve().parents[1]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sizes", default="0.05,0.1,0.2,0.4")
    ap.add_argument("--max-gib", type=float, default=6.0, help="memory allowed for one grid")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--out", default=str(ROOT / "docs" / "bench" / "voxelize.md"))
    ap.add_argument("--png", default=str(ROOT / "docs" / "img" / "voxel_size.png"))
    args = ap.parse_args(argv)
    from tlsvox.truth.scanner import paper_scan_poses, simulate_scan
    from tlsvox.truth.synthetic import make_tree

    tree = make_tree(seed=args.seed)
    scans = []
    t = time.perf_counter()
    for i, pose in enumerate(paper_scan_poses(tree)):
        s = simulate_scan(tree, pose=pose, seed=10 + i, scan_id=i, progress=False)
        s.pose = s.pose_true
        scans.append(s)
    t_sim = time.perf_counter() - t
    tracer = Tracer()
    rows, skipped = [], []
    for h in [float(v) for v in args.sizes.split(",")]:
        try:
            res = voxelize(scans, voxel_size=h, leaf_angle="uniform", ground=0.0, tracer=tracer, progress=False,
                           max_bytes=int(args.max_gib * 1024**3))
        except InputError as err:
            skipped.append((h, str(err)))
            continue
        g = res.grid
        truth = tree.leaf_area_per_voxel(origin=g.lower, voxel_size=h, shape=g.shape) / g.voxel_volume
        for est in Estimator:
            t = time.perf_counter()
            lad = estimate_lad(res.stats, estimator=est)
            t_est = time.perf_counter() - t
            occ = lad.occluded
            allv = score_lad(lad.lad, truth, voxel_volume=g.voxel_volume)
            vis = score_lad(np.where(occ, 0, lad.lad), np.where(occ, 0, truth), voxel_volume=g.voxel_volume)
            pv = score_lad(lad.lad, truth, mask=~occ)
            rows.append(dict(h=h, est=est.value, area_err=allv["area_error"], vis_err=vis["area_error"],
                             rmse=pv["rmse"], bias=pv["bias"], occluded_truth=float(truth[occ].sum() / truth.sum()),
                             trace_s=res.timings["trace"], pulses_s=res.timings["pulses"], est_s=t_est,
                             voxels=g.n_voxels, beams=res.stats.n_beams))
            print(rows[-1])
    lines = [f"Synthetic oak (seed {args.seed}, {tree.leaf_area():.0f} m2 of leaves, uniform leaf angles), "
             f"two simulated VZ-400 scans ({sum(len(s.pulses) for s in scans):,} pulses, simulated in "
             f"{t_sim:.0f} s), true poses, truth materials as echo classes, default options "
             "(n_min 5, min_explored 0.05, no fill, factor 1). Area errors are relative; `visible` counts "
             "only non-occluded voxels (the truth hidden in occluded voxels is in `hidden`). RMSE and "
             "bias in m2/m3 over non-occluded voxels.", "",
             "| voxel | estimator | area error | visible area error | hidden | RMSE | bias | trace s | estimate s |",
             "|---:|---|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        lines.append(f"| {r['h'] * 100:.0f} cm | {r['est']} | {r['area_err']:+.1%} | {r['vis_err']:+.1%} | "
                     f"{r['occluded_truth']:.1%} | {r['rmse']:.3f} | {r['bias']:+.4f} | {r['trace_s']:.2f} | "
                     f"{r['est_s']:.3f} |")
    for h, msg in skipped:
        lines.append(f"\n{h * 100:.0f} cm skipped: {msg}")
    lines += ["", "![LAD error and time vs voxel size](../img/voxel_size.png)", "",
              "Command: `.venv/bin/python benchmarks/bench_voxel_size.py`"]
    write_section(Path(args.out), "LAD error and time versus voxel size (synthetic oak)", "\n".join(lines))
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 3, figsize=(13, 4))
    for est in Estimator:
        rr = [r for r in rows if r["est"] == est.value]
        hs = [r["h"] * 100 for r in rr]
        ax[0].plot(hs, [100 * r["vis_err"] for r in rr], "o-", label=est.value)
        ax[1].plot(hs, [r["rmse"] for r in rr], "o-", label=est.value)
    rr = [r for r in rows if r["est"] == "bcmle"]
    ax[2].plot([r["h"] * 100 for r in rr], [r["trace_s"] for r in rr], "o-", label="trace")
    ax[2].plot([r["h"] * 100 for r in rr], [r["pulses_s"] for r in rr], "s-", label="pulses -> beams")
    ax[0].axhline(0, color="k", lw=0.5)
    ax[0].set(xlabel="voxel size (cm)", ylabel="leaf area error, visible voxels (%)", xscale="log")
    ax[1].set(xlabel="voxel size (cm)", ylabel="per-voxel LAD RMSE (m2/m3)", xscale="log")
    ax[2].set(xlabel="voxel size (cm)", ylabel="seconds", xscale="log")
    for a in ax:
        a.legend(fontsize=8)
        a.grid(alpha=0.3)
    fig.tight_layout()
    Path(args.png).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.png, dpi=110)
    print("\n".join(lines))


if __name__ == "__main__":
    main()
