"""Vertical profiles of a voxel scene: leaf area density against height, and what was hidden.

The profile of a layer is the mean LAD of its seen voxels (those not flagged
occluded), in m2/m3, over the scene's footprint or a disc around a centre;
beside it, the share of the layer's voxels that no beam reached.  Heights are
above the scene's ground plane when it has one.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from voxlidar.errors import InputError

__all__ = ["LadProfile", "lad_profile", "lad_profile_figure"]


@dataclass
class LadProfile:
    """One scene's profile (:func:`lad_profile`)."""

    height: np.ndarray  #: (nz,) layer centres, metres (above the ground plane when there is one)
    lad: np.ndarray  #: (nz,) mean LAD of the layer's seen voxels, m2/m3
    occluded: np.ndarray  #: (nz,) share of the layer's voxels flagged occluded
    above_ground: bool  #: heights above the ground plane (else the grid's z)
    radius: float | None  #: the disc the profile covers, metres (None: the whole footprint)

    @property
    def leaf_area_index(self) -> float:
        """The profile's leaf area per ground area over the seen voxels, m2/m2."""
        dz = float(np.median(np.diff(self.height))) if len(self.height) > 1 else 0.0
        return float(np.sum(self.lad) * dz)


def lad_profile(scene, *, radius: float | None = None, center=None) -> LadProfile:
    """The LAD profile of ``scene`` (a :class:`voxlidar.scene.Scene`) over its footprint, or over the
    columns whose centres lie within ``radius`` metres of ``center`` (default the crown centre)."""
    nx, ny, nz = (int(v) for v in scene.shape)
    s = float(scene.voxel_size)
    origin = np.asarray(scene.origin, dtype=np.float64)
    cx = origin[0] + (np.arange(nx) + 0.5) * s
    cy = origin[1] + (np.arange(ny) + 0.5) * s
    if radius is not None:
        if not (np.isfinite(radius) and radius > 0):
            raise InputError(f"profile radius {radius!r} must be a positive distance in metres (e.g. 8)")
        c = np.asarray(scene.crown_center if center is None else center, dtype=np.float64).reshape(-1)[:2]
        inside = np.hypot(cx[:, None] - c[0], cy[None, :] - c[1]) <= radius
    else:
        inside = np.ones((nx, ny), bool)
    columns = int(inside.sum())
    if not columns:
        raise InputError(f"no voxel column lies within {radius} m of {np.round(c, 2).tolist()}: give a larger "
                         "radius or a centre inside the scene")
    ijk = np.asarray(scene.ijk, dtype=np.int64).reshape(-1, 3)
    keep = inside[ijk[:, 0], ijk[:, 1]]
    k = ijk[keep, 2]
    occ = np.asarray(scene.occluded, bool)[keep] if scene.occluded is not None else np.zeros(len(k), bool)
    lad = np.asarray(scene.lad, dtype=np.float64)[keep]
    n_occ = np.bincount(k[occ], minlength=nz)
    area = np.bincount(k[~occ], weights=lad[~occ], minlength=nz)
    seen = columns - n_occ
    height = origin[2] + (np.arange(nz) + 0.5) * s
    ground = scene.ground_z is not None
    if ground:
        height = height - float(scene.ground_z)
    return LadProfile(height=height, lad=np.where(seen > 0, area / np.maximum(seen, 1), 0.0),
                      occluded=n_occ / columns, above_ground=ground, radius=radius)


def lad_profile_figure(profiles: dict, path, *, title: str, caption: str | None = None):
    """Write a picture of one or more :class:`LadProfile` (``{label: profile}``): mean LAD of the seen
    voxels against height, and the occluded share, with titles, units and a legend."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from voxlidar.safeio import check_figure_path, finish_figure

    check_figure_path("--profile", path)
    fig, (a, b) = plt.subplots(1, 2, figsize=(8.5, 5), sharey=True, gridspec_kw={"width_ratios": [2, 1]})
    for label, p in profiles.items():
        a.plot(p.lad, p.height, label=f"{label} (LAI of the seen voxels {p.leaf_area_index:.2f})")
        b.plot(p.occluded, p.height, label=label)
    first = next(iter(profiles.values()))
    a.set(xlabel="mean leaf area density of the seen voxels (m2/m3)",
          ylabel="height above the ground plane (m)" if first.above_ground else "height z (m)", title=title)
    b.set(xlabel="share of the layer's voxels occluded", title="occlusion", xlim=(0, 1))
    a.legend(fontsize=8, loc="upper right")
    if len(profiles) > 1:
        b.legend(fontsize=8, loc="upper right")
    for ax in (a, b):
        ax.grid(alpha=0.3)
    return finish_figure(fig, path, caption=caption)
