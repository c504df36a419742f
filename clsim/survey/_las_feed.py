"""The survey's LAS written as its batches finish, in pulse order, in bounded memory.

:func:`las_layout` fixes from the job alone what every batch of the file must
share: the samples per waveform packet (the longest record any pulse of the
job can have), the digitiser gain (from the strongest return physics allows)
and the coordinate offsets.  :class:`LasFeed` appends each finished batch of
``OUT/batches`` to a :class:`~clsim.survey._las_writer.SurveyLasWriter` in
pulse order (a batch that finishes early waits on disk for the ones before
it), keeps the echoes it found beside the batch
(``{a:09d}-{b:09d}.echoes.npz``), and renames the file onto ``survey.las``
when the last batch is in.  A stopped run leaves the batches and their echoes;
the next run rebuilds the LAS from them (reading, not decomposing) and goes
on, so a resumed survey's file is the same bytes as an uninterrupted one's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from clsim.errors import InputError

__all__ = ["LasFeed", "LasLayout", "las_layout"]

#: Pulses whose record windows are measured at a time by :func:`las_layout`.
_LAYOUT_CHUNK = 100_000
#: Samples added to the longest window (the sample clock's flooring, the fine bins' edges).
_WINDOW_SLACK = 6
#: Headroom of the gain over a white Lambertian surface at the nearest range: the hot spot
#: doubles single scattering at most.
_GAIN_HEADROOM = 2.0


@dataclass(frozen=True)
class LasLayout:
    """What every batch of a survey's LAS shares: ``n_samples`` per packet, ``gain`` (waveform
    units per count, offset 0) and the header's coordinate ``offsets``, m."""

    n_samples: int
    gain: float
    offsets: tuple


def las_layout(job, bits: int = 16) -> LasLayout:
    """The :class:`LasLayout` of ``job`` (a :class:`clsim.survey.SurveyJob`), from its geometry.

    - ``n_samples``: the longest record of any of its pulses (the simulator's window: scene box
      and ground, two pulse widths each side, the box's diagonal for orders above 1), measured
      over every pulse in chunks, plus a few samples.
    - ``gain``: twice the peak power a white Lambertian surface facing the sensor at the nearest
      range would return, ``2 A / (pi R^2) / (sigma sqrt(2 pi))`` (aperture area ``A``, pulse
      sigma in ns), mapped to the top count: no return of the simulator's physics clips (a
      clipped sample is counted and reported all the same).
    - ``offsets``: the floor of the scene grid's lower corner.
    """
    from clsim.scenes import load_scene
    from clsim.survey._las_writer import quantiser
    from clsim.transport.first_order import window_ns

    scene = load_scene(job.scene_path)
    lo = np.asarray(scene.origin, dtype=np.float64)
    hi = lo + scene.voxel_size * np.asarray(scene.shape)
    ground = getattr(scene, "ground_z", None)
    sensor = job.sensor
    period = 1.0 / sensor.sampling_ghz
    longest = 0.0
    end = job.first + job.count
    for a in range(job.first, end, _LAYOUT_CHUNK):
        p = job.pulses(a, min(a + _LAYOUT_CHUNK, end))
        t_start, t_end = window_ns(lo, hi, ground, p.position, p.target, sensor.pulse_fwhm_ns, job.max_order)
        longest = max(longest, float((t_end - t_start).max()))
    n_samples = int(math.ceil(longest / period + 2.0 * job.bin_ns / period)) + _WINDOW_SLACK
    top = max(hi[2], ground if ground is not None else -np.inf)
    z_min = min(min(g.start[2], g.end[2]) for g in job.trajectory.legs)
    r_min = z_min - top
    if not r_min > 0:
        raise InputError(f"the flight (lowest at z = {z_min:g} m) is not above the scene (top {top:g} m); "
                         "raise its altitude")
    peak = _GAIN_HEADROOM * sensor.aperture_area_m2 / (math.pi * r_min**2) / (
        sensor.pulse_sigma_ns * math.sqrt(2.0 * math.pi))
    dtype, _, _ = quantiser(int(bits), 1.0, 0.0)
    gain = peak / float(np.iinfo(dtype).max)
    return LasLayout(n_samples=n_samples, gain=gain, offsets=tuple(float(v) for v in np.floor(lo)))


def echoes_path(out_dir, a: int, b: int) -> Path:
    """``OUT/batches/{a:09d}-{b:09d}.echoes.npz``: the returns found in batch ``[a, b)``."""
    from clsim.survey.distributed import batch_path

    return batch_path(out_dir, a, b).with_suffix(".echoes.npz")


class LasFeed:
    """Append the finished batches of ``job`` in ``out_dir`` to ``las_path`` in pulse order.

    Call :meth:`drain` whenever a batch may have finished; :meth:`finish` closes the file when
    every batch is in (renamed onto ``las_path``) and otherwise removes the partial one.
    """

    def __init__(self, job, out_dir, las_path, *, device=None):
        from clsim.survey._las_writer import SurveyLasWriter

        self.job, self.out_dir, self.path = job, Path(out_dir), Path(las_path)
        self.ranges = job.ranges()
        self.layout = las_layout(job)
        for stale in self.path.parent.glob(f".{self.path.stem}.partial-*"):   # left by a killed run
            stale.unlink(missing_ok=True)
        self.writer = SurveyLasWriter(self.path, job.sensor, n_samples=self.layout.n_samples,
                                      bin_ns=1.0 / job.sensor.sampling_ghz, gain=self.layout.gain, offset=0.0,
                                      offsets=self.layout.offsets, device=device)
        self.key = self.writer.echo_key()
        self.next = 0
        self.reused = 0

    @property
    def pulses(self) -> int:
        return self.writer.pulses

    def drain(self) -> int:
        """Append every batch that is on disk and next in order; the pulses appended."""
        from clsim.survey._las_writer import Echoes
        from clsim.survey.distributed import batch_path
        from clsim.transport.result import PulseWaveforms

        before = self.writer.pulses
        while self.next < len(self.ranges):
            a, b = self.ranges[self.next]
            path = batch_path(self.out_dir, a, b)
            if not path.is_file():
                break
            wf = PulseWaveforms.load(path)
            cache = echoes_path(self.out_dir, a, b)
            found = Echoes.load(cache, self.key) if cache.is_file() else None
            echoes = self.writer.append(self.job.pulses(a, b), wf.waveform, wf.t0_ns, echoes=found)
            if found is None:
                echoes.save(cache, self.key)
            else:
                self.reused += 1
            self.next += 1
        return self.writer.pulses - before

    @property
    def complete(self) -> bool:
        return self.next == len(self.ranges)

    def finish(self) -> tuple[Path, Path] | None:
        """(las, wdp) when every batch is in, else None (the partial file removed)."""
        if self.complete:
            return self.writer.close()
        self.writer.abort()
        return None

    def abort(self) -> None:
        self.writer.abort()
