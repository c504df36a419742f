"""Memory and time of a plot of many trees: shared bricks against copied voxels.

For each voxel size the default plot (``make_plot(seed=0)``: 50 m x 50 m, 30
synthetic trees drawn from 6 models, trunks on the brick lattice) is built
once; then, side by side:

- *shared*: ``plot.brick_grid()``, one pool copy per model (and anchor offset)
  plus merged bricks where crowns meet, the brick index pointing instances at
  them;
- *copied*: ``build_bricks(plot.to_scene())``, every tree's voxels copied into
  one scene (what a plot without instancing holds);

with their pool and index bytes, the host bytes of the copied scene's arrays,
and the time to build each (median of ``--repeats``).  One pulse over the
plot at ``--pulse-voxel`` runs from both (same seed, same device): the
waveforms must be identical, and the times show what sharing costs the kernel.

Writes docs/bench/plot.md.

    .venv/bin/python benchmarks/bench_plot.py [--sizes 0.5,0.25,0.1] [--repeats 3]
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from pathlib import Path

import numpy as np
from _bench import machine_line, median_time, write_page

ROOT = Path(__file__).resolve().parents[1]


def host_bytes(scene) -> int:
    return sum(a.nbytes for a in (scene.ijk, scene.lad, scene.wood, scene.occluded))


def main(argv=None):
    from clsim.scenes import make_plot
    from clsim.transport.bricks import build_bricks

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sizes", default="0.5,0.25,0.1")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--pulse-voxel", type=float, default=0.25)
    ap.add_argument("--photons", type=int, default=200_000)
    ap.add_argument("--out", default=str(ROOT / "docs" / "bench" / "plot.md"))
    args = ap.parse_args(argv)
    load_before = os.getloadavg()
    rows, plots = [], {}
    for h in [float(v) for v in args.sizes.split(",")]:
        t = time.perf_counter()
        plot = make_plot(seed=0, voxel_size=h)
        t_make = time.perf_counter() - t

        def shared():
            plot._cache.clear()
            return plot.brick_grid()

        def copied():
            plot._cache.clear()
            return build_bricks(plot.to_scene())

        t_shared, gs = median_time(shared, args.repeats)
        t_copied, gc = median_time(copied, args.repeats)
        scene = plot.to_scene()
        mem = plot.memory()
        rows.append(dict(h=h, make_s=t_make, shared_s=t_shared, copied_s=t_copied, shared_pool=gs.pool.nbytes,
                         copied_pool=gc.pool.nbytes, index=gs.index.nbytes, host=host_bytes(scene),
                         bricks=gs.n_bricks, cells=mem["occupied_cells"], merged=mem["merged_bricks"],
                         leaf_area=plot.total_leaf_area(), voxels=scene.n_voxels, shape=plot.shape))
        plots[h] = plot
        print(rows[-1], flush=True)
    pulse = run_pulse(plots.get(args.pulse_voxel) or make_plot(seed=0, voxel_size=args.pulse_voxel), args)
    load_after = os.getloadavg()
    write(rows, pulse, args, load_before, load_after)


def run_pulse(plot, args) -> dict:
    from clsim.sensor import Sensor
    from clsim.transport.simulator import Simulator

    sim = Simulator()
    sensor = Sensor.preset("ahab-chiroptera-i")
    tab = plot.table()
    i = int(np.argmax(tab["height_m"]))
    target = (tab["x_m"][i] + 0.3, tab["y_m"][i] + 0.2)
    sim.run(plot, sensor, photons=1000, seed=1, target=target)          # build the kernel first
    times = {"shared": [], "copied": []}
    res = {}
    scene = plot.to_scene()
    for _ in range(args.repeats):
        for name, s in (("shared", plot), ("copied", scene)):
            r = sim.run(s, sensor, photons=args.photons, seed=7, target=target)
            times[name].append(r.elapsed_s)
            res[name] = r
    same = bool(np.array_equal(res["shared"].fine_batches, res["copied"].fine_batches))
    return dict(h=plot.voxel_size, device=sim.device_name, photons=args.photons, identical=same,
                shared_s=statistics.median(times["shared"]), copied_s=statistics.median(times["copied"]),
                energy=res["shared"].energy(), tree=str(tab["name"][i]), height=float(tab["height_m"][i]))


def write(rows, pulse, args, load_before, load_after):

    mib = 2.0**20
    lines = [
        "# A plot of many trees: shared bricks against copies", "",
        f"Command: `.venv/bin/python benchmarks/bench_plot.py --sizes {args.sizes} --repeats {args.repeats} "
        f"--pulse-voxel {args.pulse_voxel:g} --photons {args.photons}`. " + machine_line(load_before, load_after), "",
        "The plot is `make_plot(seed=0)`: 50 m x 50 m, 30 synthetic trees drawn from 6 models (2 each of broad, "
        "narrow and small crowns; 5 instances per model), trunks on the brick lattice, at least 4 m apart. "
        "*Shared*: `plot.brick_grid()` (one pool copy per model, merged bricks where crowns share a brick cell); "
        "*copied*: `build_bricks(plot.to_scene())`. Pools hold 8 bytes per voxel of every occupied 8^3 brick; "
        "*host* is the copied scene's ijk, lad, wood and occluded arrays. Build times are medians of "
        f"{args.repeats} runs; *make* (the 6 meshes and their exact-LAD voxels) one run.", "",
        "| voxel | grid | stored voxels | occupied bricks | shared pool, MiB | copied pool, MiB | copied / shared "
        "| merged bricks | index, KiB | copied scene on host, MiB | make, s | shared build, s | copied build, s |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['h'] * 100:g} cm | {' x '.join(str(v) for v in r['shape'])} | {r['voxels']:,} | {r['cells']:,} | "
            f"{r['shared_pool'] / mib:.2f} | {r['copied_pool'] / mib:.2f} | {r['copied_pool'] / r['shared_pool']:.2f} | "
            f"{r['merged']} of {r['bricks']} | {r['index'] / 1024:.1f} | {r['host'] / mib:.2f} | {r['make_s']:.1f} | "
            f"{r['shared_s']:.3f} | {r['copied_s']:.3f} |")
    e, se = pulse["energy"]
    lines += [
        "",
        "With 5 instances per model the pool can shrink at most 5 times; the bricks where crowns meet (a brick "
        "cell points at one pool slot, so two trees in one cell need a merged brick of their own) take the rest. "
        "Finer voxels mean smaller bricks (8 voxels a side) and fewer shared cells.", "",
        f"One pulse (Chiroptera preset, nadir, {pulse['photons']:,} photons, seed 7) at the top of the tallest tree "
        f"({pulse['tree']}, {pulse['height']:.1f} m) of the {pulse['h'] * 100:g} cm plot on {pulse['device']}: "
        f"shared {pulse['shared_s']:.3f} s, copied {pulse['copied_s']:.3f} s (kernel time, median of "
        f"{args.repeats}); waveforms {'identical' if pulse['identical'] else 'DIFFERENT'} "
        f"(received energy {e:.4g} +- {se:.2g} of the emitted).", "",
    ]
    out = Path(args.out)
    write_page(out, lines)


if __name__ == "__main__":
    main()
