"""Solid wood from fitted cylinders (tlsvox.voxel.wood.qsm): the fit against the tree's cylinders, and the waveforms.

The default synthetic oak (``make_tree(seed=1)``), its two simulated VZ-400
scans, registered and classified by ``tlsvox.pipeline.scene_from_scans``.
Part 1: the cylinders fitted to the wood-classified echoes against the
tree's own (trunk, leader, scaffolds, their first branches).  Part 2: the four
budget pulses (sensor ``ahab-chiroptera-i``, hot spot on, 3 orders) against
the mesh reference, from the pipeline's scene with its wood turbid
(``qsm=False``), with the fitted cylinders (the default), with the tree's true
cylinders through the same ``apply_cylinders``, with the fitted cylinders and
no other wood, and with no wood at all; and the exact-LAD twin beside them.

Writes docs/bench/qsm.md.

    .venv/bin/python benchmarks/bench_qsm.py                      # about 5 min on 2 cores
    .venv/bin/python benchmarks/bench_qsm.py --sizes 0.1 --photons 300000
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import time
from pathlib import Path

import numpy as np
from _bench import machine_line, write_page

ROOT = Path(__file__).resolve().parents[1]


def fit_rows(tree, model):
    """Per true cylinder of radius >= 5 cm: the fitted pieces on it and how far they are off."""
    from tlsvox.truth._mesh import segment_distance

    tc = tree.cylinders
    fc = model.cylinders
    mid = 0.5 * (fc[:, :3] + fc[:, 3:6])
    fu = (fc[:, 3:6] - fc[:, :3]) / np.linalg.norm(fc[:, 3:6] - fc[:, :3], axis=1, keepdims=True)
    owner = np.array([np.argmin(segment_distance(m, tc[:, :3], tc[:, 3:6])) for m in mid]) if len(fc) else []
    groups = [("trunk", [0]), ("leader", [1]), ("scaffolds", list(range(2, 2 + tree.params.n_scaffolds)))]
    first = [i for i in range(2 + tree.params.n_scaffolds, len(tc)) if abs(tc[i, 6] - tc[2, 6] * 0.55) < 1e-9]
    groups.append(("the scaffolds' branches", first))
    rows = []
    for name, ids in groups:
        ids = np.asarray(ids, int)
        on = np.isin(owner, ids) if len(fc) else np.zeros(0, bool)
        r_true = tc[ids, 6]
        length = np.linalg.norm(tc[ids, 3:6] - tc[ids, :3], axis=1).sum()
        if not on.any():
            rows.append((name, len(ids), r_true[0], length, 0, "-", "-", "-", 0.0))  # nothing fitted on them
            continue
        off, ang = [], []
        for k in np.flatnonzero(on):
            t = tc[owner[k]]
            u = (t[3:6] - t[:3]) / np.linalg.norm(t[3:6] - t[:3])
            off.append(float(segment_distance(mid[k], t[:3], t[3:6])))
            ang.append(float(np.degrees(np.arccos(min(1.0, abs(u @ fu[k]))))))
        r = fc[on, 6]
        axis_pts = np.vstack([t[:3] + np.linspace(0, 1, 200)[:, None] * (t[3:6] - t[:3]) for t in tc[ids]])
        covered = model.explained(axis_pts, tolerance=0.0).mean() * length  # axis inside a fitted cylinder
        rows.append((name, len(ids), r_true[0], length, int(on.sum()), f"{r.min():.3f}-{r.max():.3f} "
                     f"(median {np.median(r):.3f})", f"{np.median(off) * 1000:.0f} / {max(off) * 1000:.0f}",
                     f"{np.median(ang):.1f} / {max(ang):.1f}", covered / length))
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sizes", default="0.1,0.2", help="voxel sizes, m")
    ap.add_argument("--photons", type=int, default=1_000_000, help="photons per run (mesh and voxels)")
    ap.add_argument("--out", default=str(ROOT / "docs" / "bench" / "qsm.md"))
    args = ap.parse_args(argv)
    import clsim
    from clsim.sensor import C_M_PER_NS
    from clsim.validation.budget import default_pulses, waveform_metrics
    from clsim.validation.meshref import MeshReferenceSimulator
    from tlsvox.pipeline import scene_from_scans
    from tlsvox.truth.scanner import paper_scan_poses, simulate_scan
    from tlsvox.truth.synthetic import make_tree
    from tlsvox.voxel.wood.qsm import CylinderModel, apply_cylinders, wood_points

    load0 = os.getloadavg()
    t_start = time.perf_counter()
    sizes = [float(v) for v in args.sizes.split(",") if v]
    n = args.photons
    tree = make_tree(seed=1)
    base = clsim.Sensor.preset("ahab-chiroptera-i")
    pulses = default_pulses(crown_center=tree.crown_center[:2], crown_radius=tree.params.crown_radius)
    sim = clsim.Simulator()
    twin = tree.truth_scene(0.2)
    refs = {p.name: MeshReferenceSimulator().run(tree, p.sensor(base), photons=n, seed=7, max_order=3,
                                                  target=p.target, twin=twin) for p in pulses}
    scans = [simulate_scan(tree, pose=pp, seed=i, scan_id=i + 1, name=f"scan{i + 1}", progress=False)
             for i, pp in enumerate(paper_scan_poses(tree))]
    tc = tree.cylinders
    truth = CylinderModel(tc, np.zeros(len(tc), int), np.zeros(len(tc)), np.full(len(tc), 360.0), np.arange(len(tc)))

    def run(scene):
        out = []
        for p in pulses:
            s = p.sensor(base)
            res = sim.run(scene, s, photons=n, seed=1, max_order=3, target=p.target, hotspot=True)
            out.append(waveform_metrics(res, refs[p.name], ground_time_ns=2.0 * s.range_m / C_M_PER_NS))
        return out

    wave, fit, fit_info = [], None, None
    for h in sizes:
        for s in scans:
            s.pose = None  # scene_from_scans registers them
        pr = scene_from_scans(scans, voxel_size=h, progress=False)
        wood = wood_points(scans, [c.labels for c in pr.classifications])
        if fit is None:
            fit = fit_rows(tree, pr.cylinders)
            fit_info = (len(wood), pr.timings["qsm"], pr.cylinders.summary())
        turbid, fitted = pr.voxelized.scene, pr.scene
        variants = [("exact-LAD twin (true solid wood)", tree.truth_scene(h)),
                    ("exact-LAD leaves and bark, fitted cylinders", apply_cylinders(
                        tree.truth_scene(h, solid_wood=False), pr.cylinders, wood)[0]),
                    ("TLS: turbid wood (`qsm=False`)", turbid),
                    ("TLS: **fitted cylinders** (default)", fitted),
                    ("TLS: true cylinders", apply_cylinders(turbid, truth, wood)[0]),
                    ("TLS: fitted cylinders, no other wood",
                     dataclasses.replace(fitted, wood=np.where(fitted.wood_solid, fitted.wood, 0.0))),
                    ("TLS: no wood", dataclasses.replace(turbid, wood=np.zeros_like(turbid.wood)))]
        for name, scene in variants:
            ms = run(scene)
            wave.append((h, name, ms))
            print(f"{h:g} m {name}: " + " / ".join(f"r {m['r']:.3f} E {m['total']:.2f}" for m in ms), flush=True)
    minutes = (time.perf_counter() - t_start) / 60
    pn = " / ".join(p.name for p in pulses)
    lines = ["# Solid wood from fitted cylinders (`tlsvox.voxel.wood.qsm`)", "",
             f"Command: `.venv/bin/python benchmarks/bench_qsm.py --sizes {args.sizes} --photons {n}` "
             f"({minutes:.1f} min). " + machine_line(load0) + f" Device: {sim.device_name}.", "",
             f"Default oak (`make_tree(seed=1)`), two simulated VZ-400 scans, registered and classified by "
             f"`scene_from_scans`: {fit_info[0]:,} echoes classed wood; the fit took {fit_info[1]:.1f} s "
             f"and kept {fit_info[2]['cylinders']} of {fit_info[2]['tried']} pieces "
             f"({fit_info[2]['length_m']:.1f} m of stem and branches).", "",
             "## 1. The fit against the tree's cylinders", "",
             "Each fitted piece is matched to the true cylinder nearest its midpoint. The mesh's cylinders "
             "are octagonal prisms: their faces lie between 0.924 r and r, and a circle fitted to them has "
             "radius 0.949 r. Offset: the piece's midpoint from the true axis; angle: between the axes; "
             "axis inside: the share of the true axes that lies inside a fitted cylinder (the rest stays "
             "turbid wood: occlusion gaps, forks, pieces too poorly supported to keep).", "",
             "| true cylinders | count | r | pieces | fitted r, m | offset, mm (median / max) | "
             "angle, deg (median / max) | axis inside |", "|---|---:|---:|---:|---|---|---|---:|"]
    for name, count, r, _length, k, rr, off, ang, cov in fit:
        lines.append(f"| {name} | {count} | {r:.4f} | {k} | {rr} | {off} | {ang} | {cov:.2f} |")
    lines += ["", "## 2. Waveforms against the mesh", "",
              f"The four budget pulses ({pn}), {n:,} photons per run and per mesh reference, hot spot on, "
              "3 orders. r: Pearson correlation of the waveforms; E: received energy, scene / mesh "
              "(total, from vegetation, from the ground). 'true cylinders': the tree's own cylinders through "
              "`apply_cylinders`, in place of the fitted ones (the fit's term); 'no other wood': the wood "
              "echoes no cylinder explains dropped; 'exact-LAD leaves and bark, fitted cylinders': the twin "
              "without its solid wood, filled from the fitted cylinders instead (the TLS leaves' term, "
              "against the row above it).", "",
              "| voxel | scene | r | E total | E vegetation | E ground |", "|---|---|---|---|---|---|"]
    for h, name, ms in wave:
        lines.append(f"| {h * 100:g} cm | {name} | " + " / ".join(f"{m['r']:.3f}" for m in ms) + " | "
                     + " / ".join(f"{m['total']:.2f}" for m in ms) + " | "
                     + " / ".join(f"{m['vegetation']:.2f}" for m in ms) + " | "
                     + " / ".join(f"{m['ground']:.2f}" for m in ms) + " |")
    write_page(args.out, lines)
    print(f"wrote {args.out} in {minutes:.1f} min")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
