"""Pointing vectors: SVD line fit on synthetic multi-return pulses, and on the real
Leica file against its x_t, y_t, z_t."""

from __future__ import annotations

import numpy as np
import pytest

from clsim.errors import InputError
from clsim.waveforms.pointing import (
    angle_between_deg,
    fit_pulse_directions,
    off_nadir_deg,
    pointing_from_xyzt,
    pulse_ids_from_gps_time,
)


def test_line_fit_recovers_direction_within_0_1_deg(rng):
    """1000 pulses, 2-4 returns 8-30 m apart, 2 mm position noise (a typical relative
    precision of returns of one pulse); predicted angular error ~0.02 deg."""
    n = 1000
    zen = np.radians(rng.uniform(0, 20, n))
    az = rng.uniform(0, 2 * np.pi, n)
    d = np.column_stack([np.sin(zen) * np.cos(az), np.sin(zen) * np.sin(az), -np.cos(zen)])
    pts, ids, order = [], [], []
    for i in range(n):
        k = rng.integers(2, 5)
        r = np.sort(rng.uniform(0, rng.uniform(8, 30), k))
        r[-1] = max(r[-1], r[0] + 8.0)
        p = np.array([500.0, 800.0, 300.0]) + r[:, None] * d[i] + rng.normal(0, 0.002, (k, 3))
        pts.append(p)
        ids += [i] * k
        order += list(range(1, k + 1))
    fit = fit_pulse_directions(np.vstack(pts), np.array(ids), order=np.array(order))
    assert len(fit) == n
    ang = angle_between_deg(fit.direction, d[fit.pulse])
    print(f"max {ang.max():.4f} deg, median {np.median(ang):.4f} deg")
    assert ang.max() < 0.1


def test_orientation_without_order_is_downward():
    fit = fit_pulse_directions([[0, 0, 0], [0, 0, 5]], [0, 0])
    np.testing.assert_allclose(fit.direction, [[0, 0, -1]], atol=1e-12)


@pytest.mark.realdata
def test_leica_fitted_directions_match_xyzt(shared_data):
    """Directions fitted through the returns of each multi-return pulse agree with
    -(x_t, y_t, z_t). Stated error: coordinates are stored at 1 mm, so each return
    carries sqrt(1/12) mm of rounding per axis; for two returns L apart the expected
    angular error is about sqrt(2) * 0.29 mm * sqrt(2) / L. Every pulse is within 3.5
    times that (and within 0.05 deg)."""
    from clsim.waveforms.io import read_las_waveforms

    w = read_las_waveforms(shared_data / "leica-fwf-las13" / "fwf.las")
    pid = pulse_ids_from_gps_time(w.gps_time)
    fit = fit_pulse_directions(w.xyz, pid, order=w.return_number)
    assert len(fit) == 434  # pulses with 2-4 returns
    first = np.array([np.flatnonzero(pid == p)[0] for p in fit.pulse])
    ref = pointing_from_xyzt(w.xyz_t[first])
    ang = angle_between_deg(fit.direction, ref)
    q = 0.001 * w.scales[0] / 0.001
    predicted = np.degrees(np.sqrt(2) * q / np.sqrt(12) * np.sqrt(2) / fit.span_m)
    print(f"median {np.median(ang):.4f} deg, max {ang.max():.4f} deg, "
          f"max ratio to quantisation {np.max(ang / predicted):.2f}")
    assert np.all(ang <= 3.5 * predicted)
    assert ang.max() < 0.05
    nadir = off_nadir_deg(ref)
    assert 0 < nadir.min() and nadir.max() < 30


def test_bad_input():
    with pytest.raises(InputError, match="pulse_id has 1"):
        fit_pulse_directions(np.zeros((2, 3)), [0])
    with pytest.raises(InputError, match=r"\(N, 3\)"):
        pointing_from_xyzt(np.zeros((2, 2)))
    assert np.isnan(pointing_from_xyzt([[0.0, 0.0, 0.0]])).all()
