"""Run a survey's pulses in batches: a direct loop, or Dask distributed.

A :class:`SurveyJob` holds the few numbers that define every pulse (the
trajectory, scan pattern, sensor, seed, photons per pulse) and the path of the
scene file.  A batch is a pulse range ``[a, b)``: its worker rebuilds those
pulses with ``survey_pulses(first=a, count=b - a)``, simulates them with
:meth:`clsim.Simulator.run_pulses` (each pulse with its own seed, so the
result does not depend on the batching or on which worker ran it) and writes
``OUT/batches/{a:09d}-{b:09d}.npz`` atomically.  The driver skips batches
already on disk, so a run that was stopped resumes where it left off.

Each worker process (or thread) opens its own :class:`clsim.Simulator` (OpenCL
context, device, built kernel) and loads the scene once, then keeps them for
every batch it runs; tasks carry no arrays.

Examples
--------
>>> import tempfile, pathlib
>>> from clsim import Sensor
>>> from clsim.survey import ScanPattern, Trajectory
>>> from clsim.validation.testscenes import homogeneous_layer
>>> tmp = pathlib.Path(tempfile.mkdtemp())
>>> scene = homogeneous_layer(width=4.0, thickness=1.0).save(tmp / "scene.npz")
>>> job = SurveyJob(scene_path=str(scene), trajectory=Trajectory.line((-1, 0), (1, 0), altitude_m=300.0,
...                 speed_mps=50.0), pattern=ScanPattern(pulse_rate_hz=200.0, scan_rate_hz=5.0, fov_deg=0.5),
...                 sensor=Sensor.preset("riegl-lms-q680i"), photons=500, count=6, batch_size=4)
>>> job.ranges()
[(0, 4), (4, 6)]
>>> run = run_survey(job, tmp / "out", direct=True, progress=False)
>>> run.computed, load_survey(tmp / "out").waveform.shape[0]
(2, 6)
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import math
import os
import re
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path

from clsim.errors import InputError
from clsim.sensor import Sensor
from clsim.survey._pattern import ScanPattern
from clsim.survey._pulses import Pulses, pulse_range, survey_pulses
from clsim.survey._trajectory import Trajectory
from clsim.transport.result import PulseWaveforms
from voxlidar.safeio import atomic_write, json_text

__all__ = ["SurveyJob", "SurveyRun", "batch_path", "completed_batches", "load_survey", "projected_rate",
           "run_survey", "simulate_batch"]

#: File name of a finished batch (pulses a .. b-1).
BATCH_RE = re.compile(r"^(\d{9})-(\d{9})\.npz$")


def batch_path(out_dir, a: int, b: int) -> Path:
    """``OUT/batches/{a:09d}-{b:09d}.npz``: where the batch of pulses ``[a, b)`` is written."""
    return Path(out_dir) / "batches" / f"{a:09d}-{b:09d}.npz"


def _sha256(path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


@dataclass(frozen=True)
class SurveyJob:
    """A survey run: which pulses, over which scene, with what simulation settings.

    Parameters
    ----------
    scene_path : str
        Scene NPZ (:meth:`voxlidar.scene.Scene.save`); each worker loads it once.
    trajectory : Trajectory
    pattern : ScanPattern
    sensor : Sensor
        The instrument (its angles and altitude are set per pulse).
    photons : int
        Photons per pulse.
    first, count : int
        The pulses ``first .. first + count - 1`` of the trajectory (default:
        every pulse from ``first`` on).
    seed : int
        Base seed: pulse ``k`` gets ``seed + k``.
    ground_z : float
        Height of the flat ground the beams are aimed at, metres (default: the
        scene's ``ground_z``, else the bottom of its grid).
    batch_size : int
        Pulses per task and per file.
    max_order, mode, detect, batches, bin_ns, hotspot, leaf_off, first_order, beam_samples
        As :meth:`clsim.Simulator.run_pulses`.
    device : str, optional
        OpenCL device spec each worker opens (default: its ``VOXLIDAR_DEVICE``
        or best device).  Waveforms are bit-identical only on the same device
        and runtime.
    """

    scene_path: str
    trajectory: Trajectory
    pattern: ScanPattern
    sensor: Sensor
    photons: int
    first: int = 0
    count: int | None = None
    seed: int = 0
    ground_z: float | None = None
    batch_size: int = 256
    max_order: int = 3
    mode: str = "exact"
    detect: str = "nee"
    batches: int = 1
    bin_ns: float = 0.05
    hotspot: bool = False
    leaf_off: bool = False
    device: str | None = None
    first_order: str = "mc"
    beam_samples: int = 19

    def __post_init__(self):
        if not isinstance(self.trajectory, Trajectory):
            raise InputError(f"trajectory must be a clsim.survey.Trajectory, got {type(self.trajectory).__name__}")
        if not isinstance(self.pattern, ScanPattern):
            raise InputError(f"pattern must be a clsim.survey.ScanPattern, got {type(self.pattern).__name__}")
        if not isinstance(self.sensor, Sensor):
            raise InputError(f"sensor must be a clsim.Sensor, got {type(self.sensor).__name__}")
        path = Path(self.scene_path)
        if not path.is_file():
            raise InputError(f"scene file {str(path)!r} does not exist; write one with Scene.save(path)")
        object.__setattr__(self, "scene_path", str(path.resolve()))
        if self.first_order not in ("mc", "deterministic"):
            raise InputError(f"first_order must be 'mc' or 'deterministic', got {self.first_order!r}")
        for name, lo in (("photons", 1), ("batch_size", 1), ("beam_samples", 1)):
            v = getattr(self, name)
            if not isinstance(v, int) or isinstance(v, bool) or v < lo:
                raise InputError(f"{name} must be an integer >= {lo}, got {v!r}")
        first, count = pulse_range(self.pattern, self.trajectory, self.first, self.count, None, None)
        if count < 1:
            raise InputError(f"the survey has no pulses (first={self.first!r}, count={self.count!r}); "
                             "fix: a longer trajectory or a larger count")
        object.__setattr__(self, "first", first)
        object.__setattr__(self, "count", count)
        if self.ground_z is None:
            from clsim.scenes import load_scene

            scene = load_scene(path)
            g = scene.ground_z if scene.ground_z is not None else float(scene.origin[2])
            object.__setattr__(self, "ground_z", float(g))

    def ranges(self) -> list[tuple[int, int]]:
        """The batches: ``[(a, b), ...]`` pulse ranges of at most ``batch_size``."""
        end = self.first + self.count
        return [(a, min(a + self.batch_size, end)) for a in range(self.first, end, self.batch_size)]

    def pulses(self, a: int | None = None, b: int | None = None) -> Pulses:
        """The pulses ``[a, b)`` (default: all of the job's), rebuilt from the geometry."""
        a = self.first if a is None else int(a)
        b = self.first + self.count if b is None else int(b)
        return survey_pulses(self.trajectory, self.pattern, self.sensor, first=a, count=b - a,
                             ground=self.ground_z, seed=self.seed)

    def run_options(self) -> dict:
        opts = dict(photons=self.photons, max_order=self.max_order, mode=self.mode, detect=self.detect,
                    batches=self.batches, bin_ns=self.bin_ns, hotspot=self.hotspot, leaf_off=self.leaf_off)
        if self.first_order != "mc":  # the same survey.json as before for Monte Carlo surveys (resume)
            opts.update(first_order=self.first_order, beam_samples=self.beam_samples)
        return opts

    def to_dict(self) -> dict:
        """Plain data (JSON) naming every input of the output, the scene by its SHA-256."""
        return dict(
            scene_path=self.scene_path, scene_sha256=_sha256(self.scene_path),
            legs=[dict(start=list(g.start), end=list(g.end), speed_mps=g.speed_mps) for g in self.trajectory.legs],
            pattern={k: (v.value if hasattr(v, "value") else v) for k, v in dataclasses.asdict(self.pattern).items()},
            sensor=self.sensor.to_dict(), first=self.first, count=self.count, seed=int(self.seed),
            ground_z=self.ground_z, batch_size=self.batch_size, **self.run_options())


@dataclass
class SurveyRun:
    """What :func:`run_survey` did.

    Attributes
    ----------
    n_batches : int
        Batches of the job.
    skipped : int
        Batches already on disk (resumed).
    computed : int
        Batches computed by this call.
    pulses : int
        Pulses computed by this call.
    seconds : float
        Wall time of the call (including starting a cluster).
    workers : int
        Workers used (1 for the direct loop).
    finished : bool
        Whether every batch of the job is on disk.
    task_seconds : list of float
        Per batch computed: seconds the worker spent in it.
    las : tuple of Path or None
        ``(las, wdp)`` written by ``run_survey(..., las=PATH)`` when every batch is in.
    las_points, las_clipped : int
        Points written to the LAS and samples clipped by its digitiser (0 without ``las``).
    """

    n_batches: int
    skipped: int
    computed: int
    pulses: int
    seconds: float
    workers: int
    finished: bool
    task_seconds: list
    las: tuple | None = None
    las_points: int = 0
    las_clipped: int = 0


# -- the worker side ----------------------------------------------------------------
_LOCAL = threading.local()
_MALLOC_RELAXED = False


def _relax_malloc() -> None:
    """Undo what ``MALLOC_TRIM_THRESHOLD_`` does to a Dask worker's allocator.

    Dask's nanny starts workers with ``MALLOC_TRIM_THRESHOLD_=65536``; setting
    it freezes glibc's mmap threshold at 128 KiB, so every tally and waveform
    array of a pulse is mapped and unmapped afresh (page faults each time):
    measured 1.8 times the host time per pulse.  ``mallopt`` gives them room
    on the heap again (mmap above 32 MiB, trim above 128 MiB).  Linux/glibc
    only; elsewhere nothing is done."""
    global _MALLOC_RELAXED
    if _MALLOC_RELAXED or "MALLOC_TRIM_THRESHOLD_" not in os.environ or not sys.platform.startswith("linux"):
        return
    _MALLOC_RELAXED = True
    try:
        import ctypes

        libc = ctypes.CDLL("libc.so.6")
        libc.mallopt(-3, 32 << 20)     # M_MMAP_THRESHOLD
        libc.mallopt(-1, 128 << 20)    # M_TRIM_THRESHOLD
    except (OSError, AttributeError):  # not glibc: leave the allocator as it is
        pass


def _worker_state(job: SurveyJob, simulator=None):
    """(Simulator, scene, scene set-up) of this process/thread, opened once and reused."""
    from clsim.scenes import load_scene
    from clsim.transport.setup import prepare_scene

    state = getattr(_LOCAL, "state", None)
    if state is None:
        _relax_malloc()
        state = _LOCAL.state = {}
    if simulator is not None:
        sim = simulator
    else:
        sim = state.get(("sim", job.device))
        if sim is None:
            from clsim.transport.simulator import Simulator

            sim = state[("sim", job.device)] = Simulator(job.device)
    st = os.stat(job.scene_path)
    key = ("scene", job.scene_path, st.st_mtime_ns, st.st_size, job.sensor.wavelength_nm, job.leaf_off)
    if key not in state:
        for k in [k for k in state if k[0] == "scene"]:   # one scene at a time
            del state[k]
        scene = load_scene(job.scene_path)
        state[key] = (scene, prepare_scene(scene, wavelength_nm=job.sensor.wavelength_nm, leaf_off=job.leaf_off))
    scene, setup = state[key]
    return sim, scene, setup


def simulate_batch(job: SurveyJob, a: int, b: int, out_dir, simulator=None) -> dict:
    """Simulate pulses ``[a, b)`` of ``job`` and write their :class:`PulseWaveforms` to
    :func:`batch_path` atomically.  Runs on a worker (or in the driver's loop).

    Returns
    -------
    dict
        ``a``, ``b``, ``seconds`` (the whole task), ``kernel_s``, ``nbytes`` (the file).
    """
    t0 = time.perf_counter()
    sim, scene, setup = _worker_state(job, simulator)
    pulses = job.pulses(a, b)
    wf = sim.run_pulses(scene, pulses, job.sensor, scene_setup=setup, **job.run_options())
    path = wf.save(batch_path(out_dir, a, b))
    return dict(a=a, b=b, seconds=time.perf_counter() - t0, kernel_s=wf.kernel_s, nbytes=path.stat().st_size,
                pid=os.getpid())


# -- the driver ---------------------------------------------------------------------
def completed_batches(out_dir) -> set[tuple[int, int]]:
    """The pulse ranges whose batch file is in ``OUT/batches``."""
    folder = Path(out_dir) / "batches"
    if not folder.is_dir():
        return set()
    done = set()
    for p in folder.iterdir():
        m = BATCH_RE.match(p.name)
        if m:
            done.add((int(m.group(1)), int(m.group(2))))
    return done


def _claim_out_dir(job: SurveyJob, out_dir: Path) -> None:
    """Write ``OUT/survey.json`` or check that the one there describes the same job."""
    spec = job.to_dict()
    path = out_dir / "survey.json"
    if path.exists():
        try:
            old = json.loads(path.read_text())
        except (OSError, ValueError) as err:
            raise InputError(f"{path} is unreadable ({err}); fix: delete it (and the batches) or choose "
                             "another output folder") from err
        keys = sorted(k for k in set(old) | set(spec) if k != "scene_path" and old.get(k) != spec.get(k))
        if keys:
            raise InputError(f"{out_dir} holds another survey (differs in {', '.join(keys)}); fix: another "
                             "output folder, or delete it to start over")
        return

    def write(tmp):
        Path(tmp).write_text(json_text(spec))

    atomic_write(path, write)


def _cluster(workers: int, scheduler: str | None):
    """(client, cluster or None, number of workers)."""
    try:
        from dask.distributed import Client, LocalCluster
    except ImportError as err:
        raise InputError("dask.distributed is not installed; fix: pip install 'voxlidar[survey]', or run "
                         "the direct loop (direct=True, clsim survey --workers 0)") from err
    if scheduler:
        try:
            client = Client(scheduler, timeout="20s")
        except (OSError, TimeoutError) as err:
            raise InputError(f"cannot reach the Dask scheduler at {scheduler!r}: {err}; fix: start it "
                             "(dask scheduler) or leave --scheduler out for a local cluster") from err
        n = len(client.scheduler_info().get("workers", {}))
        if n < 1:
            client.wait_for_workers(1, timeout=60)
            n = len(client.scheduler_info().get("workers", {}))
        return client, None, max(1, n)
    cluster = LocalCluster(n_workers=int(workers), threads_per_worker=1, processes=True,
                           dashboard_address=":0", scheduler_port=0, silence_logs=logging.ERROR)
    return Client(cluster), cluster, int(workers)


def run_survey(job: SurveyJob, out_dir, *, workers: int = 1, scheduler: str | None = None,
               direct: bool = False, in_flight: int = 2, progress: bool = True,
               stop_after: int | None = None, simulator=None, client=None, las=None) -> SurveyRun:
    """Simulate every batch of ``job`` not yet in ``out_dir/batches``.

    Parameters
    ----------
    job : SurveyJob
    out_dir : path
        Gets ``survey.json`` (the job; a folder holding another job is refused)
        and ``batches/{a:09d}-{b:09d}.npz``.
    workers : int
        Worker processes of the local cluster (one thread each).  They are
        started with ``spawn``: a script that calls this must guard its main
        code with ``if __name__ == "__main__":``.
    scheduler : str, optional
        Address of a running Dask scheduler (``tcp://host:8786``) instead of a
        local cluster; its workers need voxlidar and the scene file at the
        same path.
    direct : bool
        A plain loop in this process, no Dask (same files, bit for bit).
    in_flight : int
        Tasks submitted per worker at a time (bounds the driver's memory).
    progress : bool
        A tqdm bar over pulses.
    stop_after : int, optional
        Stop after this many batches are computed (an interrupted run, for tests).
    simulator : Simulator, optional
        Used by the direct loop (default: one opened for this thread).
    client : dask.distributed.Client, optional
        An open client to use (not closed here).
    las : path, optional
        Write the waveforms and their returns to this LAS 1.4 file (with its ``.wdp``) as the
        batches finish, in pulse order, in memory bounded by a batch
        (:mod:`clsim.survey._las_feed`); it appears under its name when every batch is in.  The
        echoes of each batch are kept beside it, so a resumed run rebuilds the file from the
        batches on disk without decomposing them again, to the same bytes.
    """
    out_dir = Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise InputError(f"output folder {out_dir} is a file; fix: give a folder")
    if not isinstance(in_flight, int) or in_flight < 1:
        raise InputError(f"in_flight must be an integer >= 1, got {in_flight!r}")
    if not direct and client is None and scheduler is None and (not isinstance(workers, int) or workers < 1):
        raise InputError(f"workers must be an integer >= 1, got {workers!r} (or use the direct loop)")
    out_dir.mkdir(parents=True, exist_ok=True)
    _claim_out_dir(job, out_dir)
    (out_dir / "batches").mkdir(exist_ok=True)
    for stale in (out_dir / "batches").glob(".*.tmp-*"):     # left by a killed run
        stale.unlink(missing_ok=True)
    ranges = job.ranges()
    done = completed_batches(out_dir)
    todo = [r for r in ranges if r not in done]
    limit = len(todo) if stop_after is None else min(len(todo), int(stop_after))
    t0 = time.perf_counter()
    feed = None
    if las is not None:
        from clsim.survey._las_feed import LasFeed

        feed = LasFeed(job, out_dir, las, device=job.device)
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=job.count, initial=job.count - sum(b - a for a, b in todo), unit="pulse",
                   unit_scale=True, desc="survey", smoothing=0.1)
    task_s, n_workers, written = [], 1, None
    try:
        if direct:
            for a, b in todo[:limit]:
                info = simulate_batch(job, a, b, out_dir, simulator)
                task_s.append(info["seconds"])
                if bar is not None:
                    bar.update(b - a)
                _drain(feed, bar)
        else:
            own = client is None
            cluster = None
            if own:
                client, cluster, n_workers = _cluster(workers, scheduler)
            else:
                n_workers = max(1, len(client.scheduler_info().get("workers", {})))
            try:
                task_s = _run_dask(client, job, out_dir, todo[:limit], n_workers * in_flight, bar, feed)
            finally:
                if own:
                    client.close()
                    if cluster is not None:
                        cluster.close()
        if feed is not None:
            _drain(feed, bar)
            written = feed.finish()
    except BaseException:
        if feed is not None:
            feed.abort()
        raise
    finally:
        if bar is not None:
            bar.close()
    finished = completed_batches(out_dir) >= set(ranges)
    return SurveyRun(n_batches=len(ranges), skipped=len(ranges) - len(todo), computed=len(task_s),
                     pulses=sum(b - a for a, b in todo[:len(task_s)]), seconds=time.perf_counter() - t0,
                     workers=n_workers, finished=finished, task_seconds=task_s, las=written,
                     las_points=feed.writer.points if feed is not None else 0,
                     las_clipped=feed.writer.clipped if feed is not None else 0)


def _drain(feed, bar) -> None:
    """Append the batches now ready to the LAS; the bar says how far the file is."""
    if feed is not None and feed.drain() and bar is not None:
        bar.set_postfix_str(f"LAS {feed.pulses:,} pulses", refresh=False)


def _run_dask(client, job, out_dir, todo, max_in_flight: int, bar, feed=None) -> list:
    """Submit ``todo`` with at most ``max_in_flight`` tasks out at once; the workers' seconds per task."""
    from dask.distributed import as_completed

    pending = iter(todo)
    out = str(out_dir)

    def submit(r):
        a, b = r
        return client.submit(simulate_batch, job, a, b, out, key=f"clsim-batch-{a}-{b}-{job.seed}", pure=False,
                             retries=1)

    first = [submit(r) for _, r in zip(range(max_in_flight), pending)]
    seconds = []
    queue = as_completed(first)
    _drain(feed, bar)                                         # the batches of an earlier run, meanwhile
    for fut in queue:
        info = fut.result()                                   # a worker's error is raised here
        seconds.append(info["seconds"])
        if bar is not None:
            bar.update(info["b"] - info["a"])
        nxt = next(pending, None)
        if nxt is not None:
            queue.add(submit(nxt))
        _drain(feed, bar)
    return seconds


def load_survey(out_dir) -> PulseWaveforms:
    """Every batch of the survey in ``out_dir``, in pulse order, as one :class:`PulseWaveforms`.

    Raises
    ------
    InputError
        When batches are missing (the run has not finished: run it again to resume).
    """
    out_dir = Path(out_dir)
    path = out_dir / "survey.json"
    if not path.is_file():
        raise InputError(f"{out_dir} holds no survey (no survey.json); run clsim survey first")
    spec = json.loads(path.read_text())
    first, count, size = int(spec["first"]), int(spec["count"]), int(spec["batch_size"])
    ranges = [(a, min(a + size, first + count)) for a in range(first, first + count, size)]
    done = completed_batches(out_dir)
    missing = [r for r in ranges if r not in done]
    if missing:
        raise InputError(f"{out_dir}: {len(missing)} of {len(ranges)} batches missing (first: pulses "
                         f"{missing[0][0]}..{missing[0][1] - 1}); fix: run the survey again to resume")
    parts = [PulseWaveforms.load(batch_path(out_dir, a, b)) for a, b in ranges]
    return PulseWaveforms.concat(parts)


def projected_rate(n_workers, rate_per_worker: float, task_cost_s: float, batch_size: int) -> float:
    """Pulses/s of ``n_workers`` when each computes ``rate_per_worker`` and the scheduler spends
    ``task_cost_s`` per task of ``batch_size`` pulses, serially: ``min(N r, batch_size / c)``."""
    cap = batch_size / task_cost_s if task_cost_s > 0 else math.inf
    return min(n_workers * rate_per_worker, cap)
