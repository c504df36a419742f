"""Measured airborne waveforms replayed: clsim against the Blair-Hofton baseline and the nearest pulse.

The NEON Harvard Forest records (../shared/data/neon-harvard-waveforms: 500
pulses, 8 scan lines, 1 ns) are held out in two schemes, interleaved 5-fold
and leave-one-scan-line-out (:func:`clsim.replay.cross_validate`).  For each
fold, from the training pulses only: clsim simulates each test pulse as fired
over a scene made from the training pulses' echoes (gain and time offset fitted
on simulated training pulses); the Blair-Hofton baseline re-weights the
training echoes (or samples) in the test footprint; the nearest training pulse
is the ceiling.  Every method is scored on the same pulses.

Then the terms of the simulation, one at a time on the interleaved scheme
(the error budget of the replay): Monte Carlo noise (photons), multiple
scattering (max order 1), the correlated return (hot spot off), the pooling
width (beams per footprint), the voxel size, the estimator (the bcMLE for
Beer-Lambert), the full hit's energy.

With ``--set leica`` the same on the Leica LAS 1.3 tile (no outgoing pulse
recorded: the pulse from its own strongest single returns; the sensor from a
straight flight fitted to the pulses' lines).

Writes docs/bench/replay_<set>.md, docs/bench/replay_<set>.json and the pictures
docs/img/replay_<set>_{overlay,radargram,scores}.png.

    .venv/bin/python benchmarks/bench_replay.py                # NEON, about 15 minutes on 2 cores
    .venv/bin/python benchmarks/bench_replay.py --set leica
    .venv/bin/python benchmarks/bench_replay.py --quick        # both schemes, no term rows
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

from _bench import machine_line, write_page  # benchmarks/ is the script's folder

ROOT = Path(__file__).resolve().parents[1]
KEYS = (("r_median", "r", "{:.3f}"), ("r_best_median", "r best lag", "{:.3f}"),
        ("energy_ratio_q25", "energy q25", "{:.2f}"), ("energy_ratio_q75", "energy q75", "{:.2f}"),
        ("rh50_bias", "RH50 bias (m)", "{:+.2f}"), ("rh50_mae", "RH50 MAE (m)", "{:.2f}"),
        ("rh50_rmse", "RH50 RMSE (m)", "{:.2f}"), ("rh98_bias", "RH98 bias (m)", "{:+.2f}"),
        ("rh98_mae", "RH98 MAE (m)", "{:.2f}"), ("rh98_rmse", "RH98 RMSE (m)", "{:.2f}"),
        ("cover_bias", "cover bias", "{:+.3f}"), ("cover_mae", "cover MAE", "{:.3f}"))
NAMES = {"simulation": "clsim simulation", "blair_hofton": "Blair-Hofton, training echoes",
         "blair_hofton_samples": "Blair-Hofton, training samples", "nearest": "nearest training pulse (ceiling)"}
#: The goals of the issue, for the page's last column.
GOALS = {"r_median": ">= 0.96 (multi-echo >= 0.93)", "rh50_bias": "within 0.1 m", "rh98_bias": "within 0.1 m",
         "rh50_mae": "<= 0.2 m", "rh98_mae": "<= 0.2 m", "energy_ratio_q25": ">= 0.85", "energy_ratio_q75": "<= 1.15"}


def table(summary, which):
    head = "| method | " + " | ".join(k[1] for k in KEYS) + " |"
    rows = [head, "|" + "---|" * (len(KEYS) + 1)]
    for m, s in summary.items():
        v = s[which]
        if v is None:
            continue
        rows.append(f"| {NAMES[m]} | " + " | ".join(fmt.format(v[k]) for k, _, fmt in KEYS) + " |")
    return rows


def scheme_section(title, result):
    """A scheme's two tables: all pulses and the multi-echo pulses."""
    return [f"## {title}", "", "All pulses:", "", *table(result.summary, "all"), "", "Multi-echo pulses:", "",
            *table(result.summary, "multi"), ""]


