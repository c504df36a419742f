"""PulseWaves (.pls + .wvs): reader, and a writer of simulated survey waveforms.

Implements the public PulseWaves specification, version 0.3 revision 6
(github.com/PulseWaves/Specification): the Pulse file holds a 352-byte header,
VLRs (96-byte headers), 48-byte pulse records (format 0) and appended VLRs;
pulse descriptors (``PulseWaves_Spec`` VLR record ids 200,001-200,254) are a
composition record followed by sampling records (outgoing = type 1, returning
= type 2) that say how the Waves file stores each pulse: optional extra bytes,
then per sampling the number of segments, and per segment the duration from
the anchor, the number of samples and the samples.

Geometry: anchor ``A`` and target ``T`` points (scaled integers); the
direction per sampling unit is ``d = (T - A) / 1000`` and the first sample of
a segment lies at ``A + duration * d``; successive samples add ``d`` (for a
segment whose sample unit equals the composition's).

:func:`write_pulsewaves` writes one returning segment per pulse in that layout
(``clsim survey --pulsewaves``): format 0 pulse records with the anchor at the
sensor (the optical centre) and the target 1000 sampling units along the
beam, one pulse descriptor (one returning sampling: 32-bit durations in
thousandths of a sampling unit, 16-bit sample counts, 8 or 16 bits per
sample), uncompressed.  What does not fit is refused in one line: a first
sample farther than 32,767 sampling units from the sensor (the pulse
record's 16-bit first and last returning sample: 4.9 km slant range at
1 GHz, 2.7 km at 1.8 GHz), a waveform of more than 65,535 samples.

References
----------
Isenburg, M. (2012-2015). PulseWaves - full waveform LiDAR specification,
    version 0.3 revision 6. https://github.com/PulseWaves/Specification
"""

from __future__ import annotations

import os
import struct
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from clsim.errors import InputError

__all__ = ["PulseWaves", "Sampling", "WaveSegment", "read_pulsewaves", "write_pulsewaves"]

_HEADER = struct.Struct("<16sIIIHH8s64s64sHHBBHqqIIIIqIiddqqdddddddddddd")  # 352 bytes
_VLR = struct.Struct("<16sIIq64s")  # 96 bytes
_PULSE0 = np.dtype([("T", "<i8"), ("offset", "<i8"), ("anchor", "<i4", 3), ("target", "<i4", 3),
                    ("first", "<i2"), ("last", "<i2"), ("descriptor", "u1"), ("flags", "u1"),
                    ("intensity", "u1"), ("classification", "u1")])
_COMPOSITION = struct.Struct("<IIiHHfII")  # + description
_SAMPLING = struct.Struct("<IIBBBBffBBHIHHfI")  # + description
_UINT = {8: "<u1", 16: "<u2", 32: "<u4"}
_INT = {8: "<i1", 16: "<i2", 32: "<i4"}


@dataclass(frozen=True)
class Sampling:
    """One sampling record of a pulse descriptor."""

    type: int  # 1 outgoing, 2 returning
    channel: int
    bits_for_duration: int
    duration_scale: float
    duration_offset: float
    bits_for_n_segments: int
    bits_for_n_samples: int
    n_segments: int
    n_samples: int
    bits_per_sample: int
    sample_units_ns: float

    @property
    def kind(self) -> str:
        return {1: "outgoing", 2: "returning"}.get(self.type, f"type{self.type}")


@dataclass(frozen=True)
class PulseDescriptor:
    index: int
    optical_center_to_anchor: int
    extra_wave_bytes: int
    sample_units_ns: float
    samplings: tuple


@dataclass
class WaveSegment:
    """Samples of one segment of one sampling of one pulse.

    Attributes
    ----------
    pulse : int
        Pulse index.
    kind : str
        "outgoing" or "returning".
    channel : int
    duration : float
        Sampling units from the anchor to the first sample.
    samples : (S,) int
        Raw digitiser values.
    sample_units_ns : float
    """

    pulse: int
    kind: str
    channel: int
    duration: float
    samples: np.ndarray
    sample_units_ns: float


