"""HELIOS++ full-waveform text output (``*_fullwave.txt``): reader and writer.

HELIOS++ (Winiwarter et al. 2022) writes one line per pulse that hit
something, whitespace-separated, with no header::

    index  ox oy oz  dx dy dz  min_time max_time  gps_time  s_0 s_1 ... s_(n-1)

``index`` is the pulse's full-waveform index (the ``fullwaveIndex`` column of
its point output, which ties each return to its waveform); ``o`` the beam
origin and ``d`` its unit direction (scene frame, metres); ``min_time`` and
``max_time`` the times of the first and last sample, ns; ``gps_time`` in
seconds; then the ``n`` samples (received power, arbitrary units). The layout
is that of HELIOS++'s ``DirectFullWaveformWriteStrategy`` (read in its source,
``src/filems/write/strategies``): origin, direction and times with 4
decimals, the GPS time with 9.

Time axis (HELIOS++'s ``ScanningDevice::initializeFullWaveform``): the
samples are ``binSize_ns`` apart, ``max_time = min_time + (n - 1) binSize``,
and a time is the *one-way* travel time to the target, ``distance / c``
(HELIOS++ bins each hit at ``distance / c``), so the sample at time ``t`` lies
at ``o + c t d``. :meth:`HeliosFullwave.sample_geometry` gives that line in
the form the other readers give it (the first sample's position and the
metres per ns along the beam), so echoes decomposed from these waveforms are
placed where HELIOS++ placed its hits.

Examples
--------
>>> import io, numpy as np
>>> text = "7 0.0 0.0 100.0 0.0 0.0 -1.0 300.0 304.0 12.5 0 1 4 1 0\\n"
>>> fw = read_helios_fullwave(io.StringIO(text))
>>> fw.index.tolist(), fw.dt_ns.tolist(), fw.samples[0].tolist()
([7], [1.0], [0.0, 1.0, 4.0, 1.0, 0.0])
>>> start, per_ns = fw.sample_geometry(0)
>>> np.round(start, 2).tolist(), np.round(per_ns, 4).tolist()
([0.0, 0.0, 10.06], [0.0, 0.0, -0.2998])

References
----------
Winiwarter, L., Esmorís Pena, A. M., Weiser, H., Anders, K., Martínez Sánchez, J.,
    Searle, M. & Höfle, B. (2022). Virtual laser scanning with HELIOS++: a novel
    take on ray tracing-based simulation of topographic full-waveform 3D laser
    scanning. Remote Sensing of Environment 269, 112772.
    doi:10.1016/j.rse.2021.112772
"""

from __future__ import annotations

import io
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from clsim.errors import InputError

__all__ = ["C_M_PER_NS", "HeliosFullwave", "read_helios_fullwave", "write_helios_fullwave"]

#: speed of light, metres per ns (HELIOS++'s SPEEDofLIGHT_mPerNanosec)
C_M_PER_NS = 0.299792458

#: values a line holds before its samples
_HEAD = 10


