"""Plane fits of leaf echoes (steps 1 and 2 of the package docstring), their observation columns, and the trunk axis."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tlsvox.leafangles._histogram import HALF_PI

#: neighbour-count classes of the observations (counts from each edge up to the next)
_COUNT_EDGES = (0, 5, 8, 11, 15, 20, 27)


def _pairs(xyz, radius):
    """Neighbour pairs within ``radius``, both ways and each point with itself: (I, J)."""
    from scipy.spatial import cKDTree

    pairs = cKDTree(xyz).query_pairs(radius, output_type="ndarray")
    n = len(xyz)
    idx = np.arange(n)
    return np.concatenate([pairs[:, 0], pairs[:, 1], idx]), np.concatenate([pairs[:, 1], pairs[:, 0], idx])


def _normals(pts, centre, n, weights=None):
    """Per-centre plane normals (smallest covariance eigenvector), upper hemisphere.

    ``pts`` (P, 3) belong to ``centre`` (P,) in 0..n-1; returns normals (n, 3),
    counts (n,), centroids (n, 3) and in-plane minor spreads (n,) (the square
    root of the middle eigenvalue, metres).
    """
    w = np.ones(len(pts)) if weights is None else weights
    cnt = np.bincount(centre, weights=w, minlength=n)
    safe = np.where(cnt > 0, cnt, 1.0)
    mean = np.stack([np.bincount(centre, weights=w * pts[:, k], minlength=n) for k in range(3)], 1) / safe[:, None]
    dev = pts - mean[centre]
    cov = np.empty((n, 3, 3))
    for a in range(3):
        for b in range(a, 3):
            cov[:, a, b] = cov[:, b, a] = np.bincount(centre, weights=w * dev[:, a] * dev[:, b], minlength=n) / safe
    val, vec = np.linalg.eigh(cov)
    nrm = vec[:, :, 0]
    nrm = nrm * np.where(nrm[:, 2:3] < 0, -1.0, 1.0)
    return nrm, cnt, mean, np.sqrt(np.clip(val[:, 1], 0.0, None))


def _inclination_bin(nrm, n_bins):
    t = np.arccos(np.clip(np.abs(nrm[:, 2]), 0.0, 1.0))
    return np.minimum((t / HALF_PI * n_bins).astype(np.int64), n_bins - 1)


def _azimuth_class(nrm, outward, n_classes):
    """Class of the angle between a normal's horizontal part and the outward direction: 0 facing out."""
    if n_classes == 1:
        return np.zeros(len(nrm), np.int64)
    h = np.maximum(np.linalg.norm(nrm[:, :2], axis=1), 1e-12)
    c = (nrm[:, 0] * outward[:, 0] + nrm[:, 1] * outward[:, 1]) / h
    return np.minimum((np.arccos(np.clip(c, -1.0, 1.0)) / np.pi * n_classes).astype(np.int64), n_classes - 1)


def _columns(fitted, meas_bin, az_class, count, *, n_bins, n_azimuth, count_edges):
    """Observation column of each echo: (measured bin, azimuth class, count class) for a plane fit, else the
    count class alone in the last ``len(count_edges)`` columns."""
    n_count = len(count_edges)
    cc = np.searchsorted(np.asarray(count_edges), count, side="right") - 1
    return np.where(fitted, (meas_bin * n_azimuth + az_class) * n_count + cc, n_bins * n_azimuth * n_count + cc)


def _n_columns(n_bins, n_azimuth, count_edges):
    return (n_bins * n_azimuth + 1) * len(count_edges)


def _measured_bins(kernel, n_bins, n_azimuth=1, count_edges=_COUNT_EDGES):
    """Sum a kernel's observation columns over azimuth and count classes: (..., n_bins) per measured bin
    (echoes without a plane fit left out)."""
    n_count = len(count_edges)
    fit = kernel[..., :n_bins * n_azimuth * n_count]
    return fit.reshape(fit.shape[:-1] + (n_bins, n_azimuth * n_count)).sum(axis=-1)


