"""Co-registration of TLS scans: targets, rigid fit, ICP, FPFH + RANSAC.

Each scan comes in its own scanner frame.  :func:`register_pair` finds the
rigid transform ``T`` (4x4) that maps a *source* scan's scanner frame into
the *reference* scan's frame:

1. **Targets** (retro-reflectors read above 0 dB): bright small clusters
   (:func:`detect_targets`), their centres fitted to the known target shape;
   correspondences from inter-target distances, which a rigid motion keeps
   (:func:`match_targets`); a least-squares rigid fit (:func:`rigid_fit`,
   Kabsch/Umeyama).
2. **FPFH + RANSAC** (:func:`global_fpfh`) when there are no targets: Fast
   Point Feature Histograms matched by RANSAC (Rusu et al. 2009).
3. **ICP** (:func:`refine_icp`): point-to-plane, coarse to fine voxel sizes
   (Chen & Medioni 1992), with a robust (Tukey) loss.

The final transform is scored by *fitness* (the fraction of source points
with a reference point within a distance) and the inlier RMSE.  A transform
whose fitness is below ``min_fitness`` -- also after removing the dominant
plane (the ground), which alone can align two unrelated scans -- raises
:class:`RegistrationError` carrying the figures: never a silent wrong answer.

References
----------
Umeyama, S. (1991). Least-squares estimation of transformation parameters
    between two point patterns. IEEE TPAMI 13(4), 376-380. doi:10.1109/34.88573
Kabsch, W. (1976). A solution for the best rotation to relate two sets of
    vectors. Acta Cryst. A32, 922-923. doi:10.1107/S0567739476001873
Chen, Y., Medioni, G. (1992). Object modelling by registration of multiple
    range images. Image Vis. Comput. 10(3), 145-155.
    doi:10.1016/0262-8856(92)90066-C
Rusu, R. B., Blodow, N., Beetz, M. (2009). Fast Point Feature Histograms
    (FPFH) for 3D registration. Proc. IEEE ICRA, 3212-3217.
    doi:10.1109/ROBOT.2009.5152473

Examples
--------
>>> import numpy as np
>>> rng = np.random.default_rng(0)
>>> src = rng.normal(size=(10, 3))
>>> T = np.eye(4); T[:3, :3] = rotation_about_z(30.0); T[:3, 3] = [1, 2, 3]
>>> dst = src @ T[:3, :3].T + T[:3, 3]
>>> rot_deg, trans_m = pose_error(rigid_fit(src, dst), T)
>>> bool(rot_deg < 1e-6 and trans_m < 1e-9)
True
"""

from __future__ import annotations

import enum
import itertools
import json
import os
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .errors import InputError, TlsvoxError
from .io import check_scan
from .scan import Scan

__all__ = [
    "RegistrationError",
    "RegistrationMethod",
    "RegistrationResult",
    "TargetShape",
    "detect_targets",
    "global_fpfh",
    "level_transform",
    "match_targets",
    "pose_error",
    "refine_icp",
    "register_pair",
    "register_scans",
    "rigid_fit",
    "rotation_about_z",
    "write_registered",
]

#: fewest points a scan needs to be registered at all
MIN_POINTS = 50
#: largest tilt between two levelled scans' frames: a levelled scanner's
#: compensator keeps each frame within a fraction of a degree of vertical.
#: Rules out flipped fits of near-coplanar target layouts (which need a few
#: degrees of tilt); pass levelled=False for tilted (e.g. mobile) scans.
MAX_TILT_DEG = 2.0


class RegistrationError(TlsvoxError):
    """Registration failed or its result cannot be trusted.

    Attributes
    ----------
    figures : dict
        Fitness, inlier RMSE and whatever else was measured before failing.
    """

    def __init__(self, message: str, figures: dict | None = None):
        super().__init__(message)
        self.figures = dict(figures or {})


class RegistrationMethod(enum.Enum):
    """How the coarse alignment is found (ICP refines every one of them)."""

    AUTO = "auto"  #: targets when both scans show >= 3 common ones, else FPFH
    TARGETS = "targets"  #: retro-reflective targets only (fails without them)
    FPFH = "fpfh"  #: FPFH features + RANSAC, no targets
    ICP = "icp"  #: ICP alone from the given ``init``

    @classmethod
    def parse(cls, value):
        if isinstance(value, cls):
            return value
        try:
            return cls(str(value).lower())
        except ValueError as err:
            raise InputError(
                f"method={value!r} is not a registration method; expected one of "
                f"{', '.join(m.value for m in cls)}"
            ) from err


