"""The paper's chain on the synthetic oak: airborne waveforms replayed over the scene from its TLS scans.

Kim, Olsen & Béland (2015) compared waveforms simulated over a TLS voxel
scene with waveforms an airborne sensor recorded over the same tree.  No
real TLS of the NEON or Leica trees exists here, so the chain is shown on the
synthetic oak, where the "measured" airborne file is itself simulated: a
``clsim survey`` over the oak's exact-LAD twin (the mesh's own leaf and wood
area per voxel) writes a LAS 1.4 file with waveform packets, and that file is
then treated as a measurement:

1. ``clsim replay survey.las --scene TLS_SCENE``: every pulse simulated as fired
   over the scene from the oak's two TLS scans (``make demo``'s ``out/scene.npz``),
   calibrated (gain, time offset) on training pulses only, scored against the
   file beside the Blair-Hofton baseline and the nearest training pulse;
2. the same over the exact twin itself: the ceiling of a perfect scene (what
   is left is Monte Carlo noise and the file's digitiser);
3. the same without ``--scene``: each fold's scene from the other airborne pulses;
4. ``tlsvox voxelize survey.las``: the plant area of the scene made from the
   airborne file alone, against the twin's.

Writes docs/bench/replay_oak.md.

    make demo                                           # out/scene.npz (the TLS scene), if not done
    .venv/bin/python benchmarks/bench_replay_oak.py     # about 10 minutes on 2 cores
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from _bench import machine_line, write_page  # benchmarks/ is the script's folder

ROOT = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent
KEYS = (("r_median", "r", "{:.3f}"), ("energy_ratio_q25", "energy q25", "{:.2f}"),
        ("energy_ratio_q75", "energy q75", "{:.2f}"), ("rh50_bias", "RH50 bias (m)", "{:+.2f}"),
        ("rh50_mae", "RH50 MAE (m)", "{:.2f}"), ("rh98_bias", "RH98 bias (m)", "{:+.2f}"),
        ("rh98_mae", "RH98 MAE (m)", "{:.2f}"), ("cover_mae", "cover MAE", "{:.3f}"))
NAMES = {"simulation": "clsim simulation", "blair_hofton": "Blair-Hofton, training echoes",
         "nearest": "nearest training pulse"}


def sh(cmd, log):
    """Run one shell command (logged for the page); its stdout."""
    text = " ".join(str(c) for c in cmd)
    log.append(text)
    print(f"$ {text}", flush=True)
    t = time.perf_counter()
    done = subprocess.run([str(c) for c in cmd], capture_output=True, text=True)
    if done.returncode:
        sys.exit(f"failed ({done.returncode}): {text}\n{done.stderr[-3000:]}")
    print(f"  {time.perf_counter() - t:.0f} s", flush=True)
    return done.stdout


def rows(summary, which):
    out = []
    for m, s in summary.items():
        v = s[which]
        if v:
            out.append(f"| {NAMES.get(m, m)} | " + " | ".join(f.format(v[k]) for k, _, f in KEYS) + " |")
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--tls-scene", type=Path, default=ROOT / "out" / "scene.npz",
                    help="the TLS scene of the oak of seed 1 (make demo writes out/scene.npz)")
    ap.add_argument("--pulses", type=int, default=1200)
    ap.add_argument("--photons", type=int, default=1000, help="photons per pulse of the 'measured' survey")
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "bench" / "replay_oak.md")
    args = ap.parse_args(argv)
    if not args.tls_scene.is_file():
        print(f"skipped: {args.tls_scene} is absent; run `make demo` first (it writes out/scene.npz)")
        return 0
    from tlsvox.truth.synthetic import TreeParams, make_tree
    from voxlidar.scene import Scene

    load0 = os.getloadavg()
    log: list[str] = []
    tls = Scene.load(args.tls_scene)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        t = time.perf_counter()
        tree = make_tree(TreeParams(total_leaf_area=500.0, leaf_angle="uniform"), seed=1)
        twin = tree.truth_scene(0.2)
        twin.save(tmp / "twin.npz")
        twin_s = time.perf_counter() - t
        # one slow, narrow line across the crown: 5 kHz, 50 lines/s, +-1.25 deg at 300 m (a 13 m swath)
        sh([BIN / "clsim", "survey", tmp / "twin.npz", "-o", tmp / "survey", "--sensor", "riegl-lms-q680i",
            "--start=-8,0", "--end", "8,0", "--altitude", 300, "--speed", 60, "--pulse-rate", 5000,
            "--scan-rate", 50, "--fov", 2.5, "--pulses", args.pulses, "--photons", args.photons, "--seed", 1,
            "--hotspot", "--workers", 0, "-q"], log)
        las = tmp / "survey" / "survey.las"
        results = {}
        for name, extra in (("TLS scene (make demo)", ["--scene", args.tls_scene]),
                            ("the exact twin (ceiling)", ["--scene", tmp / "twin.npz"]),
                            ("held-out airborne pulses", [])):
            out = tmp / f"rep{len(results)}"
            t = time.perf_counter()
            sh([BIN / "clsim", "replay", las, "-o", out, "--scheme", "interleaved",
                "--methods", "simulation,blair_hofton,nearest", "--no-plots", "-q", *extra], log)
            results[name] = (json.loads((out / "summary.json").read_text()), time.perf_counter() - t)
        sh([BIN / "tlsvox", "voxelize", las, "--voxel-size", 0.5, "--ground", "ransac", "-o", tmp / "air.npz", "-q"],
           log)
        air = Scene.load(tmp / "air.npz")
    load1 = os.getloadavg()
    page = ["# The paper's chain on the synthetic oak: airborne waveforms replayed over its TLS scene", "",
            f"`.venv/bin/python benchmarks/bench_replay_oak.py` ({time.strftime('%Y-%m-%d')}), after `make demo`. "
            f"{machine_line(load0, load1)}", "",
            "The \"measured\" airborne file is simulated: a `clsim survey` over the oak's exact-LAD twin (0.2 m, "
            f"{twin.total_leaf_area():.0f} m2 of leaves; made in {twin_s:.0f} s) writes {args.pulses} pulses "
            f"({args.photons} photons each, single scattering returning along its free incoming path: the hot spot, "
            "as the replay simulates it) as LAS 1.4 waveform packets; `clsim replay` then treats it as a "
            "measurement: each pulse simulated as fired over a scene, calibrated on training pulses only "
            "(interleaved 5-fold), scored against the file beside the Blair-Hofton baseline and the nearest "
            "training pulse. Medians of the per-pulse scores (docs/replay.md defines them).", "",
            "| scene replayed | method | " + " | ".join(k[1] for k in KEYS) + " |",
            "|---|---|" + "---|" * len(KEYS)]
    for name, (summary, _sec) in results.items():
        for i, row in enumerate(rows(summary["schemes"]["interleaved"]["summary"], "all")):
            page.append(f"| {name if i == 0 else ''} {row}")
    page += ["", "Seconds per replay: " + ", ".join(f"{n} {s:.0f} s" for n, (_, s) in results.items()) + ".", "",
             f"The TLS scene ({tls.total_leaf_area():.0f} m2 of leaves, {tls.voxel_size:g} m voxels) is what "
             "`make demo` makes from the two simulated RIEGL VZ-400 scans; the twin is the mesh's truth. The gap "
             "between the two rows of the simulation is what the TLS scene's errors cost in the airborne "
             "waveforms.", "",
             "## The scene from the airborne file alone", "",
             f"`tlsvox voxelize survey.las --voxel-size 0.5 --ground ransac`: {air.total_leaf_area():.0f} m2 of "
             f"plant area (every echo off the fitted ground, z = {air.ground_z:.2f} m, counted as vegetation: leaves "
             f"and wood) against the twin's {twin.total_leaf_area():.0f} m2 of leaves (plus its wood); the file's "
             "pulses see the crown from above only, so what the upper crown hides is occluded "
             f"({air.occluded.sum():,} of {air.n_voxels:,} stored voxels), not counted.", "",
             "Commands (run in a temporary folder):", "", "```sh", *log, "```"]
    write_page(args.out, page)
    return 0


if __name__ == "__main__":
    sys.exit(main())
