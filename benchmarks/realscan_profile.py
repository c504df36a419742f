"""Vertical plant area density profile of the real VZ-400i scan (20 cm voxels).

Voxelises ../shared/data/tls-vz400i-scan/tls_scan.laz end to end (empty
pulses rebuilt from its angular grid, ground by RANSAC, every non-ground echo
counted as plant: no intensity to separate leaves from wood) and plots the
mean PAD per 20 cm layer over the visible voxels within 8 m of the scanner,
for each estimator, into docs/img/realscan_lad_profile.png.

    .venv/bin/python benchmarks/realscan_profile.py
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from tlsvox.scan import AngularGrid, Scan
from tlsvox.voxel.estimators import Estimator, estimate_lad
from tlsvox.voxel.pulses import rotation_from_rpy
from tlsvox.voxel.stages import voxelize

ROOT = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("VOXLIDAR_SHARED_DATA", ROOT.parent / "shared" / "data"))


def main():
    scan = Scan.read(DATA / "tls-vz400i-scan" / "tls_scan.laz")
    res = voxelize([scan], voxel_size=0.2, scanner_frame=True, leaf_angle="spherical",
                   angular_grid=AngularGrid(30.0, 0.048, 2082, 0.0, 0.622, 580),
                   socs_rotation=rotation_from_rpy(1.026, 0.746, -110.019), progress=False)
    g = res.grid
    c = g.centers().reshape(*g.shape, 3)
    near = np.hypot(c[..., 0], c[..., 1]) < 8.0
    z = g.layer_heights() - res.ground.z_center
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 2, figsize=(9, 5), sharey=True)
    for est in Estimator:
        lad = estimate_lad(res.stats, estimator=est)
        vis = near & ~lad.occluded
        prof = np.where(vis, lad.lad, 0).sum(axis=(0, 1)) / np.maximum(vis.sum(axis=(0, 1)), 1)
        ax[0].plot(prof, z, label=est.value)
    occ = (near & res.lad.occluded).sum(axis=(0, 1)) / np.maximum(near.sum(axis=(0, 1)), 1)
    ax[1].plot(occ, z, "k-")
    ax[0].set(xlabel="mean PAD of visible voxels (m2/m3)", ylabel="height above ground (m)",
              title="VZ-400i scan, 20 cm voxels, r < 8 m")
    ax[1].set(xlabel="occluded fraction", title="occlusion")
    ax[0].legend(fontsize=8)
    for a in ax:
        a.grid(alpha=0.3)
    fig.tight_layout()
    out = ROOT / "docs" / "img" / "realscan_lad_profile.png"
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    print(out, res.timings, res.scene.meta["flags"], "plant area", round(res.scene.total_leaf_area(), 1))


if __name__ == "__main__":
    main()
