"""LAS 1.3 / 1.4 waveform packets: reader and writer.

Point formats 4, 5 (LAS 1.3) and 9, 10 (LAS 1.4) carry, per point, a wave
packet descriptor index, the byte offset and size of its waveform data packet,
the return point waveform location (ps from the first sample to the point) and
the parametric line ``x_t, y_t, z_t`` (m per ps). Wave packet descriptors are
VLRs of user ``LASF_Spec`` with record id ``99 + index`` (100-354): bits per
sample, compression, number of samples, temporal spacing (ps), digitiser gain
and offset (volts = offset + gain * raw). Packets live either inside the LAS
file (an EVLR, global encoding bit 1; offsets relative to the header field
"start of waveform data packet record") or in an external ``.wdp`` file next
to it (bit 2; offsets from the start of that file, which begins with a 60-byte
EVLR-style header).

Geometry (LAS 1.3 R11, "X(t), Y(t), Z(t)"): a sample at time ``t`` ps after
the first sample lies at ``P + (L - t) * (x_t, y_t, z_t)`` where ``P`` is the
point and ``L`` its return point location: the vector points from the target
back toward the sensor (z_t > 0 for an airborne survey), its length the
one-way distance per ps of round-trip time (c/2 = 1.499e-4 m/ps in air).

References
----------
ASPRS (2011). LAS Specification Version 1.3 - R11.
ASPRS (2019). LAS Specification 1.4 - R15, sections 2.6 (global encoding),
    2.9 (wave packet descriptor VLR) and 2.7 (point data record format 9).
"""

from __future__ import annotations

import os
import struct
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from clsim.errors import InputError

__all__ = [
    "LasWaveforms",
    "WavePacketDescriptor",
    "read_las_waveforms",
    "write_las_waveforms",
]

_DESC_FMT = "<BBIIdd"
_DESC_SIZE = struct.calcsize(_DESC_FMT)  # 26
_WAVEFORM_POINT_FORMATS = (4, 5, 9, 10)
_EVLR_HEADER = struct.Struct("<H16sHQ32s")  # 60 bytes
_SAMPLE_DTYPES = {8: np.uint8, 16: np.uint16, 32: np.uint32}


@dataclass(frozen=True)
class WavePacketDescriptor:
    """One wave packet descriptor (LAS VLR record id ``99 + index``).

    Attributes
    ----------
    index : int
        1-255; the value points store in their wave packet descriptor index.
    bits_per_sample : int
        8, 16 or 32 (others are legal LAS but not supported here).
    n_samples : int
        Samples per waveform.
    spacing_ps : int
        Temporal sample spacing, picoseconds.
    gain, offset : float
        Digitiser gain and offset: volts = offset + gain * raw.
    compression : int
        Must be 0 (no compression type is defined by LAS).
    """

    index: int
    bits_per_sample: int
    n_samples: int
    spacing_ps: int
    gain: float = 1.0
    offset: float = 0.0
    compression: int = 0

    @property
    def packet_size(self) -> int:
        """Bytes of one waveform packet."""
        return self.n_samples * self.bits_per_sample // 8

    @property
    def record_id(self) -> int:
        return 99 + self.index

    def to_bytes(self) -> bytes:
        return struct.pack(_DESC_FMT, self.bits_per_sample, self.compression, self.n_samples,
                           self.spacing_ps, self.gain, self.offset)

    @classmethod
    def from_bytes(cls, index: int, data: bytes) -> WavePacketDescriptor:
        if len(data) < _DESC_SIZE:
            raise InputError(f"wave packet descriptor VLR {99 + index} has {len(data)} bytes; "
                             f"expected {_DESC_SIZE}. The file is damaged; re-export it.")
        bits, comp, ns, spacing, gain, offset = struct.unpack(_DESC_FMT, data[:_DESC_SIZE])
        return cls(index=index, bits_per_sample=bits, n_samples=ns, spacing_ps=spacing,
                   gain=gain, offset=offset, compression=comp)

    def check(self, *, reading: bool = False) -> None:
        """Raise InputError if this reader/writer cannot handle the descriptor.

        ``reading``: a non-zero compression type is let through here; the
        reader accepts it only where every packet still has its raw size, and
        otherwise says the packets are compressed (LASzip writes type 1 and
        compressed packets, in a ``.wdz`` beside a ``.laz``)."""
        if self.bits_per_sample == 0 and self.n_samples == 0 and self.spacing_ps == 0:
            raise InputError(f"wave packet descriptor {self.index}, which is empty (no sample size, count or "
                             "spacing: an exporter's placeholder record); re-export the file with the descriptor "
                             "its points use")
        if self.bits_per_sample not in _SAMPLE_DTYPES:
            raise InputError(f"wave packet descriptor {self.index}: bits_per_sample="
                             f"{self.bits_per_sample}; supported: 8, 16, 32")
        if self.compression != 0 and not reading:
            raise InputError(f"wave packet descriptor {self.index}: compression="
                             f"{self.compression}; only uncompressed (0) packets are defined")
        if not 1 <= self.index <= 255:
            raise InputError(f"wave packet descriptor index must be 1-255; got {self.index}")
        if self.n_samples < 1 or self.spacing_ps < 1:
            raise InputError(f"wave packet descriptor {self.index}: n_samples="
                             f"{self.n_samples}, spacing_ps={self.spacing_ps}; both must be >= 1")


