"""Built-in scenes with known answers (docs/method.md §8), as :class:`voxlidar.scene.Scene`.

Examples
--------
>>> s = homogeneous_layer(lad=1.0, thickness=2.0, width=4.0, voxel_size=0.5)
>>> s.n_voxels, s.ground_z, s.leaf_angle.kind.value
(256, 0.0, 'spherical')
>>> s.optics("leaf", 1064)
(0.437, 0.478)
>>> set_optics(s, 1064, leaf=(0.5, 0.0)).optics("leaf", 1064)
(0.5, 0.0)
"""

from __future__ import annotations

import copy

import numpy as np

from clsim.errors import InputError
from voxlidar.scene import Scene

__all__ = ["homogeneous_layer", "one_voxel", "ground_only", "set_optics"]


def set_optics(scene: Scene, wavelength_nm: float, **materials) -> Scene:
    """A copy of ``scene`` with ``material=(R, T)`` set at ``wavelength_nm``.

    Materials are ``leaf``, ``bark`` (wood) and ``ground``.
    """
    out = copy.deepcopy(scene)
    key = str(int(round(float(wavelength_nm))))
    for name, rt in materials.items():
        if name not in ("leaf", "bark", "ground"):
            raise InputError(f"material {name!r} must be one of leaf, bark, ground")
        r, t = (float(v) for v in rt)
        if min(r, t) < 0 or r + t > 1 + 1e-12:
            raise InputError(
                f"{name} optics R={r}, T={t}: need R, T >= 0 and R + T <= 1 "
                "(a surface cannot return more than it receives)"
            )
        out.materials.setdefault(name, {})[key] = [r, t]
    return out


def homogeneous_layer(
    *,
    lad: float = 1.0,
    thickness: float = 2.0,
    width: float = 10.0,
    voxel_size: float = 0.5,
    base_height: float = 2.0,
    leaf_angle="spherical",
    leaf_azimuth: str = "uniform",
    wood: float = 0.0,
) -> Scene:
    """A horizontal turbid layer of leaves over a ground plane at z = 0.

    Parameters
    ----------
    lad : float, m2/m3
        Leaf area density of every voxel of the layer.
    thickness : float, metres
        Layer thickness (a multiple of ``voxel_size``).
    width : float, metres
        Side of the square layer, centred on (0, 0).
    voxel_size : float, metres
    base_height : float, metres
        Height of the layer's bottom above the ground (a multiple of ``voxel_size``).
    leaf_angle : str or LeafAngle
    leaf_azimuth : {"uniform", "outward"}
        ``outward`` uses ``crown_center = (0, 0)``.
    wood : float
        Wood probability per voxel (0: none).
    """
    n_xy = int(round(width / voxel_size))
    n_z = int(round(thickness / voxel_size))
    k0 = int(round(base_height / voxel_size))
    if n_xy < 1 or n_z < 1 or k0 < 0:
        raise InputError(
            f"layer of width {width} m, thickness {thickness} m over {base_height} m needs at "
            f"least one voxel of {voxel_size} m in each direction"
        )
    i, j, k = np.meshgrid(np.arange(n_xy), np.arange(n_xy), np.arange(k0, k0 + n_z), indexing="ij")
    ijk = np.column_stack([i.ravel(), j.ravel(), k.ravel()])
    half = 0.5 * n_xy * voxel_size
    return Scene(
        origin=(-half, -half, 0.0),
        voxel_size=voxel_size,
        shape=(n_xy, n_xy, k0 + n_z),
        ijk=ijk,
        lad=np.full(len(ijk), float(lad)),
        wood=np.full(len(ijk), float(wood)),
        leaf_angle=leaf_angle,
        leaf_azimuth=leaf_azimuth,
        crown_center=(0.0, 0.0),
        ground_z=0.0,
        meta={"testscene": "homogeneous_layer", "lad": lad, "thickness": thickness,
              "base_height": base_height},
    )


def one_voxel(*, lad: float = 2.0, voxel_size: float = 1.0, height: float = 5.0,
              ground: bool = True, leaf_angle="spherical") -> Scene:
    """One cubic voxel of leaves centred over (0, 0), its bottom ``height`` above the ground."""
    k = int(round(height / voxel_size))
    return Scene(
        origin=(-0.5 * voxel_size, -0.5 * voxel_size, 0.0),
        voxel_size=voxel_size,
        shape=(1, 1, k + 1),
        ijk=[[0, 0, k]],
        lad=[float(lad)],
        leaf_angle=leaf_angle,
        ground_z=0.0 if ground else None,
        meta={"testscene": "one_voxel"},
    )


def ground_only(*, width: float = 10.0, voxel_size: float = 1.0) -> Scene:
    """A bare Lambertian ground at z = 0 under an empty grid."""
    n = max(1, int(round(width / voxel_size)))
    half = 0.5 * n * voxel_size
    return Scene(
        origin=(-half, -half, 0.0), voxel_size=voxel_size, shape=(n, n, 1),
        ijk=np.zeros((0, 3), np.int32), lad=np.zeros(0), ground_z=0.0,
        meta={"testscene": "ground_only"},
    )
