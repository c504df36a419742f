"""The synthetic truth world: a seeded procedural broadleaf tree.

The tree stands for the paper's Coast Live Oak: a trunk and recursive branches
made of cylinders, leaves as flat ellipses (about 5 x 2.5 cm) clustered around
the terminal shoots inside an ellipsoidal crown, a ground plane and
retro-reflective cylinder targets around it.  Every triangle carries a
:class:`~voxlidar.materials.Material` id, so every later stage can be scored
against the exact geometry: leaf area per voxel (:meth:`SyntheticTree.leaf_area_per_voxel`),
the material of every echo, the leaf normals.

Examples
--------
>>> tree = make_tree(TreeParams(total_leaf_area=5.0, height=6.0, crown_radius=2.0), seed=1)
>>> round(tree.leaf_area(), 9)
5.0
>>> tree.n_leaves > 0 and tree.targets.shape
(5, 3)
"""

from __future__ import annotations

import json
import os
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from tlsvox.errors import InputError
from tlsvox.truth._mesh import cylinders_mesh, leaf_mesh, orthonormal, polygon_area_factor, segment_distance
from tlsvox.truth.meshtruth import area_per_voxel, triangle_areas
from tlsvox.voxel.wood.solid import cap_share, cylinder_cells, dilate
from voxlidar.leaf_orientation import LeafAngle, LeafAzimuth, sample_leaf_normals
from voxlidar.materials import Material
from voxlidar.safeio import json_text, staged

__all__ = ["TreeParams", "SyntheticTree", "make_tree", "make_leaf_slab", "make_wall", "load_tree"]

@dataclass(frozen=True)
class TreeParams:
    """Parameters of the procedural tree (lengths in metres, areas in m2).

    The defaults give a broad oak-like crown 13.6 m tall with a leaf area
    index of about 4.4 over the crown's projection (a dense crown).
    ``capped_wood`` (default) closes each bark cylinder's ends, so wood is
    solid: with open tubes a beam down a trunk's axis reaches the ground
    inside it.
    """

    #: tree height, m
    height: float = 13.6
    #: height of the crown's lowest point (the scaffolds start above it), m
    crown_base: float = 3.0
    #: horizontal semi-axis of the ellipsoidal crown envelope, m
    crown_radius: float = 6.0
    #: trunk radius (the leader and scaffolds are thinner), m
    trunk_radius: float = 0.25
    #: one-sided leaf area of the whole tree, m2 (met exactly: the leaves are scaled)
    total_leaf_area: float = 500.0
    #: leaf length and width (an elliptical polygon), m
    leaf_length: float = 0.05
    leaf_width: float = 0.025
    #: leaf inclination model (voxlidar.leaf_orientation.LeafAngle name) and its beta parameters
    leaf_angle: str = "uniform"
    leaf_mu: float = 1.0
    leaf_nu: float = 1.0
    #: leaf normal azimuths: "outward" (facing out from the trunk) or "uniform"
    leaf_azimuth: str = "outward"
    #: scaffold branches from the trunk, levels of side branches below them, and children per branch
    n_scaffolds: int = 6
    branch_levels: int = 3
    children_per_branch: int = 3
    #: spread (1 sigma, per axis) of the leaves around the terminal shoots: how clumped the foliage is, m
    leaf_cluster_sigma: float = 0.35
    #: half the side of the square ground plane, m
    ground_half_size: float = 40.0
    #: registration targets (cylinders) on an irregular ring around the tree: count, distance, radius, height
    n_targets: int = 5
    target_distance: float = 8.0
    target_radius: float = 0.05
    target_height: float = 0.20
    #: close each bark cylinder's ends (solid wood)
    capped_wood: bool = True

    def __post_init__(self):
        positive = ("height", "crown_radius", "trunk_radius", "leaf_length", "leaf_width",
                    "leaf_cluster_sigma", "target_radius", "target_height", "ground_half_size")
        for name in positive:
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise InputError(f"TreeParams.{name}={v!r} must be a finite number > 0 (metres)")
        if not (0 <= self.crown_base < self.height):
            raise InputError(
                f"TreeParams.crown_base={self.crown_base!r} must lie in [0, height={self.height})"
            )
        if not (np.isfinite(self.total_leaf_area) and self.total_leaf_area >= 0):
            raise InputError(
                f"TreeParams.total_leaf_area={self.total_leaf_area!r} must be >= 0 m2 (0 = leaf-off)"
            )
        azimuth = LeafAzimuth.parse(self.leaf_azimuth, "TreeParams.leaf_azimuth").value
        object.__setattr__(self, "leaf_azimuth", azimuth)
        if self.n_scaffolds < 1 or self.branch_levels < 0 or self.children_per_branch < 1:
            raise InputError("TreeParams: n_scaffolds and children_per_branch must be >= 1, branch_levels >= 0")
        if self.n_targets < 0:
            raise InputError("TreeParams.n_targets must be >= 0")
        LeafAngle(self.leaf_angle, mu=self.leaf_mu, nu=self.leaf_nu)  # validates the name

    @property
    def leaf_angle_model(self) -> LeafAngle:
        return LeafAngle(self.leaf_angle, mu=self.leaf_mu, nu=self.leaf_nu)

    @property
    def crown_center(self) -> np.ndarray:
        """(3,) centre of the crown ellipsoid."""
        return np.array([0.0, 0.0, 0.5 * (self.crown_base + self.height)])

    @property
    def crown_semi_axes(self) -> np.ndarray:
        return np.array([self.crown_radius, self.crown_radius, 0.5 * (self.height - self.crown_base)])

    @property
    def crown_volume(self) -> float:
        """Volume of the crown envelope (ellipsoid), m3."""
        return float(4.0 / 3.0 * np.pi * np.prod(self.crown_semi_axes))