class TargetShape(enum.Enum):
    """Shape of the retro-reflective targets, for fitting their centres."""

    CYLINDER = "cylinder"  #: upright cylinder of known radius (scanner z is up)
    SPHERE = "sphere"  #: sphere of known radius
    FLAT = "flat"  #: flat disc or sticker: the centroid of its points

    @classmethod
    def parse(cls, value):
        if isinstance(value, cls):
            return value
        try:
            return cls(str(value).lower())
        except ValueError as err:
            raise InputError(
                f"target_shape={value!r} is not a target shape; expected one of "
                f"{', '.join(m.value for m in cls)}"
            ) from err


# -- small geometry helpers -----------------------------------------------------------

def rotation_about_z(angle_deg: float) -> np.ndarray:
    """3x3 rotation matrix about +z by ``angle_deg`` degrees."""
    a = np.deg2rad(angle_deg)
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _apply(T: np.ndarray, xyz: np.ndarray) -> np.ndarray:
    return xyz @ T[:3, :3].T + T[:3, 3]


def pose_error(T_est, T_true) -> tuple[float, float]:
    """Rotation (degrees) and translation (metres) between two rigid transforms.

    The error transform is ``E = inv(T_true) @ T_est``; the rotation error is
    the angle of ``E``'s rotation, the translation error ``|E[:3, 3]|``: how
    far the estimate moves the source frame's origin (the source scanner
    centre) from where the truth puts it.
    """
    T_est = np.asarray(T_est, dtype=float)
    T_true = np.asarray(T_true, dtype=float)
    E = np.linalg.inv(T_true) @ T_est
    cos = np.clip((np.trace(E[:3, :3]) - 1.0) / 2.0, -1.0, 1.0)
    return float(np.degrees(np.arccos(cos))), float(np.linalg.norm(E[:3, 3]))


def rigid_fit(src, dst, *, weights=None, with_scale: bool = False) -> np.ndarray:
    """Least-squares rigid (or similarity) transform mapping ``src`` onto ``dst``.

    Umeyama's closed form (SVD of the weighted cross-covariance, with the
    reflection fix); Kabsch's solution when ``with_scale`` is False.

    Parameters
    ----------
    src, dst : (N, 3) float, metres, N >= 3 and not collinear
    weights : (N,) float, optional
    with_scale : bool, default False
        Also fit an isotropic scale (Umeyama).

    Returns
    -------
    (4, 4) float64
        ``T`` with ``dst ~ s R src + t`` (``s`` folded into the 3x3 block).

    References
    ----------
    Umeyama (1991), doi:10.1109/34.88573; Kabsch (1976), doi:10.1107/S0567739476001873
    """
    src = np.asarray(src, dtype=np.float64).reshape(-1, 3)
    dst = np.asarray(dst, dtype=np.float64).reshape(-1, 3)
    if src.shape != dst.shape or len(src) < 3:
        raise InputError(
            f"rigid_fit: src and dst must both be (N, 3) with N >= 3, got {src.shape} and {dst.shape}"
        )
    w = np.ones(len(src)) if weights is None else np.asarray(weights, dtype=np.float64).reshape(-1)
    if len(w) != len(src) or np.any(w < 0) or w.sum() <= 0:
        raise InputError("rigid_fit: weights must be (N,) non-negative with a positive sum")
    w = w / w.sum()
    mu_s, mu_d = w @ src, w @ dst
    a, b = src - mu_s, dst - mu_d
    cov = (b * w[:, None]).T @ a
    U, S, Vt = np.linalg.svd(cov)
    if S[1] < 1e-12 * max(S[0], 1e-300):
        raise InputError("rigid_fit: the points are collinear (or coincide); the rotation is undetermined")
    D = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        D[2, 2] = -1.0
    R = U @ D @ Vt
    s = 1.0
    if with_scale:
        var_s = float(w @ np.sum(a * a, axis=1))
        s = float(np.sum(S * np.diag(D)) / var_s)
    T = np.eye(4)
    T[:3, :3] = s * R
    T[:3, 3] = mu_d - s * R @ mu_s
    return T


# -- targets ---------------------------------------------------------------------------

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
                   target_shape: "str | TargetShape" = TargetShape.CYLINDER,
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
    shape = TargetShape.parse(target_shape)
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


