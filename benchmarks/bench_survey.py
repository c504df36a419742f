"""Benchmark: a survey's pulses per second, in a direct loop and on Dask (1 and 2 workers).

Flight: the RIEGL LMS-Q680i preset (polygon scanner, 266 kHz, 200 lines/s,
600 m, 60 m/s) along x over the scene's middle, its field of view narrowed so
that the swath spans the scene's width (the pulses hit the trees rather than
300 m of bare ground either side).  Scene: ``--scene`` (a ``Scene.save`` or
``PlotScene.save`` file), by default the 50 m plot of 30 trees
``clsim.scenes.make_plot(seed=0, voxel_size=0.5)`` (cached under ``out/bench_cache``).

0. **Per pulse**: ``Simulator.run`` once per pulse against
   :meth:`Simulator.run_pulses` (the scene built and uploaded once), with the
   kernel's share.
1. **Rate**: the same pulses (``--pulses``, in batches of ``--batch``) with
   ``--photons`` photons each, by the direct loop (:func:`run_survey` with
   ``direct=True``, no Dask), a local cluster of 1 worker and one of 2 workers
   (one thread each), taking turns run by run; medians of ``--repeats``.  The
   clusters are started and warmed (Simulator opened, scene loaded) before
   timing, so the times are the steady state; their start-up is reported apart.
2. **Scheduler cost per task**: ``--noop-tasks`` trivial tasks (``os.getpid``)
   through the same bounded submit loop on the 2-worker cluster; with the
   bytes a task ships (the pickled :class:`SurveyJob`) and the bytes a pulse
   writes, a projection to N workers: ``rate(N) = min(N r, B / c)`` with ``r``
   the 1-worker rate, ``c`` the cost per task and ``B`` the batch size.
3. **Flight line end to end**: ``--line-pulses`` pulses (default 100,000) with
   ``--line-photons`` photons each over the scene on a fresh 2-worker local
   cluster, from start-up to every batch on disk and read back
   (:func:`load_survey`), then LAS 1.4 when ``clsim.survey.las`` exists.

Run it under the project's lock (no other benchmark at the same time):

    flock /tmp/voxlidar-bench.lock .venv/bin/python benchmarks/bench_survey.py
    .venv/bin/python benchmarks/bench_survey.py --quick      # smaller, for a check
"""

from __future__ import annotations

import argparse
import logging
import os
import pickle
import platform
import shlex
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from _bench import write_page

ROOT = Path(__file__).resolve().parents[1]
PRESET = "riegl-lms-q680i"


def log(msg):
    print(f"[{time.strftime('%H:%M:%S')}] {msg}", flush=True)


def default_scene() -> Path:
    path = ROOT / "out" / "bench_cache" / "survey_plot_seed0_0.5m.npz"
    if not path.exists():
        from clsim.scenes import make_plot

        log("building the default 30-tree plot at 0.5 m (once; cached)")
        make_plot(seed=0, voxel_size=0.5).save(path)
    return path


def make_job(scene_path, *, count: int, photons: int, batch: int, seed: int = 1, device=None):
    """The flight line over the scene's middle, long enough for ``count`` pulses."""
    from clsim.scenes import load_scene
    from clsim.sensor import Sensor
    from clsim.survey import SurveyJob, centre_line

    scene = load_scene(scene_path)
    lo = np.asarray(scene.origin, float)
    line = centre_line(lo, lo + scene.voxel_size * np.asarray(scene.shape), PRESET, count=count)
    return SurveyJob(scene_path=str(scene_path), trajectory=line.trajectory, pattern=line.pattern,
                     sensor=Sensor.preset(PRESET), photons=photons, first=line.first, count=count, batch_size=batch,
                     seed=seed, device=device), line.fov_deg


def quiet_dask():
    """No INFO lines from Dask's scheduler and nannies (clusters closing)."""
    import distributed  # noqa: F401 - creates its loggers

    for name in ["distributed"] + [n for n in logging.root.manager.loggerDict if n.startswith("distributed.")]:
        logging.getLogger(name).setLevel(logging.ERROR)