@dataclass
class SyntheticTree:
    """A triangle mesh with a material per triangle and its truth metadata.

    Attributes
    ----------
    vertices : (V, 3) float64, metres
    triangles : (T, 3) int64
    material : (T,) uint8, :class:`Material` ids
    leaf_normals : (L, 3) float64, unit, one per leaf (upper hemisphere)
    leaf_centers : (L, 3) float64, metres
    cylinders : (C, 7) float64
        Bark cylinders as start (3), end (3), radius.
    targets : (K, 3) float64, metres
        Centres of the retro-reflective cylinder targets.
    params : TreeParams or None
    seed : int or None
    """

    vertices: np.ndarray
    triangles: np.ndarray
    material: np.ndarray
    leaf_normals: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    leaf_centers: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    cylinders: np.ndarray = field(default_factory=lambda: np.zeros((0, 7)))
    targets: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    ground_z: float | None = 0.0
    crown_center: np.ndarray = field(default_factory=lambda: np.zeros(3))
    params: TreeParams | None = None
    seed: int | None = None
    leaf_angle: LeafAngle | None = None
    leaf_azimuth: str = "uniform"

    def __post_init__(self):
        if self.leaf_angle is None:
            self.leaf_angle = self.params.leaf_angle_model if self.params else LeafAngle("uniform")
        if self.params is not None:
            self.leaf_azimuth = self.params.leaf_azimuth

    @property
    def n_leaves(self) -> int:
        return len(self.leaf_normals)

    def triangle_coords(self, material: Material | None = None) -> np.ndarray:
        """(T, 3, 3) vertex coordinates, optionally of one material only."""
        tri = self.triangles if material is None else self.triangles[self.material == material]
        return self.vertices[tri]

    def leaf_area(self) -> float:
        """Total one-sided leaf area held by the mesh, m2."""
        return float(triangle_areas(self.triangle_coords(Material.LEAF)).sum())

    def leaf_area_per_voxel(self, *, origin, voxel_size, shape) -> np.ndarray:
        """Exact one-sided leaf area (m2) per voxel, (nx, ny, nz); LAD = area / h^3."""
        return area_per_voxel(self.triangle_coords(Material.LEAF), origin=origin,
                              voxel_size=voxel_size, shape=shape)

    def bark_area_per_voxel(self, *, origin, voxel_size, shape) -> np.ndarray:
        """Exact bark surface area (m2) per voxel, (nx, ny, nz)."""
        return area_per_voxel(self.triangle_coords(Material.BARK), origin=origin,
                              voxel_size=voxel_size, shape=shape)

    def raycasting_scene(self):
        """Open3D RaycastingScene (Embree BVH) of the mesh, built once and cached."""
        cached = self.__dict__.get("_raycaster")
        if cached is None:
            import open3d as o3d

            cached = o3d.t.geometry.RaycastingScene()
            mesh = o3d.t.geometry.TriangleMesh()
            mesh.vertex.positions = o3d.core.Tensor(np.asarray(self.vertices, np.float32))
            mesh.triangle.indices = o3d.core.Tensor(np.asarray(self.triangles, np.int32))
            cached.add_triangles(mesh)
            self.__dict__["_raycaster"] = cached
        return cached

    def truth_grid(self, voxel_size: float, *, margin: float = 0.0):
        """(origin, shape) of a grid aligned on multiples of ``voxel_size`` covering the vegetation."""
        lo, hi = self.bounds()
        origin = np.floor((lo - margin) / voxel_size) * voxel_size
        if self.ground_z is not None:
            origin[2] = max(origin[2], np.floor(self.ground_z / voxel_size) * voxel_size)
        shape = np.ceil((hi + margin - origin) / voxel_size).astype(int) + 1
        return origin, tuple(int(v) for v in shape)

    def solid_wood_voxels(self, *, origin, voxel_size, shape) -> tuple[np.ndarray, np.ndarray]:
        """Voxels whose centre lies inside a bark cylinder, and that cylinder's axis: ``(flat, axis)`` as
        :func:`tlsvox.voxel.wood.solid.cylinder_cells` returns them (sorted flat C-order indices; unit axes,
        z >= 0, the last cylinder listed where cylinders overlap)."""
        return self._solid_cells(origin, voxel_size, shape)[:2]

    def _solid_cells(self, origin, voxel_size, shape):
        """:meth:`solid_wood_voxels` and the row in ``cylinders`` of each voxel's cylinder."""
        return cylinder_cells(self.cylinders, origin=origin, voxel_size=voxel_size, shape=shape)

    def truth_scene(self, voxel_size: float = 0.2, *, wavelength_nm=None, wood_model: str = "directional",
                    solid_wood: bool = True, core_bark: bool = False):
        """The voxel scene of the mesh's exact leaf area and wood (the turbid-medium twin).

        LAD = leaf area in the voxel / voxel volume.  Wood becomes a crossing
        probability: bark surfaces are closed convex cylinders, whose mean
        projected area over random directions is a quarter of their surface
        (Cauchy), so the direction-averaged sigma_wood = A_bark / (4 V) and the
        chance that a beam crossing the whole voxel is stopped, averaged over
        directions, is ``1 - exp(-sigma_wood h)``.

        ``wood_model="directional"`` (default) also gives each voxel its bark
        axis and anisotropy (``wood_axis``, ``wood_beta``) from the bark
        normals' area-weighted second moment
        (:func:`tlsvox.truth.meshtruth.bark_direction`): the trunk and
        scaffolds are upright cylinders, which a turbid medium of randomly
        oriented facets overstates for oblique beams and understates across.
        ``"isotropic"`` leaves them out (randomly oriented facets, as before
        the directions existed).

        ``solid_wood`` (default) also fills the inside of the solid cylinders: every
        voxel whose centre lies inside one (:meth:`solid_wood_voxels`) becomes
        opaque wood (probability ``1 - 1e-6``, the transport's cap) from every
        direction; with ``wood_model="directional"`` it is solid wood
        (``Scene.wood_solid``) whose surface is the cylinder's side and end caps
        (axis in ``wood_axis``, cap share ``wood_cap`` from the bark normals around
        the voxel), and the cylinder's own bark in the voxels beside its core is
        dropped (the core already covers its cross-section; docs/method.md,
        solid wood); ``core_bark=True`` keeps it, as until 2026-11-23 (to
        measure the term).  Without it a trunk wider than a
        voxel is a shell of bark voxels around empty ones, which a turbid
        medium lets beams through (docs/method.md, directional wood).  The
        mesh's cylinders are closed at both ends (``TreeParams.capped_wood``) to
        match: open tubes let a beam down a trunk's axis reach the ground
        (docs/bench/waveform_terms.md measures both).

        Returns
        -------
        tlsvox.Scene
        """
        from tlsvox.truth.meshtruth import bark_direction, normal_moments_per_voxel
        from voxlidar.scene import Scene

        if wood_model not in ("directional", "isotropic"):
            raise InputError(f"wood_model={wood_model!r} must be 'directional' or 'isotropic'")
        origin, shape = self.truth_grid(voxel_size)
        kw = dict(origin=origin, voxel_size=voxel_size, shape=shape)
        leaf = self.leaf_area_per_voxel(**kw)
        vol = voxel_size**3
        solid_flat, solid_axis, solid_owner = (self._solid_cells(origin, voxel_size, shape) if solid_wood
                                               else (np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros(0, np.int64)))
        bark_tris = self.triangle_coords(Material.BARK)
        # a cylinder with a solid core is that core where it has one: its bark in the voxels around
        # the core would stop a beam a second time (the cells whose centres lie inside already
        # cover the cylinder's cross-section); thinner cylinders, and stretches of a cylinder away
        # from its core, stay turbid bark
        cored = _bark_owner(bark_tris, self.cylinders)
        cored = np.isin(cored, np.unique(solid_owner)) & (cored >= 0) & (not core_bark)
        near_core = dilate(solid_flat, shape).reshape(-1)
        # area and normal moments per voxel of the other bark and of the cored cylinders' bark
        # (disjoint sets: together, what one pass over all the bark would give)
        fo, ao, mo = normal_moments_per_voxel(bark_tris[~cored], **kw)
        fc, ac, mc = normal_moments_per_voxel(bark_tris[cored], **kw)
        flat = np.union1d(fo, fc)
        area, mom = np.zeros(len(flat)), np.zeros((len(flat), 3, 3))  # all the bark (the cap shares)
        ro, rc = np.searchsorted(flat, fo), np.searchsorted(flat, fc)
        area[ro] += ao
        mom[ro] += mo
        area[rc] += ac
        mom[rc] += mc
        t_area, t_mom = area.copy(), mom.copy()  # the turbid bark: less the cores' bark beside them
        drop = near_core[fc]
        t_area[rc[drop]] -= ac[drop]
        t_mom[rc[drop]] -= mc[drop]
        t_area[t_area < 1e-9 * max(area.max(initial=0.0), 1e-300)] = 0.0
        bark = np.zeros(int(np.prod(shape)))
        bark[flat] = t_area
        bark = bark.reshape(shape)
        occupied = (leaf > 0) | (bark > 0)
        occupied.reshape(-1)[solid_flat] = True
        ijk = np.argwhere(occupied)
        lad = leaf[tuple(ijk.T)] / vol
        wood = 1.0 - np.exp(-bark[tuple(ijk.T)] / (4.0 * vol) * voxel_size)
        solid = np.searchsorted(np.ravel_multi_index(ijk.T, shape), solid_flat)  # rows of the solid voxels
        wood[solid] = 1.0 - 1e-6
        wood_axis = wood_beta = None
        if wood_model == "directional":
            axis, beta = bark_direction(t_area, t_mom)
            keys = np.ravel_multi_index(ijk.T, shape)
            pos = np.searchsorted(flat, keys)
            found = pos < len(flat)
            found[found] = flat[pos[found]] == keys[found]
            wood_axis = np.tile([0.0, 0.0, 1.0], (len(ijk), 1))
            wood_beta = np.zeros(len(ijk))
            wood_axis[found] = axis[pos[found]]
            wood_beta[found] = beta[pos[found]]
            # inside a solid trunk the wood stops a beam from any direction, and what it hits is the
            # cylinder's side or an end cap (Scene.wood_solid; a turbid beta 1 would let a beam along
            # the axis pass, a turbid beta 0 turns the surface into random facets)
            wood_axis[solid] = solid_axis
            wood_beta[solid] = 0.0
            wood_solid = np.zeros(len(ijk), bool)
            wood_solid[solid] = True
            wood_cap = np.zeros(len(ijk))
            wood_cap[solid] = cap_share(solid_flat, solid_axis, flat, area, mom, shape)
        else:
            wood_solid = wood_cap = None
        return Scene(origin=origin, voxel_size=voxel_size, shape=shape, ijk=ijk, lad=lad, wood=wood,
                     wood_kind="probability", wood_axis=wood_axis, wood_beta=wood_beta,
                     wood_solid=wood_solid, wood_cap=wood_cap,
                     leaf_angle=self.leaf_angle, leaf_azimuth=self.leaf_azimuth,
                     crown_center=np.asarray(self.crown_center)[:2], ground_z=self.ground_z,
                     meta={"source": "mesh truth", "seed": self.seed, "voxel_size": voxel_size,
                           "wood_model": wood_model, "solid_wood": bool(solid_wood),
                           "core_bark": bool(core_bark)})

    def bounds(self, *, vegetation_only: bool = True) -> np.ndarray:
        """(2, 3) lower/upper corner of the leaves and bark (or everything)."""
        if vegetation_only:
            keep = np.isin(self.material, [Material.LEAF, Material.BARK])
            if not keep.any():
                keep = self.material != Material.GROUND
            used = np.zeros(len(self.vertices), bool)
            used[self.triangles[keep].ravel()] = True
            v = self.vertices[used]
        else:
            v = self.vertices
        if not len(v):
            raise InputError("the tree mesh is empty: it has no triangles")
        return np.stack([v.min(axis=0), v.max(axis=0)])

    def crown_mean_lad(self) -> float:
        """Leaf area divided by the crown envelope volume, m2/m3."""
        if self.params is None:
            raise InputError("crown_mean_lad needs a tree built by make_tree (it has no params)")
        return self.leaf_area() / self.params.crown_volume

    def point_inside_wood(self, point) -> bool:
        """True when ``point`` lies inside a bark cylinder (e.g. a scanner in the trunk)."""
        if not len(self.cylinders):
            return False
        d = segment_distance(np.asarray(point, dtype=float), self.cylinders[:, :3], self.cylinders[:, 3:6])
        return bool(np.any(d < self.cylinders[:, 6]))

    def material_colors(self) -> np.ndarray:
        """(V, 3) vertex colours by material (leaf green, bark brown, ground grey, target white)."""
        palette = np.array([[0.5, 0.5, 0.5], [0.20, 0.55, 0.15], [0.45, 0.30, 0.15],
                            [0.75, 0.72, 0.65], [1.0, 1.0, 1.0]])
        colors = np.zeros((len(self.vertices), 3))
        colors[self.triangles.ravel()] = palette[np.repeat(self.material, 3)]
        return colors

    def to_o3d(self):
        """Open3D legacy TriangleMesh with vertex colours by material."""
        import open3d as o3d

        mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(self.vertices),
                                         o3d.utility.Vector3iVector(self.triangles.astype(np.int32)))
        mesh.vertex_colors = o3d.utility.Vector3dVector(self.material_colors())
        mesh.compute_vertex_normals()
        return mesh

    def truth_summary(self) -> dict:
        """JSON-ready truth metadata."""
        counts = {m.name.lower(): int(np.count_nonzero(self.material == m)) for m in Material if m}
        doc = {
            "seed": self.seed,
            "params": asdict(self.params) if self.params else None,
            "leaf_area_m2": self.leaf_area(),
            "n_leaves": self.n_leaves,
            "triangles_per_material": counts,
            "crown_center": self.crown_center.tolist(),
            "ground_z": self.ground_z,
            "targets": self.targets.tolist(),
            "bounds": self.bounds().tolist(),
        }
        if self.params is not None:
            doc["crown_volume_m3"] = self.params.crown_volume
            doc["crown_mean_lad_m2_m3"] = self.crown_mean_lad()
            doc["lai_over_crown_projection"] = self.leaf_area() / (np.pi * self.params.crown_radius**2)
        return doc

    def save(self, path: str | os.PathLike) -> tuple[Path, Path]:
        """Write ``NAME.ply`` (mesh, coloured by material) and ``NAME.json`` (truth).

        The JSON holds the parameters and seed, so :func:`load_tree` rebuilds
        the identical tree.
        """
        import open3d as o3d

        path = Path(path).with_suffix(".ply")
        mesh = self.to_o3d()
        meta = path.with_suffix(".json")
        with staged([path, meta]) as tmp:  # both or neither
            o3d.io.write_triangle_mesh(str(tmp[path]), mesh, write_ascii=False)
            tmp[meta].write_text(json_text(self.truth_summary(), indent=1))
        return path, meta


