"""Where the synthetic oak's leaf area goes: the estimate against the mesh when the
tree's leaves are made more like the estimators' assumptions, one term at a time.

The default oak's leaves face outward from the crown (``leaf_azimuth="outward"``)
and grow in clusters (``leaf_cluster_sigma=0.35`` m); by default the estimators
assume azimuthally uniform leaves (G depends on the beam's zenith only) spread at
random inside each voxel; ``leaf_azimuth="outward"`` gives them the outward G.  Four oaks (same seed, 500 m2 of uniform-inclination leaves)
cross the two: outward or uniform leaf azimuth, clusters of 0.35 m or 3 m (about
random in the crown).  Each is scanned from the paper's two positions (VZ-400, 7
sub-rays, echoes weighted by their beam share: the defaults) and voxelised at 20 and
10 cm with true poses and classes (dense layout); the leaf area is scored against the
mesh over all voxels and over the voxels the scans see.

Writes docs/bench/lad_terms.md.

    .venv/bin/python benchmarks/bench_lad_terms.py      # about 8 min on 2 cores

Two more rows rescan the default oak and the most random one with a detection threshold
that keeps every weak echo (``--threshold-db``, default -60 dB against the VZ-400's -20 dB):
the scanner's term.

The scanner's term corrected: the same two oaks at the VZ-400's -20 dB voxelised with
``undetected="ignore"`` and ``undetected="model"`` (:mod:`tlsvox.voxel.detection`, the
expected unrecorded interception given back), next to the -60 dB scan, at 20 cm; written to
docs/bench/lad_terms-threshold.md.  ``--threshold-only`` runs just these (about 8 min):

    .venv/bin/python benchmarks/bench_lad_terms.py --threshold-only
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
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sizes", default="0.2,0.1")
    ap.add_argument("--out", default=str(ROOT / "docs" / "bench" / "lad_terms.md"))
    ap.add_argument("--threshold-db", type=float, default=-60.0,
                    help="detection threshold of the extra rows that keep weak echoes (the VZ-400 preset: -20 dB)")
    ap.add_argument("--threshold-only", action="store_true",
                    help="only the detection-threshold table (docs/bench/lad_terms-threshold.md)")
    ap.add_argument("--threshold-out", default=str(ROOT / "docs" / "bench" / "lad_terms-threshold.md"))
    ap.add_argument("--iterations", type=int, default=4, help="undetected_iterations of the model rows")
    args = ap.parse_args(argv)
    threshold_table(args)
    if args.threshold_only:
        return
    from tlsvox.truth.scanner import ScannerPreset
    from tlsvox.voxel.voxlad import score_lad, voxelize

    load0 = os.getloadavg()
    t0 = time.perf_counter()
    sizes = [float(v) for v in args.sizes.split(",")]
    rows = []
    vz400 = ScannerPreset.riegl_vz400()
    # the four oaks with the scanner as it is, then the two extremes with a detection threshold low
    # enough to keep every weak leaf echo (the scanner term)
    cases = [(a, s, vz400.min_reflectance_db, sizes) for a in ("outward", "uniform") for s in (0.35, 3.0)]
    cases += [(a, s, args.threshold_db, sizes[:1]) for a, s in (("outward", 0.35), ("uniform", 3.0))]
    for azimuth, sigma, threshold, case_sizes in cases:
        tree, scans = _oak_scans(azimuth, sigma, threshold)
        for h in case_sizes:
            # the estimators' G: from the beam's zenith alone, or (outward trees) per voxel for outward leaves
            for model in (("uniform", "outward") if azimuth == "outward" else ("uniform",)):
                res = voxelize(scans, voxel_size=h, leaf_angle="uniform", leaf_azimuth=model, ground=0.0,
                               layout="dense", progress=False)
                g = res.grid
                truth = tree.leaf_area_per_voxel(origin=g.lower, voxel_size=h, shape=g.shape) / g.voxel_volume
                occ = res.lad.occluded
                total = score_lad(res.lad.lad, truth, voxel_volume=g.voxel_volume)
                seen = score_lad(np.where(occ, 0, res.lad.lad), np.where(occ, 0, truth),
                                 voxel_volume=g.voxel_volume)
                rows.append((azimuth, sigma, threshold, h, model, total, seen))
                print(f"{azimuth} {sigma} {threshold} dB {h} {model}: total {100 * total['area_error']:+.1f} %, seen "
                      f"{100 * seen['area_error']:+.1f} %", flush=True)
    minutes = (time.perf_counter() - t0) / 60
    lines = ["# Where the leaf area goes (synthetic oak, the estimators' assumptions one at a time)", "",
             f"Command: `.venv/bin/python benchmarks/bench_lad_terms.py --sizes {args.sizes}` ({minutes:.1f} min). "
             + machine_line(load0) + " Two VZ-400 scans (7 sub-rays, echoes weighted by "
             "their beam share), true poses and classes, `bcmle`, uniform leaf inclination (the truth), "
             "dense layout. The default oak is the first row pair.", "",
             "| leaf azimuth | leaf clusters (sigma) | scanner's detection threshold | voxel | estimators' G | "
             "total leaf area (error) | true | leaf area in seen voxels (error) |",
             "|---|---|---|---|---|---|---|---|"]
    for azimuth, sigma, threshold, h, model, total, seen in rows:
        g_words = "per voxel, outward leaves" if model == "outward" else "beam zenith only"
        lines.append(f"| {azimuth} | {sigma:g} m | {threshold:g} dB | {h * 100:g} cm | {g_words} | {total['total_area']:.1f} m2 "
                     f"({100 * total['area_error']:+.1f} %) | {total['true_area']:.1f} m2 | "
                     f"{seen['total_area']:.1f} of {seen['true_area']:.1f} m2 ({100 * seen['area_error']:+.1f} %) |")
    lines += ["", "Outward-facing leaves are seen edge-on by beams that cross the crown sideways, so they "
              "intercept less than G(theta) of azimuthally uniform leaves says; estimators that take G from the "
              "beam's zenith alone read the lower interception as less leaf area. `voxelize(leaf_azimuth="
              "\"outward\")` gives each voxel the G of outward leaves for each beam crossing it "
              "(`tlsvox.voxel.pulses.outward_g_table`, crown axis at the middle of the leaf echoes' extent).", "",
              f"The last rows keep every weak echo (detection threshold {args.threshold_db:g} dB instead of the "
              f"VZ-400's {vz400.min_reflectance_db:g} dB). A sub-ray that grazes an edge-on leaf returns "
              "rho cos(i) / 7 and goes undetected; the beam share it stopped then counts as travelling on (the "
              "tail) and adds free path to every voxel behind it, where the true beam is already small. A few per "
              "cent of the leaf interception lost this way costs ten to sixteen points of leaf area (compare each "
              "oak's rows at 20 cm). `voxelize(undetected=\"model\")` corrects for it "
              "(`tlsvox.voxel.detection`): see the next section, measured at the VZ-400's -20 dB.", ""]
    write_page(args.out, lines)


def _oak_scans(azimuth, sigma, threshold):
    from tlsvox.truth.scanner import ScannerPreset, paper_scan_poses, simulate_scan
    from tlsvox.truth.synthetic import TreeParams, make_tree

    tree = make_tree(TreeParams(leaf_azimuth=azimuth, leaf_cluster_sigma=sigma), seed=1)
    preset = ScannerPreset.riegl_vz400(min_reflectance_db=threshold)
    scans = []
    for i, pose in enumerate(paper_scan_poses(tree)):
        s = simulate_scan(tree, pose=pose, preset=preset, seed=10 + i, scan_id=i, progress=False)
        s.pose = s.pose_true
        scans.append(s)
    return tree, scans


def threshold_table(args):
    """The default oak and the most random one at -20 dB, with and without the detection model."""
    from tlsvox.voxel.trace import Tracer
    from tlsvox.voxel.voxlad import score_lad, voxelize
    load0 = os.getloadavg()
    t_all = time.perf_counter()
    tracer = Tracer()
    rows = []
    for azimuth, sigma in (("outward", 0.35), ("uniform", 3.0)):
        for threshold, rules in ((-20.0, ("ignore", "model")), (args.threshold_db, ("ignore",))):
            tree, scans = _oak_scans(azimuth, sigma, threshold)
            for rule in rules:
                t0 = time.perf_counter()
                res = voxelize(scans, voxel_size=0.2, leaf_angle="uniform", leaf_azimuth=azimuth, ground=0.0,
                               layout="dense", progress=False, tracer=tracer, undetected=rule,
                               undetected_iterations=args.iterations)
                seconds = time.perf_counter() - t0
                g = res.grid
                truth = tree.leaf_area_per_voxel(origin=g.lower, voxel_size=g.voxel_size, shape=g.shape) / g.voxel_volume
                occ = res.lad.occluded
                total = score_lad(res.lad.lad, truth, voxel_volume=g.voxel_volume)
                seen = score_lad(np.where(occ, 0, res.lad.lad), np.where(occ, 0, truth), voxel_volume=g.voxel_volume)
                given = res.scene.meta["undetected"].get("given_back_share")
                rows.append((azimuth, sigma, threshold, rule, total, seen, given, seconds))
                print(f"{azimuth} {sigma} {threshold:g} dB undetected={rule}: total {100 * total['area_error']:+.1f} %, "
                      f"seen {100 * seen['area_error']:+.1f} %, given back {given} ({seconds:.0f} s)", flush=True)
    minutes = (time.perf_counter() - t_all) / 60
    lines = ["## The detection threshold corrected (synthetic oak, 20 cm)", "",
             f"Command: `.venv/bin/python benchmarks/bench_lad_terms.py --threshold-only --iterations {args.iterations}` "
             f"({minutes:.1f} min). " + machine_line(load0) + " The default oak (outward leaves, clusters of 0.35 m; the "
             "estimators' G per voxel for outward leaves) and the most random one (uniform azimuth, clusters of "
             "3 m), two VZ-400 scans each, true poses and classes, echoes weighted by their beam share, `bcmle`, "
             "uniform leaf inclination (the truth), dense layout, 20 cm voxels.", "",
             "| oak | scanner's detection threshold | `undetected` | total leaf area (error) | leaf area in seen "
             "voxels (error) | given back (share of the recorded leaf echo weight, per round) | voxelize time |",
             "|---|---|---|---|---|---|---|"]
    for azimuth, sigma, threshold, rule, total, seen, given, seconds in rows:
        oak = "default (outward, 0.35 m)" if azimuth == "outward" else "most random (uniform, 3 m)"
        gb = ", ".join(f"{100 * v:.2f} %" for v in given) if given else "-"
        lines.append(f"| {oak} | {threshold:g} dB | {rule} | {total['total_area']:.1f} of {total['true_area']:.1f} m2 "
                     f"({100 * total['area_error']:+.1f} %) | {seen['total_area']:.1f} of {seen['true_area']:.1f} m2 "
                     f"({100 * seen['area_error']:+.1f} %) | {gb} | {seconds:.0f} s |")
    lines += ["", "`undetected=\"model\"` (`tlsvox.voxel.detection`, equations in docs/voxelize.md and docs/method.md) gives each "
              "pulse's expected unrecorded leaf interception back as leaf echoes: the share of beam parts on a leaf "
              "at incidence cosine mu that read under the threshold (a Monte Carlo of the beam's sub-ray pattern "
              "over elliptical leaves), averaged over the leaf angle model into H, next to G; where along the beam "
              "the unrecorded stop lay follows from H u e^-tau of the current estimate, none within the range "
              "resolution of a recorded echo of the same pulse. The -60 dB rows are the floor the correction can "
              "reach: what is left there is not the scanner's term.", ""]
    write_page(args.threshold_out, lines)


if __name__ == "__main__":
    main()
