"""clsim speed and speed-vs-accuracy benchmark; writes docs/bench/clsim.md and PNG charts.

    .venv/bin/python benchmarks/bench_clsim.py            # full (a few minutes on 2 cores)
    .venv/bin/python benchmarks/bench_clsim.py --quick    # smaller photon counts

Sections
1. photons/s and voxel steps/s per OpenCL device (medians of --repeats runs),
   and the NumPy float64 oracle on the same scene (baseline ratio);
2. ``paper`` versus ``exact`` on the homogeneous layer: energies per order and
   the waveforms, side by side in one run;
3. waveform error versus wall time for ``nee`` and ``analog`` detection; the
   analog estimator at the preset's real 5 cm aperture is extrapolated from
   runs with the enlarged virtual aperture (Poisson counting: at equal photon
   numbers its relative error grows as sqrt(A_virtual / A_real));
4. float32 (device) versus float64 (NumPy oracle): the same photons (same
   seed) through both, so their waveform difference is the arithmetic's
   share of the error, set beside the Monte Carlo noise and the time.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
import time
from pathlib import Path

import numpy as np
from _bench import write_page

from clsim.cli.simulate import benchmark_scene, device_benchmark
from clsim.sensor import Sensor
from clsim.transport.reference import ReferenceSimulator
from clsim.transport.simulator import Simulator, list_devices
from clsim.validation import testscenes

ROOT = Path(__file__).resolve().parents[1]


def save_chart(fig, img: Path, name: str, alt: str) -> str:
    """Write ``fig`` to ``img/name`` and close it; returns the markdown image line."""
    import matplotlib.pyplot as plt

    fig.tight_layout()
    fig.savefig(img / name, dpi=110)
    plt.close(fig)
    return f"![{alt}](../img/{name})"


def rel_l2(a, b):
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


def section_devices(args, lines, img):
    scene, sensor = benchmark_scene()
    rows = device_benchmark(photons=args.photons_dev, repeats=args.repeats)
    lines += ["## 1. Throughput per device", "",
              f"Scene: homogeneous layer 10 m x 10 m x 2 m, voxel 0.1 m (LAD 1, spherical), ground; "
              f"sensor `{sensor.name}` at nadir; `max_order=3`. Medians of {args.repeats} runs "
              f"(after a warm-up run that builds the program).", "",
              "Voxel steps count the voxels crossed (a uniform brick crossed in one segment counts its voxels), "
              "walk steps what the walker does; `uniform` no: the voxel-by-voxel walk (docs/method.md).", "",
              "| device | runtime | mode | detect | uniform | photons | photons/s | voxel steps/s | range over the runs "
              "| walk steps/s |", "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lo, hi = r["steps_per_s_range"]
        lines.append(f"| {r['device']} | {r['runtime']} | {r['mode']} | {r['detect']} | "
                     f"{'yes' if r['uniform'] else 'no'} | {r['photons']:,} | "
                     f"{r['photons_per_s']:,.0f} | {r['steps_per_s'] / 1e6:,.1f} M | "
                     f"{lo / 1e6:,.1f} - {hi / 1e6:,.1f} M | {r['walk_steps_per_s'] / 1e6:,.1f} M |")
    # oracle on the same scene
    n_or = args.photons_dev // 20
    ref = ReferenceSimulator()
    times = []
    for _ in range(args.repeats):
        t0 = time.perf_counter()
        ref.run(scene, sensor, photons=n_or, seed=1, max_order=3)
        times.append(time.perf_counter() - t0)
    ops = n_or / statistics.median(times)
    lines += ["", f"NumPy float64 oracle, same scene: {ops:,.0f} photons/s ({n_or:,} photons).", "",
              "| device | kernel / oracle (photons/s, exact + nee) |", "|---|---|"]
    for r in rows:
        if r["mode"] == "exact" and r["detect"] == "nee" and r["uniform"]:
            lines.append(f"| {r['device']} | {r['photons_per_s'] / ops:.1f} x |")
    lines.append("")
    lines += ["Goals: at least 20 x the oracle (issue 5); at least 150 M voxel steps/s on 2 cores on the best "
              "CPU runtime (issue 11).", "",
              chart_devices(rows, ops, img), ""]
    return rows, ops


def chart_devices(rows, oracle_ps, img) -> str:
    import matplotlib.pyplot as plt

    labels = [f"{r['runtime'][:22]}\n{r['mode']} + {r['detect']}{'' if r['uniform'] else ', voxel walk'}"
              for r in rows]
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    y = np.arange(len(rows))
    axes[0].barh(y, [r["photons_per_s"] for r in rows], color="tab:blue", label="kernel")
    axes[0].axvline(oracle_ps, color="tab:red", ls="--", label="NumPy float64 oracle")
    axes[0].set_xscale("log")
    axes[0].set_xlabel("photons / s")
    axes[0].legend(fontsize=8)
    axes[1].barh(y, [r["steps_per_s"] / 1e6 for r in rows], color="tab:green")
    axes[1].axvline(150, color="grey", ls=":", label="goal, 2 CPU cores")
    axes[1].set_xlabel("voxel steps / s (millions; equivalent with uniform bricks)")
    axes[1].legend(fontsize=8)
    for ax in axes:
        ax.set_yticks(y)
        ax.set_yticklabels(labels, fontsize=8)
        ax.invert_yaxis()
    axes[1].set_yticklabels([])
    return save_chart(fig, img, "clsim_throughput.png", "throughput")


def section_paper_vs_exact(args, lines, sim, img):
    import matplotlib.pyplot as plt

    sensor = Sensor.preset("ahab-chiroptera-i")
    out = {}
    lines += ["## 2. `paper` (2 cm steps) versus `exact` (free flight)", ""]
    for lad in (1.0, 5.0):
        scene = testscenes.homogeneous_layer(lad=lad, thickness=2.0, base_height=2.0, width=10.0,
                                             voxel_size=0.5)
        for mode in ("exact", "paper"):
            t0 = time.perf_counter()
            out[lad, mode] = sim.run(scene, sensor, photons=args.photons_pve, seed=3, mode=mode,
                                     max_order=3)
            out[lad, mode].elapsed_s = time.perf_counter() - t0
    lines += ["Homogeneous layer 2 m thick, 2 m above the ground, spherical leaves, nadir, "
              f"{args.photons_pve:,} photons per run, `max_order=3`. Energy = received fraction of "
              "the emitted pulse (x 1e-10); +- one standard error.", "",
              "| LAD | order | part | exact | paper | paper/exact - 1 |", "|---|---|---|---|---|---|"]
    for lad in (1.0, 5.0):
        for order in (1, 2, 3):
            for kind in ("vegetation", "ground"):
                e, se = out[lad, "exact"].energy(order=order, kind=kind)
                p, sp = out[lad, "paper"].energy(order=order, kind=kind)
                if e == 0:
                    continue
                d = p / e - 1
                sd = abs(p / e) * np.hypot(se / e, sp / p) if p > 0 else np.nan
                lines.append(f"| {lad:g} | {order} | {kind} | {e * 1e10:.4f} +- {se * 1e10:.4f} | "
                             f"{p * 1e10:.4f} +- {sp * 1e10:.4f} | {100 * d:+.2f} % +- {100 * sd:.2f} % |")
    for lad in (1.0, 5.0):
        te, tp = out[lad, "exact"].elapsed_s, out[lad, "paper"].elapsed_s
        tr_e = out[lad, "exact"].stat("ground_direct")[0]
        tr_p = out[lad, "paper"].stat("ground_direct")[0]
        lines.append(f"\nLAD {lad:g}: direct transmission exact {tr_e:.4f} (exp(-G LAD H) = "
                     f"{np.exp(-0.5 * lad * 2):.4f}), paper {tr_p:.4f}; wall time exact {te:.2f} s, "
                     f"paper {tp:.2f} s ({tp / te:.1f} x).")
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    for ax, lad in zip(axes, (1.0, 5.0)):
        for mode, ls in (("exact", "-"), ("paper", "--")):
            r = out[lad, mode]
            ax.plot(r.time_ns, r.waveform * 1e9, ls, label=f"{mode} total")
            ax.plot(r.time_ns, r.by_order[0] * 1e9, ls, lw=0.8, label=f"{mode} order 1")
        wf = out[lad, "exact"].waveform
        nz = np.nonzero(wf > 1e-3 * wf.max())[0]
        ax.set_xlim(out[lad, "exact"].time_ns[nz[0]] - 3, out[lad, "exact"].time_ns[nz[-1]] + 3)
        ax.set_title(f"LAD {lad:g} m$^2$/m$^3$")
        ax.set_xlabel("time after emission (ns)")
        ax.set_ylabel("received power (1e-9 of emitted energy / ns)")
        ax.legend(fontsize=8)
    lines += ["", save_chart(fig, img, "clsim_paper_vs_exact.png", "paper vs exact"), ""]


def section_nee_vs_analog(args, lines, sim, img):
    import matplotlib.pyplot as plt

    sensor = Sensor.preset("ahab-chiroptera-i")
    scene = testscenes.homogeneous_layer(lad=1.0, thickness=2.0, base_height=2.0, width=10.0,
                                         voxel_size=0.5)
    kw = dict(max_order=3)
    for det in ("nee", "analog"):  # build both programs before anything is timed
        sim.run(scene, sensor, photons=1000, seed=0, detect=det, **kw)
    ref = sim.run(scene, sensor, photons=args.photons_ref, seed=99, detect="nee", **kw)
    rows = {"nee": [], "analog": []}
    for n in args.series:
        for det in ("nee", "analog"):
            times = []
            for rep in range(3):  # median wall time of 3 runs; the error of the first
                t0 = time.perf_counter()
                r = sim.run(scene, sensor, photons=n, seed=1000 + n + rep, detect=det, **kw)
                times.append(time.perf_counter() - t0)
                if rep == 0:
                    err = rel_l2(r.waveform, ref.waveform)
            rows[det].append((n, statistics.median(times), err))
    area = sensor.virtual_aperture_area_m2 / sensor.aperture_area_m2
    fits = {}
    for det in ("nee", "analog"):
        arr = np.array([(t, e) for _, t, e in rows[det] if 0 < e < 0.9])
        c = float(np.exp(np.median(np.log(arr[:, 1]) + 0.5 * np.log(arr[:, 0])))) if len(arr) else np.nan
        fits[det] = c  # error = c / sqrt(seconds)
    fits["analog_real"] = fits["analog"] * np.sqrt(area)
    t1 = {k: (c / 0.01) ** 2 for k, c in fits.items()}
    lines += ["## 3. Waveform error versus wall time: `nee` and `analog`", "",
              f"Homogeneous layer (LAD 1) over ground, nadir, preset `{sensor.name}` (5 cm aperture "
              f"at 360 m), `max_order=3`. Error = relative L2 distance of the digitised waveform to a "
              f"`nee` reference of {args.photons_ref:,} photons; wall time of a whole `Simulator.run` "
              f"(set-up, kernel, waveform), median of 3 runs. `analog` counts photons crossing the "
              f"{sensor.virtual_aperture_m:g} m virtual aperture (area ratio {area:,.0f} to the real one).",
              "", "| photons | nee s | nee error | analog (virtual) s | analog (virtual) error |",
              "|---|---|---|---|---|"]
    for (n, tn, en), (_, ta, ea) in zip(rows["nee"], rows["analog"]):
        lines.append(f"| {n:,} | {tn:.2f} | {100 * en:.2f} % | {ta:.2f} | {100 * ea:.1f} % |")
    lines += ["", "Fitted error = c / sqrt(wall seconds); time to 1 % error:", "",
              "| estimator | time to 1 % |", "|---|---|",
              f"| nee (real aperture) | {t1['nee']:.3g} s |",
              f"| analog, {sensor.virtual_aperture_m:g} m virtual aperture (biased geometry, measured) | {t1['analog']:.3g} s |",
              f"| analog, real 5 cm aperture (extrapolated x {area:,.0f} in time) | {t1['analog_real']:.3g} s |",
              "", f"`nee` reaches 1 % {t1['analog_real'] / t1['nee']:.3g} x faster than analog at the real "
              f"aperture ({t1['analog'] / t1['nee']:.3g} x faster than with the virtual aperture). "
              "At the real aperture analog detection never counted a photon in these runs, so its time is "
              "extrapolated: analog counts are Poisson, the counted number scales with the aperture area, "
              "so at equal time its relative error is sqrt(A_virtual/A_real) larger and the time to a "
              "given error A_virtual/A_real longer.", ""]
    fig, ax = plt.subplots(figsize=(6, 4.5))
    for det, mk in (("nee", "o-"), ("analog", "s-")):
        arr = np.array([(t, e) for _, t, e in rows[det]])
        ax.loglog(arr[:, 0], 100 * arr[:, 1], mk, label=f"{det} (measured)")
    ts = np.logspace(-1, np.log10(max(t1["analog_real"], 10)) + 0.3, 50)
    ax.loglog(ts, 100 * fits["analog_real"] / np.sqrt(ts), ":", label="analog, real aperture (extrapolated)")
    ax.axhline(1.0, color="grey", lw=0.6)
    ax.set_xlabel("wall time (s)")
    ax.set_ylabel("relative L2 waveform error (%)")
    ax.legend(fontsize=8)
    lines += [save_chart(fig, img, "clsim_error_vs_time.png", "error vs time"), ""]


def section_precision(args, lines, sim, img):
    import matplotlib.pyplot as plt

    sensor = Sensor.preset("ahab-chiroptera-i")
    scene = testscenes.homogeneous_layer(lad=1.0, thickness=2.0, base_height=2.0, width=10.0,
                                         voxel_size=0.5)
    ref = ReferenceSimulator()
    kw = dict(max_order=3)
    rows = []
    for n in args.series_prec:
        k1 = sim.run(scene, sensor, photons=n, seed=21, **kw)
        k2 = sim.run(scene, sensor, photons=n, seed=22, **kw)
        t0 = time.perf_counter()
        o1 = ref.run(scene, sensor, photons=n, seed=21, **kw)
        t_or = time.perf_counter() - t0
        rows.append(dict(n=n, prec=rel_l2(k1.waveform, o1.waveform),
                         noise=rel_l2(k1.waveform, k2.waveform) / np.sqrt(2),
                         t_k=k1.elapsed_s, t_o=t_or))
    lines += ["## 4. float32 (device) versus float64 (oracle)", "",
              f"Homogeneous layer (LAD 1, 0.5 m voxels) over ground, nadir, preset `{sensor.name}`, "
              "`max_order=3`. The kernel (float32) and the NumPy oracle (float64) run the *same* photons "
              "(same seed, same Philox streams), so the relative L2 distance of their waveforms is the "
              "float32 arithmetic's share of the error; the Monte Carlo noise is the distance between "
              "two kernel seeds / sqrt(2).", "",
              "| photons | float32 vs float64, same photons | Monte Carlo noise | kernel s | oracle s | oracle / kernel time |",
              "|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['n']:,} | {100 * r['prec']:.4f} % | {100 * r['noise']:.2f} % | {r['t_k']:.3f} | "
                     f"{r['t_o']:.2f} | {r['t_o'] / r['t_k']:.0f} x |")
    worst = max(r["prec"] / r["noise"] for r in rows)
    lines += ["", f"float32 moves the waveform by at most {100 * worst:.2f} % of the Monte Carlo noise at "
              "these photon counts: float64 on the device would buy nothing measurable and cost "
              "speed (consumer GPUs run float64 at 1/32 to 1/64 of float32).", ""]
    fig, ax = plt.subplots(figsize=(6, 4.5))
    ns = [r["n"] for r in rows]
    ax.loglog(ns, [100 * r["noise"] for r in rows], "o-", label="Monte Carlo noise")
    ax.loglog(ns, [100 * r["prec"] for r in rows], "s-", label="float32 vs float64 (same photons)")
    ax.set_xlabel("photons")
    ax.set_ylabel("relative L2 waveform difference (%)")
    ax2 = ax.twinx()
    ax2.loglog(ns, [r["t_k"] for r in rows], "^:", color="tab:green", label="kernel time")
    ax2.loglog(ns, [r["t_o"] for r in rows], "v:", color="tab:red", label="oracle time")
    ax2.set_ylabel("wall time (s)")
    h1, l1 = ax.get_legend_handles_labels()
    h2, l2 = ax2.get_legend_handles_labels()
    ax.legend(h1 + h2, l1 + l2, fontsize=8, loc="center right")
    lines += [save_chart(fig, img, "clsim_float32_float64.png", "float32 vs float64"), ""]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default=str(ROOT / "docs" / "bench" / "clsim.md"))
    ap.add_argument("--img", default=str(ROOT / "docs" / "img"))
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--quick", action="store_true", help="fewer photons (about a minute)")
    args = ap.parse_args(argv)
    q = args.quick
    args.photons_dev = 100_000 if q else 1_000_000
    args.photons_pve = 100_000 if q else 1_000_000
    args.photons_ref = 400_000 if q else 4_000_000
    args.series = [10_000, 30_000, 100_000] if q else [10_000, 30_000, 100_000, 300_000, 1_000_000]
    args.series_prec = [2_000, 8_000] if q else [2_000, 8_000, 32_000]
    img = Path(args.img)
    img.mkdir(parents=True, exist_ok=True)
    import matplotlib

    matplotlib.use("Agg")
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    lines = ["# clsim benchmarks", "",
             f"Written by `benchmarks/bench_clsim.py{' --quick' if q else ''}` on {time.strftime('%Y-%m-%d %H:%M')}; "
             f"{platform.processor() or platform.machine()}, {os.cpu_count()} logical CPUs, load average "
             f"{load:.1f} at start (other jobs share the machine: absolute speeds are lower bounds); "
             f"Python {sys.version.split()[0]}; OpenCL devices: "
             + ", ".join(f"{d.key} {d.label} ({d.runtime}: {'works' if r is None else 'broken, skipped: ' + r})"
                         for d, r in list_devices()) + ".", ""]
    section_devices(args, lines, img)
    sim = Simulator()
    section_paper_vs_exact(args, lines, sim, img)
    section_nee_vs_analog(args, lines, sim, img)
    section_precision(args, lines, sim, img)
    out = Path(args.out)
    write_page(out, lines, echo=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
