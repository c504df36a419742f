"""Place a TLS point cloud (or a scene built from it) in the airborne frame.

The airborne cloud sees the crown tops and the ground from above; the TLS
cloud sees the stems and the crown from below and the side. So the partial,
sparse airborne cloud is registered *onto* the complete TLS cloud (every
airborne point has a true neighbour on the TLS surface, not the other way
round) and the result inverted.

1. Initial guess ``init`` (TLS -> airborne, 4x4), e.g. from GNSS of the
   scanner position and a compass yaw.
2. Restricted yaw search: for yaw offsets within ``+-yaw_range_deg`` about the
   vertical axis through the airborne cloud's centroid, a coarse point-to-plane
   ICP (voxel-downsampled) is run; the best by fitness (then inlier RMSE) wins.
   ICP alone converges only for small rotations; yaw is the angle a compass
   gets most wrong while roll and pitch come from the scanner's inclinometer.
3. Multi-scale point-to-plane ICP refinement (Open3D) at decreasing
   correspondence distances.

Open3D is imported inside the functions, never at package import.

References
----------
Besl, P. J. & McKay, N. D. (1992). A method for registration of 3-D shapes.
    IEEE TPAMI 14(2), 239-256. doi:10.1109/34.121791
Chen, Y. & Medioni, G. (1992). Object modelling by registration of multiple
    range images. Image Vis. Comput. 10(3), 145-155.
    doi:10.1016/0262-8856(92)90066-C
Zhou, Q.-Y., Park, J. & Koltun, V. (2018). Open3D: a modern library for 3D
    data processing. arXiv:1801.09847
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from tlsvox.errors import InputError
from tlsvox.register._transforms import apply_transform, pose_error, rotation_about_z

__all__ = ["Registration", "georegister", "rotation_error_deg", "transform_points",
           "yaw_matrix"]


@dataclass
class Registration:
    """Result of :func:`georegister`.

    Attributes
    ----------
    transform : (4, 4) float64
        Maps source (TLS) coordinates to the airborne frame.
    fitness : float
        Fraction of downsampled airborne points with a TLS neighbour within
        the final correspondence distance.
    inlier_rmse : float, m
        RMS distance of those correspondences.
    yaw_offset_deg : float
        Yaw offset (about the vertical) from the initial guess that the search
        chose.
    trials : list of (yaw_deg, fitness, inlier_rmse)
        Coarse results of the yaw search.
    """

    transform: np.ndarray
    fitness: float
    inlier_rmse: float
    yaw_offset_deg: float
    trials: list = field(default_factory=list)


def yaw_matrix(yaw_deg: float, *, center=(0.0, 0.0, 0.0)) -> np.ndarray:
    """4x4 rotation by ``yaw_deg`` about the vertical axis through ``center``.

    Examples
    --------
    >>> np.round(yaw_matrix(90.0) @ [1, 0, 0, 1], 12).tolist()
    [0.0, 1.0, 0.0, 1.0]
    """
    m = np.eye(4)
    m[:3, :3] = rotation_about_z(float(yaw_deg))
    ctr = np.asarray(center, dtype=np.float64).reshape(3)
    m[:3, 3] = ctr - m[:3, :3] @ ctr
    return m


def transform_points(matrix, xyz) -> np.ndarray:
    """Apply a 4x4 rigid transform to (N, 3) points."""
    return apply_transform(_matrix(matrix, "matrix"), _points(xyz, "xyz", min_points=1))


def rotation_error_deg(a, b) -> float:
    """Angle of the rotation ``R_a^T R_b``, degrees (0 when the rotations agree).

    Examples
    --------
    >>> round(rotation_error_deg(np.eye(4), yaw_matrix(3.0)), 9)
    3.0
    """
    ra, rb = np.eye(4), np.eye(4)
    ra[:3, :3], rb[:3, :3] = _matrix(a, "a")[:3, :3], _matrix(b, "b")[:3, :3]
    return pose_error(rb, ra)[0]


def _matrix(m, name) -> np.ndarray:
    a = np.asarray(m, dtype=np.float64)
    if a.shape != (4, 4):
        raise InputError(f"{name} must be a 4x4 homogeneous transform; got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise InputError(f"{name} contains NaN or inf")
    return a


def _points(xyz, name, min_points=10) -> np.ndarray:
    p = np.asarray(xyz, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3:
        raise InputError(f"{name} must have shape (N, 3); got {p.shape}")
    if p.shape[0] < min_points:
        raise InputError(f"{name} has {p.shape[0]} points; at least {min_points} are needed")
    if not np.all(np.isfinite(p)):
        raise InputError(f"{name} contains NaN or inf coordinates")
    return p


def georegister(source_xyz, target_xyz, *, init=None, yaw_range_deg: float = 30.0,
                yaw_step_deg: float = 5.0, voxel_size: float = 0.2,
                coarse_factor: float = 4.0, max_iterations: int = 60) -> Registration:
    """Register a TLS cloud (source) to an airborne cloud (target).

    Parameters
    ----------
    source_xyz : (N, 3) array_like, m
        TLS points in the scanner (or project) frame.
    target_xyz : (M, 3) array_like, m
        Airborne points (map frame).
    init : (4, 4) array_like, optional
        Initial source -> target transform. Default: translate the source
        centroid's x, y onto the target's, and align the lowest points in z.
    yaw_range_deg, yaw_step_deg : float
        Yaw offsets tried: ``-range, -range + step, ..., +range`` (0 to disable:
        ``yaw_range_deg=0``).
    voxel_size : float, m
        Fine resolution (downsampling and normal estimation).
    coarse_factor : float
        The yaw search runs at ``coarse_factor * voxel_size``.
    max_iterations : int
        ICP iterations per stage.

    Returns
    -------
    Registration

    Raises
    ------
    InputError
        Bad shapes, too few points, a non-rigid ``init``, non-positive sizes.
    """
    import open3d as o3d  # heavy; only here

    src = _points(source_xyz, "source_xyz")
    tgt = _points(target_xyz, "target_xyz")
    if not voxel_size > 0 or not coarse_factor >= 1:
        raise InputError(f"voxel_size must be > 0 and coarse_factor >= 1; got {voxel_size}, "
                         f"{coarse_factor}")
    if yaw_range_deg < 0 or (yaw_range_deg > 0 and not yaw_step_deg > 0):
        raise InputError(f"yaw_range_deg must be >= 0 and yaw_step_deg > 0; got "
                         f"{yaw_range_deg}, {yaw_step_deg}")
    if init is None:
        init = np.eye(4)
        init[:2, 3] = tgt[:, :2].mean(axis=0) - src[:, :2].mean(axis=0)
        init[2, 3] = np.percentile(tgt[:, 2], 1) - np.percentile(src[:, 2], 1)
    init = _matrix(init, "init")
    r = init[:3, :3]
    if not np.allclose(r.T @ r, np.eye(3), atol=1e-6) or np.linalg.det(r) < 0:
        raise InputError("init must be a rigid transform (orthonormal rotation, det +1); "
                         "got a matrix with scale or shear")

    def cloud(p):
        pc = o3d.geometry.PointCloud()
        pc.points = o3d.utility.Vector3dVector(p)
        return pc

    # TLS cloud is the fixed ("target" for Open3D) surface with normals.
    tls = cloud(src)
    als = cloud(tgt)
    reg = o3d.pipelines.registration
    est = reg.TransformationEstimationPointToPlane()

    def prepare(pc, vs):
        d = pc.voxel_down_sample(vs)
        d.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=3.0 * vs, max_nn=30))
        return d

    coarse = voxel_size * coarse_factor
    tls_c, als_c = prepare(tls, coarse), als.voxel_down_sample(coarse)
    centre = tgt.mean(axis=0)
    if yaw_range_deg > 0:
        k = int(np.floor(yaw_range_deg / yaw_step_deg + 1e-9))
        yaws = yaw_step_deg * np.arange(-k, k + 1)
    else:
        yaws = np.array([0.0])
    trials = []
    best = None
    crit = reg.ICPConvergenceCriteria(max_iteration=int(max_iterations))
    for yaw in yaws:
        fwd = yaw_matrix(yaw, center=centre) @ init
        res = reg.registration_icp(als_c, tls_c, 2.5 * coarse, np.linalg.inv(fwd), est, crit)
        trials.append((float(yaw), float(res.fitness), float(res.inlier_rmse)))
        key = (round(res.fitness, 3), -res.inlier_rmse)
        if best is None or key > best[0]:
            best = (key, np.asarray(res.transformation), float(yaw))
    current = best[1]
    final = None
    for factor, dist in ((2.0, 3.0), (1.0, 2.0), (1.0, 1.0)):
        vs = voxel_size * factor
        tls_f = prepare(tls, vs)
        als_f = als.voxel_down_sample(vs)
        final = reg.registration_icp(als_f, tls_f, dist * vs, current, est, crit)
        current = np.asarray(final.transformation)
    return Registration(transform=np.linalg.inv(current), fitness=float(final.fitness),
                        inlier_rmse=float(final.inlier_rmse), yaw_offset_deg=best[2],
                        trials=trials)
