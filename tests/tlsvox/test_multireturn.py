"""Pulse-grouped multi-return exports (tlsvox.readers.pulse_text): ASCII rows with miss rows,
and LAS/LAZ grouped by GPS time, written here from a simulated scan of a leaf box and
read back into the same pulses, echoes and LAD; malformed files give one clear line."""

from __future__ import annotations

import numpy as np
import pytest

from tlsvox.errors import InputError, ScanFileError
from tlsvox.readers import ScanFormat, read_any, scan_format
from tlsvox.readers.pulse_text import looks_pulse_grouped, pulse_ids_from_time, read_pulse_text
from tlsvox.scan import Scan
from tlsvox.voxel.stages import voxelize

ORIGIN = np.array([100.0, 200.0, 10.0])  # the scanner in the file's coordinates


@pytest.fixture(scope="module")
def sim():
    """A simulated scan of a leaf box (1 m cube, 7 sub-rays, 0.5 deg steps), pose = identity."""
    pytest.importorskip("open3d")
    from tlsvox.truth.scanner import ScannerPreset, ScanPose, simulate_scan
    from tlsvox.truth.synthetic import make_leaf_slab

    box = make_leaf_slab(lad=2.0, size=(1.0, 1.0, 1.0), origin=(2.5, -0.5, -0.5), seed=5)
    preset = ScannerPreset.riegl_vz400(zenith_step_deg=0.5, azimuth_step_deg=0.5, n_subrays=7)
    scan = simulate_scan(box, pose=ScanPose(position=(0.0, 0.0, 0.0)), preset=preset, seed=1, progress=False)
    scan.pose = np.eye(4)
    assert (scan.pulses.n_echoes == 0).sum() > 100 and (scan.number_of_returns > 1).any()
    return scan


def write_rows(scan, path, *, miss="far", header=None, sep=" ", shift=ORIGIN):
    """One row per echo, one miss row per empty pulse, in time (= pulse) order."""
    xyz = scan.xyz + shift
    t = 1000.0 + 1e-5 * scan.pulse_id
    rows = np.column_stack([xyz, t, scan.return_number, scan.number_of_returns])
    empty = np.nonzero(scan.pulses.n_echoes == 0)[0]
    d = scan.pulses.direction[empty].astype(np.float64)
    if miss == "far":  # a point 1e6 m along the beam, return count 0
        m = np.column_stack([d * 1e6 + shift, 1000.0 + 1e-5 * empty, np.zeros(len(empty)), np.zeros(len(empty))])
    elif miss == "far-as-echo":  # flagged only by its distance
        m = np.column_stack([d * 1e6 + shift, 1000.0 + 1e-5 * empty, np.ones(len(empty)), np.ones(len(empty))])
    else:  # NaN coordinates: no direction
        m = np.column_stack([np.full((len(empty), 3), np.nan), 1000.0 + 1e-5 * empty, np.zeros((len(empty), 2))])
    allrows = np.vstack([rows, m])
    allrows = allrows[np.argsort(allrows[:, 3], kind="stable")]
    text = "\n".join(sep.join(f"{v:.6f}" if i < 4 else f"{int(v)}" if np.isfinite(v) else "nan"
                              for i, v in enumerate(r)) for r in allrows)
    path.write_text((header + "\n" if header else "") + text + "\n")
    return path


def _same_pulses(scan, back):
    assert len(back) == len(scan)
    assert len(back.pulses) == len(scan.pulses)
    assert back.pulses.n_echoes.tolist() == scan.pulses.n_echoes.tolist()
    assert np.allclose(back.pulses.origin, ORIGIN)
    cos = np.sum(back.pulses.direction * scan.pulses.direction, axis=1)
    assert cos.min() > np.cos(np.deg2rad(0.05))
    assert np.array_equal(back.pulse_id, scan.pulse_id)
    assert np.array_equal(back.return_number, scan.return_number)


