"""The main job on the embedded default: the synthetic oak through the pipeline.

Run with no arguments (``make demo``); figures and files go to ``out/``:

- ``oak.ply`` / ``oak.json``: the procedural tree and its truth metadata
- ``scan1.laz``, ``scan2.laz`` (+ ``.pulses.npz``, ``.pose.json``): the two
  simulated RIEGL VZ-400 scans from ~20 m and ~10 m (the paper's set-up)
- ``fig1_tree.png``: the tree mesh coloured by material
- ``fig1_scans.png``: both scans in the world frame, coloured by apparent reflectance
- ``fig_reflectance_histograms.png``: reflectance histogram per scan, by true material
- ``summary.json``: the figures printed below, with timings per stage
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np


def reflectance_histograms(scans, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from tlsvox.materials import Material
    from tlsvox.scene import atomic_write

    fig, axes = plt.subplots(1, len(scans), figsize=(6 * len(scans), 4), squeeze=False)
    bins = np.linspace(-25, 12, 149)
    colors = {Material.LEAF: "tab:green", Material.BARK: "saddlebrown", Material.GROUND: "gray",
              Material.TARGET: "magenta"}
    for ax, scan in zip(axes[0], scans):
        ax.hist(scan.reflectance_db, bins=bins, color="k", histtype="step", label="all echoes")
        for mat, col in colors.items():
            sel = scan.truth_material == mat
            ax.hist(scan.reflectance_db[sel], bins=bins, color=col, alpha=0.45, label=f"{mat.name.lower()} (truth)")
        ax.set_yscale("log")
        ax.set_xlabel("apparent reflectance (dB)")
        ax.set_ylabel("echoes")
        ax.set_title(f"{scan.name}: {len(scan):,} echoes")
        ax.legend(fontsize=8)
    fig.tight_layout()
    atomic_write(path, lambda tmp: fig.savefig(tmp, format="png", dpi=120))
    plt.close(fig)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", default="out", help="output folder (default out/)")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--leaf-area", type=float, default=None, help="override the tree's leaf area, m2")
    parser.add_argument("--step", type=float, default=None, help="override the scan step, degrees")
    args = parser.parse_args(argv)

    from tlsvox.materials import Material
    from tlsvox.render import reflectance_colors, render
    from tlsvox.scanner import ScannerPreset, paper_scan_poses, simulate_scan
    from tlsvox.synthetic import TreeParams, make_tree

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    timings, summary = {}, {}

    t0 = time.perf_counter()
    params = TreeParams() if args.leaf_area is None else TreeParams(total_leaf_area=args.leaf_area)
    tree = make_tree(params, seed=args.seed)
    tree.save(out / "oak.ply")
    timings["tree"] = time.perf_counter() - t0
    truth = tree.truth_summary()
    summary["tree"] = {k: truth[k] for k in ("leaf_area_m2", "n_leaves", "crown_mean_lad_m2_m3",
                                             "lai_over_crown_projection")}
    print(f"[tree] {truth['n_leaves']:,} leaves, leaf area {truth['leaf_area_m2']:.2f} m2 "
          f"(requested {params.total_leaf_area:.2f}), crown mean LAD {truth['crown_mean_lad_m2_m3']:.3f} m2/m3, "
          f"LAI {truth['lai_over_crown_projection']:.2f}  ({timings['tree']:.1f} s)")

    t0 = time.perf_counter()
    overrides = {} if args.step is None else dict(zenith_step_deg=args.step, azimuth_step_deg=args.step)
    preset = ScannerPreset.riegl_vz400(**overrides)
    scans = []
    for i, pose in enumerate(paper_scan_poses(tree)):
        scan = simulate_scan(tree, pose=pose, preset=preset, seed=args.seed + i, scan_id=i + 1, name=f"scan{i + 1}")
        scan.write(out / f"scan{i + 1}.laz")
        scans.append(scan)
        dist = float(np.linalg.norm(pose.matrix()[:3, 3][:2] - tree.crown_center[:2]))
        n_gap = int((scan.pulses.n_echoes == 0).sum())
        mats = {m.name.lower(): int((scan.truth_material == m).sum()) for m in Material if m}
        summary[scan.name] = {"distance_m": dist, "pulses": len(scan.pulses), "echoes": len(scan),
                              "pulses_without_echo": n_gap, "echoes_by_material": mats}
        print(f"[scan] {scan.name} from {dist:.1f} m: {len(scan.pulses):,} pulses, {len(scan):,} echoes, "
              f"{n_gap:,} pulses without echo; by material {mats}")
    timings["scans"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    reflectance_histograms(scans, out / "fig_reflectance_histograms.png")
    c = tree.crown_center
    used = render([tree.to_o3d()], out / "fig1_tree.png", eye=c + [0, -30, 1.0], center=c - [0, 0, 1.5])
    items = [(s.world_xyz(s.pose_true), reflectance_colors(s.reflectance_db)) for s in scans]
    render(items, out / "fig1_scans.png", eye=c + [-22, -26, 6.0], center=c - [0, 0, 1.5], point_size=1.5,
           background=(0.05, 0.05, 0.08))
    timings["figures"] = time.perf_counter() - t0
    print(f"[figures] fig1_tree.png, fig1_scans.png ({used}), fig_reflectance_histograms.png "
          f"({timings['figures']:.1f} s)")

    summary["timings_s"] = timings
    (out / "summary.json").write_text(json.dumps(summary, indent=1))
    print(f"[done] outputs in {out}/ ; total {sum(timings.values()):.1f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
