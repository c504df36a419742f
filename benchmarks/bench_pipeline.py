"""Speed against accuracy for the whole pipeline: voxel size and photon count.

On the default synthetic oak (``make_tree(seed=1)``) the waveform a pulse
would really record is known: the explicit-geometry mesh reference
(:class:`clsim.validation.meshref.MeshReferenceSimulator`, high photon count, cached on
disk) is "the truth".  Against it, for a nadir pulse through the crown centre
and an oblique pulse near the crown edge:

Axis 1, voxel size (photons fixed high): voxel scenes built two ways,
"exact LAD" (``tree.truth_scene``: the mesh's own leaf area and wood per voxel)
and "TLS pipeline" (two simulated scans -> register -> classify -> VoxLAD via
``tlsvox.pipeline.scene_from_scans``), each simulated with the hot-spot option
(and, at one size, without it).  Scored by waveform NRMSE and 1 - r; the time
to build the scene and the simulation time are reported separately.

Axis 2, photon count, on the 0.2 m exact-LAD scene: NRMSE against the mesh
and against a 1e7-photon voxel run of the same scene (Monte Carlo noise alone,
without the model error), and the simulation time.

Times are medians of ``--repeats`` runs for the simulations (errors: medians
over the same runs, different seeds); scene building is timed once per size.
Writes docs/bench/pipeline.md and docs/img/pipeline_speed_accuracy.png.

    .venv/bin/python benchmarks/bench_pipeline.py           # about 15 min on 2 shared cores (2 cm scenes included)
    .venv/bin/python benchmarks/bench_pipeline.py --quick   # fewer points and photons, about 4 min
    .venv/bin/python benchmarks/bench_pipeline.py --replot  # table + chart again from the last run's figures

The mesh references and the 1e7-photon voxel runs are cached under
``out/bench_cache`` (keyed by their settings and by the simulators' source), so
a second run skips them; ``--no-cache`` recomputes.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import pickle
import platform
import shlex
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
CACHE_SOURCES = ["clsim/validation/meshref.py", "clsim/transport/simulator.py", "clsim/digitize.py", "clsim/sensor.py",
                 "tlsvox/truth/synthetic.py", "voxlidar/scene.py"]


def log(msg):
    print(f"[{time.strftime('%H:%M:%S')}] {msg}", flush=True)


def source_hash() -> str:
    h = hashlib.sha1()
    files = [ROOT / p for p in CACHE_SOURCES] + sorted((ROOT / "clsim" / "kernels").glob("*"))
    for p in files:
        if p.is_file():
            h.update(p.read_bytes())
    return h.hexdigest()[:12]


def cached(cache_dir, key: dict, compute):
    """Pickle ``compute()`` under a name hashed from ``key`` (None cache_dir: no caching)."""
    if cache_dir is None:
        return compute(), False
    name = hashlib.sha1(repr(sorted(key.items())).encode()).hexdigest()[:16]
    path = Path(cache_dir) / f"{key['what']}-{name}.pkl"
    if path.exists():
        with open(path, "rb") as fh:
            return pickle.load(fh), True
    value = compute()
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    with open(tmp, "wb") as fh:
        pickle.dump(value, fh, protocol=pickle.HIGHEST_PROTOCOL)
    os.replace(tmp, path)
    return value, False


def noise_nrmse(result) -> float:
    """Monte Carlo noise of a result's waveform, as an NRMSE (from its batches)."""
    from clsim.digitize import digitize

    fb = result.fine_batches.sum(axis=(1, 2))  # (B, F)
    ok = result.batch_photons > 0
    s = result.settings["sensor"]
    _, wb = digitize(result.fine_edges_ns, fb[ok], sampling_ghz=s["sampling_ghz"], pulse_fwhm_ns=s["pulse_fwhm_ns"])
    if wb.shape[-1] != result.waveform.shape[-1]:  # pragma: no cover - settings keys differ
        return float("nan")
    se = wb.std(axis=0, ddof=1) / np.sqrt(ok.sum())
    return float(np.sqrt(np.mean(se**2)) / result.waveform.max())


