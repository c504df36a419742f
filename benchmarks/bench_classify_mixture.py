"""The classifier's leaf/wood threshold per scan: two Gaussians (the paper's fit) against the default
(two or three, chosen by BIC), for every method, scored on the echoes of simulated oaks; with the two
Gaussians' separation (Ashman's D) and EM iterations, converged or stopped at 500, and the threshold of
two Gaussians whose EM is run to convergence (up to 20,000 iterations).

Five synthetic oaks (the default, outward-facing leaves, seeds 1, 2 and 3; uniform leaf azimuth, seeds 1
and 2), each scanned from the paper's two positions with the VZ-400 preset at its -20 dB detection
threshold.  For each scan and method (``neighbourhood``, ``echo``, ``paper``; no refinement, no
cylinders) the table gives the threshold and the echoes it gets wrong (bark labelled leaf, leaves
labelled wood), next to the fewest errors any single threshold on the same feature could make (found
from the true classes: a bound, not a method).  The default was chosen after all five oaks had been
looked at (none is held out for it).  A second table says where the bark labelled leaf lies after the whole
classification ``scene_from_scans`` runs (default fit, geometric refinement, bark on fitted cylinders
relabelled): the echoes of bark per radius of the branch they hit (the simulator's cylinders), and how
many of them end up labelled leaf.  Writes docs/bench/classify_mixture.md.

    .venv/bin/python benchmarks/bench_classify_mixture.py      # about 6 min on 2 cores
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np
from _bench import machine_line, write_page

ROOT = Path(__file__).resolve().parents[1]
OAKS = ((1, "outward", "default, seed 1"), (2, "outward", "default, seed 2"), (3, "outward", "default, seed 3"),
        (1, "uniform", "uniform azimuth, seed 1"), (2, "uniform", "uniform azimuth, seed 2"))


def _errors(feature, leaf, bark, t):
    """(bark labelled leaf, leaves labelled wood) for threshold ``t`` on ``feature``."""
    return int((bark & (feature < t)).sum()), int((leaf & (feature >= t)).sum())


def _fewest(feature, leaf, bark):
    """The fewest errors of any threshold (scanned on the sorted feature values): (threshold, errors)."""
    v = feature[leaf | bark]
    is_bark = bark[leaf | bark]
    order = np.argsort(v, kind="stable")
    v, is_bark = v[order], is_bark[order]
    # threshold just above v[i]: everything up to i is leaf-labelled
    bark_below = np.concatenate([[0], np.cumsum(is_bark)])
    leaf_above = np.concatenate([[0], np.cumsum(~is_bark)])[-1] - np.concatenate([[0], np.cumsum(~is_bark)])
    err = bark_below + leaf_above
    i = int(np.argmin(err))
    t = v[0] - 1.0 if i == 0 else (v[i - 1] + v[i]) / 2 if i < len(v) else v[-1] + 1.0
    return float(t), int(err[i])


#: Branch radius bins of the second table, metres.
RADIUS_EDGES = (0.0, 0.025, 0.04, 0.08, 1.0)


def _branch_radius(tree, xyz_world):
    """Radius of the simulator's cylinder each point lies on (the nearest surface), (N,) metres."""
    a, b, r = tree.cylinders[:, :3], tree.cylinders[:, 3:6], tree.cylinders[:, 6]
    ab = b - a
    length2 = np.maximum((ab * ab).sum(axis=1), 1e-12)
    out = np.empty(len(xyz_world))
    for j in range(0, len(xyz_world), 2000):
        q = xyz_world[j:j + 2000, None, :] - a[None]
        t = np.clip((q * ab).sum(axis=2) / length2, 0.0, 1.0)
        gap = np.abs(np.linalg.norm(q - t[..., None] * ab, axis=2) - r)
        out[j:j + 2000] = r[np.argmin(gap, axis=1)]
    return out


