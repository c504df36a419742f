"""LAS 1.3/1.4 waveform packets: the real Leica file, the writer's round trip, bad input."""

from __future__ import annotations

import shutil
import struct

import laspy
import numpy as np
import pytest

from clsim.errors import InputError
from clsim.waveforms.io import LasWaveforms, read_las_waveforms, write_las_waveforms

README_FIRST = [13, 12, 13, 13, 14, 13, 13, 17, 42, 67, 87, 100, 104, 84]


@pytest.fixture(scope="module")
def leica_dir(shared_data):
    return shared_data / "leica-fwf-las13"


@pytest.fixture(scope="module")
def leica(leica_dir):
    return read_las_waveforms(leica_dir / "fwf.las")


@pytest.mark.realdata
def test_leica_all_packets_read(leica, leica_dir):
    assert len(leica) == 2250
    assert leica.n_packets == 2250
    d = leica.descriptors[1]
    assert (d.bits_per_sample, d.n_samples, d.spacing_ps) == (8, 256, 2000)
    assert d.gain == pytest.approx(0.0172906, abs=5e-8) and d.offset == 0.0  # README: 7 decimals
    assert leica.raw[leica.packet[0], :14].tolist() == README_FIRST
    # gain applied: volts = offset + gain * raw
    np.testing.assert_allclose(leica.samples(0)[:14], d.gain * np.array(README_FIRST))
    # every packet equals the bytes at its offset in the .wdp (independent plain read)
    las = laspy.read(leica_dir / "fwf.las")
    blob = np.fromfile(leica_dir / "fwf.wdp", dtype=np.uint8)
    offs = np.asarray(las.wavepacket_offset, dtype=np.int64)
    direct = blob[offs[:, None] + np.arange(256)]
    np.testing.assert_array_equal(leica.raw[leica.packet], direct)


@pytest.mark.realdata
def test_leica_return_location_sits_on_an_echo(leica):
    """The return point location (ps) of each point falls on a waveform peak.

    Independent check of the L / spacing convention: within one sample of a
    local maximum rising at least 5 counts above the baseline (median) for
    at least 95 % of the points.
    """
    d = leica.descriptors[1]
    hits = 0
    for i in range(len(leica)):
        w = leica.samples(i, volts=False).astype(float)
        j = int(round(float(leica.return_location_ps[i]) / d.spacing_ps))
        lo, hi = max(j - 1, 0), min(j + 2, w.size)
        k = lo + int(np.argmax(w[lo:hi]))
        ok = 0 < k < w.size - 1 and w[k] >= w[k - 1] and w[k] >= w[k + 1]
        hits += ok and w[k] - np.median(w) >= 5
    assert hits / len(leica) >= 0.95


@pytest.mark.realdata
def test_sample_positions_follow_the_las_line(leica):
    i = 0
    pos = leica.sample_positions(i)
    d = leica.descriptors[1]
    L = float(leica.return_location_ps[i])
    # at t = L the line passes through the point itself
    j = L / d.spacing_ps
    at_l = pos[0] + (pos[1] - pos[0]) * j
    np.testing.assert_allclose(at_l, leica.xyz[i], atol=1e-6)
    # consecutive samples are c/2 * 2 ns = 0.2998 m apart, going down (away from the sensor)
    step = np.linalg.norm(pos[1] - pos[0])
    assert step == pytest.approx(0.2998, abs=0.002)
    assert pos[1, 2] < pos[0, 2]


