"""Where the exact-LAD scene's waveform error comes from: leaves, wood and the hot spot, pulse by pulse.

The four budget pulses of :func:`clsim.validation.budget.default_pulses` over the
default synthetic oak (``make_tree(seed=1)``), sensor ``ahab-chiroptera-i``:
the explicit-geometry mesh reference against the exact-LAD voxel twin
(``tree.truth_scene``), leaf-on, leaf-off (wood and ground only) and leaves only
(the bark taken out of both), with and without the hot-spot option, and the wood
terms one at a time: what a solid voxel scatters off (the cylinder's side and
caps, or random facets), whether a cored cylinder's bark stays as turbid wood
beside its core, directional or isotropic bark, and solid or hollow wood on both
sides (the mesh's bark cylinders closed at their ends or open tubes; the twin's
trunks filled or a shell); and the TLS pipeline's scene at the same voxel size,
leaf-on, leaf-off and with its wood removed (the estimation term).

Writes docs/bench/waveform_terms.md.

    .venv/bin/python benchmarks/bench_waveform_terms.py      # about 5 min on 2 cores
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

from _bench import machine_line, write_page

ROOT = Path(__file__).resolve().parents[1]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--voxel", type=float, default=0.1, help="voxel size of the exact-LAD twin, m")
    ap.add_argument("--photons", type=int, default=300_000, help="photons per run (mesh and voxels)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--no-tls", action="store_true", help="leave out the TLS pipeline's scene")
    ap.add_argument("--out", default=str(ROOT / "docs" / "bench" / "waveform_terms.md"))
    args = ap.parse_args(argv)
    import dataclasses

    import numpy as np

    from clsim import Sensor, Simulator
    from clsim.sensor import C_M_PER_NS
    from clsim.validation.budget import default_pulses, waveform_metrics
    from clsim.validation.meshref import MeshReferenceSimulator
    from tlsvox.truth.synthetic import TreeParams, make_tree
    from voxlidar.materials import Material

    load0 = os.getloadavg()
    t0 = time.perf_counter()
    tree = make_tree(seed=1)  # bark cylinders closed at their ends (TreeParams.capped_wood)
    tubes = make_tree(TreeParams(capped_wood=False), seed=1)  # open tubes, as until 2026-11
    keep = tree.material != Material.BARK
    leaves = dataclasses.replace(tree, triangles=tree.triangles[keep], material=tree.material[keep],
                                 cylinders=np.zeros((0, 7)))
    base = Sensor.preset("ahab-chiroptera-i")
    twin = tree.truth_scene(args.voxel)  # the default: solid voxels with the cylinders' surface, bark beside dropped
    kept = tree.truth_scene(args.voxel, core_bark=True)  # the cored cylinders' bark kept beside the core
    # random facets in the core (the solid voxels opaque and isotropic), bark kept: the model until 2026-11-23
    facets = dataclasses.replace(kept, wood_solid=None, wood_cap=None)
    iso = tree.truth_scene(args.voxel, wood_model="isotropic", core_bark=True)  # and isotropic bark around
    # the twin as it was until 2026-11: isotropic bark of open tubes, hollow trunks
    hollow = tubes.truth_scene(args.voxel, solid_wood=False, wood_model="isotropic")
    sim, mesh = Simulator(), MeshReferenceSimulator()
    tls = tls_wood = None
    if not args.no_tls:  # the TLS pipeline's scene (two simulated scans, poses estimated), and without its wood
        from tlsvox.pipeline import scene_from_scans
        from tlsvox.truth.scanner import paper_scan_poses, simulate_scan

        scans = [simulate_scan(tree, pose=pp, seed=i, scan_id=i + 1, name=f"scan{i + 1}", progress=False)
                 for i, pp in enumerate(paper_scan_poses(tree))]
        tls_run = scene_from_scans(scans, voxel_size=args.voxel, progress=False)
        tls, tls_turbid = tls_run.scene, tls_run.voxelized.scene  # solid wood from fitted cylinders; without them
        tls_wood = tls_turbid.wood.copy()
    rows = []
    # (mesh's cylinders, twin's wood, mesh tree, twin, hot spot variants)
    models = [("capped", "solid surface, bark beside dropped", tree, twin, (True, False)),
              ("capped", "solid surface, bark beside kept", tree, kept, (True,)),
              ("capped", "solid facets, bark beside kept", tree, facets, (True,)),
              ("capped", "solid facets, isotropic bark kept", tree, iso, (True,)),
              ("open tubes", "hollow, isotropic", tubes, hollow, (True,))]
    for pulse in default_pulses(crown_center=tree.crown_center[:2], crown_radius=tree.params.crown_radius):
        sensor = pulse.sensor(base)
        tg = 2.0 * sensor.range_m / C_M_PER_NS
        for leaves_mode in ("on", "off", "only"):
            leaf_off = leaves_mode == "off"
            if leaves_mode == "only":  # bark out of both: the leaves' own term
                pairs = [("no bark", "no wood", leaves, leaves.truth_scene(args.voxel), (True, False))]
                if tls is not None:
                    pairs.append(("no bark", "TLS pipeline, wood removed",  leaves,
                                  dataclasses.replace(tls_turbid, wood=np.zeros_like(tls_wood)), (True,)))
            else:
                pairs = models + ([("capped", "TLS pipeline (fitted cylinders)", tree, tls, (True,)),
                                   ("capped", "TLS pipeline, turbid wood (qsm=False)", tree, tls_turbid, (True,))]
                                  if tls is not None else [])
            refs = {}
            for mesh_name, wood_name, t, scene, hots in pairs:
                if mesh_name not in refs:
                    refs[mesh_name] = mesh.run(t, sensor, photons=args.photons, seed=args.seed, max_order=3,
                                               target=pulse.target, twin=twin, leaf_off=leaf_off)
                ref = refs[mesh_name]
                for hotspot in hots:
                    res = sim.run(scene, sensor, photons=args.photons, seed=args.seed, max_order=3,
                                  target=pulse.target, leaf_off=leaf_off, hotspot=hotspot)
                    m = waveform_metrics(res, ref, ground_time_ns=tg)
                    rows.append((pulse.name, leaves_mode, mesh_name, wood_name, hotspot, m))
                    print(f"{pulse.name} leaves {leaves_mode} {mesh_name} {wood_name} hotspot={hotspot}: "
                          f"r {m['r']:.3f} E {m['total']:.3f} veg {m['vegetation']:.3f} ground {m['ground']:.3f}",
                          flush=True)
    minutes = (time.perf_counter() - t0) / 60
    lines = ["# Where the exact-LAD waveform error comes from (leaves, wood, hot spot)", "",
             f"Command: `.venv/bin/python benchmarks/bench_waveform_terms.py --voxel {args.voxel:g} --photons "
             f"{args.photons}` ({minutes:.1f} min). " + machine_line(load0)
             + f" Device: {sim.device_name}.", "",
             f"Default oak, sensor `ahab-chiroptera-i`, the four budget pulses; mesh reference against the "
             f"exact-LAD twin at {args.voxel * 100:g} cm (and the TLS pipeline's scene at the same size: two "
             f"simulated VZ-400 scans, registered, classified, voxelised), {args.photons:,} photons each, "
             "3 orders. r: Pearson "
             "correlation of the waveforms; E: received energy, twin / mesh (total, from vegetation, from the "
             "ground; ± one standard error from the 16 batches).", "",
             "| pulse | leaves | mesh's cylinders | twin's wood | hot spot | r | E total | E vegetation | E ground |",
             "|---|---|---|---|---|---:|---:|---:|---:|"]
    for name, leaves_mode, mesh_name, wood_name, hotspot, m in rows:
        lines.append(f"| {name} | {leaves_mode} | {mesh_name} | {wood_name} | {'on' if hotspot else 'off'} | "
                     f"{m['r']:.3f} | "
                     f"{m['total']:.3f} ± {m['total_se']:.3f} | {m['vegetation']:.3f} ± {m['vegetation_se']:.3f} | "
                     f"{m['ground']:.3f} ± {m['ground_se']:.3f} |")
    lines += ["", "Leaves 'on': the whole tree; 'off': wood and ground only (`leaf_off` on both sides); 'only': "
              "the bark taken out of the mesh and the twin, so the leaves' own error (clumping inside voxels, "
              "the hot spot) shows alone.", "",
              "The wood terms, one at a time (rows 'capped'): (1) what a solid voxel scatters off. A solid "
              "trunk's voxels stop a beam from every direction; until 2026-11-23 what the beam met there was "
              "random facets ('solid facets'), which return 2/3 towards the sensor from every direction, "
              "where the mesh's top cap of the leader returns 1 at nadir and an upright trunk's side 15 degrees "
              "off its axis about 0.2. Solid voxels now carry the cylinder's side and end caps "
              "(`Scene.wood_solid`, `wood_cap`; docs/method.md, solid wood). (2) The bark beside the core: "
              "the voxels whose centres lie inside a cylinder already cover its cross-section, so its bark in "
              "the voxels around them, kept as turbid wood until 2026-11-23 ('bark beside kept'), stops and "
              "returns a beam a second time; it is dropped now. (3) Orientation of the turbid bark: "
              "'isotropic bark' gives the bark around the core random facets instead of each voxel's bark "
              "axis and anisotropy. (4) Hollow wood ('open tubes / hollow'): the twin as it was until 2026-11, "
              "a shell of turbid bark around empty voxels, against a mesh of open tubes.", "",
              "'TLS pipeline (fitted cylinders)': the scene estimated from the scans, its trunk and main "
              "branches solid wood filled from cylinders fitted to the wood echoes (`tlsvox.voxel.wood.qsm`, the "
              "pipeline's default since 2026-11-23), the other wood echoes the stretched count per voxel "
              "(`count_stretch`); 'turbid wood (qsm=False)': all of its wood that count, turbid, randomly "
              "oriented facets, no solid core (the scans see a trunk's surface, not its inside). Its rows "
              "against the exact twin's give the estimation term, leaves and wood apart.", ""]
    write_page(args.out, lines)


if __name__ == "__main__":
    main()
