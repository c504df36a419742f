"""Transport speed of two versions of the kernels side by side, on real scenes.

The version in this tree is timed against an older one unpacked elsewhere, each in
its own process, on the synthetic oak (20 and 10 cm voxels) and the homogeneous
test layer, with uniform bricks and voxel by voxel; the kernels' register counts
are printed where the runtime reports them (NVIDIA: ``-cl-nv-verbose``).

    git archive da50bbc clsim voxlidar tlsvox | (mkdir -p /tmp/old && tar -x -C /tmp/old)
    python benchmarks/bench_walk_versions.py --old /tmp/old

Photons/s are wall time of ``Simulator.run`` (exact + nee, ``max_order=3``),
median of ``--repeats`` runs after a warm-up run; a run on a GPU is short, so
launches and transfers are in the figure.
"""
from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def registers(sim) -> dict:
    """Per walk, the build log's register lines (NVIDIA only; empty elsewhere)."""
    import pyopencl as cl

    from clsim.transport import simulator as S

    src, inc = S._kernel_source()
    out = {}
    for name, feats in (("uniform", {}), ("voxel walk", {"uniform": False})):
        opts = [inc] + S.build_options(sim.info, "exact", "nee", features=feats) + ["-cl-nv-verbose"]
        try:
            prg = cl.Program(sim.context, src).build(opts)
        except cl.Error:
            continue  # the runtime does not take the NVIDIA option
        log = prg.get_build_info(sim.info.device, cl.program_build_info.LOG)
        out[name] = " ".join(ln.split(":", 1)[-1].strip() for ln in log.splitlines() if "registers" in ln)
    return out


def measure(tag: str, photons: int, repeats: int) -> None:
    from clsim import Sensor, Simulator
    from clsim.validation import testscenes
    from tlsvox.truth.synthetic import make_tree

    sensor = Sensor.preset("ahab-chiroptera-i")
    scenes = {"synthetic oak, 20 cm": make_tree(seed=0).truth_scene(0.2),
              "synthetic oak, 10 cm": make_tree(seed=0).truth_scene(0.1),
              "homogeneous layer": testscenes.homogeneous_layer()}
    sims = {"uniform": Simulator(), "voxel walk": Simulator(features={"uniform": False})}
    for walk, regs in registers(sims["uniform"]).items():
        print(f"{tag}\tregisters\t{walk}\t{regs}", flush=True)
    kw = dict(bin_ns=0.05, max_order=3)
    for sname, scene in scenes.items():
        for walk, sim in sims.items():
            sim.run(scene, sensor, photons=20_000, seed=0, **kw)
            times = []
            for r in range(repeats):
                t0 = time.perf_counter()
                sim.run(scene, sensor, photons=photons, seed=100 + r, **kw)
                times.append(time.perf_counter() - t0)
            print(f"{tag}\t{sname}\t{walk}\t{photons / statistics.median(times) / 1e6:.1f}", flush=True)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--old", type=Path, help="directory holding an older clsim, voxlidar and tlsvox")
    ap.add_argument("--photons", type=int, default=4_000_000)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--tag", help=argparse.SUPPRESS)  # set in the worker processes
    args = ap.parse_args(argv)
    if args.tag:
        measure(args.tag, args.photons, args.repeats)
        return
    runs = [("now", ROOT)] + ([("before", args.old.resolve())] if args.old else [])
    rows = {}
    for tag, tree in runs:
        env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(tree), os.environ.get("PYTHONPATH", "")]))
        out = subprocess.run([sys.executable, __file__, "--tag", tag, "--photons", str(args.photons),
                              "--repeats", str(args.repeats)], env=env, capture_output=True, text=True,
                             check=True).stdout
        for line in out.splitlines():
            t, scene, walk, value = line.split("\t")
            rows.setdefault((scene, walk), {})[t] = value
    print(f"photons/s (M), exact + nee, {args.photons:,} photons, median of {args.repeats}; load {os.getloadavg()[0]:.2f}")
    print("| scene | walk | " + " | ".join(t for t, _ in runs) + " |")
    print("|---|---|" + "---|" * len(runs))
    for (scene, walk), vals in rows.items():
        print(f"| {scene} | {walk} | " + " | ".join(vals.get(t, "") for t, _ in runs) + " |")


if __name__ == "__main__":
    main()