def _tilt_deg(T) -> float:
    """Angle (degrees) between z and the rotated z axis of ``T``."""
    return float(np.degrees(np.arccos(np.clip(np.asarray(T)[2, 2], -1.0, 1.0))))


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
        if max_tilt_deg is not None and _tilt_deg(T) > max_tilt_deg:
            continue
        d = np.linalg.norm(_apply(T, a)[:, None, :] - b[None, :, :], axis=2)
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
        rmse = float(np.sqrt(np.mean(np.sum((_apply(T, a[pairs[:, 0]]) - b[pairs[:, 1]]) ** 2, axis=1))))
        cand = (len(pairs), -rmse, pairs, T)
        if best is None or cand[:2] > best[:2]:
            best = cand
        runner_up.append(cand)
    if best is None:
        return None
    for cand in runner_up:
        # another transform that fits as many targets but puts them elsewhere: ambiguous
        moved = np.linalg.norm(_apply(cand[3], a) - _apply(best[3], a), axis=1).max()
        # ... and nearly as well: within 3x the best RMSE (taken as the
        # centre noise, at least 2 mm)
        as_good = -cand[1] < 3.0 * max(-best[1], 0.002)
        if cand[0] == best[0] and moved > tolerance_m and as_good:
            return None
    return best[2], best[3]


# -- Open3D stages -----------------------------------------------------------------------

def _o3d_cloud(xyz: np.ndarray):
    import open3d as o3d

    return o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.ascontiguousarray(xyz, dtype=np.float64)))


def _down(pc, voxel: float):
    import open3d as o3d

    d = pc.voxel_down_sample(voxel)
    d.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=2.5 * voxel, max_nn=30))
    return d


def global_fpfh(source_xyz, reference_xyz, *, voxel_m: float = 0.1, seed: int = 0,
                max_iterations: int = 200_000, confidence: float = 0.999) -> np.ndarray:
    """Global alignment by FPFH features and RANSAC (no initial guess needed).

    Parameters
    ----------
    source_xyz, reference_xyz : (N, 3), (M, 3) float, metres
    voxel_m : float, default 0.1
        Down-sampling voxel; normals use a 2.5-voxel radius, FPFH a 5-voxel
        radius, RANSAC accepts correspondences within 1.5 voxels.
    seed : int, default 0
        Seeds Open3D's RANSAC sampler.

    Returns
    -------
    (4, 4) float64
        Reference-from-source transform (coarse: refine with :func:`refine_icp`).

    References
    ----------
    Rusu et al. (2009), doi:10.1109/ROBOT.2009.5152473
    """
    import open3d as o3d

    reg = o3d.pipelines.registration
    src, dst = _down(_o3d_cloud(source_xyz), voxel_m), _down(_o3d_cloud(reference_xyz), voxel_m)
    param = o3d.geometry.KDTreeSearchParamHybrid(radius=5.0 * voxel_m, max_nn=100)
    f_src = reg.compute_fpfh_feature(src, param)
    f_dst = reg.compute_fpfh_feature(dst, param)
    o3d.utility.random.seed(int(seed))
    dist = 1.5 * voxel_m
    res = reg.registration_ransac_based_on_feature_matching(
        src, dst, f_src, f_dst, True, dist,
        reg.TransformationEstimationPointToPoint(False), 3,
        [reg.CorrespondenceCheckerBasedOnEdgeLength(0.9), reg.CorrespondenceCheckerBasedOnDistance(dist)],
        reg.RANSACConvergenceCriteria(max_iterations, confidence))
    return np.asarray(res.transformation, dtype=np.float64).copy()


def _off_ground(xyz: np.ndarray, *, distance_m: float = 0.15) -> np.ndarray:
    """Points farther than ``distance_m`` from the dominant plane (the ground)."""
    import open3d as o3d

    pc = _o3d_cloud(xyz).voxel_down_sample(0.05)
    if len(pc.points) < 10:
        return xyz
    o3d.utility.random.seed(0)
    plane, _ = pc.segment_plane(distance_threshold=distance_m / 1.5, ransac_n=3, num_iterations=1000)
    n = np.asarray(plane[:3])
    d = np.abs(xyz @ n + plane[3]) / np.linalg.norm(n)
    rest = xyz[d > distance_m]
    return rest if len(rest) >= 10 else xyz


