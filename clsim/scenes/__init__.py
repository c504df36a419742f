"""Scenes of many trees: a plot of tree models (synthetic or scanned voxel scenes)
placed on a flat ground, run by the simulator as one sparse scene whose tree
instances share their voxel bricks.  See docs/survey.md ("Scenes of many trees").
"""

from clsim.scenes._bricks import merge_voxels
from clsim.scenes._make import TREE_KINDS, make_plot, random_tree_params, synthetic_tree_scene
from clsim.scenes._plot import TABLE_DTYPE, PlotScene, Snap
from clsim.scenes.pictures import plot_canopy

__all__ = ["PlotScene", "Snap", "TABLE_DTYPE", "TREE_KINDS", "load_scene", "make_plot", "merge_voxels",
           "plot_canopy", "random_tree_params", "repeat_scene_warnings", "scene_warnings", "synthetic_tree_scene"]


def load_scene(path):
    """A scene file as the simulator takes it: an AMAPVox ``.vox`` (by suffix or content), a
    :class:`PlotScene` written by :meth:`PlotScene.save`, else a :class:`voxlidar.scene.Scene` NPZ."""
    from pathlib import Path

    from voxlidar.safeio import file_kind
    from voxlidar.scene import Scene

    path = Path(path)
    if path.suffix.lower() == ".vox" or (path.is_file() and file_kind(path) == "vox"):
        from tlsvox.voxel.amapvox import read_vox

        return read_vox(path)
    return PlotScene.load(path) if PlotScene.is_plot_file(path) else Scene.load(path)


def scene_warnings(scene) -> list[str]:
    """The quality warnings a scene was written with (``tlsvox voxelize`` records them in ``meta["warnings"]``),
    for the simulator to repeat when it loads the scene; none for a scene without them (a plot, a ``.vox``)."""
    meta = getattr(scene, "meta", None) or {}
    return [str(w) for w in meta.get("warnings", [])]


def repeat_scene_warnings(tool: str, path, scene, *, strict: bool = False) -> list[str]:
    """Print the scene's recorded quality warnings to stderr (``tool: warning: ...``); with ``strict``, raise
    :class:`~clsim.errors.InputError` when there is any. Returns them."""
    import sys

    from clsim.errors import InputError

    said = scene_warnings(scene)
    for w in said:
        print(f"{tool}: warning: {path} was written with a quality warning: {w}", file=sys.stderr)
    if strict and said:
        raise InputError(f"{path}: {len(said)} quality warning(s) recorded when the scene was made, with --strict; "
                         "fix the voxelisation (see the warnings) or drop --strict")
    return said
