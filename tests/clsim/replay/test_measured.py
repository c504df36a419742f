"""Measured pulses: scan lines, positions rebuilt from the scan geometry, the NEON reader."""

from __future__ import annotations

import numpy as np
import pytest

from clsim.errors import InputError
from clsim.replay import read_neon, rebuild_positions, scan_lines


def _two_lines(rng):
    """Two zigzag scan lines from scanners that move along x; sample-0 positions exact and as NEON stores them."""
    dy = np.r_[np.linspace(-0.02, 0.02, 50), np.linspace(0.02, -0.02, 50)]
    d = np.stack([np.full(100, 0.0008) + rng.normal(0, 1e-5, 100), dy, np.full(100, -0.1499)], 1)
    k = np.r_[np.arange(50) - 24.5, np.arange(50) - 24.5]
    scanner = np.array([[10.0, 0.0, 1300.0], [10.6, 0.2, 1301.0]])
    line = np.repeat([0, 1], 50)
    origin = scanner[line] + np.c_[0.004 * k, np.zeros(100), np.zeros(100)]
    s = (origin[:, 2] - rng.uniform(345, 355, 100)) / 0.1499
    exact = origin + s[:, None] * d
    stored = np.c_[np.round(exact[:, 0], 1), np.round(exact[:, 1]), exact[:, 2]]
    return d, line, exact, stored, scanner


def test_scan_lines_split_where_the_sweep_turns():
    dy = np.r_[np.linspace(0, 1, 10), np.linspace(0.95, 0.0, 12), np.linspace(0.05, 1, 8)]
    assert np.bincount(scan_lines(dy)).tolist() == [10, 12, 8]


def test_rebuild_positions_recovers_what_rounding_lost(rng):
    d, line, exact, stored, scanner = _two_lines(rng)
    assert np.abs(stored - exact)[:, 1].max() > 0.4  # y as stored: up to half a metre off
    fit = rebuild_positions(stored, d, line)
    err = np.abs(fit.bin0 - exact)[:, :2]
    # the fit has 4 unknowns per line against 100 rounded coordinates: a few cm
    assert err[:, 0].max() < 0.02 and err[:, 1].max() < 0.1, err.max(axis=0)
    assert np.allclose(fit.scanner, scanner, atol=[0.05, 0.5, 2.0])
    # the rebuilt positions stay within the rounding of the stored ones
    assert np.all(np.abs(fit.residual) <= [0.05 + 0.02, 0.5 + 0.1])


def test_rebuild_positions_refuses_upward_beams(rng):
    d, line, _, stored, _ = _two_lines(rng)
    d[:, 2] *= -1
    with pytest.raises(InputError, match="downward"):
        rebuild_positions(stored, d, line)


def test_read_neon_rebuilds_the_real_strip(shared_data):
    m = read_neon(shared_data / "neon-harvard-waveforms")
    geo = m.meta["geometry"]
    assert len(m) == 500 and geo["lines"] == 8
    # the rebuilt positions agree with the stored ones within their rounding (0.05 m in x, 0.5 m in y) for 95 %
    assert geo["residual_x_p95_m"] < 0.07 and geo["residual_y_p95_m"] < 0.5
    # every scan line's scanner sits about 970 m above the records (the strip is at about 330 m)
    assert np.all(np.abs(np.array(geo["scanner_z_m"]) - 1310) < 15)
    # each pulse's line passes through its sensor: sample 0 lies on the ray from the origin
    rel = m.bin0 - m.origin
    cos = np.einsum("ij,ij->i", rel, m.direction) / np.linalg.norm(rel, axis=1)
    assert np.all(cos > 1 - 1e-9)
    # as stored, a quarter of the pulses share their x,y with another pulse; rebuilt, none does
    assert len(np.unique(np.round(m.bin0[:, :2], 3), axis=0)) == 500
    assert m.impulse is not None and m.outgoing is not None
    assert m.n_samples.min() == 68 and m.n_samples.max() == 196


def test_read_neon_bad_folders(tmp_path):
    with pytest.raises(InputError, match="geolocation.csv"):
        read_neon(tmp_path)
    (tmp_path / "return.csv").write_text("10,20,30,20,10\n10,20,30,20,10\n")
    (tmp_path / "geolocation.csv").write_text("index,bin0_x,bin0_y,bin0_z,bin0_dx,bin0_dy,bin0_dz\n"
                                              "1,0,0,300,0,0,-0.15\n")
    with pytest.raises(InputError, match="1 rows for 2 records"):
        read_neon(tmp_path)
    (tmp_path / "geolocation.csv").write_text("index,x,y\n1,0,0\n2,0,0\n")
    with pytest.raises(InputError, match="bin0_x"):
        read_neon(tmp_path)


def test_read_las_pulses_finds_the_flight_of_the_leica_tile(shared_data):
    from clsim.replay import read_las_pulses

    m = read_las_pulses(shared_data / "leica-fwf-las13" / "fwf.las")
    geo = m.meta["geometry"]
    # one pulse per GPS time, every discrete return kept with its pulse
    assert len(m) == 1778 and sum(r.size for r in m.meta["returns_ns"]) == 2250
    assert m.dt_ns == 2.0 and m.samples.shape[1] == 256
    # a straight, steady flight passes within 2 cm of all 1,778 lines: the file's geometry is one flight
    assert geo["off_line_max_m"] < 0.02
    assert 1000 < geo["scanner_height_m"] < 2000 and 40 < geo["speed_m_s"] < 100
    # each pulse's origin lies on its own line
    rel = m.bin0 - m.origin
    assert np.allclose(np.linalg.norm(np.cross(rel, m.direction), axis=1), 0.0, atol=1e-6)
    assert geo["lines"] == 78


def test_the_lines_scheme_groups_many_short_lines():
    from clsim.replay import folds

    class P:
        line = np.repeat(np.arange(30), 4)

        def __len__(self):
            return 120

    splits = folds(P(), "lines", k=5)
    assert len(splits) == 5  # 30 lines > 2 k: every fifth line together
    test0 = splits[0][0]
    assert set(P.line[test0]) == {0, 5, 10, 15, 20, 25}
    P.line = np.repeat(np.arange(8), 4)
    assert len(folds(P(), "lines", k=5)) == 8  # 8 lines: one line per fold
