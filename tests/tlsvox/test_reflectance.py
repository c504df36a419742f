"""Apparent reflectance: dB, inverse-square range normalisation, calibration tables."""

from __future__ import annotations

import numpy as np
import pytest

from tlsvox.errors import InputError
from tlsvox.reflectance import (
    CalibrationTable,
    apparent_reflectance,
    db_to_reflectance,
    range_normalise,
    reflectance_to_db,
)
from tlsvox.scan import Scan


def test_db_round_trip_and_white_target():
    rho = np.array([0.01, 0.267, 0.425, 1.0, 9.0])
    np.testing.assert_allclose(db_to_reflectance(reflectance_to_db(rho)), rho, rtol=1e-12)
    assert db_to_reflectance(0.0) == 1.0  # white Lambertian target reads 0 dB
    with pytest.raises(InputError):
        reflectance_to_db([0.0])


def test_inverse_square_normalisation_recovers_reflectance(rng):
    # extended Lambertian targets: I = K rho / R^2 exactly
    K = 5e4
    rho = rng.choice([0.267, 0.425], 5000)
    r = rng.uniform(2, 60, 5000)
    inten = K * rho / r**2
    norm = range_normalise(inten, r, reference_range_m=10.0)
    np.testing.assert_allclose(norm, K * rho / 100.0, rtol=1e-12)


def test_calibration_table_beats_inverse_square_at_near_range(rng):
    # a scanner whose near-range optics lose signal: I = K rho / R^2 * (1 - exp(-R/3))
    K = 5e4

    def instrument(rho, r):
        return K * rho / r**2 * (1 - np.exp(-r / 3.0))

    table_r = np.geomspace(1.0, 80.0, 60)
    cal = CalibrationTable(table_r, instrument(0.99, table_r), reference_reflectance=0.99)
    rho = rng.uniform(0.1, 0.6, 2000)
    r = rng.uniform(1.5, 70, 2000)
    got = cal.reflectance(instrument(rho, r), r)
    # log-log interpolation of a smooth curve on 60 nodes: < 0.5 % error
    np.testing.assert_allclose(got, rho, rtol=5e-3)
    # the plain inverse-square law keeps the near-range loss (1 - exp(-R/3)):
    # 26 % and more below 4 m
    naive = range_normalise(instrument(rho, r), r, reference_range_m=80.0) / (K / 80.0**2)
    np.testing.assert_allclose(naive / rho, 1 - np.exp(-r / 3.0), rtol=1e-12)
    assert np.all(naive[r < 4] / rho[r < 4] < 0.74)
    with pytest.raises(InputError, match="outside the calibration table"):
        cal.reflectance([100.0], [100.0])


def test_calibration_csv_and_bad_tables(tmp_path):
    path = tmp_path / "cal.csv"
    path.write_text("range_m,intensity\n2,1000\n4,250\n8,62.5\n")
    cal = CalibrationTable.from_csv(path, reference_reflectance=0.5)
    np.testing.assert_allclose(cal.reflectance([250.0], [4.0]), [0.5])
    np.testing.assert_allclose(cal.reflectance([1000.0], [2.828427]), [0.5 * 1000 / 500], rtol=1e-5)
    with pytest.raises(InputError, match="strictly increasing"):
        CalibrationTable([2, 1], [1, 1])
    (tmp_path / "bad.csv").write_text("r,i\n1,2\n")
    with pytest.raises(InputError, match="range_m"):
        CalibrationTable.from_csv(tmp_path / "bad.csv")


def test_apparent_reflectance_sources(rng):
    xyz = rng.normal(size=(100, 3)) * 10 + 20
    db = rng.uniform(-10, -1, 100)
    scan = Scan(xyz=xyz, reflectance_db=db, intensity=rng.uniform(1, 100, 100))
    np.testing.assert_allclose(apparent_reflectance(scan), 10 ** (db / 10), rtol=1e-6)
    only_i = Scan(xyz=xyz, intensity=rng.uniform(1, 100, 100), name="raw")
    with pytest.raises(InputError, match="relative"):
        apparent_reflectance(only_i)
    rel = apparent_reflectance(only_i, allow_relative=True, reference_range_m=10.0)
    r = np.linalg.norm(xyz, axis=1)
    np.testing.assert_allclose(rel, only_i.intensity * (r / 10.0) ** 2, rtol=1e-6)
    with pytest.raises(InputError, match="source"):
        apparent_reflectance(scan, source="lidar")
    with pytest.raises(InputError, match="neither"):
        apparent_reflectance(Scan(xyz=xyz))