@dataclass
class PulseWaves:
    """Pulses of a PulseWaves file and their waveform segments.

    Attributes
    ----------
    gps_time : (N,) float64, s
    anchor, target : (N, 3) float64, m
    first_returning_sample, last_returning_sample : (N,) int16, sampling units
    descriptor : (N,) uint8
    intensity, classification : (N,) uint8
    segments : list of WaveSegment
    descriptors : dict[int, PulseDescriptor]
    header : dict
    """

    gps_time: np.ndarray
    anchor: np.ndarray
    target: np.ndarray
    first_returning_sample: np.ndarray
    last_returning_sample: np.ndarray
    descriptor: np.ndarray
    intensity: np.ndarray
    classification: np.ndarray
    segments: list = field(default_factory=list)
    descriptors: dict = field(default_factory=dict)
    header: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return int(self.gps_time.size)

    @property
    def direction(self) -> np.ndarray:
        """(N, 3) displacement per sampling unit along each pulse, m (spec: (T-A)/1000)."""
        return (self.target - self.anchor) / 1000.0

    def waves(self, pulse: int, kind: str = "returning") -> list:
        """Segments of one pulse of the given kind ("outgoing" or "returning")."""
        return [s for s in self.segments if s.pulse == pulse and s.kind == kind]

    def segment_origin(self, seg: WaveSegment) -> tuple[np.ndarray, np.ndarray]:
        """Position of a segment's first sample (m) and displacement per ns (m/ns).

        For :func:`clsim.waveforms.decompose.echo_positions` with locations in ns from the
        segment's first sample.
        """
        d = self.direction[seg.pulse]
        unit = self.descriptors[int(self.descriptor[seg.pulse])].sample_units_ns
        return self.anchor[seg.pulse] + seg.duration * d, d / unit


def _cstr(b: bytes) -> str:
    return b.split(b"\0", 1)[0].decode("ascii", "replace")


def _parse_descriptor(index: int, payload: bytes, name: str) -> PulseDescriptor:
    if len(payload) < _COMPOSITION.size:
        raise InputError(f"{name}: pulse descriptor {index} is {len(payload)} bytes, shorter "
                         "than a composition record")
    size, _r, oc2a, extra, n_samplings, units, _scanner, _comp = _COMPOSITION.unpack_from(payload)
    # The composition's compression field is informative only (RiPROCESS writes 1 for
    # uncompressed samplings); what is stored is said per sampling record below.
    pos = size
    samplings = []
    for k in range(n_samplings):
        if pos + _SAMPLING.size > len(payload):
            raise InputError(f"{name}: pulse descriptor {index} announces {n_samplings} "
                             f"samplings but has room for {k}")
        (ssize, _r, typ, chan, _u, bdur, dscale, doff, bnseg, bnsamp, nseg, nsamp, bps, _lut,
         sunits, scomp) = _SAMPLING.unpack_from(payload, pos)
        if scomp != 0:
            raise InputError(f"{name}: sampling {k} of descriptor {index} is compressed "
                             f"({scomp}); not supported")
        if bps not in (8, 16) or bdur not in (0, 8, 16, 32) or bnseg not in (0, 8, 16) \
                or bnsamp not in (0, 8, 16):
            raise InputError(f"{name}: sampling {k} of descriptor {index} has bits per sample "
                             f"{bps}, duration bits {bdur}, segment bits {bnseg}, sample-count "
                             f"bits {bnsamp}; the specification allows 8/16, 0/8/16/32, 0/8/16, "
                             "0/8/16")
        samplings.append(Sampling(typ, chan, bdur, dscale, doff, bnseg, bnsamp, nseg, nsamp, bps,
                                  sunits))
        pos += ssize
    return PulseDescriptor(index, oc2a, extra, units, tuple(samplings))


