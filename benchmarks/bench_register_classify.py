"""Registration and classification time (medians) and accuracy on the synthetic scan pair.

Scans the default synthetic tree (tlsvox.truth.synthetic) from the paper's two
positions with the RIEGL VZ-400 preset (or a coarser step with --step), then
times: target registration, FPFH + ICP registration, and per-scan
classification by every method variant (tlsvox.classify.ClassifyMethod,
incidence correction, geometric refinement), scored against the truth
labels.  Writes docs/bench/register_classify.md.

    python benchmarks/bench_register_classify.py [--step 0.06] [--repeats 3] [--small]
        [--registration-only]

--registration-only rewrites only the registration table of an existing
report, leaving the classification rows as they were.
"""

from __future__ import annotations

import argparse
import platform
from pathlib import Path

from _bench import median_time, write_page

from tlsvox.classify import classify_scan, score
from tlsvox.register import RegistrationError, pose_error, register_pair, true_relative_transform
from tlsvox.truth.scanner import ScannerPreset, paper_scan_poses, simulate_scan
from tlsvox.truth.synthetic import TreeParams, make_tree

ROOT = Path(__file__).resolve().parents[1]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--step", type=float, default=0.06, help="angular step, degrees (VZ-400: 0.06)")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--small", action="store_true", help="the small test tree instead of the default")
    ap.add_argument("--out", default=str(ROOT / "docs" / "bench" / "register_classify.md"))
    ap.add_argument("--registration-only", action="store_true",
                    help="time registration only and replace just its table in --out")
    args = ap.parse_args(argv)

    params = (TreeParams(height=8.0, crown_base=2.0, crown_radius=3.0, total_leaf_area=60.0, trunk_radius=0.15)
              if args.small else TreeParams())
    tree = make_tree(params, seed=3)
    preset = ScannerPreset.riegl_vz400(zenith_step_deg=args.step, azimuth_step_deg=args.step)
    A, B = [simulate_scan(tree, pose=p, preset=preset, seed=k + 1, scan_id=k, name=f"scan{k}", progress=False)
            for k, p in enumerate(paper_scan_poses(tree))]
    T_true = true_relative_transform(B, A)
    rows, failures = [], []
    for method in ("targets", "fpfh"):
        reps = args.repeats if method == "targets" else max(1, args.repeats // 3)
        try:
            t, r = median_time(lambda: register_pair(B, A, method=method), reps)
        except RegistrationError as err:  # reported, not hidden: the table says it failed
            failures.append(f"{method}: {err}")
            print(failures[-1])
            continue
        rot, tr = pose_error(r.transform, T_true)
        rows.append((method, t, reps, rot, tr * 1000, r.fitness, r.inlier_rmse_m * 1000,
                     r.coincidence["coincidence_ratio"]))
        print(rows[-1])
    reg_lines = [
        "| registration | median s | repeats | rotation error deg | translation error mm | fitness "
        "| inlier RMSE mm | coincidence ratio |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for m, t, reps, rot, tr, fit, rmse, ratio in rows:
        reg_lines.append(f"| {m} | {t:.2f} | {reps} | {rot:.4f} | {tr:.2f} | {fit:.3f} | {rmse:.1f} | {ratio:.1f} |")
    for f in failures:
        reg_lines += ["", f"**Failed**, {f}"]
    reg_lines += ["", f"Registration rows: `--step {args.step} --repeats {args.repeats}` "
                  "(FPFH: repeats // 3, at least 1)."]
    out = Path(args.out)
    if args.registration_only:
        old = out.read_text().split("\n")
        start = next(i for i, line in enumerate(old) if line.startswith("| registration |"))
        end = next(i for i, line in enumerate(old) if line.startswith("Classification:"))
        out.write_text("\n".join(old[:start] + reg_lines + [""] + old[end:]))
        print(f"wrote the registration rows of {out}")
        return
    variants = [("paper", dict(method="paper"), args.repeats),
                ("paper", dict(method="paper", refine=True), 1),
                ("echo", dict(method="echo"), 1),
                ("echo + incidence", dict(method="echo", incidence_correction=True), 1),
                ("echo, fit all echoes", dict(method="echo", fit_single_returns=False), 1),
                ("neighbourhood + incidence", dict(incidence_correction=True), 1),
                ("neighbourhood, fit all echoes", dict(fit_single_returns=False), 1),
                ("neighbourhood (default)", dict(), args.repeats),
                ("neighbourhood (default)", dict(refine=True), args.repeats)]
    cls_rows, tables = [], []
    for s in (A, B):
        for name, kw, reps in variants:
            t, c = median_time(lambda: classify_scan(s, **kw), reps)
            sc = score(c.labels, s.truth_material)
            cls_rows.append((s.name, len(s), name, c.refined, t, sc.precision["leaf"], sc.recall["leaf"],
                             sc.precision["wood"], sc.recall["wood"], c.counts["noise"]))
            if name.startswith("paper") or name.startswith("neighbourhood (default)"):
                tables.append(f"**{s.name}, {name}, refine={c.refined}**\n\n{sc.table()}\n")
            print(cls_rows[-1])
    lines = [
        "# Registration and classification on the synthetic scan pair",
        "",
        f"`python benchmarks/bench_register_classify.py --step {args.step} --repeats {args.repeats}"
        + (" --small" if args.small else "") + "`",
        "",
        f"Tree: {'small test tree' if args.small else 'default (13.6 m oak-like)'}, seed 3; scans at the paper's "
        f"two positions, RIEGL VZ-400 preset, step {args.step} deg: {len(A):,} and {len(B):,} echoes. "
        f"Machine: {platform.processor() or platform.machine()}, Python {platform.python_version()}. "
        "Times are medians of the repeats (wall clock, s).",
        "",
    ] + reg_lines
    lines += ["", "Classification: P precision, R recall against the truth materials (a truth 'noise' "
              "class does not exist in a simulated scan, so every echo called noise is an error).", "",
              "| scan | echoes | method | refine | median s | leaf P | leaf R | wood P | wood R | noise echoes |",
              "|---|---|---|---|---|---|---|---|---|---|"]
    for sn, n, name, ref, t, lp, lr, wp, wr, nn in cls_rows:
        lines.append(f"| {sn} | {n:,} | {name} | {ref} | {t:.2f} | {lp:.3f} | {lr:.3f} | {wp:.3f} | {wr:.3f} "
                     f"| {nn:,} |")
    lines += ["", "Confusion matrices (rows truth, columns label):", ""] + tables
    write_page(out, lines)


if __name__ == "__main__":
    main()
