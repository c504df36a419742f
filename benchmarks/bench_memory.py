"""Peak memory and time of tracing and estimating the synthetic oak's two scans, per
voxel size and tracer layout (dense: sums for every voxel; sparse: only voxels holding
echoes, plus coarse sums per 8^3 brick), with the leaf area each gives against the mesh.

The two scans are simulated once and cached; each configuration then runs in a fresh
Python process (so its peak RSS is its own): it loads the scans (RSS "scans loaded"),
runs ``voxelize`` (the beams, the trace, the estimate and the scene: "peak"), and then,
outside the measured part, scores the result against the mesh's exact leaf area per
voxel:

- total leaf area, without and with the layer fill of occluded voxels (``fill``),
  against the tree's true leaf area;
- visible leaf area: the estimate against the truth over the voxels the scans saw
  (not flagged occluded; in the sparse layout, also not in an occluded brick).

Writes the table to docs/bench/memory.md and a chart to docs/img/memory_voxel_size.png.

    .venv/bin/python benchmarks/bench_memory.py [--sizes 0.02,0.05,0.1,0.2] [--repeats 1]
"""

from __future__ import annotations

import argparse
import json
import os
import pickle
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from _bench import machine_line, write_page

ROOT = Path(__file__).resolve().parents[1]
SEED = 1
#: (layout, fill) per voxel size
CONFIGS = (("sparse", "none"), ("sparse", "layer"), ("dense", "none"), ("dense", "layer"))


def simulate(cache: Path) -> float:
    """The paper's two scans of the oak, pickled to ``cache``; returns seconds."""
    from tlsvox.truth.scanner import paper_scan_poses, simulate_scan
    from tlsvox.truth.synthetic import make_tree

    t = time.perf_counter()
    tree = make_tree(seed=SEED)
    scans = []
    for i, pose in enumerate(paper_scan_poses(tree)):
        s = simulate_scan(tree, pose=pose, seed=10 + i, scan_id=i, progress=False)
        s.pose = s.pose_true
        scans.append(s)
    with open(cache, "wb") as fh:
        pickle.dump(scans, fh)
    return time.perf_counter() - t


def child(cache: str, h: float, layout: str, fill: str, lad_h: float | None = None) -> dict:
    """One configuration, in this (fresh) process."""
    import resource

    from tlsvox.errors import InputError
    from tlsvox.voxel.stages import voxelize

    def rss_gib():
        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024**2

    with open(cache, "rb") as fh:
        scans = pickle.load(fh)
    loaded = rss_gib()
    t = time.perf_counter()
    try:
        res = voxelize(scans, voxel_size=h, leaf_angle="uniform", ground=0.0, fill=fill,
                       layout=layout, progress=False, lad_voxel_size=lad_h)
    except InputError as err:
        return {"skipped": str(err)}
    seconds = time.perf_counter() - t
    peak = rss_gib()
    del scans
    from tlsvox.truth.synthetic import make_tree  # Open3D: after the measured part

    s, g = res.scene, res.grid
    tree = make_tree(seed=SEED)
    true_total = tree.leaf_area()
    truth = tree.leaf_area_per_voxel(origin=g.lower, voxel_size=h, shape=g.shape)
    est = np.zeros(g.shape)
    est[tuple(s.ijk.T)] = s.lad * h**3
    seen = _seen(res) if res.coarse is None else _upsample(_seen(res.coarse), round(lad_h / h), g.shape)
    return {"seconds": seconds, "trace_s": res.timings["trace"], "loaded_gib": loaded, "peak_gib": peak,
            "voxels": g.n_voxels, "rows": int(s.n_voxels), "steps": res.stats.n_steps,
            "area": float(s.lad.sum() * h**3), "true_area": true_total,
            "visible_est": float(est[seen].sum()), "visible_true": float(truth[seen].sum())}


def _seen(res) -> np.ndarray:
    """(nx, ny, nz) bool: the voxels of a run not flagged occluded (sparse: nor in an occluded brick)."""
    g, s = res.grid, res.scene
    seen = np.ones(g.shape, bool)
    seen[tuple(s.ijk[s.occluded].T)] = False
    if res.stats.sparse:  # echo-free voxels of occluded bricks were not seen either
        dark = np.repeat(np.repeat(np.repeat(res.lad.brick_occluded, 8, 0), 8, 1), 8, 2)
        seen &= ~dark[: g.shape[0], : g.shape[1], : g.shape[2]]
    return seen


