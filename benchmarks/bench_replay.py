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

Writes docs/bench/replay_neon.md, docs/bench/replay_neon.json and the pictures
docs/img/replay_neon_{overlay,radargram,scores}.png.

    .venv/bin/python benchmarks/bench_replay.py            # about 10 minutes on 2 cores
    .venv/bin/python benchmarks/bench_replay.py --quick    # both schemes, no term rows
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

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
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "bench" / "replay_neon.md")
    args = ap.parse_args(argv)
    folder = args.data / "neon-harvard-waveforms"
    if not (folder / "return.csv").is_file():
        print(f"skipped: {folder} is absent (the NEON records of ../shared/data)")
        return 0
    from clsim import Simulator
    from clsim.replay import cross_validate, prepare, read_neon, write_replay
    from clsim.replay import _forward

    load0 = os.getloadavg()
    t0 = time.perf_counter()
    measured = read_neon(folder)
    prepared = prepare(measured)
    prep_s = time.perf_counter() - t0
    sim = Simulator()
    results = {}
    for scheme in ("interleaved", "lines"):
        results[scheme] = cross_validate(prepared, scheme=scheme, photons=args.photons, seed=args.seed,
                                         simulator=sim, progress=True)
    img = ROOT / "docs" / "img"
    with tempfile.TemporaryDirectory() as tmp:
        paths = write_replay(prepared, list(results.values()), tmp)
        for scheme in ("interleaved",):
            for kind in ("overlay", "radargram", "scores"):
                shutil.copy(paths[f"{kind}-{scheme}"], img / f"replay_neon_{kind}.png")
    terms = []
    if not args.quick:
        orig = _forward.scene_from_pulses
        cases = [("Monte Carlo noise", "500 photons", dict(photons=500)),
                 ("Monte Carlo noise", "8,000 photons", dict(photons=8000)),
                 ("multiple scattering", "order 1 only", dict(max_order=1)),
                 ("correlated return", "hot spot off (turbid two-way)", dict(hotspot=False)),
                 ("pooling width", "2 beams per footprint", dict(beams_per_footprint=2.0)),
                 ("pooling width", "5 beams per footprint", dict(beams_per_footprint=5.0)),
                 ("voxel size", "0.5 m", dict(voxel_size=0.5)),
                 ("estimator", "bcMLE", dict(_estimator="bcmle")),
                 ("full-hit energy", "99th percentile", dict(_full=99.0)),
                 ("full-hit energy", "85th percentile", dict(_full=85.0))]
        for name, setting, kw in cases:
            est = kw.pop("_estimator", None)
            full = kw.pop("_full", None)
            if est or full:
                extra = {k: v for k, v in (("estimator", est), ("full_percentile", full)) if v is not None}
                _forward.scene_from_pulses = lambda *a, _e=extra, **k: orig(*a, **dict(k, **_e))
            t = time.perf_counter()
            r = cross_validate(prepared, scheme="interleaved", methods=("simulation",), simulator=sim,
                               **dict(dict(photons=args.photons, seed=args.seed), **kw))
            terms.append((name, setting, r.summary["simulation"], time.perf_counter() - t))
            _forward.scene_from_pulses = orig
            print(f"{name}, {setting}: r {r.summary['simulation']['all']['r_median']:.3f}", flush=True)
    load1 = os.getloadavg()
    geo = measured.meta["geometry"]
    il, ln = results["interleaved"], results["lines"]
    page = [
        "# Measured airborne waveforms replayed (NEON Harvard Forest)",
        "",
        f"`.venv/bin/python benchmarks/bench_replay.py{' --quick' if args.quick else ''}` "
        f"({time.strftime('%Y-%m-%d')}). {machine_line(load0, load1)} OpenCL device: {sim.device_name}.",
        "",
        f"500 NEON records (1 ns, about 12 m of range each), {geo['lines']} scan lines. Their x and y are stored to "
        "0.1 m and 1 m; the positions are rebuilt from the scan geometry (each pulse's line passes through its "
        f"scanner; one scanner per line drifting along x): 95 % of the rebuilt positions lie within "
        f"{geo['residual_x_p95_m']:.3f} m (x) and {geo['residual_y_p95_m']:.2f} m (y) of the stored ones, i.e. "
        "within their rounding. The instrument's pulse is the file's measured system impulse response; every "
        f"record's echoes are that pulse shifted and scaled ({prepared.echo_counts().mean():.2f} echoes per "
        f"record: the canopy spreads over several pulse widths). Preparation {prep_s:.1f} s.",
        "",
        "Every prediction of a pulse is made without it: the scene, the calibration (gain, time offset), the "
        "baseline's footprint width and gain all come from the other folds' pulses. Multi-echo pulses: records "
        f"with two or more peaks standing 3 noise sigma above their surroundings ({il.settings['multi_echo_pulses']} "
        "of 500). RH: heights of the energy quantiles above the measured record's lowest significant peak (the same "
        "reference for measured and predicted); cover: one minus the lowest echo's mirrored energy over the total. "
        "Medians of the per-pulse scores; RMSE over pulses.",
        "",
        "## Interleaved 5-fold (pulse i in fold i mod 5)",
        "",
        "All pulses:",
        "",
        *table(il.summary, "all"),
        "",
        "Multi-echo pulses:",
        "",
        *table(il.summary, "multi"),
        "",
        "## Leave one scan line out (the scene from the other 7 lines)",
        "",
        "All pulses:",
        "",
        *table(ln.summary, "all"),
        "",
        "Multi-echo pulses:",
        "",
        *table(ln.summary, "multi"),
        "",
        "Time per scheme (s): " + "; ".join(f"{s}: " + ", ".join(f"{m} {v:.0f}" for m, v in r.seconds.items())
                                             for s, r in results.items()) + ".",
        "",
        "What each fold chose on its training pulses (interleaved): Blair-Hofton footprint sigma "
        + ", ".join(f"{f['blair_hofton']['sigma_m']:.2f}" for f in il.folds) + " m; simulation time offset "
        + ", ".join(f"{f['simulation']['lag_samples']:+.2f}" for f in il.folds) + " samples, pooling sigma "
        + ", ".join(f"{f['simulation']['pool_m']:.2f}" for f in il.folds) + " m.",
        "",
        "Goals (issue): " + "; ".join(f"{k}: {v}" for k, v in GOALS.items()) + ".",
        "",
        "![measured and predicted waveforms](../img/replay_neon_overlay.png)",
        "",
        "![radargrams](../img/replay_neon_radargram.png)",
        "",
        "![scores](../img/replay_neon_scores.png)",
    ]
    if terms:
        page += ["", "## The simulation's terms, one at a time (interleaved)", "",
                 f"Default: {args.photons} photons, max order 3, hot spot on, 3 beams per footprint, 0.25 m voxels, "
                 "Beer-Lambert, full hit at the 95th percentile of the pulses' echo energy, divergence 0.25 mrad.", "",
                 *term_rows([("default", "as above", il.summary["simulation"], il.seconds["simulation"])] + terms)]
    write_page(args.out, page)
    data = {"interleaved": il.summary, "lines": ln.summary, "settings": il.settings,
            "terms": [{"term": n, "setting": s, "summary": v, "seconds": sec} for n, s, v, sec in terms],
            "geometry": geo, "load": [load0, load1]}
    args.out.with_suffix(".json").write_text(json.dumps(data, indent=1, default=float) + "\n")
    print(f"wrote {args.out.with_suffix('.json')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
