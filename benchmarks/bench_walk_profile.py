"""Where the transport's time goes on one CPU device: parts turned off by build switches.

    .venv/bin/python benchmarks/bench_walk_profile.py --device 0:0     # docs/bench/walk_profile.md

1. The full kernel (exact + nee, the device benchmark's layer: 10 m x 10 m x 2 m,
   0.1 m voxels, LAD 1, ground, ``max_order=3``), uniform bricks on and off, built
   as it ships and with one part left out at a time (``-DCLSIM_PROF_*=0`` in
   kernels/transport.cl and philox.cl): the shadow rays' walks (next-event
   estimation), Philox (a cheap hash instead), the G(d) table, the histogram
   atomics, the leaf normal's draw (spherical leaves: the cosine law about -d; others:
   rejection); and all of them at once.  The benchmark layer's leaves are spherical,
   whose G(d) is 1/2 without the table, so "no G(d) table" changes nothing there.  A part's
   cost is the time it adds per photon (ns), the shipped kernel's time less the
   time without it.  Leaving a part out changes the results (and so, slightly,
   the paths); the voxel steps per photon are given to show how much.
2. The walk alone (benchmarks/kernels/walk_bench.cl): straight rays down through the
   same layer, optical depth summed, no cut-off; ns per voxel step with the pool
   load and with a constant in its place (``-DCLSIM_PROF_POOL=0``).
Variants take turns run by run; medians of ``--repeats`` runs.  Wrap in
``flock /tmp/voxlidar-bench.lock`` on a shared machine.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from pathlib import Path

import numpy as np

from clsim.cli.simulate import benchmark_scene
from clsim.transport.setup import InteractionModel, PhotonTally, prepare_run
from clsim.transport.simulator import Simulator, _kernel_source, build_options
from voxlidar.devices import build_program

ROOT = Path(__file__).resolve().parents[1]

PARTS = [("shipped", []), ("no shadow-ray walks", ["-DCLSIM_PROF_NEE=0"]),
         ("no Philox (hash)", ["-DCLSIM_PROF_PHILOX=0"]), ("no G(d) table", ["-DCLSIM_PROF_G=0"]),
         ("no tally atomics", ["-DCLSIM_PROF_TALLY=0"]), ("no leaf-normal draw", ["-DCLSIM_PROF_LEAF=0"]),
         ("none of these", ["-DCLSIM_PROF_NEE=0", "-DCLSIM_PROF_PHILOX=0", "-DCLSIM_PROF_G=0",
                            "-DCLSIM_PROF_TALLY=0", "-DCLSIM_PROF_LEAF=0"])]


class ProfSimulator(Simulator):
    """A Simulator whose programs get extra ``-D`` switches."""

    def __init__(self, extra, **kw):
        super().__init__(**kw)
        self.extra = list(extra)

    def program(self, mode, detect, wood_dir=False):
        key = (InteractionModel.parse(mode, "mode"), PhotonTally.parse(detect, "detect"), bool(wood_dir))
        if key not in self._programs:
            src, inc = _kernel_source()
            opts = [inc] + build_options(self.info, key[0], key[1], wood_dir=key[2],
                                         features=self.features) + self.extra
            prg = build_program(self.context, src, opts)
            self._programs[key] = (prg, self._cl.Kernel(prg, "simulate"))
        return self._programs[key]


def full_kernel(device, photons, repeats):
    scene, sensor = benchmark_scene()
    sims = {(name, uni): ProfSimulator(extra, device=device, features=None if uni else {"uniform": False})
            for name, extra in PARTS for uni in (True, False)}
    for s in sims.values():
        s.run(scene, sensor, photons=2000, seed=0)
    t = {k: [] for k in sims}
    vs = {k: [] for k in sims}
    for r in range(repeats):
        for k, s in sims.items():
            res = s.run(scene, sensor, photons=photons, seed=r + 1, max_order=3)
            t[k].append(res.elapsed_s)
            vs[k].append(res.stat("voxel_steps")[0] / photons)
    return {k: (statistics.median(t[k]) / photons * 1e9, statistics.median(vs[k])) for k in sims}


def walk_alone(device, rays, repeats):
    import pyopencl as cl

    scene, sensor = benchmark_scene()
    base = Simulator(device=device)
    setup = prepare_run(scene, sensor, photons=1, seed=0)
    bufs = base._scene_buffers(setup)
    mf = cl.mem_flags
    ctx, q = base.context, base.queue
    params = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=setup.params)
    od = cl.Buffer(ctx, mf.WRITE_ONLY, 4 * rays)
    st = cl.Buffer(ctx, mf.WRITE_ONLY, 16 * rays)
    src = (ROOT / "benchmarks" / "kernels" / "walk_bench.cl").read_text()
    _, inc = _kernel_source()
    kerns = {}
    for uni in (True, False):
        for pool in (True, False):
            opts = [inc] + build_options(base.info, InteractionModel.EXACT, PhotonTally.NEE,
                                         features=None if uni else {"uniform": False})
            opts += [] if pool else ["-DCLSIM_PROF_POOL=0"]
            kerns[uni, pool] = cl.Kernel(build_program(ctx, src, opts), "walk_bench")
    t = {k: [] for k in kerns}
    steps = {}
    for r in range(repeats + 1):
        for k, kern in kerns.items():
            t0 = time.perf_counter()
            kern(q, (rays,), base.local_size, params, bufs["index"], bufs["boxes"], bufs["pool"], od, st,
                 np.uint32(r))
            q.finish()
            if r:
                t[k].append(time.perf_counter() - t0)
            s = np.empty(2 * rays, np.uint64)
            cl.enqueue_copy(q, s, st)
            steps[k] = (float(s[0::2].sum()), float(s[1::2].sum()))
    return {k: (statistics.median(t[k]), steps[k]) for k in kerns}, base.device_name


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default=None, help="device key, e.g. 0:0 (default: the best working device)")
    ap.add_argument("--photons", type=int, default=200_000)
    ap.add_argument("--rays", type=int, default=400_000)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args(argv)
    load0 = os.getloadavg()[0]
    t_start = time.perf_counter()
    walk, device = walk_alone(args.device, args.rays, args.repeats)
    full = full_kernel(args.device, args.photons, args.repeats)
    load1 = os.getloadavg()[0]
    lines = ["# Where the transport's time goes (one CPU device)", "",
             f"Command: `flock /tmp/voxlidar-bench.lock python benchmarks/bench_walk_profile.py --device "
             f"{args.device} --photons {args.photons} --rays {args.rays} --repeats {args.repeats}` "
             f"({time.strftime('%Y-%m-%d')}, {time.perf_counter() - t_start:.0f} s). Device: {device}; 2 logical "
             f"CPUs. Load average before {load0:.2f}, after {load1:.2f}. Medians of {args.repeats} runs, variants "
             "taking turns.", "",
             "## The walk alone", "",
             f"{args.rays:,} straight rays down through the benchmark layer (benchmarks/kernels/walk_bench.cl).", "",
             "| uniform bricks | pool load | voxel steps per ray | walk steps per ray | ns per voxel step "
             "| ns per walk step | voxel steps/s |", "|---|---|---:|---:|---:|---:|---:|"]
    for (uni, pool), (sec, (vsum, wsum)) in walk.items():
        lines.append(f"| {'yes' if uni else 'no'} | {'yes' if pool else 'constant'} | {vsum / args.rays:.1f} | "
                     f"{wsum / args.rays:.1f} | {sec / vsum * 1e9:.2f} | {sec / wsum * 1e9:.2f} | "
                     f"{vsum / sec / 1e6:.0f} M |")
    lines += ["", "## The full kernel, parts left out", "",
              f"exact + nee, {args.photons:,} photons per run. A part's cost: the shipped kernel's ns per photon "
              "less the variant's.", "",
              "| uniform bricks | variant | ns per photon | cost of the part (ns per photon) | share | "
              "voxel steps per photon | voxel steps/s |", "|---|---|---:|---:|---:|---:|---:|"]
    for uni in (True, False):
        ref = full["shipped", uni][0]
        for name, _ in PARTS:
            ns, vs = full[name, uni]
            cost = "" if name == "shipped" else f"{ref - ns:.0f}"
            share = "" if name == "shipped" else f"{(ref - ns) / ref:.0%}"
            lines.append(f"| {'yes' if uni else 'no'} | {name} | {ns:.0f} | {cost} | {share} | {vs:.1f} | "
                         f"{vs / ns * 1e3:.0f} M |")
    text = "\n".join(lines) + "\n"
    print(text)
    if args.out:
        tmp = args.out.with_suffix(".tmp")
        tmp.write_text(text)
        os.replace(tmp, args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