def _bark_owner(tris, cylinders, tol: float = 1e-6) -> np.ndarray:
    """Row in ``cylinders`` whose rims hold all three corners of each bark triangle (-1: none).

    Every triangle of :func:`tlsvox.truth._mesh.cylinders_mesh`, side or cap fan,
    has its corners on the end rings, at distance ``r`` from the axis segment.
    """
    owner = np.full(len(tris), -1, np.int64)
    if not len(cylinders) or not len(tris):
        return owner
    a, b, r = cylinders[:, :3], cylinders[:, 3:6], cylinders[:, 6]
    tol = tol * max(1.0, float(np.abs(cylinders[:, :6]).max()))
    for start in range(0, len(tris), 1024):
        t = np.asarray(tris[start:start + 1024], dtype=np.float64)  # (n, 3, 3) against (C,): (n, 3, C)
        off = np.abs(segment_distance(t[:, :, None, :], a[None, None], b[None, None]) - r).max(axis=1)
        ok = off < tol
        owner[start:start + len(t)] = np.where(ok.any(axis=1), ok.argmax(axis=1), -1)
    return owner


def _branches(p: TreeParams, rng: np.random.Generator):
    """Recursive branch skeleton: list of (start, end, radius, level) rows."""
    center, semi = p.crown_center, p.crown_semi_axes
    rows = []
    top = np.array([0.0, 0.0, p.height - 0.15 * (p.height - p.crown_base)])
    rows.append((np.zeros(3), np.array([0.0, 0.0, p.crown_base]), p.trunk_radius, -1))
    leader = (np.array([0.0, 0.0, p.crown_base]), top, 0.6 * p.trunk_radius, 1)
    rows.append(leader)

    def inside_scale(start, direction, length):
        # shorten so that the end stays inside 0.97 of the crown ellipsoid
        for _ in range(30):
            end = start + direction * length
            if np.sum(((end - center) / semi) ** 2) <= 0.97**2 or length < 0.05:
                return end
            length *= 0.85
        return start + direction * length

    frontier = [leader]
    az0 = rng.uniform(0, 2 * np.pi)
    for i in range(p.n_scaffolds):
        az = az0 + 2 * np.pi * i / p.n_scaffolds + rng.normal(0, 0.15)
        elev = np.deg2rad(rng.uniform(30, 55))
        d = np.array([np.cos(elev) * np.cos(az), np.cos(elev) * np.sin(az), np.sin(elev)])
        start = np.array([0.0, 0.0, p.crown_base + rng.uniform(0.0, 0.2) * (p.height - p.crown_base)])
        end = inside_scale(start, d, 1.2 * p.crown_radius)
        rows.append((start, end, 0.45 * p.trunk_radius, 1))
        frontier.append((start, end, 0.45 * p.trunk_radius, 1))
    for level in range(2, p.branch_levels + 2):
        nxt = []
        for start, end, radius, _ in frontier:
            axis = end - start
            length = np.linalg.norm(axis)
            d = axis / length
            for _ in range(p.children_per_branch):
                f = rng.uniform(0.35, 0.95)
                s = start + f * axis
                u, v = orthonormal(d[None])
                phi = rng.uniform(0, 2 * np.pi)
                perp = np.cos(phi) * u[0] + np.sin(phi) * v[0]
                perp[2] = abs(perp[2]) * 0.5 + 0.1  # prefer upward/outward shoots
                perp /= np.linalg.norm(perp)
                ang = np.deg2rad(rng.uniform(35, 60))
                cd = np.cos(ang) * d + np.sin(ang) * perp
                cd /= np.linalg.norm(cd)
                e = inside_scale(s, cd, max(0.6, 0.55 * (1 - f) * length + 0.4 * length * 0.5))
                r = max(0.008, 0.55 * radius)
                rows.append((s, e, r, level))
                nxt.append((s, e, r, level))
        frontier = nxt
    return rows


