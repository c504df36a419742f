"""Apparent reflectance of echoes: RIEGL dB, range-normalised or calibrated intensity.

RIEGL scanners record *reflectance* in dB: the echo amplitude relative to the
amplitude a white Lambertian target, perpendicular to the beam, would give at
the same range.  Apparent reflectance is then ``rho = 10**(dB/10)``; a white
target reads 0 dB, a retro-reflector above 0 dB (Pfennigbauer & Ullrich 2010).

Scanners that record only raw intensity need the range effect removed.  For an
extended Lambertian target the received power falls as ``1/R**2``, so the
intensity is normalised to a reference range ``R0`` as ``I * (R / R0)**2``
(Höfle & Pfeifer 2007, model-driven correction).  Near-range optics (defocus,
receiver gain) break the inverse-square law, so a measured calibration table
(intensity of a reference target of known reflectance against range) is the
data-driven alternative: ``rho = rho_ref * I / I_ref(R)``.

References
----------
Pfennigbauer, M., Ullrich, A. (2010). Improving quality of laser scanning data
    acquisition through calibrated amplitude and pulse deviation measurement.
    Proc. SPIE 7684, 76841F. doi:10.1117/12.849641
Höfle, B., Pfeifer, N. (2007). Correction of laser scanning intensity data:
    data and model-driven approaches. ISPRS J. Photogramm. Remote Sens. 62(6),
    415-433. doi:10.1016/j.isprsjprs.2007.05.008

Examples
--------
>>> round(float(db_to_reflectance(-3.0103)), 4)
0.5
>>> range_normalise([100.0], [20.0], reference_range_m=10.0).tolist()
[400.0]
"""

from __future__ import annotations

import csv
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tlsvox.errors import InputError
from tlsvox.scan import Scan
from voxlidar.choices import Choice

__all__ = [
    "CalibrationTable",
    "ReflectanceSource",
    "apparent_reflectance",
    "db_to_reflectance",
    "range_normalise",
    "reflectance_to_db",
    "scan_ranges",
]


class ReflectanceSource(Choice):
    """Where :func:`apparent_reflectance` takes its values from."""

    AUTO = "auto"  #: dB when the scan has it, else intensity
    DB = "db"  #: the scan's ``reflectance_db``
    INTENSITY = "intensity"  #: the scan's raw ``intensity``, range corrected



def db_to_reflectance(db) -> np.ndarray:
    """Apparent reflectance (linear, 1 = white Lambertian target) from dB.

    Parameters
    ----------
    db : array_like
        Reflectance in dB relative to a white Lambertian target.

    Returns
    -------
    ndarray of float64, same shape
        ``10**(db/10)``.
    """
    return np.power(10.0, np.asarray(db, dtype=np.float64) / 10.0)


def reflectance_to_db(rho) -> np.ndarray:
    """Reflectance in dB, ``10*log10(rho)``; ``rho`` must be > 0.

    Raises
    ------
    InputError
        If any value is <= 0 or not finite.
    """
    rho = np.asarray(rho, dtype=np.float64)
    if not np.all(np.isfinite(rho) & (rho > 0)):
        bad = int(np.count_nonzero(~(np.isfinite(rho) & (rho > 0))))
        raise InputError(f"rho: {bad} value(s) are <= 0 or not finite; dB needs positive reflectance")
    return 10.0 * np.log10(rho)


def scan_ranges(scan: Scan) -> np.ndarray:
    """Range (m) of every echo from the beam origin: ``|xyz - origin|``, shape (N,)."""
    origin = scan.pulses.origin if scan.pulses is not None else np.zeros(3)
    return np.linalg.norm(scan.xyz - origin, axis=1)


def range_normalise(intensity, range_m, *, reference_range_m: float, exponent: float = 2.0) -> np.ndarray:
    """Normalise raw intensity to a reference range: ``I * (R / R0)**exponent``.

    Parameters
    ----------
    intensity : (N,) array_like
        Raw intensity (any linear unit).
    range_m : (N,) array_like, metres
        Range of each echo.
    reference_range_m : float, metres
        ``R0``, the range the intensities are brought to.
    exponent : float, default 2
        2 for targets larger than the footprint (inverse-square law); 3 or 4
        for targets smaller than the footprint (Höfle & Pfeifer 2007).

    Returns
    -------
    (N,) float64
    """
    i = np.asarray(intensity, dtype=np.float64)
    r = np.asarray(range_m, dtype=np.float64)
    if i.shape != r.shape:
        raise InputError(f"intensity has shape {i.shape} but range_m has {r.shape}; they must match")
    if not (np.isfinite(reference_range_m) and reference_range_m > 0):
        raise InputError(f"reference_range_m={reference_range_m!r} must be a positive distance in metres")
    if np.any(~np.isfinite(r) | (r <= 0)):
        raise InputError("range_m: every range must be positive and finite")
    return i * (r / float(reference_range_m)) ** float(exponent)