def _upsample(mask, k, shape):
    """A coarse grid's mask on the grid k times finer (cropped to ``shape``)."""
    fine = np.repeat(np.repeat(np.repeat(mask, k, 0), k, 1), k, 2)
    return fine[: shape[0], : shape[1], : shape[2]]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sizes", default="0.02,0.05,0.1,0.2")
    ap.add_argument("--repeats", type=int, default=1, help="runs per configuration (median time)")
    ap.add_argument("--lad-sizes", default="0.1",
                    help="also run each smaller voxel size with the LAD estimated at these sizes "
                         "(voxelize's lad_voxel_size, layout auto, without and with the layer fill; '': not)")
    ap.add_argument("--dense-max-gib", type=float, default=6.0, help="skip dense grids needing more")
    ap.add_argument("--out", default=str(ROOT / "docs" / "bench" / "memory.md"))
    ap.add_argument("--png", default=str(ROOT / "docs" / "img" / "memory_voxel_size.png"))
    ap.add_argument("--child", nargs=5, metavar=("CACHE", "H", "LAYOUT", "FILL", "LAD_H"), help=argparse.SUPPRESS)
    ap.add_argument("--simulate", metavar="CACHE", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.simulate:
        print(json.dumps({"seconds": simulate(Path(args.simulate))}))
        return
    if args.child:
        cache, h, layout, fill, lad_h = args.child
        print(json.dumps(child(cache, float(h), layout, fill, None if lad_h == "none" else float(lad_h))))
        return
    load_before = os.getloadavg()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        cache = Path(tmp) / "scans.pkl"
        # every heavy step in its own process: a child's peak RSS counts from the RSS of the process that
        # started it (Linux keeps the high-water mark across exec), so this one stays small
        out = subprocess.run([sys.executable, __file__, "--simulate", str(cache)], capture_output=True, text=True,
                             cwd=ROOT)
        if out.returncode != 0:
            raise SystemExit(f"simulating the scans failed:\n{out.stderr[-3000:]}")
        t_sim = json.loads(out.stdout.strip().splitlines()[-1])["seconds"]
        lad_sizes = [float(v) for v in args.lad_sizes.split(",") if v]
        for h in [float(v) for v in args.sizes.split(",")]:
            dense_gib = (np.prod(np.ceil(np.array([15.0, 15.0, 14.0]) / h)) * 16 * 8 * 3 / 1024**3)
            configs = [(layout, fill, None) for layout, fill in CONFIGS]
            configs += [("auto", fill, H) for H in lad_sizes if h < H and abs(H / h - round(H / h)) < 1e-6
                        for fill in ("none", "layer")]
            for layout, fill, lad_h in configs:
                if layout == "dense" and dense_gib > args.dense_max_gib:
                    rows.append({"h": h, "layout": layout, "fill": fill, "lad_h": lad_h,
                                 "skipped": f"dense needs about {dense_gib:.0f} GiB"})
                    continue
                runs = []
                for _ in range(args.repeats):
                    out = subprocess.run([sys.executable, __file__, "--child", str(cache), str(h), layout, fill,
                                          "none" if lad_h is None else str(lad_h)],
                                         capture_output=True, text=True, cwd=ROOT)
                    if out.returncode != 0:
                        raise SystemExit(f"child {h} {layout} {fill} failed:\n{out.stderr[-3000:]}")
                    runs.append(json.loads(out.stdout.strip().splitlines()[-1]))
                r = dict(runs[0])
                if "seconds" in r:
                    r["seconds"] = float(np.median([x["seconds"] for x in runs]))
                    r["peak_gib"] = float(max(x["peak_gib"] for x in runs))
                rows.append({"h": h, "layout": layout, "fill": fill, "lad_h": lad_h, **r})
                print(json.dumps(rows[-1]), flush=True)
    load_after = os.getloadavg()
    write(rows, args, t_sim, load_before, load_after)


def write(rows, args, t_sim, load_before, load_after):
    from voxlidar.safeio import save_figure

    lines = [
        "# Memory and time against voxel size (synthetic oak, two scans)", "",
        f"Command: `.venv/bin/python benchmarks/bench_memory.py --sizes {args.sizes} --repeats {args.repeats}"
        f" --lad-sizes {args.lad_sizes or chr(39) * 2}`. "
        + machine_line(load_before, load_after),
        "",
        f"The two scans (4.1 M pulses, 1.7 M echoes) were simulated once ({t_sim:.0f} s, not counted). Each "
        "row is a fresh process: *scans loaded* is its RSS with the scans in memory, *peak* its peak RSS "
        "through `voxelize` (beams, trace, estimate, scene); time is `voxelize`'s wall time"
        + (f", median of {args.repeats} runs" if args.repeats > 1 else ", one run") + ". Leaf area against "
        "the mesh: *total* over the whole scene (true total in the last column), *visible* over the voxels "
        "the scans saw (estimate against truth there). *LAD at N cm*: `lad_voxel_size` (the LAD estimated on "
        "the N cm grid, where fill acts too, and put on every fine voxel; *visible*: the coarse voxels not "
        "flagged occluded). Options: `leaf_angle='uniform'` (the truth), uniform azimuths, `ground=0`, the "
        "other `voxelize` defaults: the outward-leaf G and the detection model of the pipeline are off, so "
        "the leaf area reads low (docs/voxelize.md, section 4).", "",
        "| voxel | layout | fill | grid voxels | stored voxels | time, s | trace, s | scans loaded, GiB | "
        "peak, GiB | total leaf area, m2 (error) | visible leaf area error | true area, m2 |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lad_h = r.get("lad_h")
        head = (f"| {r['h'] * 100:g} cm{'' if lad_h is None else f', LAD at {lad_h * 100:g} cm'} | {r['layout']} | "
                f"{r['fill']} |")
        if "skipped" in r:
            lines.append(head + f" not run: {r['skipped']} |||||||||")
            continue
        tot_err = (r["area"] - r["true_area"]) / r["true_area"]
        vis_err = (r["visible_est"] - r["visible_true"]) / r["visible_true"]
        lines.append(head + f" {r['voxels']:,} | {r['rows']:,} | {r['seconds']:.1f} | {r['trace_s']:.1f} | "
                     f"{r['loaded_gib']:.2f} | {r['peak_gib']:.2f} | {r['area']:.1f} ({100 * tot_err:+.1f} %) | "
                     f"{100 * vis_err:+.1f} % | {r['true_area']:.1f} |")
    lines += ["", "Goals (issue 14): 2 cm at most 4 GiB peak and 10 minutes; 5 cm at most 1.5 GiB.", ""]
    out = Path(args.out)
    write_page(out, lines)

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(13, 4))
    for layout, marker in (("dense", "s"), ("sparse", "o")):
        sel = [r for r in rows if r["layout"] == layout and r["fill"] == "none" and "skipped" not in r
               and r.get("lad_h") is None]
        if not sel:
            continue
        h = [r["h"] * 100 for r in sel]
        axes[0].plot(h, [r["peak_gib"] for r in sel], marker=marker, label=layout)
        axes[1].plot(h, [r["seconds"] for r in sel], marker=marker, label=layout)
    for layout, fill, marker in (("sparse", "none", "o"), ("sparse", "layer", "s"), ("dense", "none", "^"),
                                 ("dense", "layer", "v")):
        sel = [r for r in rows if r["layout"] == layout and r["fill"] == fill and "skipped" not in r
               and r.get("lad_h") is None]
        h = [r["h"] * 100 for r in sel]
        axes[2].plot(h, [100 * (r["area"] - r["true_area"]) / r["true_area"] for r in sel], marker=marker,
                     label=f"{layout}, fill {fill}")
    for lad_h in sorted({r["lad_h"] for r in rows if r.get("lad_h") is not None and "skipped" not in r}):
        for fill, marker in (("none", "*"), ("layer", "P")):
            sel = [r for r in rows if r.get("lad_h") == lad_h and r["fill"] == fill and "skipped" not in r]
            h = [r["h"] * 100 for r in sel]
            label = f"LAD at {lad_h * 100:g} cm, fill {fill}"
            if fill == "none":
                axes[0].plot(h, [r["peak_gib"] for r in sel], marker=marker, ls="", ms=10, label=label)
                axes[1].plot(h, [r["seconds"] for r in sel], marker=marker, ls="", ms=10, label=label)
            axes[2].plot(h, [100 * (r["area"] - r["true_area"]) / r["true_area"] for r in sel], marker=marker,
                         ls="", ms=10, label=label)
    axes[0].axhline(4, color="grey", ls="--", lw=0.8)
    axes[0].axhline(1.5, color="grey", ls=":", lw=0.8)
    titles = ("Peak memory (goal lines 4 and 1.5 GiB)", "voxelize wall time", "Total leaf area error")
    ylabels = ("peak RSS, GiB", "seconds", "error, %")
    for ax, title, yl in zip(axes, titles, ylabels):
        ax.set_xscale("log")
        ax.set_xlabel("voxel size, cm")
        ax.set_ylabel(yl)
        ax.set_title(title)
        ax.legend(fontsize=7)
    axes[2].axhline(0, color="grey", lw=0.8)
    fig.suptitle("Synthetic oak, two TLS scans: memory, time and accuracy against voxel size")
    fig.tight_layout()
    save_figure(fig, args.png)


if __name__ == "__main__":
    main()