@pytest.mark.realdata
def test_writer_round_trip_is_bit_exact(leica, tmp_path):
    las_path, wdp_path = write_las_waveforms(tmp_path / "out.las", leica)
    back = read_las_waveforms(las_path)
    for name in ("X", "Y", "Z", "gps_time", "return_number", "number_of_returns", "intensity",
                 "classification", "descriptor_index", "packet", "raw", "packet_descriptor"):
        np.testing.assert_array_equal(getattr(back, name), getattr(leica, name), err_msg=name)
    # floats compared bit for bit
    assert back.return_location_ps.tobytes() == leica.return_location_ps.tobytes()
    assert back.xyz_t.tobytes() == leica.xyz_t.tobytes()
    assert back.descriptors == leica.descriptors
    np.testing.assert_array_equal(back.scales, leica.scales)
    # laspy opens the points as LAS 1.4 point format 9 with external waveforms
    pts = laspy.read(las_path)
    assert str(pts.header.version) == "1.4" and pts.point_format.id == 9
    assert pts.header.global_encoding.waveform_data_packets_external
    # the .wdp holds exactly the packets after its 60-byte header
    blob = wdp_path.read_bytes()
    assert len(blob) == 60 + 2250 * 256
    assert blob[60:] == leica.raw.tobytes()
    # writing again gives byte-identical files
    las2, wdp2 = write_las_waveforms(tmp_path / "again.las", back)
    assert wdp2.read_bytes() == blob
    assert las2.read_bytes() == las_path.read_bytes()


def test_from_arrays_simulated_waveforms(tmp_path, rng):
    n, s = 20, 64
    t = np.arange(s)
    w = 0.05 + 0.8 * np.exp(-0.5 * ((t[None, :] - rng.uniform(10, 50, (n, 1))) / 2.0) ** 2)
    xyz = rng.uniform(0, 50, (n, 3)) + [500000.0, 4100000.0, 100.0]
    data = LasWaveforms.from_arrays(xyz, w, spacing_ps=1000, return_location_ps=np.full(n, 2e4),
                                    xyz_t=[0.0, 0.0, 1.499e-4], gain=1e-3, offset=0.0)
    las_path, _ = write_las_waveforms(tmp_path / "sim.las", data)
    back = read_las_waveforms(las_path)
    np.testing.assert_allclose(back.volts(), w, atol=0.5e-3 + 1e-12)
    np.testing.assert_allclose(back.xyz, xyz, atol=0.5e-3 + 1e-9)
    assert back.xyz_t[0, 2] == np.float32(1.499e-4)


def test_internal_packets(tmp_path, rng):
    """Packets inside the LAS file (global encoding bit 1, offsets from the EVLR start)."""
    n, s = 5, 16
    w = rng.integers(0, 200, (n, s)).astype(float)
    data = LasWaveforms.from_arrays(rng.uniform(0, 10, (n, 3)), w, spacing_ps=1000,
                                    return_location_ps=np.zeros(n), xyz_t=[0, 0, 1.5e-4],
                                    bits_per_sample=8)
    las_path, wdp_path = write_las_waveforms(tmp_path / "a.las", data)
    body = bytearray(las_path.read_bytes())
    start = len(body)
    body += wdp_path.read_bytes()  # the .wdp is an EVLR header + packets
    ge = struct.unpack_from("<H", body, 6)[0]
    struct.pack_into("<H", body, 6, (ge & ~0b110) | 0b010)  # internal, not external
    struct.pack_into("<Q", body, 227, start)  # start of waveform data packet record
    struct.pack_into("<Q", body, 235, start)  # start of first EVLR
    struct.pack_into("<I", body, 243, 1)  # one EVLR
    internal = tmp_path / "internal.las"
    internal.write_bytes(bytes(body))
    wdp_path.unlink()
    back = read_las_waveforms(internal)
    np.testing.assert_array_equal(back.raw, w.astype(np.uint8))


# ------------------------------------------------------------ bad input ---

@pytest.fixture
def leica_copy(leica_dir, tmp_path):
    shutil.copy(leica_dir / "fwf.las", tmp_path / "fwf.las")
    shutil.copy(leica_dir / "fwf.wdp", tmp_path / "fwf.wdp")
    return tmp_path / "fwf.las"


