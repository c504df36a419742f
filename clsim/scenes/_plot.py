"""A plot of many trees on a flat ground: tree *models* placed as *instances*.

A :class:`PlotScene` keeps one copy of each distinct tree (a voxel
:class:`~voxlidar.scene.Scene`: a synthetic tree's exact-LAD twin or a scanned
tree) and a table of instances (model, position).  The simulator reads it in
one of two ways, with the same values in every voxel:

- **shared** (``share=True``, default): each model is packed into bricks of
  ``B**3`` voxels (:mod:`clsim.transport.bricks`) once per distinct offset of
  its anchor modulo ``B``; the plot's brick index points every brick cell that
  one instance alone occupies at that model's pool slot.  Instances placed on
  the brick lattice (``snap="brick"``) therefore share one pool; memory is one
  copy per distinct tree plus the index.  Brick cells where two or more trees
  meet get a brick of their own with the crowns summed (below).
- **copied** (:meth:`PlotScene.to_scene`): every instance's voxels written into
  one sparse :class:`~voxlidar.scene.Scene` (what ``share=False`` runs).

Where crowns overlap, their media add: LAD is summed, wood probabilities
combine as ``1 - (1 - p1)(1 - p2)`` (``area_density`` sums), so extinction is
additive and the plot's leaf area is the sum of its trees'.  Both ways merge a
voxel's contributions in instance order with the same function, so the brick
pools hold bit-identical values (tested) and a pulse gives the identical
waveform (same seed, same device).  The brick packing and the merge are in
:mod:`clsim.scenes._bricks`.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from clsim.scenes._bricks import SharedBricks, ceil_div, merge_voxels
from clsim.transport.bricks import BRICK, WOOD_P_MAX
from voxlidar.choices import Choice
from voxlidar.errors import InputError, finite_number
from voxlidar.leaf_orientation import LeafAngle
from voxlidar.safeio import json_text, open_npz, write_npz
from voxlidar.scene import Scene

__all__ = ["PlotScene", "Snap", "TABLE_DTYPE"]

#: one row per tree of :meth:`PlotScene.table`
TABLE_DTYPE = np.dtype([
    ("tree", "<i4"), ("model", "<i4"), ("name", "U40"), ("source", "U9"), ("x_m", "<f8"), ("y_m", "<f8"),
    ("height_m", "<f8"), ("crown_radius_m", "<f8"), ("leaf_area_m2", "<f8"), ("n_voxels", "<i8"),
    ("on_lattice", "?"),
])


PLOT_FORMAT_VERSION = 1


class Snap(str, Choice):
    """Where a tree's trunk lands: the nearest voxel corner, or the nearest brick corner
    (every ``BRICK`` voxels, so that instances of one tree share their bricks)."""

    VOXEL = "voxel"
    BRICK = "brick"


@dataclass
class _Model:
    """One distinct tree: its non-empty voxels relative to the anchor voxel corner
    (trunk base on the ground)."""

    name: str
    source: str
    rel: np.ndarray            # (M, 3) int64, voxel index minus the anchor's
    lad: np.ndarray            # (M,) float64, m2/m3
    wood: np.ndarray           # (M,) float64, in the plot's wood_kind
    occluded: np.ndarray       # (M,) bool
    lad_std: np.ndarray | None
    frac_xy: np.ndarray        # trunk (x, y) minus the anchor voxel corner, metres
    leaf_area: float           # the tree scene's total_leaf_area(), m2
    obj: object                # what was added (kept so that its id stays unique)
    params: dict | None = None
    bricks: dict = field(default_factory=dict)   # (residual, leaf_off) -> (BrickGrid, pad)
    lo: np.ndarray = field(init=False)           # (3,) lowest rel index per axis
    hi: np.ndarray = field(init=False)           # (3,) highest

    def __post_init__(self):
        self.lo = self.rel.min(axis=0) if len(self.rel) else np.zeros(3, np.int64)
        self.hi = self.rel.max(axis=0) if len(self.rel) else np.full(3, -1, np.int64)


class PlotScene(SharedBricks):
    """Trees placed on a flat ground over a ``width_m`` x ``length_m`` plot.

    Parameters
    ----------
    width_m, length_m : float, metres
        Plot extent along x and y (``length_m`` defaults to ``width_m``);
        the plot spans ``origin_xy .. origin_xy + (width_m, length_m)``.
    voxel_size : float, metres
        Voxel edge; every tree added must have this voxel size.
    origin_xy : (2,) float, metres
        Lower corner of the plot.
    ground_z : float, metres
        Height of the flat ground; each tree's own ground is set on it.
    leaf_angle : LeafAngle, str or dict, optional
        Leaf inclination model of every tree (the kernel holds one).  None:
        the first tree's, and a tree with another one is refused.
    materials : dict, optional
        ``{material: {wavelength: [R, T]}}`` for the plot.  None: the first
        tree's, and a tree with other optics is refused.
    share : bool
        Run from shared bricks (True) or from the copied scene (False).

    Notes
    -----
    Leaf azimuths are uniform in a plot: a scene has one ``crown_center`` for
    outward-facing leaves, and a plot has many crowns; trees given with
    ``leaf_azimuth="outward"`` are simulated with uniform azimuths (a line in
    :attr:`notes`).  Voxels holding neither leaves nor wood are not kept.

    Examples
    --------
    >>> from voxlidar.scene import Scene
    >>> tree = Scene(origin=(-1, -1, 0), voxel_size=0.5, shape=(4, 4, 8),
    ...              ijk=[[2, 2, 4], [3, 3, 5]], lad=[1.0, 2.0], ground_z=0.0)
    >>> plot = PlotScene(20.0, voxel_size=0.5)
    >>> plot.add_tree(tree, 4.0, 4.0, snap="brick"), plot.add_tree(tree, 12.0, 4.0, snap="brick")
    (0, 1)
    >>> plot.total_leaf_area(), plot.brick_grid().n_bricks     # one brick shared by both trees
    (0.75, 1)
    >>> plot.to_scene().total_leaf_area(), plot.table()["x_m"].tolist()
    (0.75, [4.0, 12.0])
    """

    def __init__(self, width_m: float, length_m: float | None = None, *, voxel_size: float,
                 origin_xy=(0.0, 0.0), ground_z: float = 0.0, leaf_angle=None, materials=None,
                 share: bool = True):
        self.width_m = finite_number(width_m, "plot width_m")
        self.length_m = self.width_m if length_m is None else finite_number(length_m, "plot length_m")
        self.voxel_size = finite_number(voxel_size, "plot voxel_size")
        if self.voxel_size <= 0:
            raise InputError(f"plot voxel_size must be > 0 metres, got {voxel_size!r}")
        if self.width_m < self.voxel_size or self.length_m < self.voxel_size:
            raise InputError(f"plot width_m and length_m must be at least one voxel ({self.voxel_size} m), "
                             f"got {self.width_m} x {self.length_m}")
        xy = np.asarray(origin_xy, dtype=np.float64).reshape(-1)
        if xy.shape != (2,) or not np.all(np.isfinite(xy)):
            raise InputError(f"plot origin_xy must be 2 finite numbers (metres), got {origin_xy!r}")
        self.origin_xy = xy
        self.ground_z = finite_number(ground_z, "plot ground_z")
        self._leaf_angle_given = leaf_angle is not None
        self.leaf_angle = LeafAngle.from_dict(leaf_angle) if leaf_angle is not None else None
        self._materials_given = materials is not None
        self.materials = materials
        self.wood_kind: str | None = None
        self.share = bool(share)
        self.leaf_azimuth = "uniform"
        self.notes: list[str] = []
        self.meta: dict = {"source": "plot"}
        self._models: list[_Model] = []
        self._keys: dict = {}
        self._inst = np.zeros((0, 3), dtype=np.int64)      # rows: model, anchor i, anchor j
        self._cache: dict = {}

    # -- the grid -------------------------------------------------------------------
    @property
    def n_trees(self) -> int:
        return len(self._inst)

    @property
    def n_models(self) -> int:
        return len(self._models)

    @property
    def _nxy(self):
        h = self.voxel_size
        return (int(math.ceil(self.width_m / h - 1e-9)), int(math.ceil(self.length_m / h - 1e-9)))

    @property
    def _ground_k(self) -> int:
        """Voxel layer of the ground (a multiple of BRICK, room for voxels below the ground)."""
        if "ground_k" not in self._cache:
            below = max([0] + [int(-m.lo[2]) for m in self._models])
            self._cache["ground_k"] = int(BRICK * ceil_div(below, BRICK))
        return self._cache["ground_k"]

    @property
    def origin(self) -> np.ndarray:
        """(3,) lower corner of the plot's voxel grid, metres."""
        return np.array([self.origin_xy[0], self.origin_xy[1], self.ground_z - self._ground_k * self.voxel_size])

    @property
    def shape(self) -> tuple:
        """(nx, ny, nz) of the plot's voxel grid."""
        top = max([1] + [int(m.hi[2]) + 1 for m in self._models])
        return (*self._nxy, self._ground_k + top)

    @property
    def crown_center(self) -> np.ndarray:
        return self.origin_xy + 0.5 * np.array([self.width_m, self.length_m])

    @property
    def n_voxels(self) -> int:
        """Voxels of all instances (a voxel where crowns overlap counted once per tree)."""
        return int(sum(len(self._models[m].rel) for m in self._inst[:, 0]))

    def optics(self, material: str, wavelength_nm: float) -> tuple[float, float]:
        """(R, T) of ``material`` at ``wavelength_nm`` (as :meth:`voxlidar.scene.Scene.optics`)."""
        if "header" not in self._cache:
            self._cache["header"] = self._header()
        return self._cache["header"].optics(material, wavelength_nm)

    def _header(self, **arrays) -> Scene:
        """A Scene over the plot's grid holding ``arrays`` (none: an empty scene)."""
        if not arrays:
            arrays = dict(ijk=np.zeros((0, 3), np.int32), lad=np.zeros(0))
        return Scene(origin=self.origin, voxel_size=self.voxel_size, shape=self.shape,
                     wood_kind=self.wood_kind or "probability",
                     leaf_angle=self.leaf_angle if self.leaf_angle is not None else "uniform",
                     leaf_azimuth="uniform", crown_center=self.crown_center, ground_z=self.ground_z,
                     materials=self.materials, meta=dict(self.meta, n_trees=self.n_trees,
                                                         n_models=self.n_models), **arrays)

    # -- adding trees ---------------------------------------------------------------
    def add_tree(self, tree, x: float, y: float, *, name: str | None = None, trunk_xy=None,
                 snap="voxel") -> int:
        """Place a tree with its trunk at (``x``, ``y``) on the ground; returns its number.

        Parameters
        ----------
        tree : voxlidar.scene.Scene, tlsvox SyntheticTree, str, Path or int
            A voxel scene (a scanned tree), a synthetic tree (its exact-LAD
            :meth:`~tlsvox.truth.synthetic.SyntheticTree.truth_scene` at the
            plot's voxel size), a scene file (:meth:`Scene.load`) or the
            model number of a tree added before.  Adding the same object or
            file again reuses its model: no second copy of its voxels.
        x, y : float, metres
            Where the trunk stands.  The tree moves by whole voxels, so its
            trunk lands on the nearest voxel corner (``snap="voxel"``) or
            brick corner (``snap="brick"``, every ``BRICK`` voxels: instances
            of one tree then share their bricks); :meth:`table` gives where
            it stands.
        name : str, optional
        trunk_xy : (2,) float, metres, optional
            The trunk in the tree scene's frame; default its ``crown_center``.
        snap : {"voxel", "brick"}

        Raises
        ------
        InputError
            A voxel size, leaf-angle model or optics other than the plot's, or
            a tree reaching outside the plot.
        """
        snap = Snap.parse(snap, "snap")
        x = finite_number(x, "tree x")
        y = finite_number(y, "tree y")
        mi, m, key = self._model_for(tree, name, trunk_xy)
        h = self.voxel_size
        step = BRICK if snap is Snap.BRICK else 1
        a = np.round((np.array([x, y]) - m.frac_xy - self.origin_xy) / (h * step)).astype(np.int64) * step
        nxy = np.array(self._nxy)
        if len(m.rel) and (np.any(a + m.lo[:2] < 0) or np.any(a + m.hi[:2] >= nxy)):
            reach = h * np.maximum(-m.lo[:2], m.hi[:2] + 1).max()
            lo, hi = self.origin_xy, self.origin_xy + nxy * h
            raise InputError(
                f"tree {m.name!r} at ({x:g}, {y:g}) m reaches outside the plot "
                f"[{lo[0]:g}, {hi[0]:g}] x [{lo[1]:g}, {hi[1]:g}] m (its crown reaches {reach:.2f} m from "
                f"the trunk); place it at least that far inside, or enlarge the plot")
        if mi == self.n_models:                            # a new model, kept once the tree fits
            self._models.append(m)
            self._keys[key] = mi
        self._inst = np.vstack([self._inst, [[mi, a[0], a[1]]]])
        self._cache.clear()
        return self.n_trees - 1

    def _model_for(self, tree, name, trunk_xy):
        """(model number, model, key); the number is n_models for a model not kept yet."""
        if isinstance(tree, (int, np.integer)) and not isinstance(tree, bool):
            if not 0 <= int(tree) < self.n_models:
                raise InputError(f"tree model {int(tree)} does not exist; the plot has {self.n_models} "
                                 "models (numbers 0..n_models-1, the 'model' column of table())")
            return int(tree), self._models[int(tree)], None
        key = ("path", str(Path(tree).resolve())) if isinstance(tree, (str, Path)) else ("id", id(tree))
        try:
            key += (None if trunk_xy is None else tuple(np.asarray(trunk_xy, dtype=float).ravel().tolist()),)
        except (TypeError, ValueError) as err:
            raise InputError(f"trunk_xy must be 2 finite numbers (metres), got {trunk_xy!r}") from err
        if key in self._keys:
            return self._keys[key], self._models[self._keys[key]], key
        source, params = "scene", None
        if isinstance(tree, (str, Path)):
            scene = Scene.load(tree)
            name = name or Path(tree).stem
        elif isinstance(tree, Scene):
            scene = tree
            source = "synthetic" if scene.meta.get("source") == "mesh truth" else "scene"
        elif hasattr(tree, "truth_scene"):                 # tlsvox SyntheticTree
            scene = tree.truth_scene(self.voxel_size)
            source = "synthetic"
            p = getattr(tree, "params", None)
            params = None if p is None else dict(vars(p), seed=getattr(tree, "seed", None))
        else:
            raise InputError(f"a tree must be a voxlidar Scene, a tlsvox SyntheticTree, a scene file or a "
                             f"model number, got {type(tree).__name__}")
        name = str(name or scene.meta.get("name") or f"tree-{self.n_models}")
        self._check_compatible(scene, name)
        return self.n_models, self._make_model(scene, name, source, params, tree, trunk_xy), key

    def _check_compatible(self, scene: Scene, name: str) -> None:
        h = self.voxel_size
        if abs(scene.voxel_size - h) > 1e-9 * h:
            raise InputError(f"tree {name!r} has voxel_size {scene.voxel_size:g} m, the plot {h:g} m; "
                             "rebuild it at the plot's voxel size (truth_scene(voxel_size) or tlsvox voxelize "
                             "--voxel-size) or make the plot at its voxel size")
        if self.leaf_angle is None:
            self.leaf_angle = scene.leaf_angle
        elif not self._leaf_angle_given and scene.leaf_angle.to_dict() != self.leaf_angle.to_dict():
            raise InputError(f"tree {name!r} has leaf angle {scene.leaf_angle.to_dict()}, the plot "
                             f"{self.leaf_angle.to_dict()}; the simulator holds one leaf-angle model per scene: "
                             "give PlotScene(leaf_angle=...) to use one for every tree")
        if self.materials is None:
            self.materials = scene.materials
        elif not self._materials_given and scene.materials != self.materials:
            raise InputError(f"tree {name!r} has other optics than the plot's first tree; the simulator holds "
                             "one set per scene: give PlotScene(materials=...) to use one for every tree")
        if scene.leaf_azimuth != "uniform":
            self.notes.append(f"tree {name!r}: leaf_azimuth={scene.leaf_azimuth!r} simulated as uniform "
                              "(a plot has no single crown centre)")

    def _make_model(self, scene, name, source, params, obj, trunk_xy) -> _Model:
        h = self.voxel_size
        if self.wood_kind is None:
            self.wood_kind = scene.wood_kind
        wood = np.asarray(scene.wood, dtype=np.float64)
        if scene.wood_kind != self.wood_kind:               # same extinction, the plot's unit
            if self.wood_kind == "area_density":            # sigma = -ln(1 - p) / h = WAD / 2
                wood = -2.0 * np.log1p(-np.minimum(wood, WOOD_P_MAX)) / h
            else:
                wood = -np.expm1(-0.5 * wood * h)
            self.notes.append(f"tree {name!r}: wood {scene.wood_kind} converted to {self.wood_kind}")
        keep = (scene.lad > 0) | (wood > 0)
        dropped = [what for what, on in (
            (f"{int(np.count_nonzero(scene.wood_solid[keep])):,} solid wood voxels",
             np.any(scene.wood_solid[keep])),
            ("its bark directions (wood_axis, wood_beta)", np.any(scene.wood_beta[keep] > 0))) if on]
        if dropped:                                     # the plot holds one turbid wood value per voxel
            self.notes.append(f"tree {name!r}: {' and '.join(dropped)} simulated as turbid, randomly oriented "
                              "wood (a plot keeps one wood value per voxel; simulate the tree alone to keep them)")
        trunk = np.asarray(scene.crown_center if trunk_xy is None else trunk_xy, dtype=np.float64).reshape(-1)
        if trunk.shape != (2,) or not np.all(np.isfinite(trunk)):
            raise InputError(f"trunk_xy must be 2 finite numbers (metres), got {trunk_xy!r}")
        a_xy = np.round((trunk - scene.origin[:2]) / h).astype(np.int64)
        if scene.ground_z is not None:
            ground = scene.ground_z
        elif keep.any():
            ground = scene.origin[2] + h * scene.ijk[keep, 2].min()
        else:
            ground = scene.origin[2]
        a_z = int(np.round((ground - scene.origin[2]) / h))
        ijk = scene.ijk[keep].astype(np.int64)
        cols = [scene.lad[keep], wood[keep], scene.occluded[keep],
                None if scene.lad_std is None else scene.lad_std[keep]]
        if len(np.unique(ijk, axis=0)) < len(ijk):       # a voxel listed twice: one value, summed
            ijk, *cols, _ = merge_voxels(ijk, *cols, scene.shape, self.wood_kind)
        rel = ijk - np.array([a_xy[0], a_xy[1], a_z])
        return _Model(name=name, source=source, rel=rel, lad=cols[0], wood=cols[1], occluded=cols[2],
                      lad_std=cols[3], frac_xy=trunk - (scene.origin[:2] + a_xy * h), leaf_area=scene.total_leaf_area(),
                      obj=obj, params=params)

    # -- what the plot holds -------------------------------------------------------------
    def _anchor3(self, t) -> np.ndarray:
        return np.array([self._inst[t, 1], self._inst[t, 2], self._ground_k], dtype=np.int64)

    def total_leaf_area(self) -> float:
        """One-sided leaf area of all trees, m2: the (correctly rounded) sum of each
        tree's ``Scene.total_leaf_area()``."""
        return math.fsum(self._models[m].leaf_area for m in self._inst[:, 0])

    def table(self) -> np.ndarray:
        """One row per tree (:data:`TABLE_DTYPE`): number, model, name, source
        (``synthetic`` or ``scene``), trunk position, height above the ground (top of
        its highest voxel), crown radius (of a disc with the area of its voxel
        columns), leaf area, voxels, and whether it stands on the brick lattice."""
        h = self.voxel_size
        out = np.zeros(self.n_trees, dtype=TABLE_DTYPE)
        for t, (mi, ai, aj) in enumerate(self._inst):
            m = self._models[mi]
            cols = len(np.unique(m.rel[:, 0] * (1 << 32) + m.rel[:, 1])) if len(m.rel) else 0
            out[t] = (t, mi, m.name, m.source, self.origin_xy[0] + ai * h + m.frac_xy[0],
                      self.origin_xy[1] + aj * h + m.frac_xy[1], h * (m.hi[2] + 1),
                      math.sqrt(cols * h * h / math.pi), m.leaf_area, len(m.rel),
                      ai % BRICK == 0 and aj % BRICK == 0)
        return out

    def canopy_height(self) -> np.ndarray:
        """(nx, ny) height above the ground of the top of the highest voxel in each
        column, metres; NaN where no tree stands."""
        nx, ny = self._nxy
        top = np.full(nx * ny, -1, dtype=np.int64)
        for mi, ai, aj in self._inst:
            rel = self._models[mi].rel
            if len(rel):
                np.maximum.at(top, (rel[:, 0] + ai) + nx * (rel[:, 1] + aj), rel[:, 2])
        out = (top + 1).astype(np.float64) * self.voxel_size
        out[top < 0] = np.nan
        return out.reshape(ny, nx).T

    def _instance_voxels(self, t, cells=None, bshape=None):
        """Plot voxel indices and values of tree ``t``; only those in brick ``cells``."""
        m = self._models[self._inst[t, 0]]
        ijk = m.rel + self._anchor3(t)
        sel = slice(None)
        if cells is not None:
            b = ijk // BRICK
            sel = np.isin(b[:, 0] + bshape[0] * (b[:, 1] + bshape[1] * b[:, 2]), cells)
        return (ijk[sel], m.lad[sel], m.wood[sel], m.occluded[sel],
                None if m.lad_std is None else m.lad_std[sel])

    def _merged(self, trees, cells=None, bshape=None):
        parts = [self._instance_voxels(t, cells, bshape) for t in trees]
        with_std = bool(parts) and all(p[4] is not None for p in parts)
        cat = [np.concatenate([p[k] for p in parts]) if parts else None for k in range(4)]
        if not parts:
            cat = [np.zeros((0, 3), np.int64), np.zeros(0), np.zeros(0), np.zeros(0, bool)]
        std = np.concatenate([p[4] for p in parts]) if with_std else None
        ijk, lad, wood, occ, std, n_merged = merge_voxels(*cat, std, self.shape, self.wood_kind or "probability")
        return self._header(ijk=ijk, lad=lad, wood=wood, occluded=occ, lad_std=std), n_merged

    def to_scene(self) -> Scene:
        """Every tree's voxels copied into one sparse :class:`~voxlidar.scene.Scene`
        over the plot's grid (overlapping crowns summed; ``meta['merged_voxels']``
        counts the voxels where they meet)."""
        if "scene" not in self._cache:
            scene, n_merged = self._merged(range(self.n_trees))
            scene.meta["merged_voxels"] = n_merged
            self._cache["scene"] = scene
        return self._cache["scene"]

    # -- files -------------------------------------------------------------------------
    def save(self, path) -> Path:
        """Write the plot as compressed NPZ (atomic): each model's voxels once, the
        instance table and the plot's settings; :meth:`load` reads it back."""
        head = dict(format="voxlidar-plot", version=PLOT_FORMAT_VERSION, width_m=self.width_m,
                    length_m=self.length_m, voxel_size=self.voxel_size, origin_xy=self.origin_xy.tolist(),
                    ground_z=self.ground_z, share=self.share, wood_kind=self.wood_kind, notes=self.notes,
                    meta=self.meta, materials=self.materials,
                    leaf_angle=None if self.leaf_angle is None else self.leaf_angle.to_dict(),
                    leaf_angle_given=self._leaf_angle_given, materials_given=self._materials_given,
                    models=[dict(name=m.name, source=m.source, frac_xy=m.frac_xy.tolist(),
                                 leaf_area=m.leaf_area, params=m.params) for m in self._models])
        arrays = {"plot": np.str_(json_text(head)), "instances": self._inst}
        for k, m in enumerate(self._models):
            arrays.update({f"m{k}_rel": m.rel, f"m{k}_lad": m.lad, f"m{k}_wood": m.wood,
                           f"m{k}_occluded": m.occluded})
            if m.lad_std is not None:
                arrays[f"m{k}_lad_std"] = m.lad_std
        return write_npz(path, arrays)

    @staticmethod
    def is_plot_file(path) -> bool:
        """True when ``path`` is an NPZ written by :meth:`save` (False for anything else)."""
        try:
            with np.load(path, allow_pickle=False) as z:
                return "plot" in z.files
        except Exception:  # noqa: BLE001 - not a readable NPZ: not a plot file
            return False

    @classmethod
    def load(cls, path) -> PlotScene:
        """Read a plot written by :meth:`save`."""
        path = Path(path)
        if not path.is_file():
            raise InputError(f"plot file {str(path)!r} does not exist (or is a folder)")
        with open_npz(path, "plot") as z:
            if "plot" not in z:
                raise InputError(f"{str(path)!r} is not a plot file (PlotScene.save); a single tree's scene "
                                 "is read with voxlidar.scene.Scene.load")
            head = json.loads(str(z["plot"]))
            if head.get("version", 0) > PLOT_FORMAT_VERSION:
                raise InputError(f"{str(path)!r} has plot format {head['version']}; this voxlidar reads up to "
                                 f"{PLOT_FORMAT_VERSION}. Upgrade voxlidar.")
            plot = cls(head["width_m"], head["length_m"], voxel_size=head["voxel_size"],
                       origin_xy=head["origin_xy"], ground_z=head["ground_z"], share=head["share"],
                       leaf_angle=head["leaf_angle"], materials=head["materials"])
            plot._leaf_angle_given, plot._materials_given = head["leaf_angle_given"], head["materials_given"]
            plot.wood_kind, plot.notes, plot.meta = head["wood_kind"], head["notes"], head["meta"]
            for k, m in enumerate(head["models"]):
                plot._models.append(_Model(
                    name=m["name"], source=m["source"], rel=z[f"m{k}_rel"].astype(np.int64), lad=z[f"m{k}_lad"],
                    wood=z[f"m{k}_wood"], occluded=z[f"m{k}_occluded"],
                    lad_std=z[f"m{k}_lad_std"] if f"m{k}_lad_std" in z else None,
                    frac_xy=np.asarray(m["frac_xy"], dtype=np.float64), leaf_area=float(m["leaf_area"]),
                    obj=None, params=m["params"]))
            plot._inst = z["instances"].astype(np.int64).reshape(-1, 3)
        return plot

    def __getstate__(self):
        """Pickle (e.g. to a Dask worker) without caches and without the objects the trees came from."""
        state = dict(self.__dict__, _cache={}, _keys={})
        state["_models"] = [replace(m, obj=None, bricks={}) for m in self._models]
        return state

    def __repr__(self) -> str:
        return (f"PlotScene({self.width_m:g} x {self.length_m:g} m, voxel {self.voxel_size:g} m, "
                f"{self.n_trees} trees of {self.n_models} models, leaf area {self.total_leaf_area():.1f} m2, "
                f"{'shared' if self.share else 'copied'} bricks)")