def level_transform(T) -> np.ndarray:
    """The rotation about z (plus translation) nearest to ``T``: drops tilt.

    Scanners level themselves (inclination sensors): scan frames differ by a
    yaw and a translation up to tilts of a fraction of a degree, which ICP
    then recovers.
    """
    T = np.asarray(T, dtype=np.float64)
    yaw = np.degrees(np.arctan2(T[1, 0] - T[0, 1], T[0, 0] + T[1, 1]))
    out = np.eye(4)
    out[:3, :3] = rotation_about_z(yaw)
    out[:3, 3] = T[:3, 3]
    return out


def _consensus(candidates: list, *, rot_deg: float, trans_m: float) -> list[list[int]]:
    """Groups of candidate transforms that agree within the tolerances, largest first."""
    groups: list[list[int]] = []
    for i, T in enumerate(candidates):
        for g in groups:
            r, t = pose_error(T, candidates[g[0]])
            if r < rot_deg and t < trans_m:
                g.append(i)
                break
        else:
            groups.append([i])
    return sorted(groups, key=len, reverse=True)


def refine_icp(source_xyz, reference_xyz, init, *, voxel_sizes=(0.2, 0.08, 0.03),
               max_iterations: int = 60) -> tuple[np.ndarray, list[dict]]:
    """Point-to-plane ICP, coarse to fine, from ``init``.

    At each voxel size ``v`` both clouds are down-sampled to ``v``, reference
    normals are estimated on a 2.5 ``v`` neighbourhood, and correspondences
    are accepted within 2.5 ``v`` with a Tukey loss of scale ``v``.

    Parameters
    ----------
    source_xyz, reference_xyz : (N, 3), (M, 3) float, metres
    init : (4, 4) float
    voxel_sizes : sequence of float, metres, decreasing
    max_iterations : int, default 60, per scale

    Returns
    -------
    T : (4, 4) float64
    stages : list of dict
        Per scale: ``voxel_m``, ``fitness``, ``inlier_rmse_m``.

    References
    ----------
    Chen & Medioni (1992), doi:10.1016/0262-8856(92)90066-C
    """
    import open3d as o3d

    reg = o3d.pipelines.registration
    T = np.asarray(init, dtype=np.float64)
    src_full, dst_full = _o3d_cloud(source_xyz), _o3d_cloud(reference_xyz)
    stages = []
    for v in voxel_sizes:
        src, dst = _down(src_full, v), _down(dst_full, v)
        loss = reg.TukeyLoss(k=v)
        res = reg.registration_icp(
            src, dst, 2.5 * v, T, reg.TransformationEstimationPointToPlane(loss),
            reg.ICPConvergenceCriteria(relative_fitness=1e-7, relative_rmse=1e-7,
                                       max_iteration=max_iterations))
        T = np.asarray(res.transformation, dtype=np.float64).copy()
        stages.append({"voxel_m": float(v), "fitness": float(res.fitness),
                       "inlier_rmse_m": float(res.inlier_rmse)})
    return T, stages


def _fitness(source_xyz, reference_xyz, T, *, voxel_m: float, distance_m: float) -> dict:
    """Fitness and inlier RMSE of ``T``, on all points and off the dominant plane."""
    import open3d as o3d

    reg = o3d.pipelines.registration
    src = _o3d_cloud(source_xyz).voxel_down_sample(voxel_m)
    dst = _o3d_cloud(reference_xyz).voxel_down_sample(voxel_m)
    ev = reg.evaluate_registration(src, dst, distance_m, T)
    out = {"fitness": float(ev.fitness), "inlier_rmse_m": float(ev.inlier_rmse),
           "fitness_distance_m": float(distance_m)}
    # a plane (the ground) aligns with any other plane: score the rest alone
    if len(src.points) >= 10:
        o3d.utility.random.seed(0)
        _, inl = src.segment_plane(distance_threshold=distance_m, ransac_n=3, num_iterations=500)
        rest = src.select_by_index(inl, invert=True)
        if len(rest.points) >= 10:
            ev2 = reg.evaluate_registration(rest, dst, distance_m, T)
            out["fitness_off_plane"] = float(ev2.fitness)
            out["plane_fraction"] = float(len(inl) / len(src.points))
    out.setdefault("fitness_off_plane", out["fitness"])
    return out


# -- the pipeline ---------------------------------------------------------------------------