def median(v):
    return float(statistics.median(v))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="fewer voxel sizes and photon counts")
    ap.add_argument("--sizes", default=None, help="voxel sizes for the exact-LAD scene, m "
                    "(default 0.02,0.05,0.1,0.2,0.4; quick 0.2,0.4)")
    ap.add_argument("--tls-sizes", default=None, help="voxel sizes for the TLS pipeline, m "
                    "(default 0.02,0.05,0.1,0.2,0.4; quick 0.2,0.4)")
    ap.add_argument("--tls-lad-sizes", default="0.1,0.2",
                    help="also run each TLS pipeline size below these with the LAD estimated at that size "
                         "(voxelize's lad_voxel_size, placed evenly; '': not)")
    ap.add_argument("--tls-lad-echoes", action="store_true",
                    help="and with the leaf area placed by leaf echo weight (lad_placement='echoes')")
    ap.add_argument("--hotspot-off-size", type=float, default=0.2,
                    help="voxel size also simulated without the hot-spot option")
    ap.add_argument("--pulses", default="nadir-centre,oblique-edge")
    ap.add_argument("--photons-mesh", type=int, default=None, help="mesh reference (default 1M; quick 300k)")
    ap.add_argument("--photons-voxel", type=int, default=None, help="voxel-size axis (default 1M; quick 300k)")
    ap.add_argument("--photons-series", default=None,
                    help="photon axis (default 1e3,1e4,1e5,1e6,3e6; quick 1e3,1e4,1e5,1e6)")
    ap.add_argument("--photons-ref", type=int, default=None,
                    help="voxel run that stands for the noise-free voxel model (default 1e7; quick 3e6)")
    ap.add_argument("--repeats", type=int, default=3, help="simulation runs per point (median)")
    ap.add_argument("--max-order", type=int, default=3)
    ap.add_argument("--seed", type=int, default=1, help="tree seed")
    ap.add_argument("--cache", default=str(ROOT / "out" / "bench_cache"))
    ap.add_argument("--no-cache", action="store_true")
    ap.add_argument("--out", default=str(ROOT / "docs" / "bench" / "pipeline.md"))
    ap.add_argument("--png", default=str(ROOT / "docs" / "img" / "pipeline_speed_accuracy.png"))
    ap.add_argument("--replot", action="store_true",
                    help="rewrite the table and chart from the last run's figures (<cache>/pipeline_last.json)")
    args = ap.parse_args(argv)
    if args.replot:
        report(json.loads((Path(args.cache) / "pipeline_last.json").read_text()), Path(args.out), Path(args.png))
        return 0
    q = args.quick
    sizes = [float(v) for v in (args.sizes or ("0.2,0.4" if q else "0.02,0.05,0.1,0.2,0.4")).split(",") if v]
    tls_sizes = [float(v) for v in (args.tls_sizes if args.tls_sizes is not None else
                                   ("0.2,0.4" if q else "0.02,0.05,0.1,0.2,0.4")).split(",") if v]
    n_mesh = args.photons_mesh or (300_000 if q else 1_000_000)
    n_vox = args.photons_voxel or (300_000 if q else 1_000_000)
    series = [int(float(v)) for v in (args.photons_series or ("1e3,1e4,1e5,1e6" if q else
                                                               "1e3,1e4,1e5,1e6,3e6")).split(",")]
    n_ref = args.photons_ref or (3_000_000 if q else 10_000_000)
    cache_dir = None if args.no_cache else args.cache
    K = args.max_order
    t_start = time.perf_counter()
    load0 = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")

    import clsim
    from clsim.sensor import C_M_PER_NS
    from clsim.validation.budget import default_pulses, waveform_metrics
    from clsim.validation.meshref import MeshReferenceSimulator
    from tlsvox.pipeline import scene_from_scans
    from tlsvox.truth.scanner import paper_scan_poses, simulate_scan
    from tlsvox.truth.synthetic import make_tree

    src = source_hash()
    tree = make_tree(seed=args.seed)
    base = clsim.Sensor.preset("ahab-chiroptera-i")
    allp = {p.name: p for p in default_pulses(crown_center=tree.crown_center[:2], crown_radius=6.0)}
    pulses = [allp[n] for n in args.pulses.split(",")]
    twin_size = 0.2
    twin = tree.truth_scene(twin_size)
    sim = clsim.Simulator()
    device = sim.device_name
    sim.run(twin, pulses[0].sensor(base), photons=2000, seed=0, max_order=K, hotspot=True)  # builds the kernel
    MeshReferenceSimulator().run(tree, pulses[0].sensor(base), photons=100, seed=0, max_order=1, twin=twin)  # BVH

    # -- the truth: mesh reference per pulse ----------------------------------------
    refs, ref_time, ref_noise = {}, {}, {}
    for p in pulses:
        s = p.sensor(base)
        key = dict(what="mesh", tree=args.seed, pulse=repr(p), photons=n_mesh, seed=7, K=K, twin=twin_size,
                   sensor=repr(s), src=src)

        def run_mesh(p=p, s=s):
            t0 = time.perf_counter()
            r = MeshReferenceSimulator().run(tree, s, photons=n_mesh, seed=7, max_order=K, target=p.target,
                                             twin=twin)
            r.elapsed_s = time.perf_counter() - t0
            return r

        refs[p.name], hit = cached(cache_dir, key, run_mesh)
        ref_time[p.name] = refs[p.name].elapsed_s
        ref_noise[p.name] = noise_nrmse(refs[p.name])
        log(f"mesh reference {p.name}: {n_mesh:,} photons, {ref_time[p.name]:.1f} s"
            f"{' (cached)' if hit else ''}; own noise NRMSE {ref_noise[p.name]:.4f}")

    def score(res, p, ref=None):
        s = p.sensor(base)
        m = waveform_metrics(res, ref if ref is not None else refs[p.name],
                             ground_time_ns=2.0 * s.range_m / C_M_PER_NS)
        return m

    def simulate(scene, photons, hot, seeds, ref_of=None):
        """Median time and metrics over seeds, per pulse -> {pulse: dict}."""
        out = {}
        for p in pulses:
            s = p.sensor(base)
            times, nrmse, one_r, tot, nrmse2 = [], [], [], [], []
            for sd in seeds:
                t0 = time.perf_counter()
                res = sim.run(scene, s, photons=photons, seed=sd, max_order=K, target=p.target, hotspot=hot)
                times.append(time.perf_counter() - t0)
                m = score(res, p)
                nrmse.append(m["nrmse"])
                one_r.append(1.0 - m["r"])
                tot.append(m["total"])
                if ref_of is not None:
                    nrmse2.append(score(res, p, ref_of[p.name])["nrmse"])
            out[p.name] = dict(time=median(times), nrmse=median(nrmse), one_r=median(one_r), total=median(tot),
                               nrmse_vox=median(nrmse2) if nrmse2 else float("nan"),
                               noise=noise_nrmse(res))
        return out

    seeds = list(range(1, args.repeats + 1))
    rows = []

    # -- axis 1a: exact-LAD scenes ---------------------------------------------------
    for h in sizes:
        t0 = time.perf_counter()
        scene = twin if h == twin_size else tree.truth_scene(h)
        t_scene = time.perf_counter() - t0
        if h == twin_size:  # time a fresh build too
            t0 = time.perf_counter()
            tree.truth_scene(h)
            t_scene = time.perf_counter() - t0
        for hot in ((True, False) if abs(h - args.hotspot_off_size) < 1e-9 else (True,)):
            res = simulate(scene, n_vox, hot, seeds)
            rows.append(dict(axis="voxel", source="exact LAD", h=h, hot=hot, photons=n_vox, scene_s=t_scene,
                             voxels=len(scene.lad), leaf_area=float(scene.lad.sum() * h**3), per=res))
            log(f"exact LAD {h:g} m hot={hot}: scene {t_scene:.1f} s; "
                + "; ".join(f"{k} nrmse {v['nrmse']:.3f} 1-r {v['one_r']:.3f} {v['time']:.1f} s"
                            for k, v in res.items()))
        if h != twin_size:
            del scene

    # -- axis 1b: TLS pipeline scenes ------------------------------------------------
    scan_s, tls_skipped = float("nan"), []
    if tls_sizes:
        t0 = time.perf_counter()
        scans = [simulate_scan(tree, pose=pp, seed=i, scan_id=i + 1, name=f"scan{i + 1}", progress=False)
                 for i, pp in enumerate(paper_scan_poses(tree))]
        scan_s = time.perf_counter() - t0
        n_pulses = sum(len(s.pulses) for s in scans)
        log(f"two simulated scans: {n_pulses:,} pulses, {scan_s:.1f} s")
    runs = [(h, None, None) for h in tls_sizes]
    for H in [float(v) for v in args.tls_lad_sizes.split(",") if v]:  # the LAD estimated at H (a multiple of h)
        for h in tls_sizes:
            if h < H and abs(H / h - round(H / h)) < 1e-6:
                runs += [(h, H, "even")] + ([(h, H, "echoes")] if args.tls_lad_echoes else [])
    for h, lad_h, placement in runs:
        for s in scans:
            s.pose = None  # scene_from_scans sets the poses: start from unknown poses every time
        source = ("TLS pipeline" if lad_h is None else f"TLS pipeline, LAD at {lad_h * 100:g} cm"
                  + (", placed by echoes" if placement == "echoes" else ""))
        t0 = time.perf_counter()
        try:
            pr = scene_from_scans(scans, voxel_size=h, progress=False,
                                  voxelize_kwargs=None if lad_h is None else dict(lad_voxel_size=lad_h,
                                                                                  lad_placement=placement))
        except Exception as err:  # noqa: BLE001 - e.g. the memory guard at small voxel sizes
            tls_skipped.append((h, f"{type(err).__name__}: {err}"))
            log(f"{source} {h:g} m skipped: {err}")
            continue
        t_scene = time.perf_counter() - t0
        for hot in ((True, False) if abs(h - args.hotspot_off_size) < 1e-9 and lad_h is None else (True,)):
            res = simulate(pr.scene, n_vox, hot, seeds)
            rows.append(dict(axis="voxel", source=source, h=h, hot=hot, photons=n_vox, scene_s=t_scene,
                             scene_parts=dict(pr.timings), voxels=len(pr.scene.lad),
                             leaf_area=float(pr.scene.lad.sum() * h**3), per=res))
            log(f"{source} {h:g} m hot={hot}: scene {t_scene:.1f} s {pr.timings}; leaf area "
                f"{rows[-1]['leaf_area']:.1f} m2; "
                + "; ".join(f"{k} nrmse {v['nrmse']:.3f} 1-r {v['one_r']:.3f} {v['time']:.1f} s"
                            for k, v in res.items()))
        del pr

    # -- axis 2: photon count on the 0.2 m exact-LAD scene ------------------------------
    vref, vref_time = {}, {}
    for p in pulses:
        s = p.sensor(base)
        key = dict(what="voxref", tree=args.seed, pulse=repr(p), photons=n_ref, seed=999, K=K, h=twin_size,
                   hot=True, sensor=repr(s), src=src)

        def run_ref(p=p, s=s):
            t0 = time.perf_counter()
            r = sim.run(twin, s, photons=n_ref, seed=999, max_order=K, target=p.target, hotspot=True)
            r.elapsed_s = time.perf_counter() - t0
            r.traces = None
            return r

        vref[p.name], hit = cached(cache_dir, key, run_ref)
        vref_time[p.name] = vref[p.name].elapsed_s
        m = score(vref[p.name], p)
        log(f"voxel reference {p.name}: {n_ref:,} photons {vref_time[p.name]:.1f} s{' (cached)' if hit else ''}; "
            f"vs mesh nrmse {m['nrmse']:.4f}, own noise {noise_nrmse(vref[p.name]):.4f}")
    prow = []
    for n in series:
        res = simulate(twin, n, True, [1000 + 10 * n // 1000 + sd for sd in seeds], ref_of=vref)
        prow.append(dict(axis="photons", source="exact LAD", h=twin_size, hot=True, photons=n, per=res))
        log(f"photons {n:,}: " + "; ".join(f"{k} nrmse {v['nrmse']:.3f} vs-vox {v['nrmse_vox']:.4f} "
                                            f"{v['time']:.2f} s" for k, v in res.items()))
    total_s = time.perf_counter() - t_start
    cmd = shlex.join(["benchmarks/bench_pipeline.py", *(sys.argv[1:] if argv is None else argv)])
    data = dict(cmd=cmd, date=time.strftime("%Y-%m-%d %H:%M"), total_s=total_s, load0=load0, device=device,
                machine=platform.machine(), cpus=os.cpu_count(), python=platform.python_version(),
                tree_seed=args.seed, leaf_area=float(tree.leaf_area()),
                sensor=dict(name=base.name, altitude_m=base.altitude_m, divergence_mrad=base.divergence_mrad,
                            pulse_fwhm_ns=base.pulse_fwhm_ns),
                K=K, repeats=args.repeats, twin_size=twin_size,
                pulses=[dict(name=p.name, target=list(p.target), off_nadir_deg=p.off_nadir_deg) for p in pulses],
                n_mesh=n_mesh, ref_time=ref_time, ref_noise=ref_noise, n_vox=n_vox, scan_s=scan_s,
                tls_sizes=tls_sizes, tls_skipped=tls_skipped, rows=rows, n_ref=n_ref, vref_time=vref_time,
                prow=prow)
    Path(args.cache).mkdir(parents=True, exist_ok=True)  # also with --no-cache: --replot reads it
    (Path(args.cache) / "pipeline_last.json").write_text(json.dumps(data, indent=1))
    report(data, Path(args.out), Path(args.png))
    log(f"wrote {args.out} and {args.png} in {total_s:.0f} s")
    return 0


def report(d: dict, out: Path, png: Path) -> None:
    """Write the Markdown table and the two-panel chart from the measured figures."""
    from voxlidar.safeio import atomic_write

    pn = [p["name"] for p in d["pulses"]]
    rows, prow = d["rows"], d["prow"]
    sen = d["sensor"]

    def per(r, k):
        return " / ".join(f"{r['per'][n][k]:{fmt}}" for n, fmt in zip(pn, [FMT[k]] * len(pn)))

    lines = ["# Whole pipeline: speed against waveform accuracy", "",
             f"Written by `.venv/bin/python {d['cmd']}` on {d['date']} in {d['total_s'] / 60:.1f} min "
             "(parts read from the cache not counted).", "",
             f"Machine: {d['machine']}, {d['cpus']} logical CPUs shared with other jobs (load average "
             f"{d['load0']:.1f} at start, so times are upper bounds); OpenCL device `{d['device']}` (PoCL on "
             f"the CPU); mesh reference on Open3D/Embree (CPU). Python {d['python']}.", "",
             f"Tree: the default synthetic oak (`make_tree(seed={d['tree_seed']})`, {d['leaf_area']:.0f} m2 of "
             f"leaves). Sensor `{sen['name']}` ({sen['altitude_m']:g} m, {sen['divergence_mrad']:g} mrad "
             f"divergence: a footprint about 0.36 m wide; {sen['pulse_fwhm_ns']:g} ns pulse), "
             f"`max_order={d['K']}`. Pulses: "
             + ", ".join(f"`{p['name']}` (beam axis meets the ground at {p['target'][0]:g}, {p['target'][1]:g} m "
                         f"from the crown centre; {p['off_nadir_deg']:g} deg off nadir)" for p in d["pulses"]) + ".",
             "",
             f"**Truth**: the explicit-geometry mesh reference, {d['n_mesh']:,} photons per pulse ("
             + ", ".join(f"{d['ref_time'][n]:.1f} s" for n in pn) + "); its own Monte Carlo noise, from its 16 "
             "batches, is NRMSE " + " / ".join(f"{d['ref_noise'][n]:.4f}" for n in pn) + ". "
             "NRMSE = RMS waveform difference / peak of the mesh waveform; r = Pearson correlation of the "
             "waveforms; E ratio = total received energy, model / mesh. Errors and times are medians over "
             f"{d['repeats']} runs with different seeds. Columns with two values give each pulse ("
             + " / ".join(pn) + ").", ""]
    lines += ["## 1. Voxel size, scene source and hot spot", "",
              f"{d['n_vox']:,} photons per run. `scene s`: building the voxel scene, once per size. Exact LAD = "
              "`tree.truth_scene` (the mesh's leaf and bark area per voxel); TLS pipeline = "
              "`scene_from_scans` = register + classify + voxelise/VoxLAD [+ cylinders fitted to the wood echoes "
              "filling solid wood, `tlsvox.voxel.wood.qsm`, where the run had it] (the parts in brackets; the two "
              f"simulated scans, {d['scan_s']:.0f} s, are not counted); *LAD at N cm*: `voxelize`'s "
              "`lad_voxel_size`, the LAD estimated on the N cm grid and put on each of its fine voxels "
              "(*placed by echoes*: its leaf area shared by their leaf echo weight; tlsvox.voxel.coarse). "
              f"Leaf area: the scene's ({d['leaf_area']:.0f} m2 true). "
              "`sim s`: one waveform simulation.", "",
              "| scene | voxel | hot spot | voxels | leaf area, m2 | scene s | sim s | NRMSE | 1 - r | E ratio |",
              "|---|---:|---|---:|---:|---:|---:|---|---|---|"]
    for r in rows:
        parts = ""
        if "scene_parts" in r:
            sp = r["scene_parts"]
            parts = f" ({sp.get('register', 0):.0f} + {sp.get('classify', 0):.0f} + {sp.get('voxelize', 0):.0f}"
            parts += f" + {sp['qsm']:.0f})" if "qsm" in sp else ")"
        area = f"{r['leaf_area']:.1f}" if "leaf_area" in r else "-"
        lines.append(f"| {r['source']} | {r['h']:g} m | {'on' if r['hot'] else 'off'} | {r['voxels']:,} | {area} | "
                     f"{r['scene_s']:.1f}{parts} | {per(r, 'time')} | {per(r, 'nrmse')} | {per(r, 'one_r')} | "
                     f"{per(r, 'total')} |")
    for h, msg in d["tls_skipped"]:
        lines += ["", f"TLS pipeline at {h:g} m skipped: {msg}"]
    lines += ["", "The TLS pipeline's scenes at 5 cm and below are traced with the sparse layout (`voxelize`'s "
              "`layout='auto'`: full sums only for voxels holding echoes; see docs/bench/memory.md for its memory "
              "and leaf area against voxel size). The exact-LAD scenes store only voxels holding leaves or wood."]
    lines += ["", f"## 2. Photon count (exact-LAD scene, {d['twin_size']:g} m, hot spot on)", "",
              f"`vs mesh`: the total error. `vs voxel ref`: against a {d['n_ref']:,}-photon run of the same voxel "
              "scene (" + " / ".join(f"{d['vref_time'][n]:.1f} s" for n in pn) + "), i.e. the Monte Carlo noise "
              "alone, without the model error. `noise`: the run's own noise estimated from its 16 batches.", "",
              "| photons | sim s | photons/s | NRMSE vs mesh | NRMSE vs voxel ref | noise (batches) | 1 - r vs mesh |",
              "|---:|---:|---:|---|---|---|---|"]
    for r in prow:
        t = float(np.mean([r["per"][n]["time"] for n in pn]))
        lines.append(f"| {r['photons']:,} | {per(r, 'time')} | {r['photons'] / t:,.0f} | {per(r, 'nrmse')} | "
                     f"{per(r, 'nrmse_vox')} | {per(r, 'noise')} | {per(r, 'one_r')} |")
    lines += ["", "![speed against accuracy](../img/pipeline_speed_accuracy.png)", ""]

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 2, figsize=(16, 6.4))
    sources = list(dict.fromkeys(r["source"] for r in rows))
    colors = dict(zip(sources, ["tab:green", "tab:blue", "tab:orange", "tab:brown", "tab:purple", "tab:olive"]))
    marks = dict(zip(pn, ["o", "^", "s", "D"]))
    for src in sources:
        for n in pn:
            rr = [r for r in rows if r["source"] == src and r["hot"]]
            if not rr:
                continue
            xs = [r["scene_s"] + r["per"][n]["time"] for r in rr]
            ys = [r["per"][n]["nrmse"] for r in rr]
            ax[0].loglog(xs, ys, "-", marker=marks[n], color=colors[src], mec="k", ms=7, lw=0.8)
            for r, x, y in zip(rr, xs, ys):
                ax[0].annotate(f"{r['h'] * 100:g} cm", (x, y), textcoords="offset points", xytext=(5, 4),
                               fontsize=7)
            for r in (r for r in rows if r["source"] == src and not r["hot"]):
                x, y = r["scene_s"] + r["per"][n]["time"], r["per"][n]["nrmse"]
                ax[0].loglog(x, y, marks[n], color=colors[src], mfc="white", ms=7)
                ax[0].annotate(f"{r['h'] * 100:g} cm, no hot spot", (x, y), textcoords="offset points",
                               xytext=(5, -10), fontsize=7, color="dimgrey")
    floor = float(np.mean([d["ref_noise"][n] for n in pn]))
    ax[0].axhline(floor, color="grey", ls=":", lw=1, label="mesh reference's own MC noise")
    ax[0].set(xlabel="scene building + one simulation (s)", ylabel="waveform NRMSE vs mesh",
              title=f"Voxel size ({d['n_vox']:,} photons; open markers: hot spot off)")
    from matplotlib.lines import Line2D

    handles = ([Line2D([], [], color=colors[src], lw=2, label=src) for src in sources]
               + [Line2D([], [], color="k", marker=marks[n], ls="", label=n) for n in pn]
               + [Line2D([], [], color="grey", ls=":", label="mesh reference's own MC noise")])
    ax[0].legend(handles=handles, fontsize=7, loc="upper left", bbox_to_anchor=(1.0, 1.0),
                 title="scene (colour), pulse (marker)", title_fontsize=7)
    ax[0].grid(alpha=0.3, which="both")
    for n in pn:
        xs = [r["per"][n]["time"] for r in prow]
        y1 = [r["per"][n]["nrmse"] for r in prow]
        y2 = [r["per"][n]["nrmse_vox"] for r in prow]
        ax[1].loglog(xs, y1, "-", marker=marks[n], color="tab:red", mec="k", ms=7, lw=0.8,
                     label=f"{n}: vs mesh (total error)")
        ax[1].loglog(xs, y2, "--", marker=marks[n], color="tab:purple", mec="k", ms=7, lw=0.8,
                     label=f"{n}: vs {d['n_ref']:.0e}-photon voxel run (MC noise)")
        for r, x, y in zip(prow, xs, y1):
            ax[1].annotate(f"{r['photons']:.0e}", (x, y), textcoords="offset points", xytext=(4, 5), fontsize=7)
        for r, x, y in zip(prow, xs, y2):
            ax[1].annotate(f"{r['photons']:.0e}", (x, y), textcoords="offset points", xytext=(4, -11), fontsize=7)
    ax[1].axhline(floor, color="grey", ls=":", lw=1, label="mesh reference's own MC noise")
    ax[1].set(xlabel="simulation time (s)", ylabel="waveform NRMSE",
              title=f"Photon count (exact LAD, {d['twin_size']:g} m, hot spot on)")
    ax[1].legend(fontsize=7, loc="lower left")
    ax[1].grid(alpha=0.3, which="both")
    fig.tight_layout()
    atomic_write(png, lambda tmp: fig.savefig(tmp, format="png", dpi=110))
    plt.close(fig)
    text = "\n".join(lines).rstrip() + "\n"
    atomic_write(out, lambda tmp: Path(tmp).write_text(text))
    print(text)


FMT = dict(time=".2f", nrmse=".3f", one_r=".3f", total=".2f", nrmse_vox=".4f", noise=".4f")


if __name__ == "__main__":
    raise SystemExit(main())