def read_pulsewaves(path: str | os.PathLike, *, wvs: str | os.PathLike | None = None
                    ) -> PulseWaves:
    """Read a PulseWaves pulse file and its waves.

    Parameters
    ----------
    path : path-like
        The ``.pls`` file.
    wvs : path-like, optional
        The ``.wvs`` file; default: same name with suffix ``.wvs``.

    Returns
    -------
    PulseWaves

    Raises
    ------
    InputError
        Wrong signature, unsupported pulse format, missing or truncated
        ``.wvs``, a pulse that references a missing descriptor.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"PulseWaves file {str(path)!r} does not exist")
    data = path.read_bytes()
    name = path.name
    if len(data) < _HEADER.size:
        raise InputError(f"{name}: {len(data)} bytes, shorter than the 352-byte PulseWaves "
                         "header")
    h = _HEADER.unpack_from(data)
    if _cstr(h[0]) != "PulseWavesPulse":
        raise InputError(f"{name}: signature {_cstr(h[0])!r}; expected 'PulseWavesPulse' "
                         "(is this a .pls file?)")
    header = dict(system=_cstr(h[7]), software=_cstr(h[8]), version=(h[11], h[12]),
                  header_size=h[13], offset_to_pulses=h[14], n_pulses=h[15], pulse_format=h[16],
                  pulse_attributes=h[17], pulse_size=h[18], pulse_compression=h[19],
                  n_vlrs=h[21], n_avlrs=h[22], t_scale=h[23], t_offset=h[24],
                  scale=np.array(h[27:30]), offset=np.array(h[30:33]),
                  bbox_min=np.array(h[33:39:2]), bbox_max=np.array(h[34:39:2]))
    if header["pulse_format"] != 0 or header["pulse_compression"] != 0:
        raise InputError(f"{name}: pulse format {header['pulse_format']} compression "
                         f"{header['pulse_compression']}; only format 0 uncompressed is defined")
    if header["pulse_size"] < _PULSE0.itemsize:
        raise InputError(f"{name}: pulse size {header['pulse_size']} < 48 bytes of format 0")
    descriptors = {}
    pos = header["header_size"]
    for _ in range(header["n_vlrs"]):
        if pos + _VLR.size > len(data):
            raise InputError(f"{name}: truncated in the VLRs (byte {pos})")
        uid, rid, _r, length, _desc = _VLR.unpack_from(data, pos)
        payload = data[pos + _VLR.size:pos + _VLR.size + length]
        if _cstr(uid) == "PulseWaves_Spec" and 200001 <= rid < 200255:
            descriptors[rid - 200000] = _parse_descriptor(rid - 200000, payload, name)
        pos += _VLR.size + length
    n = int(header["n_pulses"])
    start = int(header["offset_to_pulses"])
    size = int(header["pulse_size"])
    if start + n * size > len(data):
        raise InputError(f"{name}: header says {n} pulses of {size} bytes from byte {start} but "
                         f"the file has {len(data)} bytes; the file is truncated")
    rec_dtype = np.dtype({"names": _PULSE0.names, "formats": [_PULSE0[k] for k in _PULSE0.names],
                          "offsets": [_PULSE0.fields[k][1] for k in _PULSE0.names],
                          "itemsize": size})
    rec = np.frombuffer(data, dtype=rec_dtype, count=n, offset=start)
    missing = sorted(set(int(d) for d in rec["descriptor"]) - set(descriptors))
    if missing:
        raise InputError(f"{name}: pulses use pulse descriptor(s) {missing} but the file has "
                         f"{sorted(descriptors)}; the descriptor VLRs are missing")
    scale, offset = header["scale"], header["offset"]
    anchor = rec["anchor"] * scale + offset
    target = rec["target"] * scale + offset
    wvs_path = Path(wvs) if wvs is not None else path.with_suffix(".wvs")
    if not wvs_path.is_file():
        alt = path.with_suffix(".WVS")
        if wvs is None and alt.is_file():
            wvs_path = alt
        else:
            raise InputError(f"{name}: the waves file {str(wvs_path)!r} is missing. A PulseWaves "
                             "file is two files: keep the .wvs next to the .pls with the same "
                             "base name (or pass wvs=)")
    waves = wvs_path.read_bytes()
    if len(waves) < 60 or _cstr(waves[:16]) != "PulseWavesWaves":
        raise InputError(f"{wvs_path.name}: not a PulseWaves waves file (signature "
                         f"{_cstr(waves[:16])!r}, expected 'PulseWavesWaves')")
    comp = struct.unpack_from("<I", waves, 16)[0]
    if comp != 0:
        raise InputError(f"{wvs_path.name}: compressed waves ({comp}) are not supported")
    segments = []
    for p in range(n):
        desc = descriptors[int(rec["descriptor"][p])]
        segments.extend(_read_waves(waves, int(rec["offset"][p]), p, desc, wvs_path.name))
    t = rec["T"] * header["t_scale"] + header["t_offset"]
    return PulseWaves(gps_time=t, anchor=anchor, target=target,
                      first_returning_sample=rec["first"].copy(),
                      last_returning_sample=rec["last"].copy(),
                      descriptor=rec["descriptor"].copy(), intensity=rec["intensity"].copy(),
                      classification=rec["classification"].copy(), segments=segments,
                      descriptors=descriptors, header=header)


def _read_waves(buf: bytes, pos: int, pulse: int, desc: PulseDescriptor, name: str) -> list:
    out = []

    def take(nbytes):
        nonlocal pos
        if pos + nbytes > len(buf):
            raise InputError(f"{name} is truncated: pulse {pulse} needs bytes up to "
                             f"{pos + nbytes} but the file has {len(buf)}; copy the complete "
                             ".wvs again")
        chunk = buf[pos:pos + nbytes]
        pos += nbytes
        return chunk

    def read_int(bits, signed):
        if bits == 0:
            return 0
        return int(np.frombuffer(take(bits // 8), dtype=(_INT if signed else _UINT)[bits])[0])

    take(desc.extra_wave_bytes)
    for s in desc.samplings:
        nseg = read_int(s.bits_for_n_segments, False) if s.bits_for_n_segments else s.n_segments
        for _k in range(nseg):
            dur = s.duration_scale * read_int(s.bits_for_duration, True) + s.duration_offset
            ns = read_int(s.bits_for_n_samples, False) if s.bits_for_n_samples else s.n_samples
            raw = np.frombuffer(take(ns * s.bits_per_sample // 8),
                                dtype=_UINT[s.bits_per_sample]).astype(np.int64)
            out.append(WaveSegment(pulse, s.kind, s.channel, float(dur), raw,
                                   s.sample_units_ns or desc.sample_units_ns))
    return out




def _fixed(text: str, n: int) -> bytes:
    return text.encode("ascii", "replace")[:n - 1].ljust(n, b"\0")


def write_pulsewaves(path: str | os.PathLike, *, gps_time, origin, direction, t0_ns, samples, n_samples=None,
                     sample_units_ns: float, bits: int = 16, system: str = "clsim", scale: float = 0.0001,
                     t_scale: float = 1e-9, description: str = "returning waveform") -> tuple[Path, Path]:
    """Write pulses and their returning waveforms as PulseWaves (``.pls`` and ``.wvs``, atomic together).

    Parameters
    ----------
    path : path-like
        The ``.pls``; the waves go to the same name with ``.wvs``.
    gps_time : (N,) float, s
    origin : (N, 3) float, m
        The sensor at each pulse (the anchor point).
    direction : (N, 3) float
        Unit direction of each beam.
    t0_ns : (N,) float, ns
        Time after emission of each waveform's first sample (two-way).
    samples : (N, S) int
        Digitiser counts, ``0 .. 2**bits - 1``; row ``i`` holds ``n_samples[i]`` of them.
    n_samples : (N,) int, optional
        Samples per row (default every column).
    sample_units_ns : float
        Sample spacing, ns.
    bits : {8, 16}
    system, description : str
        The header's system identifier; the sampling record's description.
    scale, t_scale : float
        Coordinate scale (m) and time scale (s) of the integer fields.

    Returns
    -------
    (pls, wvs) paths
    """
    from voxlidar.safeio import atomic_write

    path = Path(path)
    t = np.asarray(gps_time, dtype=np.float64).reshape(-1)
    n = len(t)
    a = np.asarray(origin, dtype=np.float64).reshape(n, 3)
    d = np.asarray(direction, dtype=np.float64).reshape(n, 3)
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    raw = np.asarray(samples)
    if raw.ndim != 2 or raw.shape[0] != n:
        raise InputError(f"samples must be (N, S) for the {n} pulses, got shape {raw.shape}")
    ns = np.full(n, raw.shape[1], np.int64) if n_samples is None else np.asarray(n_samples, dtype=np.int64)
    if bits not in (8, 16):
        raise InputError(f"PulseWaves samples are 8 or 16 bits here, got bits={bits!r}")
    if raw.size and (raw.min() < 0 or raw.max() >= 2 ** bits):
        raise InputError(f"samples must be digitiser counts in [0, {2 ** bits - 1}] for {bits} bits; quantise first")
    if ns.size and ns.max() > 65_535:
        raise InputError(f"a waveform of {int(ns.max())} samples does not fit PulseWaves' 16-bit sample count "
                         "(65,535); shorten the window (bin_ns, the scene's height)")
    unit = float(sample_units_ns)
    first = np.asarray(t0_ns, dtype=np.float64).reshape(-1) / unit  # sampling units from the optical centre
    if first.size and (first.min() < 0 or first.max() + ns.max() > 32_767):
        raise InputError(f"a waveform ends {float((first + ns).max()):,.0f} sampling units from the sensor; PulseWaves' "
                         "pulse record holds 32,767 (16-bit first/last returning sample): fly lower, or a coarser "
                         "sample spacing")
    from clsim.sensor import C_M_PER_NS

    step = 0.5 * C_M_PER_NS * unit  # metres of range per sampling unit (the simulator's time axis: vacuum c)
    target = a + 1000.0 * step * d
    pts = np.vstack([a, target]) if n else np.zeros((1, 3))
    offset = np.floor(pts.min(axis=0))
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    t_off = float(np.floor(t.min())) if n else 0.0
    # the waves: per pulse one segment: duration (int32, 1/1000 unit), sample count (uint16), the samples
    chunks, offsets, pos = [b"PulseWavesWaves\0" + struct.pack("<I", 0) + b"\0" * 40], [], 60
    dtype = _UINT[bits]
    for i in range(n):
        body = struct.pack("<iH", int(round(1000.0 * first[i])), int(ns[i])) + raw[i, :ns[i]].astype(dtype).tobytes()
        offsets.append(pos)
        chunks.append(body)
        pos += len(body)
    rec = np.zeros(n, dtype=_PULSE0)
    rec["T"] = np.round((t - t_off) / t_scale).astype(np.int64)
    rec["offset"] = offsets
    rec["anchor"] = np.round((a - offset) / scale).astype(np.int32)
    rec["target"] = np.round((target - offset) / scale).astype(np.int32)
    rec["first"] = np.floor(first).astype(np.int16)
    rec["last"] = np.ceil(first + ns - 1).astype(np.int16)
    rec["descriptor"] = 1
    sampling = _SAMPLING.pack(_SAMPLING.size + 64, 0, 2, 0, 0, 32, 0.001, 0.0, 0, 16, 1, 0, bits, 0, unit, 0) \
        + _fixed(description, 64)
    composition = _COMPOSITION.pack(_COMPOSITION.size + 64, 0, 0, 0, 1, unit, 0, 0) + _fixed("clsim survey", 64)
    payload = composition + sampling
    vlr = _VLR.pack(_fixed("PulseWaves_Spec", 16), 200001, 0, len(payload), _fixed("pulse descriptor 1", 64)) + payload
    start = _HEADER.size + len(vlr)
    tt = rec["T"]
    header = _HEADER.pack(_fixed("PulseWavesPulse", 16), 0, 0, 0, 0, 0, b"\0" * 8, _fixed(system, 64),
                          _fixed("voxlidar clsim", 64), 1, 2026, 0, 3, _HEADER.size, start, n, 0, 0,
                          _PULSE0.itemsize, 0, 0, 1, 0, t_scale, t_off, int(tt.min()) if n else 0,
                          int(tt.max()) if n else 0, scale, scale, scale, *offset, lo[0], hi[0], lo[1], hi[1],
                          lo[2], hi[2])
    wvs_path = path.with_suffix(".wvs")
    tmp_wvs = wvs_path.with_name(wvs_path.name + ".tmp")
    tmp_wvs.write_bytes(b"".join(chunks))

    def write(tmp):
        Path(tmp).write_bytes(header + vlr + rec.tobytes())

    try:
        atomic_write(path, write)
    except BaseException:
        tmp_wvs.unlink(missing_ok=True)
        raise
    os.replace(tmp_wvs, wvs_path)
    return path, wvs_path
