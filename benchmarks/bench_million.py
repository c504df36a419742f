"""Benchmark: a million-pulse flight over the 30-tree plot, LAS 1.4 written as it goes, killed and resumed.

The plot of the survey tutorial (``make_plot(50.0, 30, seed=0, voxel_size=0.5)``, cached under
out/bench_cache), one line across it at the RIEGL LMS-Q680i preset's flying height, 20 m/s and
400 kHz, single scattering computed deterministically along ``--beam-samples`` directions per pulse
(``clsim survey --first-order deterministic --max-order 1``), ``--batch-size`` pulses per batch, the
direct loop (``--workers 0``).  Three runs of ``clsim survey`` as a user types it:

1. **whole**: uninterrupted; wall seconds, pulses/s, peak memory (``/usr/bin/time -v``), the sizes
   and SHA-256 of ``survey.las`` and ``survey.wdp``.
2. **killed**: the same command into another folder, SIGKILL when ``--kill-at`` of its batches are on
   disk (peak memory read from ``/proc`` just before).
3. **resumed**: the same command again into the killed folder; its files must be the very bytes of
   run 1.

    flock /tmp/voxlidar-bench.lock .venv/bin/python benchmarks/bench_million.py
    .venv/bin/python benchmarks/bench_million.py --pulses 100000 --out /tmp/million.md   # a quick look
"""

from __future__ import annotations

import argparse
import hashlib
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

from _bench import machine_line, write_page

ROOT = Path(__file__).resolve().parents[1]
CACHE = ROOT / "out" / "bench_cache"


def log(msg):
    print(f"[{time.strftime('%H:%M:%S')}] {msg}", flush=True)


def plot_scene() -> Path:
    path = CACHE / "plot30_seed0_0.5.npz"
    if not path.is_file():
        from clsim.scenes import make_plot

        CACHE.mkdir(parents=True, exist_ok=True)
        log("building the 30-tree plot (once)")
        make_plot(50.0, 30, seed=0, voxel_size=0.5).save(path)
    return path


def sha(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 22), b""):
            h.update(block)
    return h.hexdigest()


