"""The ground plane under a scene: given, or fitted by RANSAC on the lowest points.

:func:`fit_ground` keeps the lowest point of every ``cell`` x ``cell`` metre
column (ground is what the lowest returns see), fits a plane with a seeded
RANSAC (:func:`ransac_plane`), and reports its height at the centre and its tilt.
The scene file stores a horizontal plane (``ground_z``); a tilt above a few
degrees is reported so a user knows the approximation.

Examples
--------
>>> g = GroundPlane.horizontal(1.5)
>>> float(g.height_at([[0.0, 0.0]])[0]), g.tilt_deg
(1.5, 0.0)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tlsvox.errors import InputError

__all__ = ["GroundPlane", "fit_ground", "ground_mask", "ransac_plane"]


@dataclass(frozen=True)
class GroundPlane:
    """Plane ``a x + b y + c z + d = 0`` with ``c > 0`` (normal pointing up).

    Attributes
    ----------
    coefficients : (4,) float
    z_center : float, metres
        Plane height at ``center_xy``.
    center_xy : (2,) float, metres
    inlier_rmse : float, metres
    n_inliers : int
    """

    coefficients: tuple
    z_center: float
    center_xy: tuple = (0.0, 0.0)
    inlier_rmse: float = 0.0
    n_inliers: int = 0

    @classmethod
    def horizontal(cls, z: float, center_xy=(0.0, 0.0)) -> GroundPlane:
        """A given horizontal plane at height ``z`` (metres)."""
        z = float(z)
        if not np.isfinite(z):
            raise InputError(f"ground_z={z!r} must be a finite height in metres")
        return cls((0.0, 0.0, 1.0, -z), z, tuple(float(v) for v in center_xy))

    @property
    def normal(self) -> np.ndarray:
        n = np.asarray(self.coefficients[:3], dtype=np.float64)
        return n / np.linalg.norm(n)

    @property
    def tilt_deg(self) -> float:
        """Angle between the plane's normal and vertical, degrees."""
        return float(np.degrees(np.arccos(np.clip(abs(self.normal[2]), 0.0, 1.0))))

    def height_at(self, xy) -> np.ndarray:
        """Plane height (metres) at (N, 2) horizontal positions."""
        a, b, c, d = self.coefficients
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        return -(a * xy[:, 0] + b * xy[:, 1] + d) / c

    def distance(self, points) -> np.ndarray:
        """Signed height (metres) of (N, 3) points above the plane, along its normal."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        a, b, c, d = self.coefficients
        return (p @ np.array([a, b, c]) + d) / np.linalg.norm([a, b, c])


def fit_ground(points, *, cell: float = 1.0, distance_threshold: float = 0.05, num_iterations: int = 2000,
               seed: int = 0, max_tilt_deg: float | None = None) -> GroundPlane:
    """Fit the ground plane by RANSAC on the lowest point of each column.

    Parameters
    ----------
    points : (N, 3) float, metres, world frame
    cell : float, metres
        Column size for picking the lowest points.
    distance_threshold : float, metres
        RANSAC inlier distance.
    num_iterations : int
        RANSAC iterations.
    seed : int
        Seeds the RANSAC.
    max_tilt_deg : float, optional
        Only planes tilted less than this from horizontal are candidates (a
        narrow airborne strip's lowest points also line up on steep planes
        across it); default any.

    Returns
    -------
    GroundPlane
        The plane through the lowest point of each column, with its inlier
        count and RMSE.
    """
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if len(p) < 3:
        raise InputError(f"points: need at least 3 points to fit a ground plane, got {len(p)}; give the ground "
                         "height instead (tlsvox voxelize --ground Z) or none (--ground none)")
    if not (np.isfinite(cell) and cell > 0):
        raise InputError(f"cell={cell!r} must be a positive size in metres, e.g. 1.0")
    ij = np.floor(p[:, :2] / cell).astype(np.int64)
    key = (ij[:, 0] - ij[:, 0].min()) * (ij[:, 1].max() - ij[:, 1].min() + 1) + (ij[:, 1] - ij[:, 1].min())
    order = np.lexsort((p[:, 2], key))
    first = np.ones(len(order), bool)
    first[1:] = key[order][1:] != key[order][:-1]
    low = p[order[first]]
    if len(low) < 3:
        raise InputError(
            f"only {len(low)} ground columns of {cell} m: the points cover too small an area; use a smaller cell"
        )
    plane = ransac_plane(low, distance_m=float(distance_threshold), rng=np.random.default_rng(seed),
                         n_iter=int(num_iterations), max_tilt_deg=max_tilt_deg)
    inliers = np.abs(low @ plane[:3] + plane[3]) < float(distance_threshold)
    a, b, c, d = (float(v) for v in plane)
    if c < 0:
        a, b, c, d = -a, -b, -c, -d
    if c < 1e-6:
        raise InputError("the fitted ground plane is vertical: the lowest points are not ground")
    centre = 0.5 * (p[:, :2].min(axis=0) + p[:, :2].max(axis=0))
    z_c = float(-(a * centre[0] + b * centre[1] + d) / c)
    res = (low[inliers] @ np.array([a, b, c]) + d) / np.linalg.norm([a, b, c])
    return GroundPlane((a, b, c, d), z_c, tuple(float(v) for v in centre),
                       float(np.sqrt(np.mean(res**2))) if len(res) else 0.0, int(np.count_nonzero(inliers)))


def ground_mask(points, plane: GroundPlane, *, tolerance: float = 0.15) -> np.ndarray:
    """(N,) bool: points within ``tolerance`` metres above (or any depth below) the plane."""
    return plane.distance(points) < float(tolerance)


def ransac_plane(xyz: np.ndarray, *, distance_m: float, rng: np.random.Generator,
                 n_iter: int = 1000, max_points: int = 20_000, max_tilt_deg: float | None = None) -> np.ndarray:
    """The dominant plane of a point set: seeded RANSAC, then a least-squares refit.

    The one plane fit of tlsvox (the ground under a scene, the ground band of
    a scan, the plane registration discounts).  NumPy only, so the same seed
    gives the same plane on every machine (Open3D's RANSAC is multithreaded).

    Parameters
    ----------
    xyz : (N, 3) float64, metres (N >= 3)
    distance_m : float, metres
        Inlier distance.
    rng : numpy.random.Generator
    n_iter : int
        Random 3-point samples.
    max_points : int
        Points scored per sample (a random subset beyond this).
    max_tilt_deg : float, optional
        Only samples whose plane is tilted less than this from horizontal
        count (and the refit must stay so, else the best sample is kept).

    Returns
    -------
    (4,) float64
        Unit normal ``n`` and offset ``d`` with ``n . x + d = 0``.

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> pts = np.c_[rng.uniform(0, 10, (500, 2)), np.full(500, 2.0)]
    >>> p = ransac_plane(pts, distance_m=0.01, rng=rng)
    >>> bool(abs(abs(p[2]) - 1) < 1e-9 and abs(p[3] / p[2] + 2.0) < 1e-9)
    True
    """
    pts = xyz if len(xyz) <= max_points else xyz[rng.choice(len(xyz), max_points, replace=False)]
    tri = pts[rng.integers(0, len(pts), size=(n_iter, 3))]
    nrm = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    ln = np.linalg.norm(nrm, axis=1)
    good = ln > 1e-12
    if max_tilt_deg is not None:
        good &= np.abs(nrm[:, 2]) >= np.cos(np.radians(float(max_tilt_deg))) * ln
        if not good.any():
            raise InputError(f"no three of the points span a plane tilted less than {max_tilt_deg} degrees: they "
                             "are not ground")
    nrm = nrm[good] / ln[good, None]
    off = -np.einsum("hi,hi->h", nrm, tri[good, 0])
    count = np.array([np.count_nonzero(np.abs(pts @ n + d) < distance_m) for n, d in zip(nrm, off)])
    k = int(np.argmax(count))
    n, d = nrm[k], off[k]
    inl = np.abs(pts @ n + d) < distance_m  # least-squares refit on the inliers
    c = pts[inl].mean(axis=0)
    refit = np.linalg.svd(pts[inl] - c, full_matrices=False)[2][2]
    if max_tilt_deg is not None and abs(refit[2]) < np.cos(np.radians(float(max_tilt_deg))):
        return np.append(n, d)
    return np.append(refit, -refit @ c)