def start_cluster(n: int):
    from dask.distributed import Client, LocalCluster

    t0 = time.perf_counter()
    cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=":0",
                           scheduler_port=0, silence_logs=logging.ERROR)
    client = Client(cluster)
    return client, cluster, time.perf_counter() - t0


def timed_run(job, out, **kw):
    from clsim.survey import run_survey

    shutil.rmtree(out, ignore_errors=True)
    t0 = time.perf_counter()
    run = run_survey(job, out, progress=False, **kw)
    wall = time.perf_counter() - t0
    assert run.finished and run.computed == len(job.ranges())
    return wall, run


def noop_cost(client, n_tasks: int, in_flight: int) -> float:
    """Seconds per trivial task through a bounded submit loop (as run_survey submits)."""
    from dask.distributed import as_completed

    t0 = time.perf_counter()
    todo = iter(range(n_tasks))
    futs = [client.submit(os.getpid, pure=False) for _, _ in zip(range(in_flight), todo)]
    queue = as_completed(futs)
    for fut in queue:
        fut.result()
        if next(todo, None) is not None:
            queue.add(client.submit(os.getpid, pure=False))
    return (time.perf_counter() - t0) / n_tasks


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", default=None, help="scene file (default: the 30-tree plot at 0.5 m)")
    ap.add_argument("--pulses", type=int, default=600, help="pulses of the rate runs")
    ap.add_argument("--batch", type=int, default=50, help="pulses per task in the rate runs")
    ap.add_argument("--photons", default="1000,5000", help="photons per pulse of the rate runs (comma list)")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--overhead-pulses", type=int, default=100, help="pulses of the per-pulse cost runs")
    ap.add_argument("--noop-tasks", type=int, default=400)
    ap.add_argument("--line-pulses", type=int, default=100_000)
    ap.add_argument("--line-photons", type=int, default=100)
    ap.add_argument("--line-batch", type=int, default=1000)
    ap.add_argument("--quick", action="store_true", help="small sizes: a check that it runs")
    ap.add_argument("--out", default=str(ROOT / "docs" / "bench" / "survey.md"))
    args = ap.parse_args(argv)
    if args.quick:
        args.pulses, args.batch, args.photons, args.repeats = 120, 20, "1000", 1
        args.noop_tasks, args.line_pulses, args.line_batch, args.overhead_pulses = 100, 2000, 250, 20
    photon_list = [int(x) for x in args.photons.split(",")]
    quiet_dask()
    command = "flock /tmp/voxlidar-bench.lock .venv/bin/python benchmarks/bench_survey.py" + (
        " " + shlex.join(argv if argv is not None else sys.argv[1:]) if (argv or sys.argv[1:]) else "")

    from clsim.survey import load_survey
    from clsim.survey.distributed import projected_rate
    from clsim.transport.simulator import Simulator

    scene_path = Path(args.scene) if args.scene else default_scene()
    load0 = os.getloadavg()[0]
    t_start = time.perf_counter()
    sim = Simulator()
    device = sim.device_name
    tmp = Path(tempfile.mkdtemp(prefix="bench_survey_"))
    log(f"scene {scene_path}; device {device}; load average {load0:.1f}")

    # -- 0. one pulse at a time (Simulator.run) against run_pulses, per pulse ----------------------
    from clsim.scenes import load_scene
    from clsim.transport.setup import prepare_scene

    scene = load_scene(scene_path)
    per_pulse = {}
    for ph in photon_list:
        job0, _ = make_job(scene_path, count=args.overhead_pulses, photons=ph, batch=args.overhead_pulses)
        pulses, base = job0.pulses(), job0.sensor
        sim.run_pulses(scene, pulses[:2], base, photons=ph)                    # warm
        t_run, t_many, k_many = [], [], []
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            for i in range(len(pulses)):
                sim.run(scene, pulses.sensor(i, base), photons=ph, seed=int(pulses.seed[i]), target=pulses.target[i],
                        batches=1)
            t_run.append((time.perf_counter() - t0) / len(pulses))
            t0 = time.perf_counter()
            wf0 = sim.run_pulses(scene, pulses, base, photons=ph,
                                 scene_setup=prepare_scene(scene, wavelength_nm=base.wavelength_nm))
            t_many.append((time.perf_counter() - t0) / len(pulses))
            k_many.append(wf0.kernel_s / len(pulses))
        per_pulse[ph] = dict(run=statistics.median(t_run), many=statistics.median(t_many),
                             kernel=statistics.median(k_many))
        log(f"{ph} photons: Simulator.run {per_pulse[ph]['run'] * 1e3:.1f} ms/pulse, run_pulses "
            f"{per_pulse[ph]['many'] * 1e3:.1f} ms/pulse (kernel {per_pulse[ph]['kernel'] * 1e3:.1f} ms)")

    # -- 1. rates: direct loop, 1 worker, 2 workers, taking turns --------------------------------
    c1, k1, start1 = start_cluster(1)
    c2, k2, start2 = start_cluster(2)
    log(f"clusters started: 1 worker {start1:.1f} s, 2 workers {start2:.1f} s")
    modes = {"direct loop": dict(direct=True, simulator=sim), "Dask, 1 worker": dict(client=c1),
             "Dask, 2 workers": dict(client=c2)}
    rates = {}
    try:
        for ph in photon_list:
            job, fov = make_job(scene_path, count=args.pulses, photons=ph, batch=args.batch)
            warm, _ = make_job(scene_path, count=4 * args.batch, photons=10, batch=args.batch)
            for name, kw in modes.items():                               # open simulators, load the scene
                timed_run(warm, tmp / "warm", **kw)
            walls = {name: [] for name in modes}
            tasks = {name: [] for name in modes}
            for rep in range(args.repeats):
                order = list(modes) if rep % 2 == 0 else list(reversed(modes))
                for name in order:
                    wall, run = timed_run(job, tmp / "rate", **modes[name])
                    walls[name].append(wall)
                    tasks[name] += run.task_seconds
            for name in modes:
                w = statistics.median(walls[name])
                rates[(ph, name)] = dict(wall=w, rate=args.pulses / w, task=statistics.median(tasks[name]))
                log(f"{ph} photons, {name}: {args.pulses / w:.0f} pulses/s (median of {args.repeats}: {w:.2f} s)")

        # -- 2. scheduler cost per task, bytes ----------------------------------------------------
        cost = statistics.median(noop_cost(c2, args.noop_tasks, 4) for _ in range(3))
        log(f"scheduler cost per task: {cost * 1e3:.2f} ms")
        job_bytes = len(pickle.dumps(job))
    finally:
        for c, k in ((c1, k1), (c2, k2)):
            c.close()
            k.close()

    # -- 3. the flight line end to end -------------------------------------------------------------
    line, line_fov = make_job(scene_path, count=args.line_pulses, photons=args.line_photons, batch=args.line_batch)
    from clsim.survey import run_survey

    out = tmp / "line"
    t0 = time.perf_counter()
    line_run = run_survey(line, out, workers=2, progress=False)
    t_sim = time.perf_counter() - t0
    wf = load_survey(out)
    t_read = time.perf_counter() - t0 - t_sim
    disk = sum(p.stat().st_size for p in (out / "batches").glob("*.npz"))
    las_note = "not written: `clsim.survey.las` is not in this version"
    try:
        from clsim.survey.las import write_survey_las
    except ImportError:
        write_survey_las = None
    t_las = float("nan")
    if write_survey_las is not None:
        t1 = time.perf_counter()
        write_survey_las(out / "survey.las", line.pulses(), wf.waveform, t0_ns=wf.t0_ns, bin_ns=wf.bin_ns,
                         sensor=line.sensor)
        t_las = time.perf_counter() - t1
        las_bytes = sum(p.stat().st_size for p in out.glob("survey.*") if p.suffix != ".json")
        las_note = f"written in {t_las:.1f} s, {las_bytes / 2**20:.1f} MiB (LAS + WDP)"
    t_line = time.perf_counter() - t0
    log(f"line: {args.line_pulses} pulses in {t_line:.1f} s ({line_run.seconds:.1f} s simulating)")
    load1 = os.getloadavg()[0]
    shutil.rmtree(tmp, ignore_errors=True)

    # -- the page ----------------------------------------------------------------------------------
    r1 = {ph: rates[(ph, "Dask, 1 worker")]["rate"] for ph in photon_list}
    lines = [
        "# Survey: pulses per second, direct loop and Dask",
        "",
        f"Written by `{command}` on {time.strftime('%Y-%m-%d %H:%M')} in "
        f"{(time.perf_counter() - t_start) / 60:.1f} min.",
        "",
        f"Machine: {platform.machine()}, {os.cpu_count()} logical CPUs shared with other jobs (load average "
        f"{load0:.1f} at start, {load1:.1f} at the end, so times are upper bounds); OpenCL device `{device}`; "
        f"Python {platform.python_version()}, Dask {__import__('dask').__version__}.",
        "",
        f"Scene `{scene_path.name}`. Flight: `{PRESET}` preset (polygon, 266 kHz, 200 lines/s, 600 m, "
        f"60 m/s), field of view narrowed to {fov:.2f} deg so that the swath spans the scene; `max_order=3`, "
        "1 photon batch per pulse. Each pulse has its own seed, so every mode writes the same bits (tested in "
        "tests/clsim/survey/test_survey_run.py).",
        "",
        "## 0. One pulse at a time against `run_pulses`",
        "",
        f"{args.overhead_pulses} pulses, each by `Simulator.run` (which rebuilds the scene's bricks and leaf angle "
        "tables and uploads them, per pulse) and all by `Simulator.run_pulses` (built and uploaded once; the "
        "same bits); milliseconds per pulse, medians of "
        f"{args.repeats} runs. `host` = `run_pulses` minus its kernel time: the per-pulse set-up, launch, "
        "read-back and digitising.",
        "",
        "| photons/pulse | `run` ms/pulse | `run_pulses` ms/pulse | kernel | host | speed-up |",
        "|---:|---:|---:|---:|---:|---:|",
    ]
    for ph in photon_list:
        d = per_pulse[ph]
        lines.append(f"| {ph:,} | {d['run'] * 1e3:.2f} | {d['many'] * 1e3:.2f} | {d['kernel'] * 1e3:.2f} | "
                     f"{(d['many'] - d['kernel']) * 1e3:.2f} | {d['run'] / d['many']:.1f}x |")
    lines += [
        "",
        "## 1. Pulses per second: direct loop against Dask",
        "",
        f"{args.pulses} pulses in tasks of {args.batch}; medians of {args.repeats} runs taking turns. Clusters "
        f"started and warmed before timing (start-up: 1 worker {start1:.1f} s, 2 workers {start2:.1f} s). "
        "`per worker` = pulses/s / workers; `wall vs loop` = wall time against the direct loop's, minus 1 "
        "(Dask's overhead with 1 worker); `s/task` = median seconds a worker spent in one task.",
        "",
        "| photons/pulse | mode | pulses/s | per worker | wall vs loop | s/task |",
        "|---:|---|---:|---:|---:|---:|",
    ]
    for ph in photon_list:
        d = rates[(ph, "direct loop")]
        for name in modes:
            r = rates[(ph, name)]
            n = 2 if "2" in name else 1
            over = "" if name == "direct loop" else f"{r['wall'] / d['wall'] - 1:+.0%}"
            lines.append(f"| {ph:,} | {name} | {r['rate']:.0f} | {r['rate'] / n:.0f} | {over} | {r['task']:.3f} |")
    pulse_bytes = disk / args.line_pulses
    mem_bytes = wf.waveform.shape[1] * 8
    lines += [""]
    for ph in photon_list:
        d, o = rates[(ph, "direct loop")], rates[(ph, "Dask, 1 worker")]
        lines.append(
            f"At {ph:,} photons/pulse the 1-worker overhead is {o['wall'] / d['wall'] - 1:+.0%}: the scheduler's "
            f"cost per task (section 2, {cost * 1e3:.0f} ms) is {cost / o['task']:.0%} of a {o['task']:.2f} s task, "
            f"and the worker spends {o['task'] / d['task'] - 1:+.0%} of the loop's time on a task (workers undo "
            "the `MALLOC_TRIM_THRESHOLD_` Dask's nanny sets, which had cost 1.8 times the host time per pulse; "
            "`clsim.survey.distributed._relax_malloc`).")
    lines += [
        "",
        "Two workers share the machine's 2 cores with each other, the driver, the scheduler and the other "
        "jobs, so their speed-up is bounded by the cores free at the time (see the load average).",
        "",
        "## 2. Scheduler cost and a projection to N workers",
        "",
        f"Scheduler cost per task, `c`: {cost * 1e3:.2f} ms (median of 3 runs of {args.noop_tasks} trivial "
        f"tasks through the bounded submit loop on the 2-worker cluster; scheduler, driver and workers on the "
        f"same 2 cores). A task ships {job_bytes:,} bytes (the pickled `SurveyJob`) and returns a small dict; "
        f"a pulse writes {pulse_bytes:.0f} bytes to disk (compressed NPZ, section 3; {mem_bytes:,} bytes in "
        "memory as float64 samples).",
        "",
        "Projection: `rate(N) = min(N r, B / c)`: N workers each at the 1-worker rate `r` until the "
        "scheduler, handling one task of `B` pulses every `c` seconds, saturates; the disk must take "
        "`rate x bytes per pulse`.",
        "",
        "| photons/pulse | r (pulses/s/worker) | N | B = 50 | B = 1,000 | disk at B = 1,000 |",
        "|---:|---:|---:|---:|---:|---:|",
    ]
    for ph in photon_list:
        for n in (1, 2, 8, 32, 128, 512):
            a = projected_rate(n, r1[ph], cost, 50)
            b = projected_rate(n, r1[ph], cost, 1000)
            lines.append(f"| {ph:,} | {r1[ph]:.0f} | {n} | {a:,.0f} | {b:,.0f} | {b * pulse_bytes / 2**20:.2f} MiB/s |")
    sat = {ph: 1000 / (cost * r1[ph]) for ph in photon_list}
    lines += [
        "",
        "The scheduler saturates at `N = B / (c r)` workers: " + ", ".join(
            f"{sat[ph]:,.0f} at {ph:,} photons/pulse (B = 1,000)" for ph in photon_list) + "; larger batches push "
        "it further (fewer tasks), at the cost of coarser resume and progress.",
        "",
        "## 3. A flight line end to end",
        "",
        f"{args.line_pulses:,} pulses (a {line.trajectory.legs[0].length_m:.1f} m line, field of view "
        f"{line_fov:.2f} deg) at {args.line_photons} photons per pulse (a cheap count, chosen so the run takes "
        f"minutes), tasks of {args.line_batch}, a fresh local cluster of 2 workers:",
        "",
        "| step | seconds |",
        "|---|---:|",
        f"| cluster start + simulate + write {len(line.ranges())} batch files | {line_run.seconds:.1f} |",
        f"| read back and concatenate (`load_survey`) | {t_read:.1f} |",
        f"| total | {t_line:.1f} |",
        "",
        f"{args.line_pulses / line_run.seconds:.0f} pulses/s end to end; {disk / 2**20:.1f} MiB of batch files "
        f"({pulse_bytes:.0f} bytes/pulse); waveforms of up to {wf.waveform.shape[1]} samples "
        f"({wf.bin_ns:.3f} ns); {np.mean(wf.energy > 0):.1%} of the pulses returned energy. LAS 1.4: {las_note}.",
        "",
    ]
    write_page(args.out, lines)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