@pytest.mark.parametrize("miss", ["far", "far-as-echo"])
def test_miss_rows_become_pulses_without_echo(sim, tmp_path, miss):
    path = write_rows(sim, tmp_path / "sim.txt", miss=miss)
    back = read_any(path, origin=ORIGIN)
    _same_pulses(sim, back)
    assert back.meta["miss_rows"] == int((sim.pulses.n_echoes == 0).sum())


def test_voxelised_like_the_original(sim, tmp_path):
    path = write_rows(sim, tmp_path / "sim.csv", sep=",",
                      header="# x,y,z,gps_time,return_number,number_of_returns")
    back = read_any(path, origin=ORIGIN)
    _same_pulses(sim, back)
    kw = dict(voxel_size=0.25, ground=None, bounds=[[2.5, -0.5, -0.5], [3.5, 0.5, 0.5]], progress=False,
              echo_weights="uniform")
    a = voxelize([sim], **kw, scanner_frame=True)
    shifted = np.eye(4)
    shifted[:3, 3] = -ORIGIN  # the file's frame back onto the scanner's
    back.pose = shifted
    b = voxelize([back], **kw)
    assert a.scene.n_voxels == b.scene.n_voxels > 0
    assert np.allclose(a.lad.lad, b.lad.lad, rtol=1e-4, atol=1e-6)


def test_extra_columns_by_header(sim, tmp_path):
    path = write_rows(sim, tmp_path / "h.txt", header="x y z time return_index return_count")
    text = path.read_text().splitlines()
    # add a beam_fraction column: the echoes' shares, 1 for miss rows
    frac = iter(sim.beam_fraction[np.argsort(sim.pulse_id, kind="stable")])
    out = [text[0] + " beam_fraction"] + [ln + (f" {next(frac):.6f}" if ln.split()[-1] != "0" else " 1")
                                          for ln in text[1:]]
    path.write_text("\n".join(out) + "\n")
    back = read_pulse_text(path, origin=ORIGIN)
    assert np.allclose(np.sort(back.beam_fraction), np.sort(sim.beam_fraction), atol=1e-6)


def test_xyz_suffix_is_sniffed(sim, tmp_path):
    path = write_rows(sim, tmp_path / "sim.xyz")
    assert scan_format(path) is ScanFormat.PULSES
    assert len(read_any(path, origin=ORIGIN).pulses) == len(sim.pulses)
    rgb = tmp_path / "colour.xyz"
    rgb.write_text("\n".join(f"{i} {i % 7} 1.0 {200 - i} {i % 255} {i % 100}" for i in range(50)) + "\n")
    assert not looks_pulse_grouped(rgb) and scan_format(rgb) is ScanFormat.XYZ


def test_nan_miss_rows_need_a_direction(sim, tmp_path):
    path = write_rows(sim, tmp_path / "nan.txt", miss="nan")
    with pytest.raises(InputError, match=r"miss rows .* have no coordinates, so their beam direction is unknown"):
        read_any(path, origin=ORIGIN)


