"""Rigid transforms: rotations about z, least-squares rigid fits (Kabsch/Umeyama), pose errors.

References
----------
Umeyama, S. (1991). Least-squares estimation of transformation parameters
    between two point patterns. IEEE TPAMI 13(4), 376-380. doi:10.1109/34.88573
Kabsch, W. (1976). A solution for the best rotation to relate two sets of
    vectors. Acta Cryst. A32, 922-923. doi:10.1107/S0567739476001873

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

import numpy as np

from tlsvox.errors import InputError
from tlsvox.scan import Scan

#: largest tilt between two levelled scans' frames: a levelled scanner's
#: compensator keeps each frame within a fraction of a degree of vertical.
#: Rules out flipped fits of near-coplanar target layouts (which need a few
#: degrees of tilt); pass levelled=False for tilted (e.g. mobile) scans.
MAX_TILT_DEG = 2.0


def rotation_about_z(angle_deg: float) -> np.ndarray:
    """3x3 rotation matrix about +z by ``angle_deg`` degrees."""
    a = np.deg2rad(angle_deg)
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def apply_transform(T: np.ndarray, xyz: np.ndarray) -> np.ndarray:
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


def tilt_deg(T) -> float:
    """Angle (degrees) between z and the rotated z axis of ``T``."""
    return float(np.degrees(np.arccos(np.clip(np.asarray(T)[2, 2], -1.0, 1.0))))


def levelled_fit(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Least-squares yaw + translation mapping ``p`` onto ``q`` ((N, 3), N >= 2)."""
    mp, mq = p.mean(axis=0), q.mean(axis=0)
    a, b = p - mp, q - mq
    yaw = np.degrees(np.arctan2(np.sum(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]),
                                np.sum(a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1])))
    T = np.eye(4)
    T[:3, :3] = rotation_about_z(yaw)
    T[:3, 3] = mq - T[:3, :3] @ mp
    return T


def batch_kabsch(p: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rigid fits of many small point sets: p, q (H, n, 3) -> R (H, 3, 3), t (H, 3)."""
    mp, mq = p.mean(axis=1), q.mean(axis=1)
    cov = np.einsum("hni,hnj->hij", q - mq[:, None], p - mp[:, None])
    U, _, Vt = np.linalg.svd(cov)
    d = np.sign(np.linalg.det(U) * np.linalg.det(Vt))
    U[:, :, 2] *= d[:, None]
    R = U @ Vt
    return R, mq - np.einsum("hij,hj->hi", R, mp)


def true_relative_transform(source: Scan, reference: Scan) -> np.ndarray | None:
    """``inv(pose_true_ref) @ pose_true_src`` when both scans know their true pose."""
    if source.pose_true is None or reference.pose_true is None:
        return None
    return np.linalg.inv(reference.pose_true) @ source.pose_true