@pytest.mark.realdata
def test_truncated_wdp(leica_copy):
    wdp = leica_copy.with_suffix(".wdp")
    wdp.write_bytes(wdp.read_bytes()[:-1000])
    with pytest.raises(InputError, match="truncated"):
        read_las_waveforms(leica_copy)


@pytest.mark.realdata
def test_missing_wdp(leica_copy):
    leica_copy.with_suffix(".wdp").unlink()
    with pytest.raises(InputError, match=r"\.wdp.*missing"):
        read_las_waveforms(leica_copy)


@pytest.mark.realdata
def test_wrong_packet_size(leica_copy):
    las = laspy.read(leica_copy)
    size = np.asarray(las.wavepacket_size).copy()
    size[7] = 255
    las.wavepacket_size = size
    las.write(leica_copy)
    with pytest.raises(InputError, match="point 7 has waveform packet size 255"):
        read_las_waveforms(leica_copy)


@pytest.mark.realdata
def test_missing_descriptor(leica_copy):
    las = laspy.read(leica_copy)
    las.header.vlrs = [v for v in las.header.vlrs if v.record_id != 100]
    las.write(leica_copy)
    with pytest.raises(InputError, match="record id \\[100\\]"):
        read_las_waveforms(leica_copy)


def test_not_a_waveform_point_format(tmp_path):
    las = laspy.LasData(laspy.LasHeader(version="1.4", point_format=6))
    las.x = np.zeros(3)
    las.y = np.zeros(3)
    las.z = np.zeros(3)
    las.write(tmp_path / "p6.las")
    with pytest.raises(InputError, match="point format 6 has no waveform"):
        read_las_waveforms(tmp_path / "p6.las")


def test_leica_laz_copy_says_its_packets_are_compressed(leica_dir):
    """rlas's LAZ copy has LASzip-compressed packets (type 1, 80 bytes for 256 samples): one
    clear error naming the fix, not 'compression=1; only uncompressed packets are defined'."""
    with pytest.raises(InputError, match=r"packets are compressed .*compression type 1, packets of 80 bytes.*fix:"):
        read_las_waveforms(leica_dir / "fwf.laz")


def test_unused_empty_descriptor_records_are_left_out(tmp_path, rng):
    """An exporter's placeholder descriptors (RiPROCESS writes 100, two used): read while no point uses one."""
    n, s = 10, 32
    w = rng.integers(0, 200, (n, s)).astype(float)
    data = LasWaveforms.from_arrays(rng.uniform(0, 10, (n, 3)), w, spacing_ps=1000,
                                    return_location_ps=np.full(n, 5e3), xyz_t=[0.0, 0.0, 1.5e-4])
    las_path, _ = write_las_waveforms(tmp_path / "rp.las", data)
    las = laspy.read(las_path)
    first = next(v for v in las.header.vlrs if v.record_id == 100)
    body = first.record_data_bytes() if hasattr(first, "record_data_bytes") else bytes(first.record_data)
    las.header.vlrs.append(laspy.VLR(user_id="LASF_Spec", record_id=101, description="", record_data=body))
    for rid in range(102, 200):  # 98 empty placeholders
        las.header.vlrs.append(laspy.VLR(user_id="LASF_Spec", record_id=rid, description="", record_data=bytes(26)))
    index = np.asarray(las["wavepacket_index"]).copy()
    index[::2] = 2  # half the points use the second (identical) descriptor
    las["wavepacket_index"] = index
    las.write(las_path)
    back = read_las_waveforms(las_path)
    assert sorted(back.descriptors) == [1, 2]
    np.testing.assert_array_equal(back.raw[back.packet], data.raw[data.packet])
    index[3] = 7  # a point that uses an empty one: one clear line
    las["wavepacket_index"] = index
    las.write(las_path)
    with pytest.raises(InputError, match="1 point\\(s\\) use wave packet descriptor 7, which is empty"):
        read_las_waveforms(las_path)
