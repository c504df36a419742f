"""Laser pointing vectors per pulse.

Two sources:

- the waveform geometry of LAS point formats 4/5/9/10 (``x_t, y_t, z_t``,
  pointing from the target back to the sensor; :func:`pointing_from_xyzt`
  turns it into the direction of travel), or PulseWaves anchor/target points;
- where only discrete returns exist, a straight-line fit through the returns
  of one pulse (the paper's way): the principal axis of the centred points
  (SVD), oriented from the first to the last return
  (:func:`fit_pulse_directions`). The points of a pulse are found by their
  common GPS time (:func:`pulse_ids_from_gps_time`).

References
----------
Kim, A. M., Olsen, R. C. & Béland, M. (2015). Simulation of small-footprint
    full-waveform LiDAR propagation through a tree canopy in 3D. Proc. SPIE
    9465, 94650P. doi:10.1117/12.2177539
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from clsim.errors import InputError

__all__ = [
    "PulseLines",
    "angle_between_deg",
    "fit_pulse_directions",
    "off_nadir_deg",
    "pointing_from_xyzt",
    "pulse_ids_from_gps_time",
]


def _vectors(v, name: str) -> np.ndarray:
    a = np.asarray(v, dtype=np.float64)
    if a.ndim == 1 and a.size == 3:
        a = a[None, :]
    if a.ndim != 2 or a.shape[1] != 3:
        raise InputError(f"{name} must have shape (N, 3); got {a.shape}")
    return a


def pointing_from_xyzt(xyz_t) -> np.ndarray:
    """Unit direction of travel of each pulse from LAS ``x_t, y_t, z_t``.

    Parameters
    ----------
    xyz_t : (N, 3) array_like, m/ps
        LAS parametric line (points back toward the sensor).

    Returns
    -------
    (N, 3) float64
        Unit vectors pointing away from the sensor; NaN rows where the
        vector is zero (point without waveform geometry).

    Examples
    --------
    >>> pointing_from_xyzt([[0.0, 0.0, 1.5e-4]]).tolist()
    [[-0.0, -0.0, -1.0]]
    """
    v = _vectors(xyz_t, "xyz_t")
    n = np.linalg.norm(v, axis=1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        out = -v / n
    out[(n[:, 0] == 0) | ~np.isfinite(n[:, 0])] = np.nan
    return out


def pulse_ids_from_gps_time(gps_time) -> np.ndarray:
    """Pulse id per point: points with the same GPS time share a pulse.

    Parameters
    ----------
    gps_time : (N,) array_like

    Returns
    -------
    (N,) int64, 0..P-1 in time order

    Examples
    --------
    >>> pulse_ids_from_gps_time([5.0, 5.0, 3.0]).tolist()
    [1, 1, 0]
    """
    t = np.asarray(gps_time, dtype=np.float64).reshape(-1)
    return np.unique(t, return_inverse=True)[1].astype(np.int64)


@dataclass
class PulseLines:
    """Line fits of multi-return pulses.

    Attributes
    ----------
    pulse : (M,) int64
        Pulse id of each fitted pulse.
    direction : (M, 3) float64
        Unit direction, from the first toward the last return.
    centroid : (M, 3) float64, m
    n_points : (M,) int64
    span_m : (M,) float64
        Distance between the extreme returns along the line.
    rms_m : (M,) float64
        RMS distance of the returns from the line.
    """

    pulse: np.ndarray
    direction: np.ndarray
    centroid: np.ndarray
    n_points: np.ndarray
    span_m: np.ndarray
    rms_m: np.ndarray

    def __len__(self) -> int:
        return int(self.pulse.size)


def fit_pulse_directions(xyz, pulse_id, *, order=None, min_points: int = 2) -> PulseLines:
    """Fit a straight line (SVD) through the returns of each pulse.

    Parameters
    ----------
    xyz : (N, 3) array_like, m
        Return positions.
    pulse_id : (N,) array_like of int
        Pulse of each return (e.g. :func:`pulse_ids_from_gps_time`).
    order : (N,) array_like, optional
        Return number (or range); the direction points from the smallest to
        the largest. Default: orient downward (negative z component), as for
        an airborne sensor.
    min_points : int
        Pulses with fewer returns are skipped (at least 2).

    Returns
    -------
    PulseLines

    Examples
    --------
    >>> pts = [[0, 0, 10], [0.1, 0, 9], [0.2, 0, 8]]
    >>> fit = fit_pulse_directions(pts, [0, 0, 0], order=[1, 2, 3])
    >>> np.round(fit.direction, 4).tolist()
    [[0.0995, 0.0, -0.995]]
    """
    p = _vectors(xyz, "xyz")
    ids = np.asarray(pulse_id).reshape(-1)
    if ids.size != p.shape[0]:
        raise InputError(f"pulse_id has {ids.size} entries for {p.shape[0]} points; give one "
                         "pulse id per point")
    if int(min_points) < 2:
        raise InputError(f"min_points must be >= 2 (a line needs two points); got {min_points}")
    rank = None if order is None else np.asarray(order, dtype=np.float64).reshape(-1)
    if rank is not None and rank.size != p.shape[0]:
        raise InputError(f"order has {rank.size} entries for {p.shape[0]} points")
    srt = np.argsort(ids, kind="stable")
    uid, start, counts = np.unique(ids[srt], return_index=True, return_counts=True)
    keep = counts >= int(min_points)
    out_dir, out_c, out_span, out_rms = [], [], [], []
    for s, c in zip(start[keep], counts[keep]):
        idx = srt[s:s + c]
        q = p[idx]
        cen = q.mean(axis=0)
        d = q - cen
        _u, sv, vt = np.linalg.svd(d, full_matrices=False)
        axis = vt[0]
        proj = d @ axis
        if rank is not None:
            r = rank[idx]
            sign = np.sign(proj[np.argmax(r)] - proj[np.argmin(r)])
        else:
            sign = -np.sign(axis[2])
        axis = axis * (sign if sign != 0 else 1.0)
        resid = d - np.outer(d @ axis, axis)
        out_dir.append(axis)
        out_c.append(cen)
        out_span.append(float(np.ptp(proj)))
        out_rms.append(float(np.sqrt(np.mean(np.sum(resid * resid, axis=1)))))
    m = len(out_dir)
    return PulseLines(pulse=uid[keep].astype(np.int64),
                      direction=np.array(out_dir).reshape(m, 3),
                      centroid=np.array(out_c).reshape(m, 3), n_points=counts[keep].astype(np.int64),
                      span_m=np.array(out_span), rms_m=np.array(out_rms))


def angle_between_deg(a, b) -> np.ndarray:
    """Angle between direction vectors, degrees (rows of ``a`` and ``b``).

    Examples
    --------
    >>> float(angle_between_deg([1, 0, 0], [0, 1, 0])[0])
    90.0
    """
    u = _vectors(a, "a")
    v = _vectors(b, "b")
    u = u / np.linalg.norm(u, axis=1, keepdims=True)
    v = v / np.linalg.norm(v, axis=1, keepdims=True)
    # atan2 of cross and dot: accurate for tiny angles too
    cross = np.linalg.norm(np.cross(u, v), axis=1)
    return np.degrees(np.arctan2(cross, np.sum(u * v, axis=1)))


def off_nadir_deg(direction) -> np.ndarray:
    """Angle of each direction from straight down, degrees.

    Examples
    --------
    >>> float(off_nadir_deg([0, 0, -1])[0])
    0.0
    """
    return angle_between_deg(direction, np.broadcast_to([0.0, 0.0, -1.0],
                                                        _vectors(direction, "direction").shape))
