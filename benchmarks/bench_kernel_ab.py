"""The transport kernel of two source trees side by side (a kernel change measured against its base).

    git -C . archive main clsim/kernels | tar -x -C /tmp/base     # the base kernels
    .venv/bin/python benchmarks/bench_kernel_ab.py --base /tmp/base/clsim/kernels --label "base: main"

exact + nee on the device benchmark's layer (``clsim bench``: 10 m x 10 m x 2 m,
0.1 m voxels, LAD 1, ground, ``ahab-chiroptera-i`` at nadir, ``max_order=3``):
photons/s and voxel steps/s of the kernels in ``--base`` and of this tree's
(clsim/kernels), the same host code and launch for both, taking turns run by run
(medians of ``--repeats`` runs, with the range).  The load average is logged
before and after.  Wrap in ``flock /tmp/voxlidar-bench.lock`` on a shared machine.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from pathlib import Path

from clsim.cli.simulate import benchmark_scene
from clsim.transport.setup import Detect, Mode
from clsim.transport.simulator import Simulator, _kernel_source, build_options
from voxlidar.devices import build_program
from voxlidar.safeio import atomic_write

ROOT = Path(__file__).resolve().parents[1]


class TreeSimulator(Simulator):
    """A Simulator whose programs are built from the kernels in ``kdir`` (None: this tree's)."""

    def __init__(self, kdir, **kw):
        super().__init__(**kw)
        self.kdir = kdir

    def program(self, mode, detect, wood_dir=False):
        key = (Mode.parse(mode, "mode"), Detect.parse(detect, "detect"), bool(wood_dir))
        if key not in self._programs:
            src, inc = _kernel_source()
            if self.kdir is not None:
                src, inc = (Path(self.kdir) / "transport.cl").read_text(), f"-I{self.kdir}"
            opts = [inc] + build_options(self.info, key[0], key[1], wood_dir=key[2], features=self.features)
            prg = build_program(self.context, src, opts)
            self._programs[key] = (prg, self._cl.Kernel(prg, "simulate"))
        return self._programs[key]


def measure(base: Path, device, photons: int, repeats: int) -> dict:
    scene, sensor = benchmark_scene()
    sims = {"base": TreeSimulator(base, device=device), "this tree": TreeSimulator(None, device=device)}
    for s in sims.values():
        s.run(scene, sensor, photons=2000, seed=0)  # build
    t = {k: [] for k in sims}
    vs = {k: [] for k in sims}
    for r in range(repeats):
        for k, s in sims.items():
            res = s.run(scene, sensor, photons=photons, seed=r + 1, max_order=3)
            t[k].append(res.elapsed_s)
            vs[k].append(res.stat("voxel_steps")[0] / res.elapsed_s)
    return {k: dict(pps=photons / statistics.median(t[k]), vps=statistics.median(vs[k]),
                    vrange=(min(vs[k]), max(vs[k])), name=sims[k].device_name) for k in sims}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base", type=Path, required=True, help="directory of the base kernels (transport.cl etc.)")
    ap.add_argument("--label", default="base", help="what the base is (written into the page)")
    ap.add_argument("--device", default=None, help="device key, e.g. 0:0 (default: the best working device)")
    ap.add_argument("--photons", type=int, default=200_000)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "bench" / "kernel_ab.md")
    args = ap.parse_args(argv)
    if not (args.base / "transport.cl").is_file():
        raise SystemExit(f"no transport.cl in {args.base}; fix: --base names a kernels directory")
    load0 = os.getloadavg()[0]
    t0 = time.perf_counter()
    res = measure(args.base, args.device, args.photons, args.repeats)
    load1 = os.getloadavg()[0]
    b, n = res["base"], res["this tree"]
    lines = ["# The transport kernel against its base", "",
             f"Command: `flock /tmp/voxlidar-bench.lock python benchmarks/bench_kernel_ab.py --base ... "
             f"--label \"{args.label}\" --photons {args.photons} --repeats {args.repeats}` "
             f"({time.strftime('%Y-%m-%d %H:%M')}, {time.perf_counter() - t0:.0f} s). Device: {n['name']}; "
             f"{os.cpu_count()} logical CPUs. Load average before {load0:.2f}, after {load1:.2f}. "
             f"exact + nee, the benchmark layer, `max_order=3`, {args.photons:,} photons per run; medians of "
             f"{args.repeats} runs, the two kernels taking turns.", "",
             "| kernels | photons/s | voxel steps/s (median) | range |", "|---|---:|---:|---|"]
    for k, label in (("base", args.label), ("this tree", "this tree")):
        r = res[k]
        lines.append(f"| {label} | {r['pps']:,.0f} | {r['vps'] / 1e6:.1f} M | "
                     f"{r['vrange'][0] / 1e6:.1f}-{r['vrange'][1] / 1e6:.1f} M |")
    lines += ["", f"Ratio this tree / base: photons/s x{n['pps'] / b['pps']:.3f}, voxel steps/s "
              f"x{n['vps'] / b['vps']:.3f}.", ""]
    text = "\n".join(lines)
    print(text)
    if args.out:
        atomic_write(args.out, lambda tmp: Path(tmp).write_text(text))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
