"""A seeded plot of synthetic trees: a few tree models of varied kind, size and
seed, placed at random positions with a minimum spacing."""

from __future__ import annotations

import math

import numpy as np

from clsim.scenes._plot import BRICK, PlotScene, Snap
from voxlidar.errors import InputError, finite_number

__all__ = ["TREE_KINDS", "make_plot", "random_tree_params", "synthetic_tree_scene"]

#: Ranges each kind of tree draws its size from (uniform): height (m), crown radius (m),
#: crown base as a fraction of the height, mean LAD over the crown ellipsoid (m2/m3),
#: trunk radius (m), scaffold branches.  Broad oak-like crowns, narrow tall crowns,
#: small trees of the understorey.
TREE_KINDS = {
    "broadleaf": dict(height=(10.0, 16.0), crown_radius=(3.0, 5.0), crown_base=(0.2, 0.3),
                      lad=(0.4, 0.8), trunk_radius=(0.2, 0.35), n_scaffolds=(5, 7)),
    "narrow": dict(height=(12.0, 20.0), crown_radius=(1.5, 2.5), crown_base=(0.3, 0.4),
                   lad=(0.6, 1.0), trunk_radius=(0.15, 0.3), n_scaffolds=(4, 6)),
    "small": dict(height=(4.0, 8.0), crown_radius=(1.5, 3.0), crown_base=(0.15, 0.25),
                  lad=(0.5, 1.0), trunk_radius=(0.08, 0.15), n_scaffolds=(3, 5)),
}


def random_tree_params(kind: str, rng: np.random.Generator, *, leaf_angle: str = "uniform",
                       leaf_length_m: float = 0.2):
    """TreeParams of one tree of ``kind`` (a key of :data:`TREE_KINDS`) drawn with ``rng``.

    Leaves are ``leaf_length_m`` x ``leaf_length_m / 2`` ellipses: their size
    sets only how many triangles the mesh has (the voxel scene holds the exact
    leaf area per voxel, a turbid medium has no leaf size), so plot trees use
    leaves larger than the oak's 5 cm to build fast.
    """
    from tlsvox.truth.synthetic import TreeParams

    if kind not in TREE_KINDS:
        raise InputError(f"tree kind {kind!r} is not known; choose from {sorted(TREE_KINDS)}")
    r = TREE_KINDS[kind]
    u = lambda key: float(rng.uniform(*r[key]))        # noqa: E731
    height, radius = u("height"), u("crown_radius")
    base = u("crown_base") * height
    volume = 4.0 / 3.0 * math.pi * radius**2 * 0.5 * (height - base)
    return TreeParams(height=height, crown_base=base, crown_radius=radius, trunk_radius=u("trunk_radius"),
                      total_leaf_area=u("lad") * volume, leaf_length=leaf_length_m,
                      leaf_width=0.5 * leaf_length_m, leaf_angle=leaf_angle, leaf_azimuth="uniform",
                      n_scaffolds=int(rng.integers(r["n_scaffolds"][0], r["n_scaffolds"][1] + 1)),
                      n_targets=0)


def synthetic_tree_scene(params, *, seed: int, voxel_size: float, name: str | None = None):
    """The exact-LAD voxel scene of ``make_tree(params, seed=seed)`` (trunk at (0, 0),
    ground at z = 0): leaf area per voxel from the mesh's triangles, wood as a
    crossing probability (:meth:`~tlsvox.truth.synthetic.SyntheticTree.truth_scene`)."""
    from tlsvox.truth.synthetic import make_tree

    scene = make_tree(params, seed=seed).truth_scene(voxel_size)
    scene.meta["name"] = name or f"tree-{seed}"
    return scene