def make_tree(params: TreeParams | None = None, *, seed: int = 0) -> SyntheticTree:
    """Build the procedural tree.

    Parameters
    ----------
    params : TreeParams, optional
        Geometry; defaults to the oak-like default.
    seed : int
        Seed of every random choice (same seed, same tree).

    Returns
    -------
    SyntheticTree
        Mesh with materials; the leaf mesh holds exactly
        ``params.total_leaf_area`` m2 (to float rounding).
    """
    p = params or TreeParams()
    rng = np.random.default_rng(seed)
    rows = _branches(p, rng)
    cyl = np.array([np.r_[s, e, r] for s, e, r, _ in rows])
    levels = np.array([lv for *_, lv in rows])
    bark_v, bark_t = cylinders_mesh(cyl, caps=p.capped_wood)

    # leaves clustered around the terminal shoots, kept inside the crown envelope
    terminal = cyl[levels == levels.max()]
    seg_len = np.linalg.norm(terminal[:, 3:6] - terminal[:, :3], axis=1)
    leaf_poly_area = polygon_area_factor() * 0.25 * p.leaf_length * p.leaf_width
    n_leaves = int(round(p.total_leaf_area / leaf_poly_area)) if p.total_leaf_area > 0 else 0
    centers = np.zeros((0, 3))
    center, semi = p.crown_center, p.crown_semi_axes
    while len(centers) < n_leaves:
        m = int(1.3 * (n_leaves - len(centers))) + 16
        pick = rng.choice(len(terminal), size=m, p=seg_len / seg_len.sum())
        t = rng.uniform(0.3, 1.0, m)
        base = terminal[pick, :3] + t[:, None] * (terminal[pick, 3:6] - terminal[pick, :3])
        c = base + rng.normal(0, p.leaf_cluster_sigma, (m, 3))
        ok = np.sum(((c - center) / semi) ** 2, axis=1) <= 1.0
        centers = np.concatenate([centers, c[ok]])
    centers = centers[:n_leaves]
    normals = sample_leaf_normals(n_leaves, p.leaf_angle_model, rng, azimuth=p.leaf_azimuth,
                                  positions=centers, crown_center=center[:2])
    # scale both axes so that the polygons hold exactly the requested area
    scale = np.sqrt(p.total_leaf_area / (n_leaves * leaf_poly_area)) if n_leaves else 1.0
    leaf_v, leaf_t = leaf_mesh(centers, normals, p.leaf_length * scale, p.leaf_width * scale, rng)

    # ground: a square, two triangles
    g = p.ground_half_size
    ground_v = np.array([[-g, -g, 0.0], [g, -g, 0.0], [g, g, 0.0], [-g, g, 0.0]])
    ground_t = np.array([[0, 1, 2], [0, 2, 3]])

    # retro-reflective cylinder targets on the ground around the tree
    # an irregular layout (distances, azimuth gaps and heights all differ), so that no
    # rotation or reflection maps the target set onto itself: registration by
    # inter-target distances is then unambiguous
    k = np.arange(p.n_targets)
    az = np.deg2rad(60.0) + 2 * np.pi * k / max(p.n_targets, 1) + np.deg2rad(9.0) * np.sin(2.3 * k + 0.5)
    dist = p.target_distance * (1.0 + 0.12 * np.sin(1.7 * k + 0.3))
    heights = 1.25 + 0.9 * ((0.618 * k + 0.2) % 1.0)
    targets = np.column_stack([dist * np.cos(az), dist * np.sin(az), heights])
    if p.n_targets:
        tc = np.column_stack([targets - [0, 0, p.target_height / 2], targets + [0, 0, p.target_height / 2],
                              np.full(p.n_targets, p.target_radius)])
        target_v, target_t = cylinders_mesh(tc, sides=24)
    else:
        target_v, target_t = np.zeros((0, 3)), np.zeros((0, 3), int)

    parts = [(bark_v, bark_t, Material.BARK), (leaf_v, leaf_t, Material.LEAF),
             (ground_v, ground_t, Material.GROUND), (target_v, target_t, Material.TARGET)]
    verts, tris, mats, offset = [], [], [], 0
    for v, t, m in parts:
        verts.append(v)
        tris.append(t + offset)
        mats.append(np.full(len(t), m, np.uint8))
        offset += len(v)
    return SyntheticTree(
        vertices=np.concatenate(verts), triangles=np.concatenate(tris).astype(np.int64),
        material=np.concatenate(mats), leaf_normals=normals, leaf_centers=centers,
        cylinders=cyl, targets=targets, ground_z=0.0, crown_center=center, params=p, seed=seed,
    )