def term_rows(results):
    head = "| term | setting | r | r multi | energy IQR | RH50 bias / MAE (m) | RH98 bias / MAE (m) | cover MAE | s |"
    rows = [head, "|---|---|---|---|---|---|---|---|---|"]
    for name, setting, s, sec in results:
        a, m = s["all"], s["multi"]
        rows.append(f"| {name} | {setting} | {a['r_median']:.3f} | {m['r_median']:.3f} | "
                    f"{a['energy_ratio_q25']:.2f}-{a['energy_ratio_q75']:.2f} | {a['rh50_bias']:+.2f} / "
                    f"{a['rh50_mae']:.2f} | {a['rh98_bias']:+.2f} / {a['rh98_mae']:.2f} | {a['cover_mae']:.3f} | "
                    f"{sec:.0f} |")
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", type=Path, default=ROOT.parent / "shared" / "data")
    ap.add_argument("--photons", type=int, default=2000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--quick", action="store_true", help="the two schemes only, no term rows")
    ap.add_argument("--set", choices=("neon", "leica"), default="neon",
                    help="neon: the NEON Harvard Forest records; leica: the Leica LAS 1.3 tile")
    ap.add_argument("--out", type=Path, default=None, help="page (default docs/bench/replay_<set>.md)")
    ap.add_argument("--terms", default=None,
                    help="comma-separated term names to run (default all), e.g. 'footprint,multiple scattering'")
    args = ap.parse_args(argv)
    out = args.out or ROOT / "docs" / "bench" / f"replay_{args.set}.md"
    source = (args.data / "neon-harvard-waveforms" / "return.csv" if args.set == "neon"
              else args.data / "leica-fwf-las13" / "fwf.las")
    if not source.is_file():
        print(f"skipped: {source} is absent (../shared/data)")
        return 0
    from clsim import Simulator
    from clsim.replay import _forward, cross_validate, prepare, read_las_pulses, read_neon, write_replay

    load0 = os.getloadavg()
    t0 = time.perf_counter()
    measured = read_neon(source.parent) if args.set == "neon" else read_las_pulses(source)
    prepared = prepare(measured)
    prep_s = time.perf_counter() - t0
    sim = Simulator()
    # NEON pulses lie about 0.4 m apart, the Leica tile's about 1.5 m (its pooling about 1.1 m): 1 m voxels
    voxel = 0.25 if args.set == "neon" else 1.0
    results = {}
    for scheme in ("interleaved", "lines"):
        results[scheme] = cross_validate(prepared, scheme=scheme, photons=args.photons, seed=args.seed,
                                         voxel_size=voxel, simulator=sim, progress=True)
    img = ROOT / "docs" / "img"
    with tempfile.TemporaryDirectory() as tmp:
        paths = write_replay(prepared, list(results.values()), tmp)
        for kind in ("overlay", "radargram", "scores"):
            shutil.copy(paths[f"{kind}-interleaved"], img / f"replay_{args.set}_{kind}.png")
    terms = []
    if not args.quick:
        orig = _forward.scene_from_pulses
        div = measured.divergence_mrad
        cases = [("Monte Carlo noise", "500 photons", dict(photons=500)),
                 ("Monte Carlo noise", "8,000 photons", dict(photons=8000)),
                 ("multiple scattering", "order 1 only", dict(max_order=1)),
                 ("correlated return", "hot spot off (turbid two-way)", dict(hotspot=False)),
                 ("footprint", f"divergence x 3 ({3 * div:g} mrad)", dict(_divergence=3 * div)),
                 ("pooling width", "2 beams per footprint", dict(beams_per_footprint=2.0)),
                 ("pooling width", "5 beams per footprint", dict(beams_per_footprint=5.0)),
                 ("voxel size", f"{2 * voxel:g} m", dict(voxel_size=2 * voxel)),
                 *([("voxel size", f"{voxel / 2:g} m", dict(voxel_size=voxel / 2))] if args.set == "leica" else []),
                 ("estimator", "bcMLE", dict(_estimator="bcmle")),
                 ("echo profile", "each echo at its mean range (no profile)", dict(_spread=False)),
                 ("full-hit energy", "99th percentile", dict(_full=99.0)),
                 ("full-hit energy", "85th percentile", dict(_full=85.0))]
        if args.terms:
            keep = {t.strip() for t in args.terms.split(",")}
            cases = [c for c in cases if c[0] in keep]
        for name, setting, kw in cases:
            est = kw.pop("_estimator", None)
            full = kw.pop("_full", None)
            wide = kw.pop("_divergence", None)
            spread = kw.pop("_spread", None)
            if est or full or spread is not None:
                extra = {k: v for k, v in (("estimator", est), ("full_percentile", full), ("spread", spread))
                         if v is not None}
                _forward.scene_from_pulses = lambda *a, _e=extra, **k: orig(*a, **dict(k, **_e))
            if wide:
                prepared.pulses.divergence_mrad = wide
            t = time.perf_counter()
            r = cross_validate(prepared, scheme="interleaved", methods=("simulation",), simulator=sim,
                               **dict(dict(photons=args.photons, seed=args.seed, voxel_size=voxel), **kw))
            terms.append((name, setting, r.summary["simulation"], time.perf_counter() - t))
            _forward.scene_from_pulses = orig
            prepared.pulses.divergence_mrad = div
            print(f"{name}, {setting}: r {r.summary['simulation']['all']['r_median']:.3f}", flush=True)
    load1 = os.getloadavg()
    geo = measured.meta["geometry"]
    il, ln = results["interleaved"], results["lines"]
    n = len(measured)
    if args.set == "neon":
        title = "Measured airborne waveforms replayed (NEON Harvard Forest)"
        about = (f"{n} NEON records (1 ns, about 12 m of range each), {geo['lines']} scan lines. Their x and y are "
                 "stored to 0.1 m and 1 m; the positions are rebuilt from the scan geometry (each pulse's line passes "
                 "through its scanner; one scanner per line drifting along x): 95 % of the rebuilt positions lie "
                 f"within {geo['residual_x_p95_m']:.3f} m (x) and {geo['residual_y_p95_m']:.2f} m (y) of the stored "
                 "ones, i.e. within their rounding. The instrument's pulse is the file's measured system impulse "
                 "response.")
        lines_title = f"Leave one scan line out (the scene from the other {geo['lines'] - 1} lines)"
    else:
        title = "Measured airborne waveforms replayed (Leica LAS 1.3 tile)"
        about = (f"{n} pulses of the Leica tile (256 samples at 2 ns, 76.8 m of range each; the first point's packet "
                 f"of each GPS time), {geo['lines']} scan lines (runs between gaps in time). The file gives each "
                 "pulse's line, not the sensor: a straight, steady flight fitted to all the lines puts the sensor "
                 f"{geo['scanner_height_m']:.0f} m above the records at {geo['speed_m_s']:.1f} m/s, every line within "
                 f"{100 * geo['off_line_max_m']:.1f} cm of it (median {1000 * geo['off_line_median_m']:.1f} mm). The "
                 "tile records **no outgoing pulse and no impulse response**: the pulse shape is the median of its "
                 f"20 strongest single returns, and the divergence is not in the file ({measured.divergence_mrad:g} "
                 "mrad assumed, a Leica ALS50-II; the footprint row of the terms table shows what it costs).")
        lines_title = "Every fifth scan line held out (5 folds of the 78 short lines)"
    page = [
        f"# {title}",
        "",
        f"`.venv/bin/python benchmarks/bench_replay.py --set {args.set}{' --quick' if args.quick else ''}` "
        f"({time.strftime('%Y-%m-%d')}). {machine_line(load0, load1)} OpenCL device: {sim.device_name}.",
        "",
        about + f" Every record's echoes are the pulse shifted and scaled ({prepared.echo_counts().mean():.2f} echoes "
        f"per record). Preparation {prep_s:.1f} s.",
        "",
        "Every prediction of a pulse is made without it: the scene, the calibration (gain, time offset), the "
        "baseline's footprint width and gain all come from the other folds' pulses. Multi-echo pulses: records "
        f"with two or more peaks standing 3 noise sigma above their surroundings ({il.settings['multi_echo_pulses']} "
        f"of {n}). RH: heights of the energy quantiles above the measured record's lowest significant peak (the same "
        "reference for measured and predicted); cover: one minus the lowest echo's mirrored energy over the total, "
        "clipped to 0-1 (a single-peaked record reads 0 in both, so the multi-echo rows are the informative ones). "
        "Medians of the per-pulse scores; RMSE over pulses.",
        "",
        *scheme_section("Interleaved 5-fold (pulse i in fold i mod 5)", il),
        *scheme_section(lines_title, ln),
        "Time per scheme (s): " + "; ".join(f"{s}: " + ", ".join(f"{m} {v:.0f}" for m, v in r.seconds.items())
                                             for s, r in results.items()) + ".",
        "",
        "What each fold chose on its training pulses (interleaved): Blair-Hofton footprint sigma "
        + ", ".join(f"{f['blair_hofton']['sigma_m']:.2f}" for f in il.folds) + " m; simulation time offset "
        + ", ".join(f"{f['simulation']['lag_samples']:+.2f}" for f in il.folds) + " samples, pooling sigma "
        + ", ".join(f"{f['simulation']['pool_m']:.2f}" for f in il.folds) + " m.",
        "",
        ("Goals (issue, NEON): " + "; ".join(f"{k}: {v}" for k, v in GOALS.items()) + "." if args.set == "neon"
         else "No goal numbers on this tile (issue): the terms table below measures what each part of the model costs."),
        "",
        f"![measured and predicted waveforms](../img/replay_{args.set}_overlay.png)",
        "",
        f"![radargrams](../img/replay_{args.set}_radargram.png)",
        "",
        f"![scores](../img/replay_{args.set}_scores.png)",
    ]
    if terms:
        page += ["", "## The simulation's terms, one at a time (interleaved)", "",
                 f"Default: {args.photons} photons, max order 3, hot spot on, 3 beams per footprint, {voxel:g} m voxels, "
                 "Beer-Lambert, full hit at the 95th percentile of the pulses' echo energy, divergence "
                 f"{measured.divergence_mrad:g} mrad.", "",
                 *term_rows([("default", "as above", il.summary["simulation"], il.seconds["simulation"])] + terms)]
    write_page(out, page)
    data = {"interleaved": il.summary, "lines": ln.summary, "settings": il.settings,
            "folds": {k: [{a: b for a, b in f.items() if a != "test_pulses"} for f in r.folds]
                      for k, r in results.items()},
            "terms": [{"term": t, "setting": st, "summary": v, "seconds": sec} for t, st, v, sec in terms],
            "geometry": {k: v for k, v in geo.items()}, "load": [load0, load1]}
    from voxlidar.safeio import json_text

    out.with_suffix(".json").write_text(json_text(data, indent=1) + "\n")
    print(f"wrote {out.with_suffix('.json')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
