"""The voxel stage (VoxLAD): registered scans -> leaf area density, wood and ground.

- :mod:`tlsvox.voxel.grid`: the regular grid beams are traced through;
- :mod:`tlsvox.voxel.pulses`: beams (pulses with their echoes) from scans;
- :mod:`tlsvox.voxel.weights`: how much of its beam each echo stops;
- :mod:`tlsvox.voxel.trace`: beam tracing on OpenCL (per-voxel sums);
- :mod:`tlsvox.voxel.estimators`: LAD estimators on those sums;
- :mod:`tlsvox.voxel.wood`: wood in one place: per voxel, and solid from cylinders fitted to the wood echoes;
- :mod:`tlsvox.voxel.stages`: the whole stage as its stages, :func:`~tlsvox.voxel.stages.voxelize`;
- :mod:`tlsvox.voxel.settings`: its settings, grouped by stage, and their TOML file;
- :mod:`tlsvox.voxel.amapvox`: AMAPVox ``.vox`` import and export.
"""

from tlsvox.voxel.estimators import Estimator
from tlsvox.voxel.grid import VoxelGrid
from tlsvox.voxel.settings import VoxelizeSettings
from tlsvox.voxel.stages import voxelize
from tlsvox.voxel.weights import EchoWeights

__all__ = ["EchoWeights", "Estimator", "VoxelGrid", "VoxelizeSettings", "voxelize"]
