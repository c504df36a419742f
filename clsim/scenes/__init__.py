"""Scenes of many trees: a plot of tree models (synthetic or scanned voxel scenes)
placed on a flat ground, run by the simulator as one sparse scene whose tree
instances share their voxel bricks.  See docs/survey.md ("Scenes of many trees").
"""

from clsim.scenes._make import TREE_KINDS, make_plot, random_tree_params, synthetic_tree_scene
from clsim.scenes._plot import TABLE_DTYPE, PlotScene, Snap, merge_voxels
from clsim.scenes.pictures import plot_canopy

__all__ = ["PlotScene", "Snap", "TABLE_DTYPE", "TREE_KINDS", "make_plot", "merge_voxels", "plot_canopy",
           "random_tree_params", "synthetic_tree_scene"]