def load_tree(path: str | os.PathLike) -> SyntheticTree:
    """Rebuild a tree from the JSON written by :meth:`SyntheticTree.save`."""
    path = Path(path)
    meta = path.with_suffix(".json") if path.suffix.lower() != ".json" else path
    if not meta.exists():
        raise InputError(f"tree metadata {str(meta)!r} does not exist; write it with `tlsvox tree -o NAME.ply`")
    try:
        doc = json.loads(meta.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise InputError(f"{str(meta)!r} is not readable JSON ({err}); give the NAME.json that `tlsvox tree` "
                         "wrote") from None
    if not isinstance(doc, dict) or not doc.get("params") or "seed" not in doc:
        raise InputError(f"{str(meta)!r} is not a tlsvox tree file (no generator parameters and seed); give the "
                         "NAME.json that `tlsvox tree` wrote")
    try:
        params = TreeParams(**doc["params"])
    except TypeError as err:
        raise InputError(f"{str(meta)!r}: its tree parameters do not match this version ({err})") from None
    return make_tree(params, seed=int(doc["seed"]))


# --------------------------------------------------------------------------------------
# test scenes made of the same parts


def make_leaf_slab(*, lad: float, size=(4.0, 4.0, 1.0), leaf_angle="spherical", leaf_length=0.05,
                   leaf_width=0.025, origin=(0.0, 0.0, 0.0), seed: int = 0, ground: bool = False,
                   ground_half_size: float = 50.0) -> SyntheticTree:
    """A box of randomly placed, randomly oriented leaves (a Poisson Boolean model).

    The number of leaves is Poisson with mean ``lad * volume / leaf_area``, so
    the gap probability along a straight path of length L inside the slab is
    exactly ``exp(-G(theta) * lad * L)`` (edge effects aside).  With
    ``ground=True`` a Lambertian ground square lies at z = 0.
    """
    rng = np.random.default_rng(seed)
    size = np.asarray(size, dtype=float)
    leaf_poly_area = polygon_area_factor() * 0.25 * leaf_length * leaf_width
    n = rng.poisson(lad * np.prod(size) / leaf_poly_area)
    centers = np.asarray(origin) + rng.uniform(0, 1, (n, 3)) * size
    la = LeafAngle(leaf_angle)
    normals = sample_leaf_normals(n, la, rng)
    v, t = leaf_mesh(centers, normals, leaf_length, leaf_width, rng)
    mat = np.full(len(t), Material.LEAF, np.uint8)
    if ground:
        g = ground_half_size
        c = np.asarray(origin, float)[:2] + size[:2] / 2
        gv = np.array([[c[0] - g, c[1] - g, 0], [c[0] + g, c[1] - g, 0], [c[0] + g, c[1] + g, 0],
                       [c[0] - g, c[1] + g, 0]], float)
        t = np.concatenate([t, np.array([[0, 1, 2], [0, 2, 3]]) + len(v)])
        v = np.concatenate([v, gv])
        mat = np.concatenate([mat, np.full(2, Material.GROUND, np.uint8)])
    return SyntheticTree(vertices=v, triangles=t.astype(np.int64), material=mat,
                         leaf_normals=normals, leaf_centers=centers, ground_z=0.0 if ground else None,
                         crown_center=np.asarray(origin) + size / 2, leaf_angle=la)


def make_wall(*, center=(10.0, 0.0, 0.0), normal=(-1.0, 0.0, 0.0), half_size=5.0,
              material: Material = Material.BARK) -> SyntheticTree:
    """A flat square wall (two triangles) of one material, facing ``normal``."""
    c = np.asarray(center, dtype=float)
    n = np.asarray(normal, dtype=float)
    n /= np.linalg.norm(n)
    u, v = orthonormal(n[None])
    u, v = u[0] * half_size, v[0] * half_size
    verts = np.array([c - u - v, c + u - v, c + u + v, c - u + v])
    tris = np.array([[0, 1, 2], [0, 2, 3]])
    return SyntheticTree(vertices=verts, triangles=tris, material=np.full(2, material, np.uint8),
                         ground_z=None, crown_center=c)