BAD = {
    "columns": ("1 2 3 0.1 1 1\n1 2 3 0.2 1\n", "number of columns changed"),
    "index above count": ("1 2 3 0.1 3 2\n", "return_index 3 is above its return_count 2"),
    "counts disagree": ("1 2 3 0.1 1 2\n2 2 3 0.1 2 3\n", "disagree on the return count"),
    "index twice": ("1 2 3 0.1 1 2\n2 2 3 0.1 1 2\n", "both have return index 1"),
    "fractional index": ("1 2 3 0.1 1.5 2\n", "return_index=1.5 must be a whole number"),
    "two miss rows": ("1 2 3 0.1 1 2\n0 9e6 0 0.1 2 2\n0 9e6 1 0.1 3 2\n", "has 2 miss rows"),
    "header lacks a column": ("x y z time return_index\n1 2 3 0.1 1\n", "but not ['return_count']"),
    "header only": ("x y z time return_index return_count\n", "no rows"),
    "words": ("one two three\n1 2 3\n", "but not"),
    "time not a number": ("1 2 3 nan 1 1\n", "time that is not a number"),
    "echo at the origin": ("0 0 0 0.1 1 1\n", "at the scanner origin"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_malformed_files_one_line(tmp_path, case):
    text, says = BAD[case]
    path = tmp_path / "bad.txt"
    path.write_text(text)
    with pytest.raises(InputError, match=None) as err:
        read_pulse_text(path)
    msg = str(err.value)
    assert says in msg and "\n" not in msg and str(path) in msg, msg


def test_empty_and_missing_files(tmp_path):
    (tmp_path / "e.txt").write_text("")
    with pytest.raises(InputError, match="is empty"):
        read_pulse_text(tmp_path / "e.txt")
    with pytest.raises(ScanFileError, match="does not exist"):
        read_pulse_text(tmp_path / "nope.txt")
    (tmp_path / "p.xyz").write_text("0 0 1\n1 0 1\n0 1 1\n")
    with pytest.raises(InputError, match="origin= is for pulse-grouped text and LAS"):
        read_any(tmp_path / "p.xyz", origin=(0, 0, 0))


def _las(tmp_path):
    Scan(xyz=np.ones((3, 3)) + np.arange(3)[:, None], name="plain").write(tmp_path / "plain.las")
    return tmp_path / "plain.las"


# ---- LAS/LAZ grouped by GPS time

def _foreign_las(scan, path, times):
    """A LAS written by another tool: no pulse_id dimension, no sidecars, pulses by GPS time."""
    import laspy

    h = laspy.LasHeader(point_format=6, version="1.4")
    h.scales = np.array([1e-4] * 3)
    las = laspy.LasData(h)
    las.x, las.y, las.z = scan.xyz[:, 0], scan.xyz[:, 1], scan.xyz[:, 2]
    las.return_number = scan.return_number
    las.number_of_returns = scan.number_of_returns
    las.gps_time = times
    las.write(str(path))
    return path


def test_las_pulses_grouped_by_gps_time(sim, tmp_path):
    rng = np.random.default_rng(0)
    perm = rng.permutation(len(sim))  # echoes in any order
    shuffled = Scan(xyz=sim.xyz[perm], return_number=sim.return_number[perm],
                    number_of_returns=sim.number_of_returns[perm])
    times = 5e8 + 1e-5 * sim.pulse_id[perm]
    back = Scan.read(_foreign_las(shuffled, tmp_path / "foreign.laz", times))
    assert back.meta["pulse_grouping"] == "gps_time" and back.pulses is None
    # the same partition of echoes into pulses as the simulator's
    truth = sim.pulse_id[perm]
    pairs = set(zip(back.pulse_id.tolist(), truth.tolist()))
    assert len(pairs) == len(np.unique(truth)) == len(np.unique(back.pulse_id))
    # 1/n per pulse from its return count: every pulse's weights add up to 1
    from tlsvox.voxel.pulses import beams_from_scan

    back.pose = np.eye(4)
    beams, info = beams_from_scan(back, reconstruct=False, echo_weights="uniform")
    sums = np.add.reduceat(beams.echo_weight, beams.echo_start[:-1][np.diff(beams.echo_start) > 0])
    assert np.allclose(sums, 1.0) and info["pulses"] == len(np.unique(truth))


def test_las_times_that_do_not_group_pulses_are_ignored(sim, tmp_path):
    back = Scan.read(_foreign_las(sim, tmp_path / "zero.laz", np.zeros(len(sim))))
    assert back.pulse_id is None and "pulse_grouping" not in back.meta


def test_pulse_ids_from_time():
    pid = pulse_ids_from_time([3.0, 1.0, 3.0, 2.0], [1, 1, 2, 1], [2, 1, 2, 1])
    assert pid.tolist() == [2, 0, 2, 1]


def test_cli_voxelizes_a_pulse_text_export(sim, tmp_path, capsys):
    import json

    from tlsvox.cli.voxelize import main

    path = write_rows(sim, tmp_path / "sim.txt")
    out = tmp_path / "scene.npz"
    code = main([str(path), "--scanner-frame", "--scan-origin", ",".join(map(str, ORIGIN)), "--ground", "none",
                 "--voxel-size", "0.25", "-o", str(out)])
    text = capsys.readouterr().out
    assert code == 0 and out.exists()
    summary = json.loads(text[text.index("{"):])
    assert summary["echo_weights"] == ["uniform"] and summary["beams"] == len(sim.pulses)


def write_helios(scan, path, shift=ORIGIN):
    """The scan as HELIOS++ writes its point output (``legNNN_points.xyz``): one row per echo, 11 columns,
    4 decimals, pulses by their full-waveform index; no row for a pulse that hit nothing."""
    xyz = scan.xyz + shift
    rows = np.column_stack([xyz, np.full(len(scan), 12.5), np.full(len(scan), 1.3), scan.return_number,
                            scan.number_of_returns, 5000 + scan.pulse_id, np.full(len(scan), 3),
                            np.zeros(len(scan)), 1e3 * (1000.0 + 1e-5 * scan.pulse_id)])
    ints = (5, 6, 7, 8, 9)
    path.write_text("\n".join(" ".join(f"{int(v)}" if i in ints else f"{v:.4f}" for i, v in enumerate(r))
                              for r in rows) + "\n")
    return path


def test_helios_point_output_read_and_voxelised_with_the_angular_grid(sim, tmp_path):
    """HELIOS++'s point layout is recognised, its pulses grouped by full-waveform index, its echoes kept; it
    has no empty pulses, so voxelize rebuilds them from the angular grid (said when none is given), and the
    leaf box's LAD comes back as from the scan with every pulse."""
    path = write_helios(sim, tmp_path / "leg000_points.xyz")
    assert scan_format(path) is ScanFormat.PULSES
    back = read_any(path, origin=ORIGIN)
    assert back.meta["layout"] == "HELIOS++ point output" and back.pulses is None
    assert len(back) == len(sim) and np.array_equal(back.return_number, sim.return_number)
    assert len(np.unique(back.pulse_id)) == len(np.unique(sim.pulse_id))
    assert np.allclose(back.xyz, sim.xyz, atol=1e-4) and np.allclose(back.pose[:3, 3], ORIGIN)
    assert np.allclose(back.intensity, 12.5)
    kw = dict(voxel_size=0.25, ground=None, bounds=[[102.5, 199.5, 9.5], [103.5, 200.5, 10.5]], progress=False,
              echo_weights="uniform")
    with pytest.raises(InputError, match="angular grid"):
        voxelize([back], **kw)
    g = sim.pulses.grid
    grid = dict(zenith_start_deg=g.zenith_start_deg, zenith_step_deg=g.zenith_step_deg, n_zenith=g.n_zenith,
                azimuth_start_deg=g.azimuth_start_deg, azimuth_step_deg=g.azimuth_step_deg, n_azimuth=g.n_azimuth)
    b = voxelize([back], **kw, angular_grid=grid)
    full = sim.world_xyz(np.eye(4))  # the original, every pulse in its table, in the same world
    moved = Scan(xyz=full, return_number=sim.return_number, number_of_returns=sim.number_of_returns,
                 pulse_id=sim.pulse_id, pulses=sim.pulses, pose=back.pose, name="full")
    a = voxelize([moved], **kw)
    assert a.scene.n_voxels == b.scene.n_voxels > 0
    # the rebuilt directions sit on the grid, the measured ones scatter by the sub-rays: within 2 %
    assert abs(b.lad.lad.sum() / a.lad.lad.sum() - 1) < 0.02


def test_a_scan_without_its_misses_is_named_as_the_cause(sim, tmp_path):
    """An export that dropped its miss rows reads (every pulse it lists has an echo); voxelize then warns that
    the scan has no empty pulses and blames them, not the grid or the units, for the implausible LAD."""
    path = write_rows(sim, tmp_path / "nomiss.txt")
    lines = [ln for ln in path.read_text().splitlines() if not ln.endswith(" 0 0")]  # the miss rows go
    path.write_text("\n".join(lines) + "\n")
    back = read_any(path, origin=ORIGIN)
    assert back.meta["miss_rows"] == 0 and (back.pulses.n_echoes > 0).all()
    shifted = np.eye(4)
    shifted[:3, 3] = -ORIGIN
    back.pose = shifted
    res = voxelize([back], voxel_size=0.25, ground=None, bounds=[[2.5, -0.5, -0.5], [3.5, 0.5, 0.5]],
                   progress=False)
    said = [w for w in res.scene.meta["warnings"] if "no empty pulses" in w]
    assert len(said) == 1 and "--angular-grid" in said[0] and "biased high" in said[0]
    with_misses = voxelize([sim], voxel_size=0.25, ground=None, bounds=[[2.5, -0.5, -0.5], [3.5, 0.5, 0.5]],
                           progress=False, scanner_frame=True)
    assert not any("no empty pulses" in w for w in with_misses.scene.meta["warnings"])


def write_with_tails(scan, path, shift=ORIGIN):
    """Another simulator's layout: a partly intercepted pulse (its echoes' beam fractions sum under 1) gets a
    miss row numbered after its echoes and counted in its return count, 1e6 m along its beam; an empty pulse
    one miss row numbered 1 of 1."""
    frac = np.bincount(scan.pulse_id, weights=scan.beam_fraction, minlength=len(scan.pulses))
    k = scan.pulses.n_echoes.astype(int)
    partial = (k > 0) & (frac < 0.999)
    n = k + partial
    t = 1000.0 + 1e-5 * np.arange(len(scan.pulses))
    d = scan.pulses.direction.astype(np.float64)
    rows = [np.column_stack([scan.xyz + shift, t[scan.pulse_id], scan.return_number, n[scan.pulse_id]])]
    tails = np.nonzero(partial | (k == 0))[0]
    rows.append(np.column_stack([d[tails] * 1e6 + shift, t[tails], np.maximum(k[tails] + 1, 1), np.maximum(n[tails], 1)]))
    allrows = np.vstack(rows)
    allrows = allrows[np.argsort(allrows[:, 3], kind="stable")]
    path.write_text("\n".join(" ".join(f"{v:.6f}" if i < 4 else f"{int(v)}" for i, v in enumerate(r))
                               for r in allrows) + "\n")
    return path, int(partial.sum())


def test_a_miss_row_in_a_pulse_with_echoes_is_its_tail(sim, tmp_path):
    """The tail's share goes on through the voxels: with 1/n weights that count it, the leaf box's LAD comes
    nearer the estimate with the measured beam fractions (the unbiased one, issue 14) than 1/n without."""
    path, n_partial = write_with_tails(sim, tmp_path / "tails.txt")
    back = read_any(path, origin=ORIGIN)
    assert n_partial > 100 and back.meta["tail_rows"] == n_partial and len(back) == len(sim)
    assert len(back.pulses) == len(sim.pulses)
    shifted = np.eye(4)
    shifted[:3, 3] = -ORIGIN
    back.pose = shifted
    kw = dict(voxel_size=0.25, ground=None, bounds=[[2.5, -0.5, -0.5], [3.5, 0.5, 0.5]], progress=False)
    tails = voxelize([back], **kw, echo_weights="uniform").lad.lad.sum()
    plain = voxelize([sim], **kw, echo_weights="uniform", scanner_frame=True).lad.lad.sum()
    fraction = voxelize([sim], **kw, echo_weights="fraction", scanner_frame=True).lad.lad.sum()
    print(f"total LAD: fractions {fraction:.1f}, 1/n with tails {tails:.1f}, 1/n {plain:.1f}")
    assert abs(tails - fraction) < 0.5 * abs(plain - fraction)


def write_helios_las(scan, path, shift=ORIGIN):
    """The scan as HELIOS++ writes its LAS output: LAS 1.4 point format 6 in world coordinates, extra bytes
    echo_width and heliosAmplitude (double), fullwaveIndex and hitObjectId (int); one GPS time per pulse, no
    point for a pulse that hit nothing."""
    import laspy

    h = laspy.LasHeader(point_format=6, version="1.4")
    h.scales = np.array([1e-4] * 3)
    h.offsets = np.floor(scan.xyz.min(axis=0) + shift)
    h.add_extra_dims([laspy.ExtraBytesParams("echo_width", np.float64, description="Helios++ echo width"),
                      laspy.ExtraBytesParams("fullwaveIndex", np.int32, description="Helios++ fullwave index"),
                      laspy.ExtraBytesParams("hitObjectId", np.int32, description="Helios++ hit object ID"),
                      laspy.ExtraBytesParams("heliosAmplitude", np.float64, description="Helios++ Amplitude")])
    las = laspy.LasData(h)
    xyz = scan.xyz + shift
    las.x, las.y, las.z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    las.return_number, las.number_of_returns = scan.return_number, scan.number_of_returns
    las.gps_time = 1000.0 + 1e-5 * scan.pulse_id
    las.echo_width = np.full(len(scan), 1.3)
    las.fullwaveIndex = 7000 + scan.pulse_id.astype(np.int32)
    las.hitObjectId = np.full(len(scan), 3, np.int32)
    las.heliosAmplitude = np.full(len(scan), 12.5)
    las.write(str(path))
    return path


def test_helios_las_output_read_and_voxelised_with_the_angular_grid(sim, tmp_path):
    """HELIOS++'s LAS output: pulses by fullwaveIndex, world coordinates put in the scanner's frame by the
    scan origin, no empty pulses (rebuilt from the angular grid); the leaf box's LAD as from the scan with
    every pulse (within 2 %, the rebuilt directions on the grid against the measured ones)."""
    path = write_helios_las(sim, tmp_path / "leg000_points.las")
    back = read_any(path, origin=ORIGIN)
    assert back.meta["layout"] == "HELIOS++ LAS output" and back.meta["hit_object_ids"] == [3]
    assert back.pulses is None and len(back) == len(sim)
    assert len(np.unique(back.pulse_id)) == len(np.unique(sim.pulse_id))
    assert np.allclose(back.xyz, sim.xyz, atol=2e-4) and np.allclose(back.pose[:3, 3], ORIGIN)
    g = sim.pulses.grid
    grid = dict(zenith_start_deg=g.zenith_start_deg, zenith_step_deg=g.zenith_step_deg, n_zenith=g.n_zenith,
                azimuth_start_deg=g.azimuth_start_deg, azimuth_step_deg=g.azimuth_step_deg, n_azimuth=g.n_azimuth)
    kw = dict(voxel_size=0.25, ground=None, bounds=[[102.5, 199.5, 9.5], [103.5, 200.5, 10.5]], progress=False,
              echo_weights="uniform")
    b = voxelize([back], **kw, angular_grid=grid)
    moved = Scan(xyz=sim.xyz, return_number=sim.return_number, number_of_returns=sim.number_of_returns,
                 pulse_id=sim.pulse_id, pulses=sim.pulses, pose=back.pose, name="full")
    a = voxelize([moved], **kw)
    assert a.scene.n_voxels == b.scene.n_voxels > 0
    assert abs(b.lad.lad.sum() / a.lad.lad.sum() - 1) < 0.02


def test_cli_voxelizes_a_helios_las_with_its_scan_origin(sim, tmp_path, capsys):
    from tlsvox.cli.voxelize import main

    path = write_helios_las(sim, tmp_path / "leg000_points.las")
    g = sim.pulses.grid
    grid = (f"{g.zenith_start_deg},{g.zenith_step_deg},{g.n_zenith},{g.azimuth_start_deg},{g.azimuth_step_deg},"
            f"{g.n_azimuth}")
    out = tmp_path / "scene.npz"
    code = main([str(path), "--scan-origin", ",".join(map(str, ORIGIN)), "--angular-grid", grid, "--ground", "none",
                 "--voxel-size", "0.25", "-q", "-o", str(out)])
    err = capsys.readouterr().err
    assert code == 0 and out.exists(), err
    # a scan that has a pose sidecar refuses an origin: its echoes are in its scanner's frame already
    sim.pose = np.eye(4)
    sim.write(tmp_path / "posed.laz")
    code = main([str(tmp_path / "posed.laz"), "--scan-origin", "1,2,3", "-q", "-o", str(tmp_path / "x.npz")])
    err = capsys.readouterr().err
    assert code == 2 and "has a pose" in err and len(err.strip().splitlines()) == 1