def make_plot(width_m: float = 50.0, n_trees: int = 30, *, seed: int = 0, voxel_size: float = 0.5,
              length_m: float | None = None, n_models: int = 6, kinds=("broadleaf", "narrow", "small"),
              min_spacing_m: float = 4.0, snap="brick", leaf_angle: str = "uniform",
              ground_z: float = 0.0, share: bool = True, leaf_length_m: float = 0.2,
              tries: int = 5000) -> PlotScene:
    """A plot of ``n_trees`` synthetic trees drawn from ``n_models`` distinct trees.

    Model ``k`` is of kind ``kinds[k % len(kinds)]`` with its size drawn from
    :data:`TREE_KINDS` and its own mesh seed; the trees are assigned to models in
    turn (every model used) and shuffled, then placed one after another at
    uniform random positions that keep the whole crown inside the plot and at
    least ``min_spacing_m`` from every trunk placed before (dart throwing,
    ``tries`` draws per tree).  Everything comes from ``seed``: the same seed
    gives the same plot.

    Parameters
    ----------
    width_m, length_m : float, metres
    n_trees, n_models : int
    seed : int
    voxel_size : float, metres
    kinds : sequence of str
        Keys of :data:`TREE_KINDS`.
    min_spacing_m : float, metres
        Smallest distance between two trunks (crowns may still overlap; they add).
    snap : {"brick", "voxel"}
        ``"brick"`` (default) draws positions on the brick lattice (every
        ``8 x voxel_size``) so that the instances of a model share bricks;
        ``"voxel"`` on the voxel lattice.
    leaf_angle : str
        Leaf inclination model of every tree.
    ground_z : float, metres
    share : bool
        See :class:`PlotScene`.
    leaf_length_m : float
        Leaf size of the meshes (see :func:`random_tree_params`).

    Returns
    -------
    PlotScene

    Examples
    --------
    >>> plot = make_plot(24.0, 4, seed=1, n_models=2, kinds=("small",), voxel_size=0.5)
    >>> plot.n_trees, plot.n_models, len(set(plot.table()["x_m"] + 1000 * plot.table()["y_m"]))
    (4, 2, 4)
    """
    snap = Snap.parse(snap, "snap")
    for name, v in (("n_trees", n_trees), ("n_models", n_models), ("tries", tries)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
            raise InputError(f"make_plot {name} must be an integer >= 1, got {v!r}")
    spacing = finite_number(min_spacing_m, "make_plot min_spacing_m")
    if spacing < 0:
        raise InputError(f"make_plot min_spacing_m must be >= 0 metres, got {min_spacing_m!r}")
    kinds = [kinds] if isinstance(kinds, str) else list(kinds)
    if not kinds:
        raise InputError(f"make_plot kinds must name at least one of {sorted(TREE_KINDS)}")
    n_models = min(int(n_models), int(n_trees))
    plot = PlotScene(width_m, length_m, voxel_size=voxel_size, ground_z=ground_z, leaf_angle=leaf_angle,
                     share=share)
    rng = np.random.default_rng(seed)
    scenes = []
    for k in range(n_models):
        params = random_tree_params(kinds[k % len(kinds)], rng, leaf_angle=leaf_angle,
                                    leaf_length_m=leaf_length_m)
        tree_seed = int(rng.integers(2**31))
        scenes.append(synthetic_tree_scene(params, seed=tree_seed, voxel_size=plot.voxel_size,
                                           name=f"{kinds[k % len(kinds)]}-{k}"))
    which = rng.permutation(np.arange(n_trees) % n_models)
    h = plot.voxel_size
    step = h * (BRICK if snap is Snap.BRICK else 1)
    placed = np.zeros((0, 2))
    for t, k in enumerate(which):
        scene = scenes[k]
        ext = scene.extent - np.append(scene.crown_center, 0.0)       # the crown's box around the trunk
        lo = plot.origin_xy - ext[0, :2]
        hi = plot.origin_xy + np.array([plot.width_m, plot.length_m]) - ext[1, :2]
        first = np.ceil((lo - plot.origin_xy) / step - 1e-9).astype(np.int64)
        last = np.floor((hi - plot.origin_xy) / step + 1e-9).astype(np.int64)
        if np.any(last < first):
            raise InputError(f"tree {scene.meta['name']!r} ({ext[1, 0] - ext[0, 0]:.1f} m wide) does not fit in "
                             f"the {plot.width_m:g} x {plot.length_m:g} m plot; widen the plot")
        for _ in range(tries):
            xy = plot.origin_xy + step * rng.integers(first, last + 1)
            if not len(placed) or np.min(np.hypot(*(placed - xy).T)) >= spacing:
                break
        else:
            raise InputError(f"could not place tree {t + 1} of {n_trees} at least {spacing:g} m from the others in "
                             f"{tries} tries; lower n_trees or min_spacing_m, or widen the plot")
        plot.add_tree(scene, xy[0], xy[1], name=scene.meta["name"], snap=snap)
        placed = np.vstack([placed, xy])
    plot.meta.update(seed=int(seed), n_models=n_models, kinds=kinds, min_spacing_m=spacing, snap=snap.value)
    return plot
