"""Benchmark: echo weighting rules on the leaf box of known LAD, pencil and wide beams.

A 2 m cube of 5 x 2.5 cm leaves (LAD 1.5 m2/m3, spherical angles), scanned by
the simulated RIEGL VZ-400 from two sides with pencil beams (1 sub-ray) and
with its 7 mm Gaussian beam (7 sub-rays), voxelised at 50 cm with the true
poses and each echo weighting rule of :mod:`tlsvox.voxel.weights`:

- ``uniform``: 1/n;
- ``fraction``: the intercepted share of the beam, from the scan's
  ``beam_fraction`` column (sub-ray counts);
- ``fraction (reflectance)``: the same rule on the scan without that column,
  the share taken from apparent reflectance over the nominal leaf reflectance;
- ``threshold``: the paper's rule (drop returns under 50 % of the nominal
  leaf reflectance, then 1/n);
- ``geometric (no reflectance)``: the scans stripped of their share column,
  reflectance and intensity (a multi-return export with nothing but
  returns), each echo's expected share from the beam's footprint
  (:mod:`tlsvox.voxel.footprint`); ``uniform (no reflectance)`` is 1/n on
  the same stripped scans.

Scored against the exact leaf area per voxel of the mesh (the voxels the
scans see): mean LAD, its error and the standard error of that mean from the
estimator's per-voxel standard errors.  Writes a Markdown table.

With ``--oak`` it also runs the demo's synthetic oak (seed 1, the paper's two
VZ-400 scans at 0.06 deg, true poses and classes, 20 cm voxels): the share
column against ``uniform`` and ``geometric`` on the same scans stripped of
it and of their reflectance.  There the share column is the reference: the
leaf area it gives is the estimator's with the right weights, whose own
shortfall (clumped leaves in 20 cm voxels, occlusion) is measured in
``docs/bench/lad_terms.md``.

    .venv/bin/python benchmarks/bench_echo_weights.py [--step 0.1] [--oak] [--out docs/bench/echo_weights.md]
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import time
from pathlib import Path

import numpy as np
from _bench import machine_line, write_page

from tlsvox import voxelize
from tlsvox.truth.meshtruth import area_per_voxel
from tlsvox.truth.scanner import ScannerPreset, ScanPose, simulate_scan
from tlsvox.truth.synthetic import make_leaf_slab

ROOT = Path(__file__).resolve().parents[1]
BOUNDS = np.array([[-1.0, -1.0, 1.0], [1.0, 1.0, 3.0]])
POSES = (ScanPose(position=(-8.0, -3.0, 1.7), yaw_deg=10.0), ScanPose(position=(6.0, 7.0, 1.7), yaw_deg=-150.0))
RULES = ("uniform", "fraction", "fraction (reflectance)", "threshold", "geometric (no reflectance)")


def leaf_box(seed: int = 3):
    return make_leaf_slab(lad=1.5, size=(2.0, 2.0, 2.0), origin=(-1.0, -1.0, 1.0), leaf_angle="spherical",
                          seed=seed)


def scan_box(box, n_subrays: int, step_deg: float, *, min_reflectance_db: float = -20.0):
    preset = ScannerPreset.riegl_vz400(zenith_step_deg=step_deg, azimuth_step_deg=step_deg, n_subrays=n_subrays,
                                       min_reflectance_db=min_reflectance_db)
    scans = []
    for i, pose in enumerate(POSES):
        s = simulate_scan(box, pose=pose, preset=preset, seed=i, scan_id=i + 1, progress=False)
        s.pose = s.pose_true
        scans.append(s)
    return scans


def score(box, scans, rule: str, *, voxel_size: float = 0.5, estimator: str = "bcmle", tracer=None,
          undetected: str = "ignore") -> dict:
    """Mean LAD of the seen voxels against the mesh truth, for one rule (and detection-threshold correction)."""
    if rule == "fraction (reflectance)":
        scans = [dataclasses.replace(s, beam_fraction=None) for s in scans]
        rule = "fraction"
    elif rule.endswith(" (no reflectance)"):
        scans = [dataclasses.replace(s, beam_fraction=None, reflectance_db=None, intensity=None) for s in scans]
        rule = rule.split(" ")[0]
    res = voxelize(scans, voxel_size=voxel_size, leaf_angle="spherical", estimator=estimator, ground=None,
                   bounds=BOUNDS, echo_weights=rule, progress=False, tracer=tracer, undetected=undetected)
    tris = box.vertices[box.triangles]
    truth = area_per_voxel(tris, origin=res.grid.lower, voxel_size=res.grid.voxel_size,
                           shape=res.grid.shape) / res.grid.voxel_volume
    seen = ~res.lad.occluded
    est, std = res.lad.lad[seen], res.lad.lad_std[seen]
    mean, true = float(est.mean()), float(truth[seen].mean())
    return {"mean": mean, "true": true, "error": mean / true - 1, "se": float(np.sqrt(np.sum(std**2)) / est.size),
            "seen": int(seen.sum()), "voxels": int(seen.size), "source": res.scene.meta["scans"][0]["echo_weights_source"]}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--step", type=float, default=0.1, help="angular step of the scans, degrees")
    ap.add_argument("--oak", action="store_true", help="also the demo's synthetic oak (a few minutes)")
    ap.add_argument("--out", default=str(ROOT / "docs" / "bench" / "echo_weights.md"))
    args = ap.parse_args(argv)
    from tlsvox.voxel.trace import Tracer

    tracer = Tracer()
    load0 = os.getloadavg()
    box = leaf_box()
    rows = []
    # the VZ-400's detection floor (-20 dB), and (last) the wide beam with every echo detected
    for n_sub, floor, rules in ((1, -20.0, RULES), (7, -20.0, RULES), (7, -60.0, RULES[:2] + RULES[4:])):
        t0 = time.perf_counter()
        scans = scan_box(box, n_sub, args.step, min_reflectance_db=floor)
        t_scan = time.perf_counter() - t0
        for rule in rules:
            r = score(box, scans, rule, tracer=tracer)
            rows.append((n_sub, floor, rule, r))
            print(f"{n_sub} sub-ray(s), floor {floor:g} dB, {rule:>22}: mean LAD {r['mean']:.3f} (true {r['true']:.3f}) "
                  f"{100 * r['error']:+.1f} % +- {100 * r['se'] / r['true']:.1f} % (SE), {r['seen']}/{r['voxels']} "
                  f"voxels seen  [{r['source']}]")
        print(f"  (scans: {t_scan:.1f} s)")
    lines = ["## Echo weights on the leaf box", "",
             "Leaf box 2 x 2 x 2 m, LAD 1.5 m2/m3 (spherical), two VZ-400 scans, angular step "
             f"{args.step} deg, 50 cm voxels, `bcmle`, truth = exact mesh leaf area of the seen voxels.", "",
             f"Command: `.venv/bin/python benchmarks/bench_echo_weights.py --step {args.step}"
             f"{' --oak' if args.oak else ''}` ({time.strftime('%Y-%m-%d')}). {machine_line(load0, os.getloadavg())}", "",
             "| beam | rule | mean LAD (m2/m3) | true | error | SE of the mean |",
             "|---|---|---|---|---|---|"]
    for n_sub, floor, rule, r in rows:
        beam = "pencil (1 sub-ray)" if n_sub == 1 else "VZ-400 Gaussian (7 sub-rays)"
        if floor != -20.0:
            beam += f", detection floor {floor:g} dB (not -20)"
        lines.append(f"| {beam} | {rule} | {r['mean']:.3f} | {r['true']:.3f} | {100 * r['error']:+.1f} % | "
                     f"{100 * r['se'] / r['true']:.1f} % |")
    if args.oak:
        lines += oak_rows(tracer)
    write_page(args.out, lines)
    return 0


def oak_rows(tracer) -> list[str]:
    """The demo's oak with the share column, and stripped of it and of reflectance (uniform, geometric)."""
    from bench_lad_terms import _area, _oak_scans, _score

    tree, scans = _oak_scans("outward", 0.35, -20.0)
    bare = [dataclasses.replace(s, beam_fraction=None, reflectance_db=None, intensity=None) for s in scans]
    rows = ["", "### The demo's oak (seed 1, two VZ-400 scans at 0.06 deg, true poses and classes, 20 cm)", "",
            "The share column is the reference here: its leaf area is the estimator's with the right weights "
            "(its shortfall is the turbid estimate's, docs/bench/lad_terms.md); `geometric` takes the LAD "
            "estimate through two rounds (`tlsvox.voxel.stages.GEOMETRIC_ROUNDS`).", "",
            "| scans | rule | total leaf area | seen voxels | time (s) |", "|---|---|---|---|---|"]
    for label, ss, rule in (("with the share column", scans, "fraction"), ("stripped", bare, "uniform"),
                            ("stripped", bare, "geometric")):
        t0 = time.perf_counter()
        res = voxelize(ss, voxel_size=0.2, leaf_angle="uniform", leaf_azimuth="outward", ground=0.0, layout="dense",
                       echo_weights=rule, progress=False, tracer=tracer)
        sec = time.perf_counter() - t0
        tot, seen = _score(tree, res)
        print(f"oak, {label}, {rule}: {_area(tot)}; seen {_area(seen)}; {sec:.1f} s")
        rows.append(f"| {label} | {rule} | {_area(tot)} | {_area(seen)} | {sec:.1f} |")
    return rows


if __name__ == "__main__":
    raise SystemExit(main())
