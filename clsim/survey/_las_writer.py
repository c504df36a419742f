"""A survey's LAS 1.4 file written batch by batch: memory bounded by one batch.

:class:`SurveyLasWriter` holds what every batch must share (the wave packet
descriptor: samples per packet, spacing, gain, offset; the coordinates' scales
and offsets; the detection settings) and appends each batch's points to the
``.las`` and its packets to the ``.wdp`` as it comes, both under temporary
names; :meth:`SurveyLasWriter.close` completes the headers (point counts,
bounds, returns per number, the ``.wdp``'s byte count) and renames both.
:func:`clsim.survey.write_survey_las` is this writer over the chunks of
arrays held in memory, so a file streamed batch by batch and one written at
once from the same waveforms with the same settings are the same bytes.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from clsim.errors import InputError
from clsim.sensor import C_M_PER_NS, Sensor
from voxlidar.errors import finite_number

__all__ = ["Echoes", "SurveyLasWriter"]

#: LAS 1.4 point format 6-10 scan angle unit, degrees.
SCAN_ANGLE_STEP_DEG = 0.006
#: LAS 1.4 allows return numbers 1-15.
MAX_RETURNS_LAS = 15
_EMPTY = ("withheld", "drop")
_EXTRA = {
    "pulse_index": ("u8", "survey pulse number"),
    "amplitude": ("f4", "echo amplitude, waveform units"),
    "echo_width_ns": ("f4", "echo Gaussian sigma, ns"),
}


class Echoes:
    """The returns decomposed from one batch: ``pulse`` (row in the batch), ``tau`` (ns after
    emission), ``amplitude`` (waveform units), ``sigma`` (ns); what :meth:`SurveyLasWriter.append`
    needs to skip the decomposition (a resumed survey keeps them beside its batches)."""

    FIELDS = ("pulse", "tau", "amplitude", "sigma")

    def __init__(self, pulse, tau, amplitude, sigma):
        self.pulse = np.asarray(pulse, dtype=np.int64)
        self.tau = np.asarray(tau, dtype=np.float64)
        self.amplitude = np.asarray(amplitude, dtype=np.float64)
        self.sigma = np.asarray(sigma, dtype=np.float64)

    @classmethod
    def none(cls) -> Echoes:
        """No echo."""
        return cls(*(np.zeros(0) for _ in cls.FIELDS))

    def save(self, path, key: str) -> Path:
        """Write to ``path`` (atomically) with ``key`` naming the settings they were found with."""
        from voxlidar.safeio import atomic_write

        def write(tmp):
            with open(tmp, "wb") as fh:
                np.savez(fh, key=np.array(key), **{f: getattr(self, f) for f in self.FIELDS})

        return atomic_write(Path(path), write)

    @classmethod
    def load(cls, path, key: str) -> Echoes | None:
        """The echoes saved at ``path`` with the same ``key``; None when absent, unreadable or
        found with other settings."""
        try:
            with np.load(path) as z:
                if str(z["key"]) != key:
                    return None
                return cls(*(z[f] for f in cls.FIELDS))
        except (OSError, ValueError, KeyError):
            return None


def quantiser(bits: int, gain: float, offset: float):
    """(raw dtype, gain, offset) checked."""
    from clsim.waveforms.io.las import _SAMPLE_DTYPES

    if bits not in _SAMPLE_DTYPES:
        raise InputError(f"bits must be 8, 16 or 32 (the digitiser's sample size); got {bits!r}")
    offset = finite_number(offset, "offset")
    gain = finite_number(gain, "gain")
    if not gain > 0:
        raise InputError(f"gain must be > 0 (volts or power per digitiser count); got {gain!r}")
    return _SAMPLE_DTYPES[bits], gain, offset


class SurveyLasWriter:
    """LAS 1.4 point format 9 with an external ``.wdp``, appended one batch of pulses at a time.

    Parameters
    ----------
    path : path-like
        The ``.las``; the packets go to the same name with ``.wdp``.  Both are
        written to temporary names and renamed together by :meth:`close`.
    sensor : clsim.Sensor
        Its name goes to the header; its pulse width is the detection's
        matched filter.
    n_samples : int
        Samples of every packet: a batch's waveforms are padded with zeros to
        it (a wider one is refused).
    bin_ns : float
        Sample spacing, ns.
    gain, offset : float
        Stored ``raw = round((w - offset) / gain)`` clipped to the sample
        range (clipped samples are counted in :attr:`clipped`).
    offsets : (3,) float
        Coordinate offsets of the header, m.
    bits, returns, false_alarm, min_amplitude, max_returns, empty, gps_time_offset_s, scales, device, chunk
        As :func:`clsim.survey.write_survey_las`.

    Attributes
    ----------
    pulses, points, packets, clipped : int
        Written so far: pulses given, points, waveform packets, samples clipped.
    """

    def __init__(self, path, sensor: Sensor, *, n_samples: int, bin_ns: float, gain: float, offset: float = 0.0,
                 offsets, bits: int = 16, returns: bool = True, false_alarm: float = 0.01,
                 min_amplitude: float = 0.0, max_returns: int = 8, empty: str = "withheld",
                 gps_time_offset_s: float = 0.0, scales=(0.001, 0.001, 0.001), device=None, chunk: int = 2000):
        import laspy

        from clsim.waveforms.io.las import _EVLR_HEADER, WavePacketDescriptor

        path = Path(path)
        if path.suffix.lower() != ".las":
            raise InputError(f"path must end in .las (the waveform packets go to a .wdp beside it); "
                             f"got {str(path)!r}")
        if not isinstance(sensor, Sensor):
            raise InputError(f"sensor must be a clsim.Sensor (e.g. Sensor.preset(...)); got {type(sensor).__name__}")
        if empty not in _EMPTY:
            raise InputError(f"empty must be one of {_EMPTY}; got {empty!r}")
        if not 1 <= int(max_returns) <= MAX_RETURNS_LAS:
            raise InputError(f"max_returns must be 1-{MAX_RETURNS_LAS} (LAS return numbers); got {max_returns!r}")
        b = finite_number(bin_ns, "bin_ns")
        if not b > 0:
            raise InputError(f"bin_ns must be > 0 (the sample spacing, ns); got {bin_ns!r}")
        if int(n_samples) < 4:
            raise InputError(f"n_samples must be >= 4; got {n_samples!r}")
        self.dtype, self.gain, self.offset = quantiser(int(bits), gain, offset)
        self.path, self.wdp_path = path, path.with_suffix(".wdp")
        self.sensor, self.n_samples, self.bin_ns = sensor, int(n_samples), b
        self.returns, self.false_alarm, self.min_amplitude = bool(returns), float(false_alarm), float(min_amplitude)
        self.max_returns, self.empty, self.device, self.chunk = int(max_returns), empty, device, max(1, int(chunk))
        self.gps_time_offset_s = float(gps_time_offset_s)
        self.spacing_ps = max(1, int(round(b * 1000.0)))
        self.desc = WavePacketDescriptor(1, int(bits), self.n_samples, self.spacing_ps, float(self.gain),
                                         float(self.offset))
        self.desc.check()
        self.packet_size = self.desc.packet_size
        self.scales = np.asarray(scales, dtype=np.float64)
        self.offsets = np.asarray(offsets, dtype=np.float64)
        if self.offsets.shape != (3,) or not np.isfinite(self.offsets).all():
            raise InputError(f"offsets must be three finite numbers (m); got {offsets!r}")

        header = laspy.LasHeader(version="1.4", point_format=9)
        header.add_extra_dims([laspy.ExtraBytesParams(name, np.dtype(dt), description=desc[:31])
                               for name, (dt, desc) in _EXTRA.items()])
        header.system_identifier = f"clsim {sensor.name}"[:31]
        header.generating_software = "clsim"
        header.scales = self.scales
        header.offsets = self.offsets
        header.global_encoding.waveform_data_packets_external = True
        header.global_encoding.waveform_data_packets_internal = False
        header.start_of_waveform_data_packet_record = 0
        header.vlrs.append(laspy.VLR(user_id="LASF_Spec", record_id=self.desc.record_id,
                                     description="Waveform Data", record_data=self.desc.to_bytes()))
        self.header = header
        self.path.parent.mkdir(parents=True, exist_ok=True)
        tag = f"partial-{os.getpid()}"
        self._tmp_las = path.with_name(f".{path.stem}.{tag}.las")
        self._tmp_wdp = path.with_name(f".{path.stem}.{tag}.wdp")
        self._header_size = _EVLR_HEADER.size
        self._wdp = open(self._tmp_wdp, "wb")
        self._wdp.write(b"\0" * self._header_size)          # completed by close()
        self._las = laspy.open(str(self._tmp_las), mode="w", header=header)
        self.pulses = self.points = self.packets = self.clipped = 0
        self._extra_range = {name: [np.inf, -np.inf] for name in _EXTRA}
        self._closed = False

    # -- the batch's parts -------------------------------------------------------------
    def quantise(self, waveforms) -> np.ndarray:
        """(n, n_samples) raw samples of ``waveforms`` (padded with zeros to ``n_samples``)."""
        w = np.asarray(waveforms)
        if w.ndim != 2 or w.shape[1] > self.n_samples:
            raise InputError(f"waveforms must have shape (n_pulses, <= {self.n_samples}) for this file; "
                             f"got {w.shape}")
        info = np.iinfo(self.dtype)
        raw = np.empty((w.shape[0], self.n_samples), self.dtype)
        zero = np.clip(np.rint((0.0 - self.offset) / self.gain), info.min, info.max)
        raw[:, w.shape[1]:] = zero
        for lo in range(0, w.shape[0], self.chunk):
            q = np.rint((w[lo:lo + self.chunk].astype(np.float64) - self.offset) / self.gain)
            self.clipped += int(((q < info.min) | (q > info.max)).sum())
            raw[lo:lo + self.chunk, :w.shape[1]] = np.clip(q, info.min, info.max)
        return raw

    def find_echoes(self, raw, t0_ns) -> Echoes:
        """The returns of quantised waveforms (what the file keeps, so decomposing the ``.wdp``
        again finds them), the sensor's pulse as the matched filter."""
        from clsim.waveforms.decompose import decompose_batch

        parts = []
        t0 = np.asarray(t0_ns, dtype=np.float64)
        for lo in range(0, raw.shape[0], self.chunk):
            table = decompose_batch(self.offset + self.gain * raw[lo:lo + self.chunk].astype(np.float64),
                                    dt_ns=self.bin_ns, t0_ns=t0[lo:lo + self.chunk],
                                    pulse_sigma_ns=self.sensor.pulse_sigma_ns, false_alarm=self.false_alarm,
                                    max_components=self.max_returns, device=self.device, chunk=self.chunk)
            parts.append((table.waveform + lo, table.location_ns, table.amplitude, table.sigma_ns))
        if not parts:
            return Echoes.none()
        return Echoes(*(np.concatenate(c) for c in zip(*parts)))

    def echo_key(self) -> str:
        """The settings the echoes depend on (:meth:`Echoes.load` compares them)."""
        return (f"bits={self.desc.bits_per_sample} n={self.n_samples} bin={self.bin_ns!r} gain={self.gain!r} "
                f"offset={self.offset!r} sigma={self.sensor.pulse_sigma_ns!r} fa={self.false_alarm!r} "
                f"max={self.max_returns}")

    def append(self, pulses, waveforms, t0_ns, *, echoes: Echoes | None = None) -> Echoes:
        """Write one batch: its points to the ``.las``, its packets to the ``.wdp``.

        Parameters
        ----------
        pulses : clsim.survey.Pulses
            One per waveform row.
        waveforms : (n, <= n_samples) float
        t0_ns : (n,) float or float
            Time after emission of each row's first sample, ns.
        echoes : Echoes, optional
            This batch's returns found before with the same settings (skips the decomposition).

        Returns
        -------
        Echoes
            The batch's returns (before the amplitude and record-span cuts).
        """
        from clsim.survey._pulses import Pulses

        if self._closed:
            raise InputError(f"{self.path.name}: the writer is closed; open a new one")
        if not isinstance(pulses, Pulses):
            raise InputError(f"pulses must be a clsim.survey.Pulses (from survey_pulses); got {type(pulses).__name__}")
        n = len(pulses)
        w = np.asarray(waveforms)
        if w.ndim != 2 or w.shape[0] != n:
            raise InputError(f"waveforms must have one row per pulse ({n}); got shape {w.shape}")
        t0 = np.broadcast_to(np.asarray(t0_ns, dtype=np.float64), (n,)).copy()
        raw = self.quantise(w)
        if echoes is None:
            echoes = self.find_echoes(raw, t0) if self.returns else Echoes.none()
        self._write(pulses, raw, t0, echoes)
        self.pulses += n
        return echoes

    def _write(self, pulses, raw, t0, echoes: Echoes) -> None:
        import laspy

        n, b, n_bins = len(pulses), self.bin_ns, self.n_samples
        pulse, tau, amp, sig = echoes.pulse, echoes.tau, echoes.amplitude, echoes.sigma
        keep = ((amp > self.min_amplitude) & (tau >= t0[pulse]) & (tau <= t0[pulse] + (n_bins - 1) * b))
        pulse, tau, amp, sig = pulse[keep], tau[keep], amp[keep], sig[keep]
        synthetic = np.zeros(pulse.size, bool)
        withheld = np.zeros(pulse.size, bool)
        lonely = np.setdiff1d(np.arange(n), pulse)
        if lonely.size and (self.empty == "withheld" or not self.returns):
            j = np.argmax(raw[lonely], axis=1)                 # gain > 0: the strongest sample
            pulse = np.concatenate([pulse, lonely])
            tau = np.concatenate([tau, t0[lonely] + j * b])
            amp = np.concatenate([amp, np.zeros(lonely.size)])
            sig = np.concatenate([sig, np.zeros(lonely.size)])
            synthetic = np.concatenate([synthetic, np.ones(lonely.size, bool)])
            withheld = np.concatenate([withheld, np.full(lonely.size, self.returns)])
        order = np.lexsort((tau, pulse))
        pulse, tau, amp, sig = pulse[order], tau[order], amp[order], sig[order]
        synthetic, withheld = synthetic[order], withheld[order]
        counts = np.bincount(pulse, minlength=n)
        first = np.concatenate(([0], np.cumsum(counts)[:-1]))
        rn = np.arange(pulse.size) - first[pulse] + 1
        kept = np.flatnonzero(counts > 0)                   # the pulses that have points keep a packet
        packet_of_pulse = np.full(n, -1, np.int64)
        packet_of_pulse[kept] = np.arange(kept.size)
        m = pulse.size
        if m == 0:
            return
        d = np.asarray(pulses.direction, dtype=np.float64)[pulse]
        xyz = np.asarray(pulses.position, dtype=np.float64)[pulse] + (0.5 * C_M_PER_NS * tau)[:, None] * d
        ints = np.rint((xyz - self.offsets) / self.scales)
        if np.abs(ints).max() > np.iinfo(np.int32).max:
            raise InputError("coordinates do not fit int32 at the given scales; pass larger scales or "
                             "offsets closer to the data")
        step_per_ps = 0.5 * C_M_PER_NS * b / self.spacing_ps            # m per digitiser ps
        rec = laspy.ScaleAwarePointRecord.zeros(m, header=self.header)
        rec.X, rec.Y, rec.Z = (ints[:, k].astype(np.int32) for k in range(3))
        rec.gps_time = self.gps_time_offset_s + np.asarray(pulses.time_s, dtype=np.float64)[pulse]
        rec.return_number = rn.astype(np.uint8)
        rec.number_of_returns = counts[pulse].astype(np.uint8)
        rec.intensity = np.clip(np.rint(amp / self.gain), 0, 65535).astype(np.uint16)
        rec.wavepacket_index = np.ones(m, np.uint8)
        start = self._header_size + (self.packets + packet_of_pulse[pulse]) * self.packet_size
        rec.wavepacket_offset = start.astype(np.uint64)
        rec.wavepacket_size = np.full(m, self.packet_size, np.uint32)
        rec.return_point_wave_location = ((tau - t0[pulse]) / b * self.spacing_ps).astype(np.float32)
        xt = (-d * step_per_ps).astype(np.float32)
        rec.x_t, rec.y_t, rec.z_t = xt[:, 0], xt[:, 1], xt[:, 2]
        scan = np.rint(np.asarray(pulses.scan_angle_deg, dtype=np.float64)[pulse] / SCAN_ANGLE_STEP_DEG)
        rec.scan_angle = np.clip(scan, -30000, 30000).astype(np.int16)
        rec.point_source_id = (np.asarray(pulses.leg)[pulse] + 1).astype(np.uint16)
        rec.synthetic = synthetic.astype(np.uint8)
        rec.withheld = withheld.astype(np.uint8)
        rec.pulse_index = np.asarray(pulses.index)[pulse].astype(np.uint64)
        rec.amplitude = amp.astype(np.float32)
        rec.echo_width_ns = sig.astype(np.float32)
        for name, r in self._extra_range.items():
            v = np.asarray(rec[name])
            r[0], r[1] = min(r[0], v.min()), max(r[1], v.max())
        self._las.write_points(rec)
        dt = np.dtype(self.dtype).newbyteorder("<")
        self._wdp.write(np.ascontiguousarray(raw[kept], dtype=dt).tobytes())
        self.points += m
        self.packets += kept.size

    # -- the end ------------------------------------------------------------------------
    def close(self) -> tuple[Path, Path]:
        """Complete both headers and rename the files onto their names: (las_path, wdp_path)."""
        from clsim.waveforms.io.las import _wdp_header

        if self._closed:
            return self.path, self.wdp_path
        self._closed = True
        try:
            self._set_extra_ranges()
            self._las.close()
            self._wdp.seek(0)
            self._wdp.write(_wdp_header(self.packets * self.packet_size))
            self._wdp.flush()
            os.fsync(self._wdp.fileno())
            self._wdp.close()
            os.replace(self._tmp_wdp, self.wdp_path)
            os.replace(self._tmp_las, self.path)
        except BaseException:
            self.abort()
            raise
        return self.path, self.wdp_path

    def _set_extra_ranges(self) -> None:
        """The extra bytes' minimum and maximum over every point (laspy 2.7 grows them from the
        first point of each batch only)."""
        vlrs = self._las.header.vlrs.get("ExtraBytesVlr")
        if not vlrs:
            return
        for struct in vlrs[0].extra_bytes_structs:
            lo, hi = self._extra_range.get(struct.format_name(), (np.inf, -np.inf))
            if self.points and struct.min_is_relevant():
                struct._raw_min()[:] = lo
            if self.points and struct.max_is_relevant():
                struct._raw_max()[:] = hi

    def abort(self) -> None:
        """Close and delete the temporary files (no output appears)."""
        self._closed = True
        for fh in (self._las, self._wdp):
            try:
                fh.close()
            except (OSError, ValueError, AttributeError):
                pass
        for p in (self._tmp_las, self._tmp_wdp):
            p.unlink(missing_ok=True)

    def __enter__(self) -> SurveyLasWriter:
        return self

    def __exit__(self, kind, value, tb) -> None:
        if kind is None:
            self.close()
        else:
            self.abort()