def timed(cmd, env) -> tuple[float, float, str]:
    """(wall s, peak RSS MiB, stderr) of ``cmd`` run to the end under /usr/bin/time -v."""
    t = time.perf_counter()
    p = subprocess.run(["/usr/bin/time", "-v", *cmd], env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t
    if p.returncode:
        sys.exit(f"bench_million: {' '.join(cmd)} failed:\n{p.stderr[-3000:]}")
    m = re.search(r"Maximum resident set size \(kbytes\): (\d+)", p.stderr)
    return wall, (int(m.group(1)) / 1024 if m else float("nan")), p.stderr


def batches(folder: Path) -> int:
    d = folder / "batches"
    return sum(1 for p in d.iterdir() if re.match(r"^\d{9}-\d{9}\.npz$", p.name)) if d.is_dir() else 0


def vm_hwm_mib(pid: int) -> float:
    try:
        text = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return float("nan")
    m = re.search(r"VmHWM:\s+(\d+) kB", text)
    return int(m.group(1)) / 1024 if m else float("nan")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pulses", type=int, default=1_000_000)
    ap.add_argument("--batch-size", type=int, default=10_000)
    ap.add_argument("--beam-samples", type=int, default=19)
    ap.add_argument("--kill-at", type=float, default=0.4, help="fraction of the batches on disk at the kill")
    ap.add_argument("--work", default=str(ROOT / "out" / "bench_million"), help="folder of the runs (emptied)")
    ap.add_argument("--keep", action="store_true", help="keep the runs' folders")
    ap.add_argument("--out", default=str(ROOT / "docs" / "bench" / "million.md"))
    args = ap.parse_args(argv)

    scene = plot_scene()
    work = Path(args.work)
    shutil.rmtree(work, ignore_errors=True)
    work.mkdir(parents=True)
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
    base = [sys.executable, "-m", "clsim.cli", "survey", str(scene), "--first-order", "deterministic",
            "--max-order", "1", "--beam-samples", str(args.beam_samples), "--pulses", str(args.pulses),
            "--pulse-rate", "400000", "--speed", "20", "--fov", "4.5", "--workers", "0", "--batch-size", str(args.batch_size),
            "--seed", "1", "-q"]
    n_batches = -(-args.pulses // args.batch_size)
    load0 = os.getloadavg()

    log(f"whole run: {args.pulses:,} pulses in {n_batches} batches")
    wall_whole, mem_whole, err = timed(base + ["-o", str(work / "whole")], env)
    las, wdp = work / "whole" / "survey.las", work / "whole" / "survey.wdp"
    sums = (sha(las), sha(wdp))
    sizes = (las.stat().st_size, wdp.stat().st_size)
    log(f"whole: {wall_whole:.1f} s, {args.pulses / wall_whole:,.0f} pulses/s, peak {mem_whole:.0f} MiB")

    log(f"killed run: SIGKILL at {args.kill_at:.0%} of the batches")
    kill_at = max(1, int(args.kill_at * n_batches))
    t = time.perf_counter()
    proc = subprocess.Popen(base + ["-o", str(work / "killed")], env=env, stderr=subprocess.DEVNULL)
    mem_killed = float("nan")
    while batches(work / "killed") < kill_at and proc.poll() is None:
        mem_killed = vm_hwm_mib(proc.pid)
        time.sleep(0.05)
    mem_killed = max(mem_killed, vm_hwm_mib(proc.pid))
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    wall_killed = time.perf_counter() - t
    done_at_kill = batches(work / "killed")
    if done_at_kill >= n_batches:
        sys.exit("bench_million: the run finished before the kill; lower --kill-at")
    log(f"killed after {wall_killed:.1f} s with {done_at_kill} of {n_batches} batches on disk")
    wall_resume, mem_resume, _ = timed(base + ["-o", str(work / "killed")], env)
    same = (sha(work / "killed" / "survey.las"), sha(work / "killed" / "survey.wdp")) == sums
    left = [p.name for p in (work / "killed").iterdir() if p.name.startswith(".")]
    log(f"resumed: {wall_resume:.1f} s, peak {mem_resume:.0f} MiB, same bytes: {same}, temporary files: {left}")
    load1 = os.getloadavg()

    import laspy

    with laspy.open(las) as f:
        n_points = f.header.point_count
    disk = sum(p.stat().st_size for p in (work / "whole" / "batches").iterdir())
    lines = [
        "# A million-pulse flight, LAS written as it goes",
        "",
        "Written by `benchmarks/bench_million.py` (the module's docstring says what each run does):",
        "",
        "    flock /tmp/voxlidar-bench.lock .venv/bin/python benchmarks/bench_million.py"
        + ("" if args.pulses == 1_000_000 else f" --pulses {args.pulses}"),
        "",
        machine_line(load0, load1),
        "",
        f"The 30-tree plot of the survey tutorial, {args.pulses:,} pulses of one line at 400 kHz and "
        f"20 m/s, a 4.5 degree field of view (the swath spans the plot), single scattering along {args.beam_samples} beam samples per pulse, batches of "
        f"{args.batch_size:,} pulses, the direct loop:",
        "",
        "    " + " ".join(["clsim", *base[3:]]).replace(str(scene), "plot30.npz") + " -o OUT",
        "",
        "| run | wall s | pulses/s | peak memory MiB | note |",
        "| --- | ---: | ---: | ---: | --- |",
        f"| whole | {wall_whole:.1f} | {args.pulses / wall_whole:,.0f} | {mem_whole:.0f} | "
        f"{n_points:,} points; survey.las {sizes[0] / 2**20:,.0f} MiB, survey.wdp {sizes[1] / 2**20:,.0f} MiB |",
        f"| killed (SIGKILL) | {wall_killed:.1f} | | {mem_killed:.0f} | {done_at_kill} of {n_batches} batches "
        "on disk at the kill |",
        f"| resumed | {wall_resume:.1f} | {(args.pulses - done_at_kill * args.batch_size) / wall_resume:,.0f} "
        f"(new pulses) | {mem_resume:.0f} | {'the same bytes as the whole run' if same else 'DIFFERENT bytes'} "
        f"(SHA-256 of both files); {len(left)} temporary files left |",
        "",
        f"Peak memory is bounded by a batch, not by the flight (goal: at most 2 GiB): "
        f"{max(mem_whole, mem_killed, mem_resume):.0f} MiB at most over the three runs.  The batch files "
        f"(the resume points, float64 waveforms and the echoes found) take {disk / 2**30:.2f} GiB on disk.",
    ]
    write_page(args.out, lines, echo=True)
    if not args.keep:
        shutil.rmtree(work, ignore_errors=True)
    return 0 if same and not left else 1


if __name__ == "__main__":
    sys.exit(main())