@dataclass
class RegistrationResult:
    """Outcome of registering one source scan to a reference scan.

    Attributes
    ----------
    transform : (4, 4) float64
        Reference-from-source: maps the source scanner frame into the
        reference frame.
    method : str
        Coarse stage used: ``targets``, ``fpfh`` or ``icp``.
    fitness : float
        Fraction of source points (voxel down-sampled) with a reference point
        within ``fitness_distance_m`` after the transform.
    fitness_off_plane : float
        The same after removing the source's dominant plane (the ground).
    inlier_rmse_m : float
    target_pairs : (M, 2) int or None
        Source/reference target indices used.
    target_rmse_m : float or None
        RMSE of the matched target centres after the *final* transform.
    stages : list of dict
        ICP per-scale figures.
    seconds : float
    error_vs_truth : dict or None
        ``rotation_deg``, ``translation_m`` when both scans know ``pose_true``.
    """

    source: str
    reference: str
    transform: np.ndarray
    method: str
    fitness: float
    fitness_off_plane: float
    inlier_rmse_m: float
    fitness_distance_m: float
    target_pairs: np.ndarray | None = None
    target_rmse_m: float | None = None
    n_targets: tuple[int, int] | None = None
    stages: list = field(default_factory=list)
    hypothesis_groups: list | None = None
    seconds: float = 0.0
    error_vs_truth: dict | None = None

    def to_dict(self) -> dict:
        d = {k: getattr(self, k) for k in ("source", "reference", "method", "fitness",
                                           "fitness_off_plane", "inlier_rmse_m",
                                           "fitness_distance_m", "target_rmse_m", "stages", "hypothesis_groups",
                                           "seconds", "error_vs_truth")}
        d["transform"] = np.asarray(self.transform).tolist()
        d["target_pairs"] = None if self.target_pairs is None else np.asarray(self.target_pairs).tolist()
        d["n_targets"] = None if self.n_targets is None else list(self.n_targets)
        return d


def true_relative_transform(source: Scan, reference: Scan) -> np.ndarray | None:
    """``inv(pose_true_ref) @ pose_true_src`` when both scans know their true pose."""
    if source.pose_true is None or reference.pose_true is None:
        return None
    return np.linalg.inv(reference.pose_true) @ source.pose_true