def _bark_by_radius(tree, scans):
    """Bark echoes and those the pipeline's classes label leaf, per RADIUS_EDGES bin (summed over scans)."""
    from bench_lad_terms import _label_errors, _pipeline_labels

    from voxlidar.materials import Material

    labels = _pipeline_labels(scans)
    bark_as_leaf, _ = _label_errors(scans, labels)
    n_all, n_leaf = np.zeros(len(RADIUS_EDGES) - 1, int), np.zeros(len(RADIUS_EDGES) - 1, int)
    for s, wrong in zip(scans, bark_as_leaf):
        bark = np.asarray(s.truth_material) == Material.BARK
        pose = np.asarray(s.pose_true)
        radius = _branch_radius(tree, s.xyz[bark] @ pose[:3, :3].T + pose[:3, 3])
        n_all += np.histogram(radius, RADIUS_EDGES)[0]
        n_leaf += np.histogram(radius[wrong[bark]], RADIUS_EDGES)[0]
    return n_all, n_leaf


def fitted(c, scan):
    """The echoes ``classify_scan`` fitted its Gaussians to (single-echo pulses unless ``paper``)."""
    ok = np.isfinite(c.feature)
    if c.method == "paper":
        return ok  # the feature is set on the echoes between the noise and target thresholds only
    single = np.asarray(scan.number_of_returns) == 1
    return ok & single if c.fit_single_returns else ok


