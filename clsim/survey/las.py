"""A survey's simulated waveforms as LAS 1.4: waveform packets and discrete returns.

:func:`write_survey_las` writes point format 9 with the waveform packets in an
external ``.wdp`` (one packet per pulse, quantised to the digitiser's bits
with the gain and offset in the wave packet descriptor) and, as the points,
the returns found by decomposing every waveform (:func:`clsim.decompose_batch`,
the matched-filter detection of the sensor's pulse). :func:`read_survey_las`
reads it back: the waveforms per pulse with the position of each sample, and
the returns.

Time and space. A pulse leaves the platform at ``position`` along the unit
vector ``direction``; sample ``j`` of its waveform was recorded
``t0_ns + j * bin_ns`` after emission, so it lies (single scattering, the
simulator's vacuum speed of light ``c``) at
``position + c (t0_ns + j bin_ns) / 2 * direction``. A return found at
``tau`` ns after emission is the point ``position + c tau / 2 * direction``.
Each point stores the LAS waveform fields of its pulse's packet: descriptor
index 1, byte offset and size, the return point location ``L`` (ps from the
first sample) and ``x_t, y_t, z_t``, the displacement per ps pointing back to
the sensor, so that sample ``j`` lies at ``P + (L - j s) (x_t, y_t, z_t)``
with ``s`` the descriptor's spacing (LAS 1.3 R11 / 1.4 R15; the project's
reader :meth:`clsim.waveforms.io.LasWaveforms.sample_positions`).

The descriptor holds the spacing in whole picoseconds. When ``bin_ns`` is
not a whole number of ps (1.8 GHz: 555.56 ps) the spacing is rounded
(``s = 556``) and ``L`` and ``x_t, y_t, z_t`` are written in those digitiser
picoseconds: ``L = (tau - t0) / bin_ns * s`` and ``|(x_t, y_t, z_t)| = c
bin_ns / (2 s)`` (m per ps, off c/2 by the rounding, 0.08 % at 1.8 GHz), so
every sample and the return still lie where the geometry puts them; only the
time a reader infers from ``L`` and ``s`` carries the rounding.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from clsim.errors import InputError
from clsim.sensor import C_M_PER_NS, Sensor
from clsim.survey._las_writer import SCAN_ANGLE_STEP_DEG, SurveyLasWriter, quantiser
from voxlidar.errors import finite_number

__all__ = ["SurveyLas", "read_survey_las", "write_survey_las", "write_survey_pulsewaves"]

def _default_gain(w, bits, gain, offset):
    """(gain, offset): ``offset + gain * raw`` spans ``w`` unless given (the writer checks them)."""
    dtype, _, _ = quantiser(bits, 1.0, 0.0)
    top = float(np.iinfo(dtype).max)
    if offset is None:
        offset = min(0.0, float(w.min())) if w.size else 0.0
    offset = finite_number(offset, "offset")
    if gain is None:
        span = (float(w.max()) - offset) if w.size else 0.0
        gain = span / top if span > 0 else 1.0
    return gain, offset


def _check(pulses, waveforms, t0_ns, bin_ns, sensor):
    from clsim.survey._pulses import Pulses

    if not isinstance(pulses, Pulses):
        raise InputError(f"pulses must be a clsim.survey.Pulses (from survey_pulses); got "
                         f"{type(pulses).__name__}")
    if not isinstance(sensor, Sensor):
        raise InputError(f"sensor must be a clsim.Sensor (e.g. Sensor.preset(...)); got "
                         f"{type(sensor).__name__}")
    n = len(pulses)
    try:
        w = np.asarray(waveforms)                      # no float64 copy of a float32 survey
        t0 = np.asarray(t0_ns, dtype=np.float64)
    except (TypeError, ValueError) as err:
        raise InputError(f"waveforms and t0_ns must be arrays of numbers: {err}") from None
    if not (np.issubdtype(w.dtype, np.floating) or np.issubdtype(w.dtype, np.integer)):
        raise InputError(f"waveforms must be an array of numbers; got dtype {w.dtype}")
    if n == 0:
        raise InputError("no pulses to write; pass at least one pulse")
    if w.ndim != 2 or w.shape[0] != n or w.shape[1] < 4:
        raise InputError(f"waveforms must have shape (n_pulses, n_bins) = ({n}, >= 4), one row "
                         f"per pulse; got {w.shape}")
    if t0.shape not in ((), (n,)):
        raise InputError(f"t0_ns must be one number or one per pulse ({n},); got shape {t0.shape}")
    t0 = np.broadcast_to(t0, (n,)).copy()
    bad = np.flatnonzero(~np.isfinite(t0))
    if np.issubdtype(w.dtype, np.floating):
        bad = np.union1d(bad, np.flatnonzero(~np.isfinite(w).all(axis=1)))
    if bad.size:
        raise InputError(f"pulses {bad[:5].tolist()} have NaN or inf in their waveform or t0_ns; "
                         "fill or drop them before writing")
    b = finite_number(bin_ns, "bin_ns")
    if not b > 0:
        raise InputError(f"bin_ns must be > 0 (the sample spacing, ns); got {bin_ns!r}")
    return w, t0, b


def write_survey_las(path: str | os.PathLike, pulses, waveforms, *, t0_ns, bin_ns: float,
                     sensor: Sensor, returns: bool = True, bits: int = 16, gain=None,
                     offset=None, false_alarm: float = 0.01, min_amplitude: float = 0.0,
                     max_returns: int = 8, empty: str = "withheld",
                     gps_time_offset_s: float = 0.0, scales=(0.001, 0.001, 0.001),
                     offsets=None, device=None, chunk: int = 2000) -> tuple[Path, Path]:
    """Write a survey's waveforms and their returns as LAS 1.4 (format 9) plus ``.wdp``.

    Parameters
    ----------
    path : path-like
        The ``.las``; the packets go to the same name with ``.wdp``. Both are
        written to temporary names and renamed together at the end.
    pulses : clsim.survey.Pulses
        The pulses, one per waveform row (``position``, ``direction``,
        ``time_s``, ``scan_angle_deg``, ``leg``, ``index``).
    waveforms : (n_pulses, n_bins) float
        Received waveform of each pulse (the simulator's unit: fraction of the
        emitted energy per ns; any unit works, it is the descriptor's "volts").
    t0_ns : (n_pulses,) float or float
        Time after emission of each waveform's first bin, ns.
    bin_ns : float
        Sample spacing, ns.
    sensor : clsim.Sensor
        Its name goes to the header's system identifier; its pulse width
        (``pulse_sigma_ns``) is the matched filter of the detection.
    returns : bool
        Decompose each waveform and write its returns as the points (default).
        ``False``: no decomposition, one point per pulse at its strongest
        sample, flagged synthetic (a waveform-only file).
    bits : {8, 16, 32}
        Digitiser sample size of the packets.
    gain, offset : float, optional
        Stored ``raw = round((w - offset) / gain)`` clipped to the sample range;
        a reader recovers ``offset + gain * raw`` to within ``gain / 2``.
        Default: ``offset = min(0, min(w))`` and the gain that maps the largest
        sample to the top count, so nothing clips.
    false_alarm : float
        Detection threshold of :func:`clsim.decompose_batch`: expected false
        echoes per noise-only waveform (matched filter; the noise sigma is
        estimated per waveform, at least the quantisation's ``gain / sqrt(12)``).
    min_amplitude : float
        Echoes with amplitude at or under this (waveform units) are dropped.
    max_returns : int
        At most this many returns per pulse (1-15, LAS's limit).
    empty : {"withheld", "drop"}
        A pulse with no return: ``"withheld"`` (default) keeps its waveform
        with one point at its strongest sample (the first for an all-zero
        waveform), return 1 of 1, intensity 0, flagged synthetic and withheld
        (LAS: "should be considered deleted"), so that every waveform is in
        the file; ``"drop"`` writes no point and so no waveform for it.
    gps_time_offset_s : float
        GPS time of the trajectory's start: a point's GPS time is
        ``gps_time_offset_s + time_s`` of its pulse.
    scales, offsets : (3,) float
        Coordinate scale and offset (default 1 mm, offset the floor of the
        smallest coordinates).
    device : optional
        Where the decomposition's fits run (see :func:`clsim.decompose_batch`).
    chunk : int
        Waveforms quantised and decomposed together (memory: besides the
        input and its raw samples, about ``chunk * n_bins * 100`` bytes).

    Returns
    -------
    (las_path, wdp_path)

    Notes
    -----
    The decomposition runs on the quantised waveforms (what the file keeps),
    so decomposing the ``.wdp`` again finds the same returns. Each point
    carries ``gps_time``, ``return_number`` / ``number_of_returns`` (in time
    order: the first return is the one nearest the sensor), ``scan_angle``
    (0.006 degree steps), ``point_source_id`` = leg + 1, ``intensity`` = the
    echo amplitude in digitiser counts (clipped to 65535), and extra bytes
    ``pulse_index`` (the survey pulse number), ``amplitude`` (waveform units)
    and ``echo_width_ns`` (Gaussian sigma). Echoes placed outside the record
    (before its first or after its last sample) are dropped.
    Not written: scan direction and edge-of-flight-line flags (the pulses do
    not say where a scan line turns), classification (0, never classified).
    """
    w, t0, b = _check(pulses, waveforms, t0_ns, bin_ns, sensor)
    n, n_bins = w.shape
    gain, offset = _default_gain(w, int(bits), gain, offset)
    if offsets is None:     # the floor of the smallest coordinate a sample (so a point) can have
        d = np.asarray(pulses.direction, dtype=np.float64)
        ends = [np.asarray(pulses.position, dtype=np.float64) + (0.5 * C_M_PER_NS * t)[:, None] * d
                for t in (t0, t0 + (n_bins - 1) * b)]
        offsets = np.floor(np.minimum(*ends).min(axis=0))
    step = max(1, int(chunk))
    with SurveyLasWriter(path, sensor, n_samples=n_bins, bin_ns=b, gain=gain, offset=offset, offsets=offsets,
                         bits=int(bits), returns=returns, false_alarm=false_alarm, min_amplitude=min_amplitude,
                         max_returns=max_returns, empty=empty, gps_time_offset_s=gps_time_offset_s,
                         scales=scales, device=device, chunk=step) as out:
        for lo in range(0, n, step):                  # memory: the input and one chunk
            out.append(pulses[lo:lo + step], w[lo:lo + step], t0[lo:lo + step])
    return out.path, out.wdp_path


def write_survey_pulsewaves(path: str | os.PathLike, pulses, waveforms, *, bits: int = 16, gain=None, offset=None,
                            gps_time_offset_s: float = 0.0, system: str = "clsim") -> tuple[Path, Path, float, float]:
    """Write a survey's waveforms as PulseWaves (``.pls`` + ``.wvs``; :func:`clsim.waveforms.io.write_pulsewaves`).

    Parameters
    ----------
    path : path-like
        The ``.pls``.
    pulses : clsim.survey.Pulses
        One per waveform row (``position``, ``direction``, ``time_s``).
    waveforms : PulseWaveforms
        Their waveforms (:func:`clsim.survey.load_survey`).
    bits : {8, 16}
    gain, offset : float, optional
        Stored ``count = round((w - offset) / gain)``; default as :func:`write_survey_las`
        (nothing clips).  PulseWaves has no field for them: they are returned, and written in
        the sampling's description.

    Returns
    -------
    (pls, wvs, gain, offset)
    """
    from clsim.waveforms.io.pulsewaves import write_pulsewaves

    w = np.asarray(waveforms.waveform, dtype=np.float64)
    if len(pulses) != len(w):
        raise InputError(f"{len(pulses)} pulses for {len(w)} waveforms; one pulse per waveform row")
    gain, offset = _default_gain(w, bits, gain, offset)
    counts = np.clip(np.round((w - offset) / gain), 0, 2 ** bits - 1).astype(np.int64)
    pls, wvs = write_pulsewaves(path, gps_time=np.asarray(pulses.time_s) + gps_time_offset_s,
                                origin=pulses.position, direction=pulses.direction, t0_ns=waveforms.t0_ns,
                                samples=counts, n_samples=waveforms.n_samples, sample_units_ns=waveforms.bin_ns,
                                bits=bits, system=system,
                                description=f"power = {offset:.6g} + {gain:.6g} x count (fraction of the emitted "
                                            "energy per ns)")
    return pls, wvs, gain, offset


@dataclass
class SurveyLas:
    """A survey LAS read back: waveforms per pulse and the returns.

    Attributes
    ----------
    waveforms : (P, S) float64
        One row per pulse that has a packet, in file (pulse) order:
        ``offset + gain * raw`` (the recorded values to within ``gain / 2``).
    raw : (P, S) unsigned int
    gain, offset : float
        The descriptor's.
    spacing_ps : int
        The descriptor's sample spacing.
    origin : (P, 3) float64
        Position of each waveform's first sample, m.
    step : (P, 3) float64
        Displacement from one sample to the next, m (away from the sensor).
    pulse_index : (P,) int64
        Survey pulse number of each waveform.
    pulse_gps_time, pulse_scan_angle_deg : (P,) float64
    xyz : (M, 3) float64
        The points (returns), m.
    pulse : (M,) int64
        Row of ``waveforms`` each point belongs to.
    return_number, number_of_returns : (M,) uint8
    gps_time, scan_angle_deg : (M,) float64
    intensity : (M,) uint16
    amplitude, echo_width_ns : (M,) float32
    synthetic, withheld : (M,) bool
        A pulse without return's stand-in point (synthetic and withheld), or
        a waveform-only file's point (synthetic).
    point_source_id : (M,) uint16
    system_identifier : str
    """

    waveforms: np.ndarray
    raw: np.ndarray
    gain: float
    offset: float
    spacing_ps: int
    origin: np.ndarray
    step: np.ndarray
    pulse_index: np.ndarray
    pulse_gps_time: np.ndarray
    pulse_scan_angle_deg: np.ndarray
    xyz: np.ndarray
    pulse: np.ndarray
    return_number: np.ndarray
    number_of_returns: np.ndarray
    gps_time: np.ndarray
    scan_angle_deg: np.ndarray
    intensity: np.ndarray
    amplitude: np.ndarray
    echo_width_ns: np.ndarray
    synthetic: np.ndarray
    withheld: np.ndarray
    point_source_id: np.ndarray
    system_identifier: str = ""

    @property
    def n_pulses(self) -> int:
        return int(self.waveforms.shape[0])

    @property
    def returns(self) -> np.ndarray:
        """(M,) bool: the points that are detected returns (not stand-ins)."""
        return ~self.synthetic

    def sample_positions(self, p: int) -> np.ndarray:
        """(S, 3) positions of the samples of waveform ``p``, m."""
        j = np.arange(self.waveforms.shape[1], dtype=np.float64)
        return self.origin[p] + j[:, None] * self.step[p]


def read_survey_las(path: str | os.PathLike, *, wdp=None) -> SurveyLas:
    """Read a file written by :func:`write_survey_las` (waveforms, geometry, returns).

    The waveforms and the geometry come from :func:`clsim.read_las_waveforms`
    (any LAS 1.4 format 9 file with one descriptor works); the other point
    fields from laspy. The extra bytes ``pulse_index``, ``amplitude`` and
    ``echo_width_ns`` are read when present (else the packet number, zeros).

    Raises
    ------
    InputError
        What :func:`clsim.read_las_waveforms` refuses; a file with several
        wave packet descriptors or points without a waveform.
    """
    import laspy

    from clsim.waveforms.io.las import read_las_waveforms

    path = Path(path)
    lw = read_las_waveforms(path, wdp=wdp)
    if len(lw.descriptors) != 1:
        raise InputError(f"{path.name}: {len(lw.descriptors)} wave packet descriptors; a survey "
                         "file has one (all pulses sampled alike)")
    if (lw.packet < 0).any():
        raise InputError(f"{path.name}: {int((lw.packet < 0).sum())} point(s) without a waveform; "
                         "not a survey file from write_survey_las")
    (desc,) = lw.descriptors.values()
    las = laspy.read(path)
    names = set(las.point_format.dimension_names)
    n_pts = len(lw)
    pkt = lw.packet
    first = np.full(lw.n_packets, -1, np.int64)
    first[pkt[::-1]] = np.arange(n_pts)[::-1]                    # first point of each packet
    xt = lw.xyz_t.astype(np.float64)
    xyz = lw.xyz
    loc = lw.return_location_ps.astype(np.float64)
    origin = xyz[first] + loc[first, None] * xt[first]
    step = -desc.spacing_ps * xt[first]

    def opt(name, default, dt):
        return np.asarray(las[name]).astype(dt) if name in names else default

    pulse_index = (opt("pulse_index", None, np.int64)[first] if "pulse_index" in names
                   else np.arange(lw.n_packets, dtype=np.int64))
    waveforms = desc.offset + desc.gain * lw.raw[:, :desc.n_samples].astype(np.float64)
    scan = np.asarray(las.scan_angle, dtype=np.float64) * SCAN_ANGLE_STEP_DEG
    return SurveyLas(
        waveforms=waveforms, raw=lw.raw[:, :desc.n_samples], gain=desc.gain, offset=desc.offset,
        spacing_ps=desc.spacing_ps, origin=origin, step=step,
        pulse_index=pulse_index, pulse_gps_time=lw.gps_time[first],
        pulse_scan_angle_deg=scan[first], xyz=xyz, pulse=pkt.copy(),
        return_number=lw.return_number, number_of_returns=lw.number_of_returns,
        gps_time=lw.gps_time, scan_angle_deg=scan, intensity=lw.intensity,
        amplitude=opt("amplitude", np.zeros(n_pts, np.float32), np.float32),
        echo_width_ns=opt("echo_width_ns", np.zeros(n_pts, np.float32), np.float32),
        synthetic=np.asarray(las.synthetic).astype(bool),
        withheld=np.asarray(las.withheld).astype(bool),
        point_source_id=np.asarray(las.point_source_id, dtype=np.uint16),
        system_identifier=str(las.header.system_identifier).rstrip("\0"))
