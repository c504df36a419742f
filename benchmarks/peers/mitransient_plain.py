"""Is the benchmark's mitransient set-up slower than a plain one?  Both on the slab, alternating.

    DRJIT_LIBLLVM_PATH=$(cat .peer-venv/mitransient/llvm-path.txt) \\
        .peer-venv/mitransient/bin/python benchmarks/peers/mitransient_plain.py SPEC.json

``SPEC.json``: the slab spec of benchmarks/bench_mitransient.py (``peer_spec`` of its slab,
laser end, max_depth 4; ``bench_mitransient.py --dump-slab-spec SPEC.json`` writes it).  Set-ups:

- **benchmark**: :func:`mitransient_worker.scene_dict` of the spec (tabulated Ross phase function,
  one-pixel camera along the beam, the receiver as a spot light, 942 bins of 0.25 ns).
- **plain**: what a first user would write for the same slab (20 x 20 x 2 m, sigma_t 0.5 /m,
  albedo 0.915, ground 0.30, sensor at 360 m): an ``isotropic`` phase function, a point light at
  the sensor, a 0.05 degree one-pixel camera, the same film and integrator depth.
- **plain, max_depth 2**: single scattering only (what a peer run without multiple scattering costs).

Each is rendered ``--repeats`` times at ``--spp`` samples (new seed each time, Dr.Jit's kernels
compiled before timing); it prints samples/s per render and the median, one line per set-up.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))


def plain_scene(mi, spec: dict, max_depth: int) -> dict:
    T = mi.ScalarTransform4f
    zs = float(spec["sensor_z"])
    look = T().look_at(origin=[0, 0, zs], target=[0, 0, 0], up=[0, 1, 0])
    film = {"type": "transient_hdr_film", "width": 1, "height": 1, "temporal_bins": int(spec["nbins"]),
            "bin_width_opl": float(spec["bin_opl"]), "start_opl": float(spec["start_opl"]), "rfilter": {"type": "box"}}
    return {"type": "scene", "integrator": {"type": "transient_prbvolpath", "max_depth": max_depth},
            "sensor": {"type": "perspective", "fov": 0.05, "to_world": look,
                       "sampler": {"type": "independent", "sample_count": 4}, "film": film},
            "light": {"type": "point", "position": [0, 0, zs], "intensity": {"type": "spectrum", "value": 1.0}},
            "ground": {"type": "rectangle", "to_world": T().scale([1000.0, 1000.0, 1.0]),
                       "bsdf": {"type": "diffuse", "reflectance": {"type": "spectrum", "value": 0.3}}},
            "canopy": {"type": "cube", "to_world": T().translate([0, 0, 3]).scale([10, 10, 1]), "bsdf": {"type": "null"},
                       "interior": {"type": "homogeneous", "sigma_t": 0.5, "albedo": 0.915,
                                    "phase": {"type": "isotropic"}}}}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("spec", type=Path)
    ap.add_argument("--spp", type=int, default=1 << 21)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--out", type=Path, default=None, help="also write these lines as a markdown page")
    args = ap.parse_args(argv)
    import mitsuba as mi

    mi.set_variant("llvm_ad_mono")
    import drjit as dr
    import mitransient  # noqa: F401  (registers the transient plugins)
    from mitransient_worker import scene_dict

    spec = json.loads(args.spec.read_text())
    setups = {"benchmark": scene_dict(mi, spec), "plain": plain_scene(mi, spec, int(spec["max_depth"])),
              "plain, max_depth 2": plain_scene(mi, spec, 2)}
    scenes = {}
    for name, d in setups.items():
        scenes[name] = mi.load_dict(d)
        mi.render(scenes[name], spp=1024, seed=1)                 # compile
    rates: dict[str, list] = {k: [] for k in setups}
    for r in range(args.repeats):                                 # alternating
        for name, scene in scenes.items():
            t = time.perf_counter()
            _, tr = mi.render(scene, spp=args.spp, seed=100 + r)
            np.array(tr)
            rates[name].append(args.spp / (time.perf_counter() - t))
    import os
    import platform

    load = os.getloadavg()
    lines = ["## mitransient: the benchmark's set-up against a plain one", "",
             "Written by `benchmarks/peers/mitransient_plain.py` (its docstring says what each set-up is):", "",
             "    .venv/bin/python benchmarks/bench_mitransient.py --dump-slab-spec /tmp/slab.json",
             "    DRJIT_LIBLLVM_PATH=$(cat .peer-venv/mitransient/llvm-path.txt) .peer-venv/mitransient/bin/python "
             "benchmarks/peers/mitransient_plain.py /tmp/slab.json --out docs/bench/mitransient-plain.md", "",
             f"mitransient {mitransient.__version__}, Mitsuba {mi.__version__}, Dr.Jit {dr.__version__} "
             f"(`llvm_ad_mono`, {dr.thread_count()} threads) on {platform.processor() or platform.machine()}, "
             f"{os.cpu_count()} CPUs; load average {load[0]:.2f} at the end; {args.spp:,} samples a render, "
             f"{args.repeats} renders a set-up, alternating.", "",
             "| set-up | M samples/s, median | each render |", "| --- | ---: | --- |"]
    for name, v in rates.items():
        lines.append(f"| {name} | {statistics.median(v) / 1e6:.2f} | {', '.join(f'{x / 1e6:.2f}' for x in v)} |")
    b, p = statistics.median(rates["benchmark"]), statistics.median(rates["plain"])
    lines += ["", f"The benchmark's set-up runs at {b / p:.2f} times the plain one's samples/s on this machine: "
              "what it adds (the tabulated phase function, the beam-shaped camera, the receiver as a spot "
              "light) costs that much, and bench_mitransient.py's ratios stand against a plain set-up within it. "
              "Single scattering alone (max_depth 2) runs "
              f"{statistics.median(rates['plain, max_depth 2']) / p:.1f} times faster than three scatterings."]
    text = "\n".join(lines) + "\n"
    print(text)
    if args.out is not None:
        tmp = args.out.with_name(f".{args.out.name}.tmp")
        tmp.write_text(text)
        tmp.replace(args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