def register_pair(source: Scan, reference: Scan, *, method: "str | RegistrationMethod" = "auto",
                  init=None, voxel_sizes=(0.2, 0.08, 0.03), global_voxel_m: float = 0.3,
                  min_fitness: float = 0.25, target_tolerance_m: float = 0.03,
                  target_shape: "str | TargetShape" = TargetShape.CYLINDER,
                  target_radius_m: float = 0.05, min_target_reflectance_db: float = 0.0,
                  icp_after_targets: bool = False, n_hypotheses: int = 5, min_consensus: int = 2,
                  consensus_rot_deg: float = 1.0, consensus_trans_m: float = 0.1,
                  levelled: bool = True, seed: int = 0) -> RegistrationResult:
    """Register ``source`` onto ``reference`` (both in their scanner frames).

    Parameters
    ----------
    source, reference : Scan
    method : {'auto', 'targets', 'fpfh', 'icp'}
        Coarse stage; ``auto`` uses targets when >= 3 match, else FPFH.
    init : (4, 4) float, optional
        Start for ``method='icp'``.
    voxel_sizes : sequence of float, metres
        ICP scales, coarse to fine; the finest also scores the fitness.
    global_voxel_m : float, default 0.3
        Voxel of the FPFH + RANSAC stage.
    min_fitness : float, default 0.25
        Least accepted fitness (the larger of source->reference and
        reference->source, at the finest voxel within 2.5 voxels), on all
        points *and* off the dominant plane.  Necessary, not sufficient: a
        crown laid on another crown also scores 0.4-0.5, which is why FPFH
        answers also need a consensus of hypotheses.
    target_tolerance_m : float, default 0.03
    target_shape, target_radius_m, min_target_reflectance_db
        See :func:`detect_targets`.
    icp_after_targets : bool, default False
        Refine a target fit with ICP.  Off by default: target centres fit to
        millimetres, while ICP on foliage is biased by mixed echoes (partial
        hits averaged along the beam) that differ between viewpoints
        (measured: 0.08 deg / 18 mm on the synthetic pair).
    n_hypotheses : int, default 5
        FPFH + RANSAC runs (seeds ``seed .. seed + n - 1``), each refined by
        coarse ICP.
    min_consensus : int, default 2
        Refined hypotheses that must agree (within ``consensus_rot_deg`` and
        ``consensus_trans_m``) for an FPFH answer to be accepted: a true
        alignment is a strong attractor, a wrong one (crown blob on crown
        blob) is not reproduced by independent samples.
    levelled : bool, default True
        Scanners are levelled: drop the tilt of each RANSAC hypothesis before
        ICP (ICP recovers residual tilt), and reject target matches that tilt
        by more than :data:`MAX_TILT_DEG` (upside-down fits of symmetric layouts).
    seed : int, default 0
        First RANSAC seed.

    Returns
    -------
    RegistrationResult

    Raises
    ------
    RegistrationError
        No transform found, or one whose fitness is below ``min_fitness``
        (the figures are in the message and in ``err.figures``).
    InputError
        Bad scans or options.
    """
    t0 = time.perf_counter()
    m = RegistrationMethod.parse(method)
    for s in (source, reference):
        check_scan(s, min_points=MIN_POINTS)
    if not (0.0 < min_fitness <= 1.0):
        raise InputError(f"min_fitness={min_fitness!r} must lie in (0, 1]")
    voxel_sizes = tuple(float(v) for v in voxel_sizes)
    if not voxel_sizes or any(v <= 0 for v in voxel_sizes):
        raise InputError(f"voxel_sizes={voxel_sizes!r} must be positive lengths in metres, coarse to fine")
    if m is RegistrationMethod.ICP and init is None:
        raise InputError("method='icp' needs init= (a 4x4 start transform); or use method='auto'")
    pairs = None
    n_targets = None
    used = m.value
    T0 = None
    if m in (RegistrationMethod.AUTO, RegistrationMethod.TARGETS):
        have = source.reflectance_db is not None and reference.reflectance_db is not None
        if have:
            kw = dict(min_reflectance_db=min_target_reflectance_db, target_shape=target_shape,
                      target_radius_m=target_radius_m)
            ts, tr = detect_targets(source, **kw), detect_targets(reference, **kw)
            n_targets = (len(ts), len(tr))
            found = match_targets(ts, tr, tolerance_m=target_tolerance_m,
                                  max_tilt_deg=MAX_TILT_DEG if levelled else None)
            if found is not None:
                pairs, T0 = found
                used = "targets"
        if T0 is None and m is RegistrationMethod.TARGETS:
            raise RegistrationError(
                f"{source.name!r} -> {reference.name!r}: no 3 targets in common "
                f"(targets found: {n_targets if n_targets else 'no reflectance to find them'}); "
                "use method='fpfh' or 'auto'", {"n_targets": n_targets})
    hypotheses = None
    if T0 is None and m in (RegistrationMethod.AUTO, RegistrationMethod.FPFH):
        # FPFH on the off-ground points (the ground is featureless and would
        # dominate), several RANSAC seeds, each levelled and ICP-refined at
        # the coarse scales; an answer needs >= min_consensus of them to agree.
        src_og, ref_og = _off_ground(source.xyz), _off_ground(reference.xyz)
        cands, figs = [], []
        for h in range(n_hypotheses):
            Tg = global_fpfh(src_og, ref_og, voxel_m=global_voxel_m, seed=seed + h)
            if levelled:
                Tg = level_transform(Tg)
            Th, st = refine_icp(source.xyz, reference.xyz, Tg, voxel_sizes=voxel_sizes[:1])
            cands.append(Th)
            figs.append(st[-1])
        groups = _consensus(cands, rot_deg=consensus_rot_deg, trans_m=consensus_trans_m)
        hypotheses = [len(g) for g in groups]
        if len(groups[0]) < min_consensus:
            raise RegistrationError(
                f"{source.name!r} -> {reference.name!r}: FPFH + RANSAC found no consistent "
                f"transform: {n_hypotheses} hypotheses fell in {len(groups)} different groups "
                f"(largest {len(groups[0])}, need {min_consensus}); coarse-ICP fitness of each: "
                f"{[round(f['fitness'], 3) for f in figs]}. The scans probably do not overlap; "
                "if they do, add targets or give init= with method='icp'",
                {"hypothesis_groups": hypotheses, "fitness": [f["fitness"] for f in figs],
                 "inlier_rmse_m": [f["inlier_rmse_m"] for f in figs]})
        T0 = cands[groups[0][0]]
        used = "fpfh"
    if T0 is None:
        T0 = np.asarray(init, dtype=np.float64)
        if T0.shape != (4, 4) or not np.all(np.isfinite(T0)):
            raise InputError(f"init must be a finite 4x4 matrix, got shape {T0.shape}")
        used = "icp"
    if used == "targets" and not icp_after_targets:
        T, stages = T0, []
    else:
        T, stages = refine_icp(source.xyz, reference.xyz, T0, voxel_sizes=voxel_sizes)
    # fitness both ways (scans of different density and extent), the larger kept
    kw = dict(voxel_m=voxel_sizes[-1], distance_m=2.5 * voxel_sizes[-1])
    fit_a = _fitness(source.xyz, reference.xyz, T, **kw)
    fit_b = _fitness(reference.xyz, source.xyz, np.linalg.inv(T), **kw)
    fit = {k: max(fit_a[k], fit_b[k]) for k in ("fitness", "fitness_off_plane")}
    fit["inlier_rmse_m"] = fit_a["inlier_rmse_m"] if fit_a["fitness"] >= fit_b["fitness"] else fit_b["inlier_rmse_m"]
    fit["fitness_distance_m"] = kw["distance_m"]
    target_rmse = None
    if pairs is not None:
        d = _apply(T, ts[pairs[:, 0]]) - tr[pairs[:, 1]]
        target_rmse = float(np.sqrt(np.mean(np.sum(d * d, axis=1))))
    result = RegistrationResult(
        source=source.name, reference=reference.name, transform=T, method=used,
        fitness=fit["fitness"], fitness_off_plane=fit["fitness_off_plane"],
        inlier_rmse_m=fit["inlier_rmse_m"], fitness_distance_m=fit["fitness_distance_m"],
        target_pairs=pairs, target_rmse_m=target_rmse, n_targets=n_targets, stages=stages,
        hypothesis_groups=hypotheses, seconds=time.perf_counter() - t0)
    T_true = true_relative_transform(source, reference)
    if T_true is not None:
        rot, tr_err = pose_error(T, T_true)
        result.error_vs_truth = {"rotation_deg": rot, "translation_m": tr_err}
    if min(result.fitness, result.fitness_off_plane) < min_fitness:
        figures = result.to_dict()
        raise RegistrationError(
            f"{source.name!r} -> {reference.name!r}: registration by {used} is not trustworthy: "
            f"fitness {result.fitness:.3f}, off the dominant plane {result.fitness_off_plane:.3f} "
            f"(need >= {min_fitness}), inlier RMSE {result.inlier_rmse_m * 1000:.1f} mm within "
            f"{result.fitness_distance_m * 1000:.0f} mm. Do the scans overlap? If so, try "
            "another method, larger voxel_sizes, or targets", figures)
    return result


