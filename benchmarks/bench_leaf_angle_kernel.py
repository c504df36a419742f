"""Benchmark: the leaf-angle kernel's response per true inclination against the scans' own.

Where does the deconvolution's remaining flat bias come from?  The synthetic
oak (``make_tree(TreeParams(leaf_angle=KIND, leaf_azimuth=AZ), seed=SEED)``)
is scanned from the paper's two positions by the simulated VZ-400 (true
poses), and every leaf echo is given the leaf it most likely came from: among
the leaves whose centres lie within 6 cm of it, the one whose plane is
nearest, the echo's foot within 3 cm of the leaf's centre (echoes merged far
off any leaf stay unassigned; the share assigned is reported).  Per scan and
crown layer (4 layers between the 1st and 99th height percentiles of the
echoes with a plane fit, as ``measure_leaf_angles`` cuts them) and per true
inclination class of 15 degrees:

- *measured*: the mean measured inclination of the plane fits of the echoes
  from leaves of that class (weights r^2 / |cos a|, as the deconvolution
  weighs them), and the share of their weight with a plane fit;
- *kernel*: the same two numbers predicted by the deconvolution's kernel for
  that scan and layer (its sampled echoes, the outward azimuth model, the
  occlusion mix the EM fits to the layer's echoes), its true bins within a
  class weighted by the layer's true leaf area in each.

A kernel that measured every class as the scans do would leave the EM no
bias; where the kernel measures a class steeper than the scans, measured
echoes are read as coming from flatter leaves.  The far scan (~20 m) gives
almost no plane fits (its pulses lie 2.1 cm apart: too few within the 2.5 cm
radius), so its rows hold the neighbour counts alone and it is left out of
the table.

    .venv/bin/python benchmarks/bench_leaf_angle_kernel.py [--kind uniform] [--seed 0] [--leaf-azimuth outward]

Writes docs/bench/leaf_angle_kernel.md (``--out``).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))

from _bench import machine_line, write_page  # noqa: E402

CLASS_DEG = 15


def assign_leaves(xyz, centres, normals):
    """Index of each echo's leaf (-1: none within reach)."""
    from scipy.spatial import cKDTree

    dist, idx = cKDTree(centres).query(xyz, k=12, distance_upper_bound=0.06)
    best = np.full(len(xyz), -1)
    best_d = np.full(len(xyz), np.inf)
    for j in range(idx.shape[1]):
        ok = np.isfinite(dist[:, j])
        ii = np.where(ok, idx[:, j], 0)
        rel = xyz - centres[ii]
        signed = np.einsum("ij,ij->i", rel, normals[ii])
        off_plane = np.abs(signed)
        in_plane = np.linalg.norm(rel - signed[:, None] * normals[ii], axis=1)
        take = ok & (in_plane <= 0.03) & (off_plane < best_d)
        best[take], best_d[take] = ii[take], off_plane[take]
    return best


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--kind", default="uniform")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--leaf-azimuth", default="outward", choices=("outward", "uniform"))
    ap.add_argument("--out", default=str(ROOT / "docs/bench/leaf_angle_kernel.md"))
    args = ap.parse_args(argv)

    from tlsvox import leafangles as la
    from tlsvox.truth.scanner import paper_scan_poses, simulate_scan
    from tlsvox.truth.synthetic import TreeParams, make_tree
    from voxlidar.materials import Material

    t0 = time.perf_counter()
    load0 = os.getloadavg()
    tree = make_tree(TreeParams(leaf_angle=args.kind, leaf_azimuth=args.leaf_azimuth), seed=args.seed)
    scans = [simulate_scan(tree, pose=pose, seed=10 + i, scan_id=i, progress=False)
             for i, pose in enumerate(paper_scan_poses(tree))]
    model = "outward" if args.leaf_azimuth == "outward" else "uniform"
    leaf_xyz, origins, wood = [], [], []
    for s in scans:
        xyz = s.world_xyz(s.pose_true)
        mat = np.asarray(s.truth_material)
        leaf_xyz.append(xyz[mat == Material.LEAF])
        wood.append(xyz[mat == Material.BARK])
        origins.append(np.asarray(s.pose_true, float)[:3, 3])
    centre, _ = la.trunk_center(np.concatenate(wood))
    n_bins, n_az = 18, 4 if model == "outward" else 1
    fits = [la._fit_scan(xyz, origin, radius=0.025, min_points=5, min_spread=0.0, n_bins=n_bins, cap=0.2,
                         centre=centre, n_azimuth=n_az) for xyz, origin in zip(leaf_xyz, origins)]
    # the layers as measure_leaf_angles cuts them: between the 1st and 99th height percentiles of the fitted echoes
    cuts = np.linspace(*np.percentile(np.concatenate([f.z[f.ok] for f in fits]), [1, 99]), 5)
    leaf_z = tree.leaf_centers[:, 2]
    mid = (np.arange(n_bins) + 0.5) * 90 / n_bins
    n_class = 90 // CLASS_DEG
    class_of_bin = (mid // CLASS_DEG).astype(int)
    true_incl = np.degrees(np.arccos(np.abs(tree.leaf_normals[:, 2])))
    rng = np.random.default_rng(0)
    rows_md = []
    summary = {"meas": [], "kern": [], "fit_meas": [], "fit_kern": []}
    for i, (xyz, f) in enumerate(zip(leaf_xyz, fits)):
        leaf = assign_leaves(xyz, tree.leaf_centers, tree.leaf_normals)
        t_class = np.where(leaf >= 0, np.minimum((true_incl[np.maximum(leaf, 0)] // CLASS_DEG).astype(int),
                                                 n_class - 1), -1)
        step = tuple(np.radians([scans[i].meta["preset"]["zenith_step_deg"],
                                 scans[i].meta["preset"]["azimuth_step_deg"]]))
        for k in range(4):
            sel = la._in_layer(f.z, cuts, k)
            if f.ok[sel].mean() < 0.05:
                continue  # a scan too far for plane fits (its rows are the neighbour counts alone)
            rows = la._layer_rows(f, sel, n_bins=n_bins, n_groups=6, max_sim=3000, rng=rng, step=step,
                                  beam=la._scan_beam(scans[i]), leaf_size=0.05, radius=0.025, min_points=5,
                                  min_spread=0.0, range_noise=0.005, samples=3, cap=0.2, second_leaf=True,
                                  azimuths=(model,), n_azimuth=n_az)
            _, mix, _ = la._em([(0, 0, 0, h, K) for h, K in rows], (1, 1, 1), 300)
            kern = sum(h.sum() * np.einsum("l,lbc->bc", mix[0], K[0]) for h, K in rows)  # (true bin, column)
            # the kernel is per unit leaf area of each true bin: weigh the bins of a class by the layer's leaf area
            in_layer = la._in_layer(leaf_z, cuts, k)
            area = np.bincount(np.minimum((true_incl[in_layer] / (90 / n_bins)).astype(int), n_bins - 1),
                               minlength=n_bins).astype(float)
            kern = kern * area[:, None]
            fit_cols = la._measured_bins(kern, n_bins, n_az)  # (true bin, measured bin), fits only
            cells = []
            for c in range(n_class):
                tb = class_of_bin == c
                kb = fit_cols[tb].sum(axis=0)
                m = sel & (t_class == c)
                w, ok = f.weight[m], f.ok[m]
                if w[ok].sum() <= 0 or kb.sum() <= 0:
                    cells.append("-")
                    continue
                meas = float((w[ok] * mid[f.meas_bin[m][ok]]).sum() / max(w[ok].sum(), 1e-300))
                kmean = float((kb * mid).sum() / max(kb.sum(), 1e-300))
                fm, fk = float(w[ok].sum() / max(w.sum(), 1e-300)), float(fit_cols[tb].sum() / kern[tb].sum())
                cells.append(f"{meas:.1f} / {kmean:.1f} ({fm:.2f} / {fk:.2f})")
                for key, v in (("meas", meas), ("kern", kmean), ("fit_meas", fm), ("fit_kern", fk)):
                    summary[key].append((c, v))
            assigned = float((sel & (leaf >= 0)).sum() / sel.sum())
            rows_md.append(f"| scan {i + 1}, layer {k + 1} | {assigned:.2f} | " + " | ".join(cells) + " |")
    diff = {c: [kv - mv for (cm, mv), (ck, kv) in zip(summary["meas"], summary["kern"]) if cm == c]
            for c in range(n_class)}
    ratio = {c: [fk / fm for (cm, fm), (ck, fk) in zip(summary["fit_meas"], summary["fit_kern"]) if cm == c and fm > 0]
             for c in range(n_class)}
    head = " | ".join(f"true {c * CLASS_DEG}-{(c + 1) * CLASS_DEG} deg" for c in range(n_class))
    lines = [f"# The leaf-angle kernel against the scans, per true inclination ({args.kind} leaves, "
             f"{args.leaf_azimuth} azimuths, seed {args.seed})", "",
             f"Command: `.venv/bin/python benchmarks/bench_leaf_angle_kernel.py --kind {args.kind} --seed {args.seed} "
             f"--leaf-azimuth {args.leaf_azimuth}` ({(time.perf_counter() - t0) / 60:.1f} min). "
             f"{machine_line(load0, os.getloadavg())}", "",
             "Each echo of the oak's near scan is given its true leaf (the nearest leaf plane among the leaves "
             "within reach; *assigned* is the share of the layer's echoes that got one); per layer and true "
             "inclination class, the mean measured inclination of their plane fits, measured / kernel, in "
             "degrees, and in brackets the share of their weight with a plane fit, measured / kernel. The "
             f"kernel is the deconvolution's for that scan and layer ({model} azimuth model, the occlusion mix "
             "fitted to the layer's echoes). The far scan is left out: it gives almost no plane fits.", "",
             f"| scan, layer | assigned | {head} |", "|---|---|" + "---|" * n_class]
    lines += rows_md
    lines += ["", "Over the layers, kernel minus measured (mean inclination of the fits, degrees) and kernel over "
              "measured (share with a plane fit):", "",
              f"| | {head} |", "|---|" + "---|" * n_class,
              "| mean inclination, kernel - measured (deg) | "
              + " | ".join(f"{np.mean(diff[c]):+.1f}" if diff[c] else "-" for c in range(n_class)) + " |",
              "| share with a fit, kernel / measured | "
              + " | ".join(f"{np.mean(ratio[c]):.2f}" if ratio[c] else "-" for c in range(n_class)) + " |"]
    write_page(args.out, lines, echo=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
