"""The transport of two source trees side by side (a kernel change measured against its base).

    git archive main | tar -x -C /tmp/base          # the base tree (any commit)
    .venv/bin/python benchmarks/bench_kernel_ab.py --base /tmp/base --label "base: main"

exact + nee on the device benchmark's layer (``clsim bench``: 10 m x 10 m x 2 m,
0.1 m voxels, LAD 1, ground, ``ahab-chiroptera-i`` at nadir, ``max_order=3``):
photons/s and voxel steps/s of the tree in ``--base`` and of this tree, each in
its own worker process importing its own ``clsim`` (kernels and host code), the
two taking turns run by run (medians of ``--repeats`` runs, with the range), so
that a slow spell of a shared machine falls on both alike.  Beside the wall-clock
rates, voxel steps per CPU-second of the worker process (its OpenCL runtime's
threads included): another process sharing the cores lowers the wall-clock rate
by up to 2x, the CPU-time rate much less.  The load average is logged before
and after.  Wrap in ``flock /tmp/voxlidar-bench.lock`` on a shared
machine.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

from voxlidar.safeio import atomic_write

ROOT = Path(__file__).resolve().parents[1]

# The worker: builds the kernel once, then runs one benchmark per line of stdin (the seed)
# and answers with one JSON line.
WORKER = """
import json, resource, sys
from clsim.cli.simulate import benchmark_scene
from clsim.transport.simulator import Simulator
import clsim
scene, sensor = benchmark_scene()
sim = Simulator(device=sys.argv[1] or None)
sim.run(scene, sensor, photons=2000, seed=0)
print(json.dumps(dict(device=sim.device_name, clsim=clsim.__file__)), flush=True)
def cpu():
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime
for line in sys.stdin:
    c0 = cpu()
    res = sim.run(scene, sensor, photons=int(sys.argv[2]), seed=int(line), max_order=3)
    print(json.dumps(dict(s=res.elapsed_s, cpu=cpu() - c0, steps=float(res.stat("voxel_steps")[0]))), flush=True)
"""


class Worker:
    """One tree's benchmark process (``PYTHONPATH`` = the tree)."""

    def __init__(self, tree: Path, device: str | None, photons: int):
        env = dict(os.environ, PYTHONPATH=str(tree))
        self.p = subprocess.Popen([sys.executable, "-c", WORKER, device or "", str(photons)], cwd=tree,
                                  env=env, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        self.info = self._read()

    def _read(self) -> dict:
        line = self.p.stdout.readline()
        if not line:
            raise SystemExit(f"the benchmark worker of {self.p.args} stopped (its error is above)")
        return json.loads(line)

    def run(self, seed: int) -> dict:
        self.p.stdin.write(f"{seed}\n")
        self.p.stdin.flush()
        return self._read()

    def close(self):
        self.p.stdin.close()
        self.p.wait()


def measure(trees: dict, device, photons: int, repeats: int) -> dict:
    workers = {k: Worker(t, device, photons) for k, t in trees.items()}
    runs = {k: [] for k in workers}
    try:
        for r in range(repeats):
            for k, w in workers.items():
                runs[k].append(w.run(r + 1))
    finally:
        for w in workers.values():
            w.close()
    out = {}
    for k, rs in runs.items():
        vps = [x["steps"] / x["s"] for x in rs]
        cps = [x["steps"] / max(x["cpu"], 1e-9) for x in rs]
        out[k] = dict(pps=photons / statistics.median(x["s"] for x in rs), vps=statistics.median(vps),
                      vrange=(min(vps), max(vps)), cps=statistics.median(cps), crange=(min(cps), max(cps)),
                      **workers[k].info)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base", type=Path, required=True, help="the base source tree (holds clsim/ and voxlidar/)")
    ap.add_argument("--label", default="base", help="what the base is (written into the page)")
    ap.add_argument("--device", default=None, help="device key, e.g. 0:0 (default: the best working device)")
    ap.add_argument("--photons", type=int, default=200_000)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "bench" / "kernel_ab.md")
    args = ap.parse_args(argv)
    if not (args.base / "clsim" / "kernels" / "transport.cl").is_file():
        raise SystemExit(f"no clsim/kernels/transport.cl under {args.base}; fix: --base names a source tree")
    load0 = os.getloadavg()[0]
    t0 = time.perf_counter()
    res = measure({"base": args.base.resolve(), "this tree": ROOT}, args.device, args.photons, args.repeats)
    load1 = os.getloadavg()[0]
    b, n = res["base"], res["this tree"]
    lines = ["# The transport against its base tree", "",
             f"Command: `flock /tmp/voxlidar-bench.lock python benchmarks/bench_kernel_ab.py --base {args.base} "
             f"--label \"{args.label}\" --photons {args.photons} --repeats {args.repeats}` "
             f"({time.strftime('%Y-%m-%d %H:%M')}, {time.perf_counter() - t0:.0f} s). Device: {n['device']}; "
             f"{os.cpu_count()} logical CPUs. Load average before {load0:.2f}, after {load1:.2f}. "
             f"exact + nee, the benchmark layer, `max_order=3`, {args.photons:,} photons per run; medians of "
             f"{args.repeats} runs, the two trees taking turns.", "",
             "Voxel steps per CPU-second: the run's voxel steps over the CPU time its process took (the "
             "runtime's threads included, and the host's set-up of the run, which the wall-clock time leaves out), "
             "which another process sharing the cores changes less than the wall-clock rate.", "",
             "| tree | photons/s | voxel steps/s (median) | range | voxel steps per CPU-second (median) | range |",
             "|---|---:|---:|---|---:|---|"]
    for k, label in (("base", args.label), ("this tree", "this tree")):
        r = res[k]
        lines.append(f"| {label} | {r['pps']:,.0f} | {r['vps'] / 1e6:.1f} M | "
                     f"{r['vrange'][0] / 1e6:.1f}-{r['vrange'][1] / 1e6:.1f} M | {r['cps'] / 1e6:.1f} M | "
                     f"{r['crange'][0] / 1e6:.1f}-{r['crange'][1] / 1e6:.1f} M |")
    lines += ["", f"Ratio this tree / base: photons/s x{n['pps'] / b['pps']:.3f}, voxel steps/s "
              f"x{n['vps'] / b['vps']:.3f}, voxel steps per CPU-second x{n['cps'] / b['cps']:.3f}.", ""]
    text = "\n".join(lines)
    print(text)
    if args.out:
        atomic_write(args.out, lambda tmp: Path(tmp).write_text(text))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
