"""``clsim survey``: simulate a flight line over a scene, pulse by pulse, in batches.

The pulses come from :mod:`clsim.survey` (a straight line, the preset's scan
pattern); batches run on a local Dask cluster, a running Dask scheduler, or in
a plain loop (``--workers 0``), each written to ``OUT/batches/`` as it
finishes, so that running the same command again resumes a stopped run.  The
waveforms and their returns go to LAS 1.4 (``OUT/survey.las`` with its
``.wdp``) batch by batch as they finish, in memory bounded by a batch
(:mod:`clsim.survey._las_feed`), unless ``--no-las``.

Examples
--------
>>> from clsim.cli.app import build_parser
>>> a = build_parser().parse_args(["survey", "scene.npz", "-o", "out", "--pulses", "1000"])
>>> a.sensor, a.photons, a.batch_size, a.pulses
('riegl-lms-q680i', 1000, 256, 1000)
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
from pathlib import Path

import numpy as np

from clsim.errors import InputError
from clsim.sensor import list_presets
from voxlidar.cli import number, numbers

__all__ = ["register", "cmd_survey", "line_through"]


def register(subparsers) -> None:
    """Add ``survey`` to an argparse subparsers object."""
    p = subparsers.add_parser(
        "survey", help="simulate the pulses of a flight line over a scene (Dask or a loop; resumable)",
        description="Simulate every pulse of a straight flight line over a voxel scene: the preset's "
                    "scan pattern and pulse rate, each pulse with its own seed (seed + pulse number), "
                    "in batches written to OUT/batches/ as they finish. Running the same command again "
                    "resumes: finished batches are kept. Ends with OUT/survey.las (LAS 1.4 waveform "
                    "packets) when the LAS writer is available.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument("scene", help="scene file: a voxel scene (.npz, voxlidar.scene.Scene.save), a plot of trees "
                                 "(clsim.scenes.PlotScene.save) or an AMAPVox .vox; every worker loads it")
    p.add_argument("-o", "--output", required=True, help="output folder (survey.json, batches/, survey.las)")
    p.add_argument("--sensor", default="riegl-lms-q680i",
                   help=f"preset with a [survey] table ({', '.join(list_presets())}) or a .toml file")
    p.add_argument("--start", default=None, metavar="X,Y", type=numbers(2, what="X,Y in metres", example="-20,0"),
                   help="start of the line, metres (default: the scene's west edge at its middle y), e.g. "
                        "--start -20,0")
    p.add_argument("--end", default=None, metavar="X,Y", type=numbers(2, what="X,Y in metres", example="20,0"),
                   help="end of the line (default: the scene's east edge)")
    p.add_argument("--altitude", type=number(lo=0, lo_open=True, unit="m"), default=None,
                   help="flying height, m (default: the preset's typical flying height)")
    p.add_argument("--speed", type=number(lo=0, lo_open=True, unit="m/s"), default=None,
                   help="ground speed, m/s (default: the preset's)")
    p.add_argument("--pulse-rate", type=number(lo=0, lo_open=True, unit="Hz"), default=None,
                   help="override the preset's pulse rate, Hz")
    p.add_argument("--scan-rate", type=number(lo=0, lo_open=True, unit="Hz"), default=None,
                   help="override the preset's scan rate (lines or rotations per second)")
    p.add_argument("--fov", type=number(lo=0, lo_open=True, hi=180, hi_open=True, unit="degrees"), default=None,
                   help="override the preset's full field of view, degrees")
    span = p.add_mutually_exclusive_group()
    span.add_argument("--duration", type=number(lo=0, lo_open=True, unit="s"), default=None,
                      help="simulate the first DURATION seconds of the line (default: all of it)")
    span.add_argument("--pulses", type=number(int, lo=1), default=None, help="simulate the first N pulses")
    p.add_argument("--photons", type=number(int, lo=1), default=1000, help="photons per pulse")
    p.add_argument("--max-order", type=number(int, lo=1, hi=64), default=3, help="highest scattering order")
    p.add_argument("--hotspot", action="store_true",
                   help="single scattering returns along its free incoming path (the hot spot of a small footprint; "
                        "docs/method.md) instead of through the canopy independently")
    p.add_argument("--first-order", choices=("mc", "deterministic"), default="mc",
                   help="single scattering by the photons (mc), or integrated along --beam-samples directions "
                        "through the beam, all the pulses of a batch in one kernel launch, without Monte Carlo "
                        "noise (deterministic; with --max-order 1 no photons are traced)")
    p.add_argument("--beam-samples", type=number(int, lo=1, hi=100000), default=19,
                   help="directions through the beam of --first-order deterministic (more: closer to the "
                        "Gaussian beam, slower; docs/survey.md)")
    p.add_argument("--bin-ns", type=number(lo=0.001, hi=1.0, unit="ns"), default=None,
                   help="fine time bin before the pulse convolution (default 0.05 ns; with --first-order "
                        "deterministic, whose bins hold exact integrals, a 16th of the pulse width)")
    p.add_argument("--seed", type=number(int, lo=0), default=1, help="base seed: pulse k gets seed + k")
    p.add_argument("--batch-size", type=number(int, lo=1), default=256, help="pulses per task and per file")
    p.add_argument("--workers", type=number(int, lo=0), default=os.cpu_count() or 1,
                   help="worker processes of the local Dask cluster (one thread each); 0: a plain loop "
                        "in this process, no Dask")
    p.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="address of a running Dask scheduler (tcp://host:8786) instead of a local cluster; "
                        "its workers need voxlidar and the scene file at the same path")
    p.add_argument("--in-flight", type=number(int, lo=1), default=2,
                   help="tasks per worker submitted at a time (bounds memory)")
    p.add_argument("--device", default=None, help="OpenCL device each worker opens (default: VOXLIDAR_DEVICE "
                   "or the best working device)")
    p.add_argument("--restart", action="store_true",
                   help="delete the batches of an earlier run in OUT and start over (default: resume)")
    p.add_argument("--no-las", action="store_true", help="keep only the batch files, write no LAS")
    p.add_argument("--pulsewaves", action="store_true",
                   help="also write OUT/survey.pls and survey.wvs (PulseWaves: every pulse's waveform) at the end")
    p.add_argument("--helios", metavar="DIR", default=None,
                   help="also write the HELIOS++ scene, scanner, platform and survey XML (and the scene as an "
                        "AMAPVox .vox) that fly the same pulses, into DIR (clsim.survey.helios)")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    p.add_argument("--strict", action="store_true",
                   help="refuse a scene written with quality warnings (tlsvox voxelize records them; they are "
                        "repeated here either way)")
    p.set_defaults(func=cmd_survey)


def line_through(scene, start=None, end=None):
    """(start, end) of the default line: across the scene along x at its middle y."""
    lo = np.asarray(scene.origin, dtype=float)  # a Scene or a PlotScene: the grid's corners
    hi = lo + scene.voxel_size * np.asarray(scene.shape)
    ym = 0.5 * (lo[1] + hi[1])
    return (start or (float(lo[0]), float(ym))), (end or (float(hi[0]), float(ym)))


def cmd_survey(args) -> int:
    from clsim.scenes import load_scene, repeat_scene_warnings
    from clsim.sensor import Sensor
    from clsim.survey import ScanPattern, Trajectory, pulse_count, typical_flight
    from clsim.survey.distributed import SurveyJob, run_survey

    scene = load_scene(args.scene)  # a voxel scene, a plot of trees (PlotScene.save) or an AMAPVox .vox
    repeat_scene_warnings("clsim survey", args.scene, scene, strict=args.strict)
    sensor = Sensor.preset(args.sensor)
    overrides = {k: v for k, v in (("pulse_rate_hz", args.pulse_rate), ("scan_rate_hz", args.scan_rate),
                                   ("fov_deg", args.fov)) if v is not None}
    pattern = ScanPattern.preset(args.sensor, **overrides)
    flight = typical_flight(args.sensor)
    start, end = line_through(scene, args.start, args.end)
    if start == end:
        raise InputError(f"--start and --end are the same point {start}; give a line of some length")
    tr = Trajectory.line(start, end, altitude_m=args.altitude or flight.altitude_m,
                         speed_mps=args.speed or flight.speed_mps)
    count = args.pulses
    if args.duration is not None:
        count = pulse_count(args.duration, pattern.pulse_rate_hz)         # the pulses with t_k < duration
    job = SurveyJob(scene_path=args.scene, trajectory=tr, pattern=pattern, sensor=sensor, photons=args.photons,
                    count=count, seed=args.seed, batch_size=args.batch_size, max_order=args.max_order,
                    hotspot=args.hotspot, device=args.device, first_order=args.first_order,
                    bin_ns=args.bin_ns or (sensor.pulse_fwhm_ns / 16 if args.first_order == "deterministic" else 0.05),
                    beam_samples=args.beam_samples)
    out = Path(args.output)
    if args.helios:
        from clsim.survey.helios import write_helios_survey

        files = write_helios_survey(job, args.helios)
        print(f"survey: wrote {files.survey} (HELIOS++: its pulse k is this run's pulse {files.first} + k; run "
              f"helios++ {files.survey.name} --assets <helios>/python/pyhelios --fullwave)", file=sys.stderr)
    if args.restart and out.is_dir():
        shutil.rmtree(out / "batches", ignore_errors=True)
        (out / "survey.json").unlink(missing_ok=True)
    say = (lambda *a: None) if args.quiet else (lambda *a: print(*a, file=sys.stderr))
    n_b = len(job.ranges())
    how = f"{args.photons:,} photons each"
    if args.first_order == "deterministic":
        how = f"single scattering along {args.beam_samples} beam samples" + (
            f", orders 2-{args.max_order} by {args.photons:,} photons each" if args.max_order > 1 else "")
    say(f"survey: {job.count:,} pulses ({job.count / pattern.pulse_rate_hz:.3g} s of a {tr.duration_s:.3g} s "
        f"line at {tr.legs[0].start[2]:g} m), {how}, {n_b} batches of "
        f"{args.batch_size}; " + ("a plain loop" if args.workers == 0 and not args.scheduler else
                                  f"Dask {'scheduler ' + args.scheduler if args.scheduler else f'{args.workers} local workers'}"))
    run = run_survey(job, out, workers=max(args.workers, 1), scheduler=args.scheduler,
                     direct=args.workers == 0 and not args.scheduler, in_flight=args.in_flight,
                     progress=not args.quiet, las=None if args.no_las else out / "survey.las")
    if run.computed:
        say(f"survey: {run.computed} batches computed ({run.pulses:,} pulses, {run.pulses / run.seconds:,.0f} "
            f"pulses/s), {run.skipped} already on disk")
    else:
        say(f"survey: nothing to compute: all {run.n_batches} batches are on disk")
    if args.pulsewaves:
        from clsim.survey import load_survey, write_survey_pulsewaves

        pls, wvs, gain, offset = write_survey_pulsewaves(out / "survey.pls", job.pulses(), load_survey(out))
        say(f"survey: wrote {pls} and {wvs.name} (PulseWaves; power = {offset:.4g} + {gain:.4g} x count)")
    if args.no_las:
        say(f"survey: waveforms in {out / 'batches'} (one .npz per batch; clsim.survey.load_survey reads them)")
        return 0
    if run.las is None:
        raise InputError(f"{out}: not every batch is on disk, so no survey.las; run the same command again to resume")
    las, wdp = run.las
    say(f"survey: wrote {las} ({run.las_points:,} points: the decomposed returns) and {wdp.name} (the "
        "waveforms), batch by batch as they finished")
    if run.las_clipped:
        say(f"survey: warning: {run.las_clipped:,} waveform samples clipped at the digitiser's top count")
    return 0