def register_scans(scans: list[Scan], *, reference: int = 0, **kwargs) -> list[RegistrationResult | None]:
    """Register every scan to ``scans[reference]`` and set each scan's ``pose``.

    The reference keeps its ``pose`` (identity when unknown); every other scan
    gets ``pose = pose_ref @ T``.  Keyword arguments go to :func:`register_pair`.

    Returns
    -------
    list
        One :class:`RegistrationResult` per scan, None for the reference.

    Raises
    ------
    RegistrationError
        When any scan fails; no scan's pose is changed then.
    """
    if len(scans) < 2:
        raise InputError(f"register_scans needs at least 2 scans, got {len(scans)}")
    if not (0 <= reference < len(scans)):
        raise InputError(f"reference={reference} is not a scan index (0..{len(scans) - 1})")
    ref = scans[reference]
    results: list[RegistrationResult | None] = []
    for k, s in enumerate(scans):
        results.append(None if k == reference else register_pair(s, ref, **kwargs))
    pose_ref = ref.pose if ref.pose is not None else np.eye(4)
    ref.pose = pose_ref
    for s, r in zip(scans, results):
        if r is not None:
            s.pose = pose_ref @ r.transform
    return results


def write_registered(path: "str | os.PathLike", scans: list[Scan], *,
                     results: list | None = None, transforms_path: "str | os.PathLike | None" = None,
                     labels: list | None = None) -> tuple[Path, Path]:
    """Write registered scans merged into one LAS/LAZ, and a JSON of their transforms.

    Parameters
    ----------
    path : path-like, ``.las`` or ``.laz``
        Merged cloud in the reference frame: LAS 1.4 point format 6,
        ``point_source_id`` = scan id, extra bytes ``reflectance_db``,
        ``pulse_id``, ``truth_material`` (when every scan has it).
    scans : list of Scan
        Each with ``pose`` set (see :func:`register_scans`).
    results : list of RegistrationResult or None, optional
        Their fit figures go into the JSON.
    transforms_path : path-like, optional
        Defaults to ``path`` with suffix ``.transforms.json``.
    labels : list of (N_i,) uint8, optional
        Per-scan classes (:class:`tlsvox.classify.PointClass`) written to the
        LAS ``classification`` field.

    Returns
    -------
    (las_path, json_path)

    Both files are written to temporary names and renamed only once both are
    complete.
    """
    import laspy

    path = Path(path)
    if path.suffix.lower() not in (".las", ".laz"):
        raise InputError(f"output {str(path)!r} must end in .las or .laz")
    if transforms_path is None:
        transforms_path = path.with_suffix(".transforms.json")
    transforms_path = Path(transforms_path)
    for s in scans:
        if s.pose is None:
            raise InputError(f"scan {s.name!r} has no pose; register the scans first")
    xyz = np.concatenate([s.world_xyz() for s in scans])
    n = len(xyz)
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.offsets = np.floor(xyz.min(axis=0)) if n else np.zeros(3)
    header.scales = np.array([1e-4, 1e-4, 1e-4])
    extra = [laspy.ExtraBytesParams(name="reflectance_db", type=np.float32,
                                    description="apparent reflectance dB"),
             laspy.ExtraBytesParams(name="pulse_id", type=np.uint32, description="pulse row")]
    with_truth = all(s.truth_material is not None for s in scans)
    if with_truth:
        extra.append(laspy.ExtraBytesParams(name="truth_material", type=np.uint8,
                                            description="tlsvox Material id"))
    header.add_extra_dims(extra)
    las = laspy.LasData(header)
    las.x, las.y, las.z = xyz[:, 0], xyz[:, 1], xyz[:, 2]

    def cat(get, dtype):
        return np.concatenate([np.asarray(get(s), dtype=dtype) for s in scans])

    las.return_number = cat(lambda s: np.clip(s.return_number, 1, 15), np.uint8)
    las.number_of_returns = cat(lambda s: np.clip(s.number_of_returns, 1, 15), np.uint8)
    las.point_source_id = cat(lambda s: np.full(len(s), s.scan_id & 0xFFFF), np.uint16)
    las.reflectance_db = cat(lambda s: s.reflectance_db if s.reflectance_db is not None
                             else np.full(len(s), np.nan), np.float32)
    las.pulse_id = cat(lambda s: s.pulse_id if s.pulse_id is not None else np.arange(len(s)), np.uint32)
    if with_truth:
        las.truth_material = cat(lambda s: s.truth_material, np.uint8)
    if labels is not None:
        if len(labels) != len(scans) or any(len(l) != len(s) for l, s in zip(labels, scans)):
            raise InputError("labels must hold one (N_i,) array per scan")
        las.classification = np.concatenate([np.asarray(l, dtype=np.uint8) for l in labels])
    doc = {"format": "tlsvox-registration-1", "frame": "reference scanner frame" if scans else "",
           "scans": []}
    results = results if results is not None else [None] * len(scans)
    for s, r in zip(scans, results):
        entry = {"name": s.name, "scan_id": int(s.scan_id), "n_points": len(s),
                 "pose": np.asarray(s.pose).tolist()}
        if r is not None:
            entry["registration"] = r.to_dict()
        doc["scans"].append(entry)
    tmp_las = path.with_name(f".{path.name}.tmp-{os.getpid()}{path.suffix}")
    tmp_json = transforms_path.with_name(f".{transforms_path.name}.tmp-{os.getpid()}")
    path.parent.mkdir(parents=True, exist_ok=True)
    transforms_path.parent.mkdir(parents=True, exist_ok=True)
    try:
        las.write(str(tmp_las))
        tmp_json.write_text(json.dumps(doc, indent=1))
        os.replace(tmp_las, path)
        os.replace(tmp_json, transforms_path)
    finally:
        for t in (tmp_las, tmp_json):
            if t.exists():
                t.unlink()
    return path, transforms_path


def read_transforms(path: "str | os.PathLike") -> dict[str, np.ndarray]:
    """Scan name -> 4x4 pose from a JSON written by :func:`write_registered`."""
    doc = json.loads(Path(path).read_text())
    return {e["name"]: np.asarray(e["pose"], dtype=np.float64) for e in doc["scans"]}