@dataclass
class _ScanFits:
    """Plane fits of one scan's leaf echoes (every echo; ``ok`` marks those with a fit)."""

    z: np.ndarray  # (n,) echo heights
    r: np.ndarray  # (n,) range, metres
    d: np.ndarray  # (n, 3) unit beam direction
    ok: np.ndarray  # (n,) bool, a plane fit
    theta: np.ndarray  # (n,) beam zenith angle, folded to [0, pi/2]
    weight: np.ndarray  # (n,) r^2 / max(|n . d|, cap) with a fit (|n . d| >= cap), r^2 without
    meas_bin: np.ndarray  # (n,) measured inclination bin
    outward: np.ndarray  # (n, 2) unit horizontal direction from the crown centre (zeros without a centre)
    column: np.ndarray  # (n,) observation column (see _columns)


def _fit_scan(xyz, origin, *, radius, min_points, min_spread, n_bins, cap, centre=None, n_azimuth=1,
              count_edges=_COUNT_EDGES):
    d = xyz - origin
    r = np.linalg.norm(d, axis=1)
    d = d / r[:, None]
    pi, J = _pairs(xyz, radius)
    nrm, cnt, _, spread = _normals(xyz[J], pi, len(xyz))
    cos_a = np.abs(np.einsum("ij,ij->i", nrm, d))
    ok = (cnt >= min_points) & (spread >= min_spread) & (cos_a >= cap)
    outward = np.zeros((len(xyz), 2))
    if centre is not None:
        outward = xyz[:, :2] - np.asarray(centre, float)[None, :2]
        outward /= np.maximum(np.linalg.norm(outward, axis=1, keepdims=True), 1e-9)
    meas_bin = _inclination_bin(nrm, n_bins)
    column = _columns(ok, meas_bin, _azimuth_class(nrm, outward, n_azimuth), cnt.astype(np.int64), n_bins=n_bins,
                      n_azimuth=n_azimuth, count_edges=count_edges)
    return _ScanFits(z=xyz[:, 2], r=r, d=d, ok=ok, theta=np.arccos(np.abs(d[:, 2])),
                     weight=np.where(ok, r * r / np.maximum(cos_a, cap), r * r), meas_bin=meas_bin, outward=outward,
                     column=column)


def trunk_center(wood_xyz, *, low: float = 0.3, high: float = 1.3):
    """The trunk's axis (x, y) and radius from wood echoes near its base.

    A circle fitted by least squares (Kasa 1976) to the wood echoes between
    ``low`` and ``high`` metres above their 1st height percentile, refitted
    without the echoes more than three median deviations off the circle
    (branches, mislabelled ground) until the kept ones stay the same.

    Returns
    -------
    centre : (2,) float, metres, or None
        None when fewer than 30 echoes lie in the slice or the fit is not a
        trunk (radius outside 1 cm - 3 m).
    radius : float, metres (nan with no centre)
    """
    wood_xyz = np.asarray(wood_xyz, float).reshape(-1, 3)
    if len(wood_xyz) < 30:
        return None, float("nan")
    z0 = np.percentile(wood_xyz[:, 2], 1)
    sel = wood_xyz[(wood_xyz[:, 2] > z0 + low) & (wood_xyz[:, 2] < z0 + high)][:, :2]
    from tlsvox.voxel.wood.qsm import _circle

    keep = np.ones(len(sel), bool)
    for _ in range(20):
        if keep.sum() < 30:
            return None, float("nan")
        centre, rad = _circle(sel[keep])
        off = np.abs(np.linalg.norm(sel - centre, axis=1) - rad)
        new = off <= 3.0 * max(np.median(off[keep]), 1e-3)
        if np.array_equal(new, keep):
            break
        keep = new
    if not 0.01 <= rad <= 3.0:
        return None, float("nan")
    return centre, rad