@dataclass(frozen=True)
class CalibrationTable:
    """Intensity of a reference target of known reflectance against range.

    Parameters
    ----------
    range_m : (K,) float, metres, strictly increasing, K >= 2
    intensity : (K,) float, > 0
        Raw intensity the scanner records from the reference target.
    reference_reflectance : float
        Lambertian reflectance of that target (e.g. 0.99 for Spectralon).

    Interpolation is linear in log(range)-log(intensity); outside the table
    the inverse-square law continues from the nearest end when
    ``extrapolate``, else an error is raised.
    """

    range_m: np.ndarray
    intensity: np.ndarray
    reference_reflectance: float = 1.0

    def __post_init__(self):
        r = np.asarray(self.range_m, dtype=np.float64).reshape(-1)
        i = np.asarray(self.intensity, dtype=np.float64).reshape(-1)
        if r.shape != i.shape or len(r) < 2:
            raise InputError(
                f"calibration table: need >= 2 (range, intensity) rows of equal length, "
                f"got {len(r)} ranges and {len(i)} intensities"
            )
        if np.any(np.diff(r) <= 0) or np.any(r <= 0):
            raise InputError("calibration table: range_m must be positive and strictly increasing")
        if np.any(~np.isfinite(i) | (i <= 0)):
            raise InputError("calibration table: intensities must be positive and finite")
        if not (0 < self.reference_reflectance):
            raise InputError(f"reference_reflectance={self.reference_reflectance!r} must be > 0")
        object.__setattr__(self, "range_m", r)
        object.__setattr__(self, "intensity", i)

    @classmethod
    def from_csv(cls, path: str | os.PathLike, *, reference_reflectance: float = 1.0) -> CalibrationTable:
        """Read a CSV with columns ``range_m`` and ``intensity`` (header row)."""
        path = Path(path)
        with open(path, newline="") as fh:
            rows = list(csv.DictReader(fh))
        try:
            r = [float(row["range_m"]) for row in rows]
            i = [float(row["intensity"]) for row in rows]
        except (KeyError, ValueError) as err:
            raise InputError(
                f"calibration file {str(path)!r}: expected numeric columns 'range_m' and "
                f"'intensity' with a header row ({err})"
            ) from err
        return cls(np.array(r), np.array(i), reference_reflectance)

    def reference_intensity(self, range_m, *, extrapolate: bool = False) -> np.ndarray:
        """Intensity of the reference target at the given ranges (m)."""
        r = np.asarray(range_m, dtype=np.float64)
        lo, hi = self.range_m[0], self.range_m[-1]
        outside = (r < lo) | (r > hi)
        if np.any(outside) and not extrapolate:
            raise InputError(
                f"{int(outside.sum())} range(s) fall outside the calibration table "
                f"[{lo:g}, {hi:g}] m; extend the table or pass extrapolate=True "
                "(inverse-square law beyond its ends)"
            )
        logi = np.interp(np.log(np.clip(r, lo, hi)), np.log(self.range_m), np.log(self.intensity))
        out = np.exp(logi)
        return out * np.where(outside, (np.clip(r, lo, hi) / r) ** 2, 1.0)

    def reflectance(self, intensity, range_m, *, extrapolate: bool = False) -> np.ndarray:
        """Apparent reflectance ``rho_ref * I / I_ref(R)``, shape of ``intensity``."""
        i = np.asarray(intensity, dtype=np.float64)
        return self.reference_reflectance * i / self.reference_intensity(range_m, extrapolate=extrapolate)


def apparent_reflectance(scan: Scan, *, source: str | ReflectanceSource = ReflectanceSource.AUTO,
                         calibration: CalibrationTable | None = None,
                         reference_range_m: float | None = None,
                         allow_relative: bool = False) -> np.ndarray:
    """Linear apparent reflectance of every echo of a scan.

    Parameters
    ----------
    scan : Scan
    source : {'auto', 'db', 'intensity'}
        ``auto`` uses ``reflectance_db`` when present, else intensity.
    calibration : CalibrationTable, optional
        Turns intensity into absolute reflectance.
    reference_range_m : float, optional
        Without calibration: normalise intensity to this range (inverse-square
        law).  The result is *relative* (arbitrary unit), so
        ``allow_relative=True`` is required.  Defaults to the median range.
    allow_relative : bool, default False
        Accept a relative (range-normalised intensity) result.

    Returns
    -------
    (N,) float64
        Reflectance (1 = white Lambertian target), or relative values.

    Raises
    ------
    InputError
        The scan has no usable reflectance/intensity, or only a relative
        result is possible and ``allow_relative`` is False.
    """
    src = ReflectanceSource.parse(source, "source")
    has_db = scan.reflectance_db is not None and np.any(np.isfinite(scan.reflectance_db))
    has_i = scan.intensity is not None and np.any(scan.intensity > 0)
    if src is ReflectanceSource.AUTO:
        src = ReflectanceSource.DB if has_db else ReflectanceSource.INTENSITY
    if src is ReflectanceSource.DB:
        if not has_db:
            raise InputError(
                f"scan {scan.name!r}: source='db' but the scan has no reflectance_db; "
                "use source='intensity' with a calibration table or reference range"
            )
        return db_to_reflectance(scan.reflectance_db)
    if not has_i:
        raise InputError(
            f"scan {scan.name!r}: has neither reflectance (dB) nor non-zero intensity; "
            "re-export the scan with reflectance or intensity"
        )
    ranges = scan_ranges(scan)
    if calibration is not None:
        return calibration.reflectance(scan.intensity, ranges)
    if not allow_relative:
        raise InputError(
            f"scan {scan.name!r}: only raw intensity is available, which gives relative "
            "values; pass calibration=CalibrationTable(...) for absolute reflectance, or "
            "allow_relative=True (CLI: tlsvox classify --intensity relative)"
        )
    r0 = float(np.median(ranges)) if reference_range_m is None else reference_range_m
    return range_normalise(scan.intensity, ranges, reference_range_m=r0)