@dataclass
class HeliosFullwave:
    """The pulses of a HELIOS++ full-waveform file, one entry per line.

    Attributes
    ----------
    index : (N,) int64
        Full-waveform index of each pulse (its points' ``fullwaveIndex``).
    origin, direction : (N, 3) float64
        Beam origin (metres) and unit direction.
    min_time_ns, max_time_ns : (N,) float64
        Times of the first and the last sample (one-way travel time, ns).
    gps_time : (N,) float64
        Seconds.
    samples : list of (n_i,) float64
    """

    index: np.ndarray
    origin: np.ndarray
    direction: np.ndarray
    min_time_ns: np.ndarray
    max_time_ns: np.ndarray
    gps_time: np.ndarray
    samples: list

    def __len__(self) -> int:
        return len(self.samples)

    @property
    def dt_ns(self) -> np.ndarray:
        """Sample spacing of each pulse, ns (``(max - min) / (n - 1)``; 0 for a single sample)."""
        n = np.array([len(s) for s in self.samples], dtype=float)
        return np.where(n > 1, (self.max_time_ns - self.min_time_ns) / np.maximum(n - 1, 1), 0.0)

    def sample_geometry(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """Pulse ``i``'s first sample position and the metres per ns along its beam (one-way time)."""
        d = self.direction[i]
        return self.origin[i] + C_M_PER_NS * self.min_time_ns[i] * d, C_M_PER_NS * d


def _lines(source):
    if hasattr(source, "read"):  # an open text stream
        return source.read().splitlines(), "<text>"
    path = Path(source)
    if not path.is_file():
        raise InputError(f"HELIOS++ full-waveform file {str(path)!r} does not exist")
    try:
        return path.read_text(encoding="ascii").splitlines(), path.name
    except UnicodeDecodeError:
        raise InputError(f"{path.name} is not a HELIOS++ full-waveform text file (not ASCII text)") from None


def read_helios_fullwave(source: str | os.PathLike | io.TextIOBase) -> HeliosFullwave:
    """Read a HELIOS++ ``*_fullwave.txt`` (module docstring).

    Raises
    ------
    InputError
        No such file; a line with fewer than 11 values, a value that is not a
        number or not finite, a direction that is not a unit vector, times that
        run backwards; no line at all. The message names the line.
    """
    lines, name = _lines(source)
    rows = []
    for k, line in enumerate(lines, start=1):
        cells = line.split()
        if not cells:
            continue
        try:
            vals = np.array([float(c) for c in cells])
        except ValueError:
            bad = next(c for c in cells if not _is_number(c))
            raise InputError(f"{name}: line {k} holds {bad[:20]!r}, not a number; a HELIOS++ full-waveform line "
                             "is: index, origin (3), direction (3), min and max time (ns), GPS time (s), "
                             "samples") from None
        if vals.size < _HEAD + 1:
            raise InputError(f"{name}: line {k} has {vals.size} values; a HELIOS++ full-waveform line has "
                             f"{_HEAD} before its samples and at least one sample (truncated file?)")
        if not np.isfinite(vals).all():
            raise InputError(f"{name}: line {k} holds NaN or inf; re-export the run")
        norm = float(np.linalg.norm(vals[4:7]))
        if abs(norm - 1.0) > 1e-3:
            raise InputError(f"{name}: line {k}: the beam direction ({', '.join(f'{v:g}' for v in vals[4:7])}) "
                             f"has length {norm:.4g}, not 1; is this a HELIOS++ full-waveform file?")
        if vals[8] < vals[7]:
            raise InputError(f"{name}: line {k}: max time {vals[8]:g} ns is before min time {vals[7]:g} ns")
        if vals[0] != np.round(vals[0]):
            raise InputError(f"{name}: line {k}: the full-waveform index {cells[0]!r} is not an integer")
        rows.append(vals)
    if not rows:
        raise InputError(f"{name}: no full-waveform lines (an empty file: did the HELIOS++ run hit anything, with "
                         "writeWaveform enabled?)")
    head = np.array([r[:_HEAD] for r in rows])
    d = head[:, 4:7]
    return HeliosFullwave(index=head[:, 0].astype(np.int64), origin=head[:, 1:4].copy(),
                          direction=d / np.linalg.norm(d, axis=1, keepdims=True), min_time_ns=head[:, 7].copy(),
                          max_time_ns=head[:, 8].copy(), gps_time=head[:, 9].copy(),
                          samples=[r[_HEAD:].copy() for r in rows])


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def write_helios_fullwave(path: str | os.PathLike, data: HeliosFullwave) -> Path:
    """Write ``data`` in HELIOS++'s full-waveform layout (atomically; the same decimals as HELIOS++)."""
    from voxlidar.safeio import atomic_write

    def write(tmp):
        with open(tmp, "w", encoding="ascii") as fh:
            for i in range(len(data)):
                head = [f"{int(data.index[i])}"] + [f"{v:.4f}" for v in (*data.origin[i], *data.direction[i],
                                                                         data.min_time_ns[i], data.max_time_ns[i])]
                head.append(f"{data.gps_time[i]:.9f}")
                fh.write(" ".join(head + [f"{float(v):.9f}" for v in data.samples[i]]) + "\n")

    return atomic_write(path, write)
