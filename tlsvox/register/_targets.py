"""Retro-reflective targets: detection in a scan, centres fitted to the target's shape,
and correspondences between two scans from their inter-target distances.
"""

from __future__ import annotations

import itertools

import numpy as np

from tlsvox.errors import InputError
from tlsvox.register._transforms import apply_transform, rigid_fit, tilt_deg
from tlsvox.scan import Scan
from voxlidar.choices import Choice


class TargetShape(Choice):
    """Shape of the retro-reflective targets, for fitting their centres."""

    CYLINDER = "cylinder"  #: upright cylinder of known radius (scanner z is up)
    SPHERE = "sphere"  #: sphere of known radius
    FLAT = "flat"  #: flat disc or sticker: the centroid of its points


def _clusters(xyz: np.ndarray, link_m: float) -> list[np.ndarray]:
    """Single-linkage clusters (indices) of points closer than ``link_m``."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    if len(xyz) == 0:
        return []
    pairs = cKDTree(xyz).query_pairs(link_m, output_type="ndarray")
    n = len(xyz)
    g = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    _, lab = connected_components(g, directed=False)
    order = np.argsort(lab, kind="stable")
    splits = np.flatnonzero(np.diff(lab[order])) + 1
    return np.split(order, splits)


def _fit_centre(pts: np.ndarray, origin: np.ndarray, shape: TargetShape, radius: float) -> np.ndarray:
    """Centre of one target from its points (scanner frame)."""
    from scipy.optimize import least_squares

    c0 = pts.mean(axis=0)
    if shape is TargetShape.FLAT:
        return c0
    view = c0 - origin
    if shape is TargetShape.CYLINDER:
        # the visible half of an upright cylinder: its points' mean lies
        # r*pi/4 in front of the axis (uniform angular sampling)
        u = view[:2] / max(np.linalg.norm(view[:2]), 1e-12)
        start = c0[:2] + radius * np.pi / 4.0 * u
        res = least_squares(lambda c: np.linalg.norm(pts[:, :2] - c, axis=1) - radius, start)
        return np.array([res.x[0], res.x[1], c0[2]])
    u = view / max(np.linalg.norm(view), 1e-12)  # sphere: visible cap, mean r*2/3 in front
    start = c0 + radius * 2.0 / 3.0 * u
    res = least_squares(lambda c: np.linalg.norm(pts - c, axis=1) - radius, start)
    return res.x


def detect_targets(scan: Scan, *, min_reflectance_db: float = 0.0,
                   target_shape: str | TargetShape = TargetShape.CYLINDER,
                   target_radius_m: float = 0.05, max_size_m: float = 0.4, min_points: int = 3,
                   link_m: float | None = None) -> np.ndarray:
    """Centres of the retro-reflective targets in a scan (scanner frame).

    A target is a cluster of echoes brighter than ``min_reflectance_db``
    (a Lambertian surface cannot exceed 0 dB; retro-reflectors do) no larger
    than ``max_size_m`` and with at least ``min_points`` echoes.

    Parameters
    ----------
    scan : Scan
        Needs ``reflectance_db``.
    min_reflectance_db : float, default 0.0
    target_shape : {'cylinder', 'sphere', 'flat'}
    target_radius_m : float, default 0.05
    max_size_m : float, default 0.4
        Largest extent (bounding-box diagonal) of a target's cluster.
    min_points : int, default 3
    link_m : float, optional
        Single-linkage distance; defaults to ``max_size_m / 2``.

    Returns
    -------
    (K, 3) float64, metres
    """
    if scan.reflectance_db is None:
        raise InputError(
            f"scan {scan.name!r}: target detection needs reflectance_db (bright retro-reflectors); "
            "this scan has none: use method='fpfh'"
        )
    shape = TargetShape.parse(target_shape, "target_shape")
    bright = np.flatnonzero(np.nan_to_num(scan.reflectance_db, nan=-np.inf) > min_reflectance_db)
    link = max_size_m / 2.0 if link_m is None else link_m
    origin = scan.pulses.origin if scan.pulses is not None else np.zeros(3)
    centres = []
    for idx in _clusters(scan.xyz[bright], link):
        pts = scan.xyz[bright[idx]]
        if len(pts) < min_points:
            continue
        if np.linalg.norm(pts.max(axis=0) - pts.min(axis=0)) > max_size_m:
            continue
        centres.append(_fit_centre(pts, origin, shape, target_radius_m))
    return np.array(centres, dtype=np.float64).reshape(-1, 3)


def match_targets(source, reference, *, tolerance_m: float = 0.03, min_side_m: float = 0.5,
                  max_tilt_deg: float | None = None) -> tuple[np.ndarray, np.ndarray] | None:
    """Correspondences between two target sets from their inter-target distances.

    Every triangle of source targets is compared with every ordered triangle
    of reference targets; a rigid motion keeps side lengths, so triangles
    whose three sides agree within ``tolerance_m`` propose a transform.  The
    proposal that brings the most targets within ``tolerance_m`` of a
    reference target wins (ties: the smaller RMSE); it is refitted on all its
    matches.

    Parameters
    ----------
    source, reference : (Ks, 3), (Kr, 3) float, metres
    tolerance_m : float, default 0.03
        Accepted error of a target centre distance.
    min_side_m : float, default 0.5
        Shortest triangle side used (short sides fix the rotation poorly).
    max_tilt_deg : float, optional
        Skip transforms that tilt the z axis by more (levelled scanners):
        targets at evenly spaced heights also fit upside down.

    Returns
    -------
    (pairs, T) or None
        ``pairs`` (M, 2) int: source index, reference index (M >= 3);
        ``T`` the rigid fit on them.  None when no 3 targets match, or when
        another transform matches as many targets with an RMSE within 3x
        the best (a symmetric layout): then targets cannot decide.
    """
    a = np.asarray(source, dtype=np.float64).reshape(-1, 3)
    b = np.asarray(reference, dtype=np.float64).reshape(-1, 3)
    if len(a) < 3 or len(b) < 3:
        return None
    tri_a = np.array(list(itertools.combinations(range(len(a)), 3)))
    tri_b = np.array(list(itertools.permutations(range(len(b)), 3)))

    def sides(p, t):
        return np.stack([np.linalg.norm(p[t[:, 0]] - p[t[:, 1]], axis=1),
                         np.linalg.norm(p[t[:, 1]] - p[t[:, 2]], axis=1),
                         np.linalg.norm(p[t[:, 0]] - p[t[:, 2]], axis=1)], axis=1)

    sa, sb = sides(a, tri_a), sides(b, tri_b)
    keep_a = sa.min(axis=1) >= min_side_m
    tri_a, sa = tri_a[keep_a], sa[keep_a]
    ok = np.all(np.abs(sa[:, None, :] - sb[None, :, :]) < tolerance_m, axis=2)
    best = None  # (n_inliers, -rmse, pairs, T)
    runner_up = []
    for ia, ib in zip(*np.nonzero(ok)):
        try:
            T = rigid_fit(a[tri_a[ia]], b[tri_b[ib]])
        except InputError:
            continue
        if max_tilt_deg is not None and tilt_deg(T) > max_tilt_deg:
            continue
        d = np.linalg.norm(apply_transform(T, a)[:, None, :] - b[None, :, :], axis=2)
        pairs = []
        used = set()
        for i in np.argsort(d.min(axis=1)):
            j = int(np.argmin(d[i]))
            if d[i, j] < tolerance_m and j not in used:
                pairs.append((int(i), j))
                used.add(j)
        if len(pairs) < 3:
            continue
        pairs = np.array(sorted(pairs))
        T = rigid_fit(a[pairs[:, 0]], b[pairs[:, 1]])
        rmse = float(np.sqrt(np.mean(np.sum((apply_transform(T, a[pairs[:, 0]]) - b[pairs[:, 1]]) ** 2, axis=1))))
        cand = (len(pairs), -rmse, pairs, T)
        if best is None or cand[:2] > best[:2]:
            best = cand
        runner_up.append(cand)
    if best is None:
        return None
    for cand in runner_up:
        # another transform that fits as many targets but puts them elsewhere: ambiguous
        moved = np.linalg.norm(apply_transform(cand[3], a) - apply_transform(best[3], a), axis=1).max()
        # ... and nearly as well: within 3x the best RMSE (taken as the
        # centre noise, at least 2 mm)
        as_good = -cand[1] < 3.0 * max(-best[1], 0.002)
        if cand[0] == best[0] and moved > tolerance_m and as_good:
            return None
    return best[2], best[3]