def main(argv=None):
    from bench_lad_terms import _oak_scans

    from tlsvox.classify import classify_scan, fit_two_gaussians, leaf_wood_threshold
    from voxlidar.materials import Material

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default=str(ROOT / "docs" / "bench" / "classify_mixture.md"))
    args = ap.parse_args(argv)
    load0 = os.getloadavg()
    t_all = time.perf_counter()
    rows = []
    total = {}
    radius_rows = []
    for seed, azimuth, label in OAKS:
        tree, scans = _oak_scans(azimuth, 0.35, -20.0, seed=seed)  # true poses, the VZ-400 at -20 dB
        for i, scan in enumerate(scans):
            m = np.asarray(scan.truth_material)
            for method in ("neighbourhood", "echo", "paper"):
                cells = []
                for k in (2, "bic"):
                    c = classify_scan(scan, method=method, components=k)
                    f = c.feature
                    ok = np.isfinite(f) if method != "paper" else np.isfinite(f) & (f >= c.noise_threshold)
                    leaf, bark = ok & (m == Material.LEAF), ok & (m == Material.BARK)
                    bl, lw = _errors(f, leaf, bark, c.leaf_wood_threshold)
                    extra = None
                    if k == 2:
                        x = c.feature[fitted(c, scan)]
                        conv = fit_two_gaussians(x, max_iter=20000)
                        extra = (c.mixture.separation, c.mixture.n_iter, conv.separation, conv.n_iter,
                                 *_errors(f, leaf, bark, leaf_wood_threshold(conv)), leaf_wood_threshold(conv))
                    cells.append((c.mixture.n_components, c.leaf_wood_threshold, bl, lw, extra))
                    total.setdefault((method, k), [0, 0])
                    total[(method, k)][0] += bl + lw
                t_best, e_best = _fewest(f, leaf, bark)
                total.setdefault((method, "fewest"), [0, 0])
                total[(method, "fewest")][0] += e_best
                rows.append((label, i + 1, method, cells, t_best, e_best, int(leaf.sum()), int(bark.sum())))
                print(f"{label} scan {i + 1} {method}: " + " | ".join(
                    f"{n} Gaussians t {t:.3f}: {bl:,} / {lw:,} {e or ''}" for n, t, bl, lw, e in cells)
                    + f" | fewest {e_best:,} at {t_best:.3f}", flush=True)
        radius_rows.append((label, float(tree.cylinders[:, 6].min()), *_bark_by_radius(tree, scans)))
        print(f"{label}: bark echoes / labelled leaf per radius bin {radius_rows[-1][2]} / {radius_rows[-1][3]}",
              flush=True)
    unit = {"neighbourhood": "dB", "echo": "", "paper": ""}
    lines = ["## The leaf/wood threshold: two Gaussians or BIC's choice, per scan", "",
             f"Command: `.venv/bin/python benchmarks/bench_classify_mixture.py` "
             f"({(time.perf_counter() - t_all) / 60:.1f} min). {machine_line(load0, os.getloadavg())}", "",
             "Five synthetic oaks, two VZ-400 scans each at -20 dB (true classes from the simulator). Per scan "
             "and method, no refinement: the two Gaussians' separation (Ashman's D) and EM iterations (EM stops at "
             "500), then for each choice the Gaussians fitted, the midway threshold (`neighbourhood` in dB of the "
             "neighbourhood-mean reflectance, the others in linear apparent reflectance) and its errors as "
             "*bark labelled leaf / leaves labelled wood*; last, the fewest errors any threshold on the same "
             "feature makes (found from the truth: a bound). `paper` counts the echoes above its noise "
             "threshold only. No oak was held out when the default was chosen.", "",
             "| oak | scan | method | two Gaussians: D (EM iterations); threshold, errors | the same run to "
             "convergence | BIC (default): Gaussians, threshold, errors | fewest errors (threshold) | leaf / bark "
             "echoes |", "|---|---|---|---|---|---|---|---|"]
    for label, scan, method, cells, t_best, e_best, n_leaf, n_bark in rows:
        (n2, t2, b2, l2, (sep, it, csep, cit, cb, cl, ct)), (nb, tb, bb, lb, _) = cells
        u = " " + unit[method] if unit[method] else ""
        lines.append(f"| {label} | {scan} | {method} | {sep:.2f} ({it}); {t2:.3f}{u}: {b2:,} / {l2:,} | {csep:.2f} "
                     f"({cit}); {ct:.3f}{u}: {cb:,} / {cl:,} | {nb}, {tb:.3f}{u}: {bb:,} / {lb:,} | {e_best:,} "
                     f"({t_best:.3f}) | {n_leaf:,} / {n_bark:,} |")
        total.setdefault((method, "converged"), [0, 0])
        total[(method, "converged")][0] += cb + cl
    lines += ["", "Errors summed over the ten scans (bark labelled leaf plus leaves labelled wood):", "",
              "| method | two Gaussians | two, EM converged | BIC (default) | fewest |", "|---|---|---|---|---|"]
    for method in ("neighbourhood", "echo", "paper"):
        lines.append(f"| {method} | {total[(method, 2)][0]:,} | {total[(method, 'converged')][0]:,} | "
                     f"{total[(method, 'bic')][0]:,} | {total[(method, 'fewest')][0]:,} |")
    bins = [f"{100 * lo:g}-{100 * hi:g} cm" if hi < 1 else f">= {100 * lo:g} cm"
            for lo, hi in zip(RADIUS_EDGES[:-1], RADIUS_EDGES[1:])]
    lines += ["", "Where the bark labelled leaf lies, after the whole classification (default fit, refinement, "
              "the bark on fitted cylinders relabelled; both scans): bark echoes per radius of the branch hit, "
              "and how many are labelled leaf.", "",
              "| oak | thinnest branch | " + " | ".join(bins) + " |", "|---|---|" + "---|" * len(bins)]
    for label, thinnest, n_all, n_leaf in radius_rows:
        lines.append(f"| {label} | {100 * thinnest:.1f} cm | " + " | ".join(
            f"{b:,} of {a:,} ({100 * b / max(a, 1):.0f} %)" for a, b in zip(n_all, n_leaf)) + " |")
    lines += ["", "Reading: see docs/classify_register.md, *Two or three Gaussians*.", ""]
    write_page(args.out, lines)


if __name__ == "__main__":
    main()