@dataclass
class LasWaveforms:
    """Points of a LAS file with their waveform packets.

    Attributes
    ----------
    X, Y, Z : (N,) int32
        Scaled integer coordinates as stored (kept for bit-exact rewrite).
    scales, offsets : (3,) float64
        Coordinate scale and offset of the header.
    gps_time : (N,) float64
    return_number, number_of_returns : (N,) uint8
    intensity : (N,) uint16
    classification : (N,) uint8
    descriptor_index : (N,) uint8
        0 = the point has no waveform.
    packet : (N,) int64
        Index of the point's packet in ``raw`` (points of one pulse may share
        a packet); -1 when the point has no waveform.
    return_location_ps : (N,) float32
        Time from the first sample of the packet to the point, ps.
    xyz_t : (N, 3) float32
        Parametric line, m per ps, pointing back toward the sensor.
    raw : (P, S) uint8/uint16/uint32
        Raw samples of each distinct packet (S = the longest descriptor;
        shorter packets are zero padded).
    packet_descriptor : (P,) uint8
        Descriptor index of each packet.
    descriptors : dict[int, WavePacketDescriptor]
    """

    X: np.ndarray
    Y: np.ndarray
    Z: np.ndarray
    scales: np.ndarray
    offsets: np.ndarray
    gps_time: np.ndarray
    return_number: np.ndarray
    number_of_returns: np.ndarray
    intensity: np.ndarray
    classification: np.ndarray
    descriptor_index: np.ndarray
    packet: np.ndarray
    return_location_ps: np.ndarray
    xyz_t: np.ndarray
    raw: np.ndarray
    packet_descriptor: np.ndarray
    descriptors: dict = field(default_factory=dict)
    source: str = ""

    def __len__(self) -> int:
        return int(self.X.size)

    @property
    def xyz(self) -> np.ndarray:
        """(N, 3) float64 point coordinates, metres."""
        ints = np.column_stack([self.X, self.Y, self.Z]).astype(np.float64)
        return ints * self.scales + self.offsets

    @property
    def n_packets(self) -> int:
        return int(self.raw.shape[0])

    def descriptor_of_point(self, i: int) -> WavePacketDescriptor:
        idx = int(self.descriptor_index[i])
        if idx == 0 or self.packet[i] < 0:
            raise InputError(f"point {i} has no waveform (descriptor index 0)")
        return self.descriptors[idx]

    def samples(self, i: int, *, volts: bool = True) -> np.ndarray:
        """Waveform of point ``i``: (S,) volts (gain and offset applied) or raw counts."""
        d = self.descriptor_of_point(i)
        raw = self.raw[self.packet[i], :d.n_samples]
        return d.offset + d.gain * raw.astype(np.float64) if volts else raw.copy()

    def time_ps(self, i: int) -> np.ndarray:
        """(S,) sample times of point ``i``'s waveform, ps from its first sample."""
        d = self.descriptor_of_point(i)
        return np.arange(d.n_samples, dtype=np.float64) * d.spacing_ps

    def sample_positions(self, i: int) -> np.ndarray:
        """(S, 3) positions of the samples of point ``i``'s waveform, metres.

        ``P + (L - t) (x_t, y_t, z_t)`` (LAS 1.3 R11).
        """
        t = self.time_ps(i)
        p = self.xyz[i]
        return p + (float(self.return_location_ps[i]) - t)[:, None] * self.xyz_t[i].astype(
            np.float64)

    def waveform_origin(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """Position of sample 0 (m) and displacement per ns (m/ns) of point ``i``'s waveform.

        Suitable for :func:`clsim.waveforms.decompose.echo_positions`.
        """
        xt = self.xyz_t[i].astype(np.float64)
        origin = self.xyz[i] + float(self.return_location_ps[i]) * xt
        return origin, -1000.0 * xt

    def volts(self) -> np.ndarray:
        """(P, S) float64 every packet in volts (gain/offset of its descriptor)."""
        out = np.zeros(self.raw.shape, dtype=np.float64)
        for idx, d in self.descriptors.items():
            rows = self.packet_descriptor == idx
            out[rows, :d.n_samples] = d.offset + d.gain * self.raw[rows, :d.n_samples]
        return out

    @classmethod
    def from_arrays(cls, xyz, waveforms, *, spacing_ps: int, return_location_ps, xyz_t,
                    gain: float = 1.0, offset: float = 0.0, bits_per_sample: int = 16,
                    gps_time=None, return_number=None, number_of_returns=None,
                    intensity=None, classification=None, scales=(0.001, 0.001, 0.001),
                    offsets=None) -> LasWaveforms:
        """Build from simulated (or any) waveforms, one per point.

        Parameters
        ----------
        xyz : (N, 3) float, metres
        waveforms : (N, S) float
            Waveforms in volts (or any unit); stored as
            ``raw = round((w - offset) / gain)`` clipped to the sample range.
        spacing_ps : int
            Sample spacing, ps.
        return_location_ps : (N,) float
            Time from the first sample to the point, ps.
        xyz_t : (N, 3) or (3,) float
            Parametric line, m/ps, pointing back toward the sensor.
        gain, offset : float
            Digitiser gain/offset written to the descriptor.
        bits_per_sample : {8, 16, 32}
        """
        xyz = np.asarray(xyz, dtype=np.float64)
        if xyz.ndim != 2 or xyz.shape[1] != 3:
            raise InputError(f"xyz must have shape (N, 3); got {xyz.shape}")
        n = xyz.shape[0]
        w = np.asarray(waveforms, dtype=np.float64)
        if w.ndim != 2 or w.shape[0] != n:
            raise InputError(f"waveforms must have shape (N, S) with N={n}; got {w.shape}")
        if not gain > 0:
            raise InputError(f"gain must be > 0; got {gain!r}")
        desc = WavePacketDescriptor(1, int(bits_per_sample), int(w.shape[1]), int(spacing_ps),
                                    float(gain), float(offset))
        desc.check()
        dtype = _SAMPLE_DTYPES[desc.bits_per_sample]
        info = np.iinfo(dtype)
        raw = np.clip(np.rint((w - offset) / gain), info.min, info.max).astype(dtype)
        scales = np.asarray(scales, dtype=np.float64)
        offsets = (np.floor(xyz.min(axis=0)) if offsets is None and n else
                   np.zeros(3) if offsets is None else np.asarray(offsets, dtype=np.float64))
        ints = np.rint((xyz - offsets) / scales)
        if n and (np.abs(ints).max() > np.iinfo(np.int32).max):
            raise InputError("coordinates do not fit int32 at the given scales; pass larger "
                             "scales or offsets closer to the data")
        ints = ints.astype(np.int32)

        def col(v, default, dt):
            return (np.full(n, default, dtype=dt) if v is None
                    else np.asarray(v).astype(dt).reshape(n))

        xt = np.broadcast_to(np.asarray(xyz_t, dtype=np.float32), (n, 3)).copy()
        return cls(X=ints[:, 0], Y=ints[:, 1], Z=ints[:, 2], scales=scales, offsets=offsets,
                   gps_time=col(gps_time, 0.0, np.float64),
                   return_number=col(return_number, 1, np.uint8),
                   number_of_returns=col(number_of_returns, 1, np.uint8),
                   intensity=col(intensity, 0, np.uint16),
                   classification=col(classification, 0, np.uint8),
                   descriptor_index=np.ones(n, np.uint8), packet=np.arange(n, dtype=np.int64),
                   return_location_ps=col(return_location_ps, 0.0, np.float32),
                   xyz_t=xt, raw=raw, packet_descriptor=np.ones(n, np.uint8),
                   descriptors={1: desc})


def _read_descriptors(header) -> dict:
    out = {}
    for vlr in list(header.vlrs) + list(getattr(header, "evlrs", None) or []):
        if getattr(vlr, "user_id", "").rstrip("\0") != "LASF_Spec":
            continue
        rid = int(vlr.record_id)
        if 100 <= rid <= 354:
            data = vlr.record_data_bytes() if hasattr(vlr, "record_data_bytes") else bytes(
                vlr.record_data)
            d = WavePacketDescriptor.from_bytes(rid - 99, data)
            out[d.index] = d
    return out


def _find_wdp(path: Path) -> Path | None:
    for suffix in (".wdp", ".WDP"):
        cand = path.with_suffix(suffix)
        if cand.is_file():
            return cand
    return None


def read_las_waveforms(path: str | os.PathLike, *, wdp: str | os.PathLike | None = None
                       ) -> LasWaveforms:
    """Read the points and waveform packets of a LAS/LAZ 1.3 or 1.4 file.

    Parameters
    ----------
    path : path-like
        LAS or LAZ file with point format 4, 5, 9 or 10.
    wdp : path-like, optional
        External waveform data file; default: ``path`` with suffix ``.wdp``
        when the header says the packets are external.

    Returns
    -------
    LasWaveforms

    Raises
    ------
    InputError
        Not a waveform point format; a point references a descriptor that is
        missing; a packet size that disagrees with its descriptor; a
        truncated or missing ``.wdp``; unsupported bits per sample or
        compression.
    """
    import laspy  # local: laspy is only needed for file work

    path = Path(path)
    if not path.is_file():
        raise InputError(f"LAS file {str(path)!r} does not exist")
    try:
        las = laspy.read(path)
    except Exception as err:  # laspy raises several types for damaged files
        raise InputError(f"could not read {str(path)!r} as LAS/LAZ: {err}") from err
    hdr = las.header
    pf = int(las.point_format.id)
    if pf not in _WAVEFORM_POINT_FORMATS:
        raise InputError(f"{path.name}: point format {pf} has no waveform packets; expected "
                         f"one of {_WAVEFORM_POINT_FORMATS} (LAS 1.3/1.4 full waveform)")
    descriptors = _read_descriptors(hdr)
    n = len(las.points)
    desc_idx = np.asarray(las["wavepacket_index"], dtype=np.uint8)
    offs = np.asarray(las["wavepacket_offset"], dtype=np.uint64)
    sizes = np.asarray(las["wavepacket_size"], dtype=np.uint64)
    used = np.unique(desc_idx[desc_idx > 0])
    missing = [int(i) for i in used if int(i) not in descriptors]
    if missing:
        have = sorted(99 + i for i in descriptors)
        raise InputError(
            f"{path.name}: points use wave packet descriptor index {missing} but the file has "
            f"no LASF_Spec VLR with record id {[99 + i for i in missing]} (present: {have}). "
            "The descriptor VLR was lost, e.g. by a tool that drops unknown VLRs; re-export "
            "the file with its waveform descriptors.")
    # a descriptor is wrong only when a point uses it: exporters write placeholder records (RiPROCESS: 100,
    # two used); the unused ones that this reader could not read are left out
    for idx in used:
        try:
            descriptors[int(idx)].check(reading=True)
        except InputError as err:
            raise InputError(f"{path.name}: {int(np.sum(desc_idx == idx))} point(s) use {err}") from None
    for k in [k for k in descriptors if k not in set(int(i) for i in used)]:
        try:
            descriptors[k].check(reading=True)
        except InputError:
            del descriptors[k]
    has = desc_idx > 0
    expect = np.zeros(n, dtype=np.uint64)
    for idx in used:
        expect[desc_idx == idx] = descriptors[int(idx)].packet_size
    bad = np.flatnonzero(has & (sizes != expect))
    if bad.size and descriptors[int(desc_idx[int(bad[0])])].compression != 0:
        i = int(bad[0])
        d = descriptors[int(desc_idx[i])]
        raise InputError(
            f"{path.name}: its waveform packets are compressed (descriptor {d.index}: compression type "
            f"{d.compression}, packets of {int(sizes[i])} bytes for {d.n_samples} samples of "
            f"{d.bits_per_sample} bits), which this reader does not decode; fix: read the uncompressed "
            f"LAS with its .wdp (laszip -i {path.name} -o {path.stem}.las writes both from the .laz and "
            "its .wdz)")
    if bad.size:
        i = int(bad[0])
        raise InputError(
            f"{path.name}: point {i} has waveform packet size {int(sizes[i])} bytes but its "
            f"descriptor {int(desc_idx[i])} implies {int(expect[i])} "
            f"({descriptors[int(desc_idx[i])].n_samples} samples x "
            f"{descriptors[int(desc_idx[i])].bits_per_sample} bits); {bad.size} point(s) "
            "disagree. The points and descriptors do not belong together.")
    ge = hdr.global_encoding
    internal = bool(getattr(ge, "waveform_data_packets_internal", False))
    external = bool(getattr(ge, "waveform_data_packets_external", False))
    if internal:
        src = path
        base = int(getattr(hdr, "start_of_waveform_data_packet_record", 0) or 0)
        if path.suffix.lower() == ".laz":
            raise InputError(f"{path.name}: internal waveform packets in a LAZ file are "
                             "compressed with the points; decompress to LAS first")
    else:
        src = Path(wdp) if wdp is not None else _find_wdp(path)
        base = 0
        if src is None or not Path(src).is_file():
            raise InputError(
                f"{path.name}: waveform packets are {'external' if external else 'not internal'}"
                f" but the .wdp file {str(path.with_suffix('.wdp'))!r} is missing; keep the "
                ".wdp next to the LAS file with the same name, or pass wdp=")
    if src.stat().st_size == 0:
        raise InputError(f"{path.name}: its waveform packet file {src.name} is empty (0 bytes): the copy was "
                         "cut short; copy the complete .wdp again")
    blob = np.memmap(src, dtype=np.uint8, mode="r")
    absolute = offs.astype(np.int64) + base
    end = absolute + sizes.astype(np.int64)
    over = np.flatnonzero(has & (end > blob.size))
    if over.size:
        i = int(over[0])
        raise InputError(
            f"{Path(src).name} is truncated: point {i}'s packet ends at byte {int(end[i])} but "
            f"the file has {blob.size} bytes ({over.size} packet(s) beyond the end). Copy the "
            "complete .wdp again.")
    keys = np.where(has, absolute, -1)
    uniq, packet = np.unique(keys, return_inverse=True)
    packet = packet.astype(np.int64)
    if uniq.size and uniq[0] == -1:
        packet -= 1
        uniq = uniq[1:]
    first = np.full(uniq.size, -1, np.int64)
    valid = packet >= 0
    first[packet[valid][::-1]] = np.flatnonzero(valid)[::-1]
    pdesc = desc_idx[first] if first.size else np.zeros(0, np.uint8)
    s_max = max((descriptors[int(i)].n_samples for i in used), default=0)
    bits = {descriptors[int(i)].bits_per_sample for i in used} or {8}
    dtype = _SAMPLE_DTYPES[max(bits)]
    raw = np.zeros((uniq.size, s_max), dtype=dtype)
    for idx in used:
        d = descriptors[int(idx)]
        rows = np.flatnonzero(pdesc == idx)
        gather = uniq[rows][:, None] + np.arange(d.packet_size)[None, :]
        chunk = np.asarray(blob[gather.ravel()]).reshape(rows.size, d.packet_size)
        vals = np.ascontiguousarray(chunk).view(np.dtype(_SAMPLE_DTYPES[d.bits_per_sample]
                                                         ).newbyteorder("<"))
        raw[rows, :d.n_samples] = vals
    del blob

    def arr(name, dt):
        return np.asarray(las[name]).astype(dt)

    return LasWaveforms(
        X=np.asarray(las.X, dtype=np.int32), Y=np.asarray(las.Y, dtype=np.int32),
        Z=np.asarray(las.Z, dtype=np.int32), scales=np.asarray(hdr.scales, dtype=np.float64),
        offsets=np.asarray(hdr.offsets, dtype=np.float64),
        gps_time=arr("gps_time", np.float64), return_number=arr("return_number", np.uint8),
        number_of_returns=arr("number_of_returns", np.uint8),
        intensity=arr("intensity", np.uint16), classification=arr("classification", np.uint8),
        descriptor_index=desc_idx, packet=packet,
        return_location_ps=arr("return_point_wave_location", np.float32),
        xyz_t=np.column_stack([arr("x_t", np.float32), arr("y_t", np.float32),
                               arr("z_t", np.float32)]),
        raw=raw, packet_descriptor=pdesc.astype(np.uint8), descriptors=dict(descriptors),
        source=str(path))


def _wdp_header(n_bytes: int) -> bytes:
    return _EVLR_HEADER.pack(0, b"LASF_Spec", 65535, n_bytes,
                             b"clsim waveform data packets".ljust(32, b"\0"))


def write_las_waveforms(path: str | os.PathLike, data: LasWaveforms, *, point_fields=None,
                        extra_bytes=None, system_identifier: str | None = None
                        ) -> tuple[Path, Path]:
    """Write LAS 1.4 point format 9 plus an external ``.wdp`` with the packets.

    The points (laspy opens them) carry the descriptor index, byte offset and
    size of their packet, the return point location and ``x_t, y_t, z_t``;
    one wave packet descriptor VLR per descriptor; global encoding bit 2
    (external packets). The ``.wdp`` starts with a 60-byte EVLR-style header
    (as LAStools writes it) followed by the packets, each distinct packet
    once. Both files are written to temporary names then renamed.

    Parameters
    ----------
    path : path-like
        Destination ``.las``; the packets go to the same name with ``.wdp``.
    data : LasWaveforms
        From :func:`read_las_waveforms` or :meth:`LasWaveforms.from_arrays`.
    point_fields : dict[str, (N,) array], optional
        Further standard point format 9 fields that ``data`` does not hold
        (``scan_angle`` in 0.006 degree steps, ``point_source_id``,
        ``synthetic``, ``withheld``, ``user_data``...), by their laspy name.
    extra_bytes : dict[str, tuple[(N,) array, str]], optional
        Extra byte dimensions (LAS 1.4 extra bytes VLR): name to values (their
        dtype is the stored type) and a description of at most 32 characters.
    system_identifier : str, optional
        The header's system identifier (32 characters at most).

    Returns
    -------
    (las_path, wdp_path)
        Both written or neither (temporary names renamed at the end).
    """
    import laspy

    from voxlidar.safeio import staged

    path = Path(path)
    if path.suffix.lower() != ".las":
        raise InputError(f"path must end in .las (the waveform packets go to a .wdp beside "
                         f"it); got {str(path)!r}")
    for d in data.descriptors.values():
        d.check()
    n = len(data)
    n_packets = data.n_packets
    # packet byte layout: 60-byte header, then packets in order
    psize = np.zeros(n_packets, dtype=np.int64)
    for idx, d in data.descriptors.items():
        psize[data.packet_descriptor == idx] = d.packet_size
    if n_packets and (psize == 0).any():
        bad = sorted(set(int(i) for i in data.packet_descriptor[psize == 0]))
        raise InputError(f"packets use descriptor index {bad} that is not in descriptors "
                         f"{sorted(data.descriptors)}; add the descriptor")
    start = _EVLR_HEADER.size + np.concatenate(([0], np.cumsum(psize)[:-1])).astype(np.int64)
    total = int(psize.sum())

    def write_wdp(tmp):
        with open(tmp, "wb") as fh:
            fh.write(_wdp_header(total))
            if len(data.descriptors) == 1:                # one descriptor: the packets in one go
                (d,) = data.descriptors.values()
                dt = np.dtype(_SAMPLE_DTYPES[d.bits_per_sample]).newbyteorder("<")
                fh.write(np.ascontiguousarray(data.raw[:, :d.n_samples], dtype=dt).tobytes())
                return
            for p in range(n_packets):
                d = data.descriptors[int(data.packet_descriptor[p])]
                dt = np.dtype(_SAMPLE_DTYPES[d.bits_per_sample]).newbyteorder("<")
                fh.write(np.ascontiguousarray(data.raw[p, :d.n_samples], dtype=dt).tobytes())

    point_fields = dict(point_fields or {})
    extra_bytes = dict(extra_bytes or {})
    standard = set(laspy.PointFormat(9).dimension_names)
    for name, values in list(point_fields.items()) + [(k, v[0]) for k, v in extra_bytes.items()]:
        if np.shape(values) != (n,):
            raise InputError(f"point field {name!r} has shape {np.shape(values)}; expected ({n},), "
                             "one value per point")
    unknown = sorted(set(point_fields) - standard)
    if unknown:
        raise InputError(f"point fields {unknown} are not in point format 9; pass them as "
                         "extra_bytes")
    clash = sorted(set(extra_bytes) & standard)
    if clash:
        raise InputError(f"extra bytes {clash} have the names of point format 9 fields; "
                         "rename them")
    header = laspy.LasHeader(version="1.4", point_format=9)
    if extra_bytes:
        header.add_extra_dims([laspy.ExtraBytesParams(name, np.asarray(v).dtype,
                                                      description=str(desc)[:31])
                               for name, (v, desc) in extra_bytes.items()])
    if system_identifier is not None:
        header.system_identifier = str(system_identifier)[:31]
    header.generating_software = "clsim"
    header.scales = np.asarray(data.scales, dtype=np.float64)
    header.offsets = np.asarray(data.offsets, dtype=np.float64)
    header.global_encoding.waveform_data_packets_external = True
    header.global_encoding.waveform_data_packets_internal = False
    header.start_of_waveform_data_packet_record = 0
    for idx in sorted(data.descriptors):
        d = data.descriptors[idx]
        header.vlrs.append(laspy.VLR(user_id="LASF_Spec", record_id=d.record_id,
                                     description="Waveform Data", record_data=d.to_bytes()))
    las = laspy.LasData(header)
    las.X = data.X
    las.Y = data.Y
    las.Z = data.Z
    las.gps_time = data.gps_time
    las.return_number = data.return_number
    las.number_of_returns = data.number_of_returns
    las.intensity = data.intensity
    las.classification = data.classification
    has = data.packet >= 0
    las.wavepacket_index = np.where(has, data.descriptor_index, 0).astype(np.uint8)
    las.wavepacket_offset = np.where(has, start[np.clip(data.packet, 0, None)] if n_packets
                                     else 0, 0).astype(np.uint64)
    las.wavepacket_size = np.where(has, psize[np.clip(data.packet, 0, None)] if n_packets
                                   else 0, 0).astype(np.uint32)
    las.return_point_wave_location = data.return_location_ps.astype(np.float32)
    las.x_t = data.xyz_t[:, 0].astype(np.float32)
    las.y_t = data.xyz_t[:, 1].astype(np.float32)
    las.z_t = data.xyz_t[:, 2].astype(np.float32)
    for name, values in point_fields.items():
        las[name] = np.asarray(values)
    for name, (values, _) in extra_bytes.items():
        las[name] = np.asarray(values)
    wdp_path = path.with_suffix(".wdp")
    with staged([wdp_path, path]) as tmp:
        write_wdp(tmp[wdp_path])
        las.write(str(tmp[path]))
    return path, wdp_path
