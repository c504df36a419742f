"""The synthetic truth world: procedural tree and exact per-voxel truth."""

import numpy as np
import pytest
from scipy import stats

from tlsvox import InputError, LeafAngle, Material
from tlsvox.truth.meshtruth import area_per_voxel, triangle_areas
from tlsvox.truth.synthetic import TreeParams, load_tree, make_tree

SMALL = dict(height=6.0, crown_base=1.5, crown_radius=2.0, trunk_radius=0.12, total_leaf_area=12.0,
             n_scaffolds=4, branch_levels=2, target_distance=4.0)


def small_tree(seed=3, **kw):
    return make_tree(TreeParams(**{**SMALL, **kw}), seed=seed)


@pytest.mark.parametrize("area", [0.5, 12.0, 37.25])
def test_leaf_area_is_what_was_requested(area):
    tree = small_tree(total_leaf_area=area)
    assert tree.leaf_area() == pytest.approx(area, rel=1e-12)


def test_default_tree_is_the_paper_oak():
    p = TreeParams()
    assert p.height == 13.6
    # dense crown: leaf area index over the crown projection between 3 and 6
    lai = p.total_leaf_area / (np.pi * p.crown_radius**2)
    assert 3.0 < lai < 6.0


def _mesh_leaf_zenith(tree):
    """Zenith of each leaf's plane normal, recomputed from its first triangle."""
    leaf_tris = tree.triangle_coords(Material.LEAF)[::6]  # 6 triangles per leaf
    n = np.cross(leaf_tris[:, 1] - leaf_tris[:, 0], leaf_tris[:, 2] - leaf_tris[:, 0])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    return np.arccos(np.abs(n[:, 2]))


@pytest.mark.parametrize("kind", ["uniform", "planophile", "erectophile", "spherical", "plagiophile"])
def test_leaf_zenith_follows_the_requested_distribution(kind):
    tree = small_tree(leaf_angle=kind, total_leaf_area=8.0, seed=11)
    zen = _mesh_leaf_zenith(tree)
    assert len(zen) == tree.n_leaves > 5000
    # Kolmogorov-Smirnov against the distribution's CDF; p-value would be
    # uniform under H0: failing at 1e-3 is a 1-in-1000 false alarm.
    res = stats.kstest(zen, LeafAngle(kind).cdf)
    assert res.pvalue > 1e-3, res
    # and the test has power: the same sample against another distribution fails
    other = "erectophile" if kind in ("planophile", "uniform") else "planophile"
    assert stats.kstest(zen, LeafAngle(other).cdf).pvalue < 1e-6


def test_leaf_azimuth_faces_out_of_the_crown():
    tree = small_tree(leaf_azimuth="outward")
    n, c = tree.leaf_normals, tree.leaf_centers
    tilted = np.hypot(n[:, 0], n[:, 1]) > 0.1
    radial = c[:, :2] - tree.crown_center[:2]
    cosang = np.einsum("ij,ij->i", n[tilted, :2], radial[tilted]) / (
        np.linalg.norm(n[tilted, :2], axis=1) * np.linalg.norm(radial[tilted], axis=1))
    assert np.all(cosang > 1 - 1e-9)


def test_per_voxel_truth_sums_to_total():
    tree = small_tree()
    lo, hi = tree.bounds()
    for h in (0.05, 0.2, 0.5):
        shape = np.ceil((hi - lo) / h).astype(int) + 2
        a = tree.leaf_area_per_voxel(origin=lo - h, voxel_size=h, shape=shape)
        assert a.sum() == pytest.approx(tree.leaf_area(), rel=1e-9)
        assert a.min() >= 0


def test_area_per_voxel_of_a_plane_is_h_squared():
    # a 2 x 2 m horizontal square split into two triangles over 0.25 m voxels
    sq = np.array([[[0, 0, 0.3], [2, 0, 0.3], [2, 2, 0.3]], [[0, 0, 0.3], [2, 2, 0.3], [0, 2, 0.3]]], float)
    a = area_per_voxel(sq, origin=(0, 0, 0), voxel_size=0.25, shape=(8, 8, 4))
    np.testing.assert_allclose(a[:, :, 1], 0.0625, rtol=1e-12)
    assert a.sum() == pytest.approx(4.0, rel=1e-12)


def test_area_per_voxel_matches_monte_carlo(rng):
    # random triangles: the area falling in each voxel, estimated by sampling
    # uniform points on the triangles (standard error ~ 1/sqrt(n))
    tris = rng.uniform(0, 1, (40, 3, 3))
    a = area_per_voxel(tris, origin=(0, 0, 0), voxel_size=0.5, shape=(2, 2, 2))
    areas = triangle_areas(tris)
    n = 20000
    r1, r2 = rng.random((2, len(tris), n))
    s = np.sqrt(r1)
    pts = ((1 - s)[..., None] * tris[:, None, 0] + (s * (1 - r2))[..., None] * tris[:, None, 1]
           + (s * r2)[..., None] * tris[:, None, 2])
    ijk = np.floor(pts / 0.5).astype(int).clip(0, 1)
    flat = np.ravel_multi_index(ijk.reshape(-1, 3).T, (2, 2, 2))
    w = np.repeat(areas / n, n)
    mc = np.bincount(flat, weights=w, minlength=8).reshape(2, 2, 2)
    se = areas.sum() / np.sqrt(n * len(tris))
    assert np.all(np.abs(mc - a) < 5 * se + 1e-12)


def test_same_seed_same_tree_other_seed_other_tree():
    a, b, c = small_tree(seed=5), small_tree(seed=5), small_tree(seed=6)
    np.testing.assert_array_equal(a.vertices, b.vertices)
    np.testing.assert_array_equal(a.material, b.material)
    assert a.vertices.shape != c.vertices.shape or not np.array_equal(a.vertices, c.vertices)


def test_save_and_rebuild(tmp_path):
    tree = small_tree()
    ply, meta = tree.save(tmp_path / "oak.ply")
    assert ply.stat().st_size > 0 and meta.exists()
    again = load_tree(meta)
    np.testing.assert_array_equal(again.vertices, tree.vertices)


def test_materials_present():
    tree = small_tree()
    mats = set(np.unique(tree.material).tolist())
    assert mats == {Material.LEAF, Material.BARK, Material.GROUND, Material.TARGET}
    assert len(tree.targets) >= 4


@pytest.mark.parametrize("bad, word", [(dict(height=-1.0), "height"), (dict(total_leaf_area=-3.0), "total_leaf_area"),
                                       (dict(crown_base=7.0), "crown_base"), (dict(leaf_angle="flat"), "leaf_angle"),
                                       (dict(leaf_azimuth="north"), "leaf_azimuth")])
def test_bad_tree_parameters_name_the_parameter(bad, word):
    with pytest.raises(InputError, match=word):
        TreeParams(**{**SMALL, **bad})


def test_truth_scene_holds_the_leaf_area_and_wood():
    tree = small_tree()
    scene = tree.truth_scene(0.25)
    assert scene.total_leaf_area() == pytest.approx(tree.leaf_area(), rel=1e-9)
    assert scene.wood.max() <= 1.0 and scene.wood.max() > 0.5  # trunk voxels are nearly opaque
    assert scene.leaf_angle == tree.params.leaf_angle_model and scene.leaf_azimuth == "outward"
    # trunk voxel at the base: bark surface of the trunk segment inside it
    i, j, k = np.floor((np.array([0.0, 0.0, 0.1]) - scene.origin) / 0.25).astype(int)
    assert scene.dense("wood")[i, j, k] > 0


def test_solid_wood_voxels_are_the_centres_inside_the_cylinders():
    tree = small_tree(trunk_radius=0.3)
    h = 0.1
    origin, shape = tree.truth_grid(h)
    flat, _ = tree.solid_wood_voxels(origin=origin, voxel_size=h, shape=shape)
    # brute force over every voxel centre of the grid: between the end planes of a cylinder
    # (flat ends, as the mesh's caps) and nearer its axis than its radius
    ijk = np.argwhere(np.ones(shape, dtype=bool))
    c = origin + (ijk + 0.5) * h
    inside = np.zeros(len(c), dtype=bool)
    for a, b, r in zip(tree.cylinders[:, :3], tree.cylinders[:, 3:6], tree.cylinders[:, 6]):
        ab = b - a
        t = (c - a) @ ab / (ab @ ab)
        inside |= (t >= 0) & (t <= 1) & (np.linalg.norm(a + t[:, None] * ab - c, axis=1) < r)
    assert flat.tolist() == sorted(np.ravel_multi_index(ijk[inside].T, shape).tolist())
    assert len(flat) > 20  # the 0.3 m trunk holds whole 0.1 m voxels
    solid = np.stack(np.unravel_index(flat, shape), axis=1)

    hollow, filled = tree.truth_scene(h, solid_wood=False), tree.truth_scene(h)
    assert filled.total_leaf_area() == pytest.approx(hollow.total_leaf_area(), rel=1e-12)
    dense = filled.dense("wood")
    assert np.all(dense[tuple(solid.T)] == pytest.approx(1 - 1e-6))
    assert hollow.dense("wood")[tuple(solid.T)].min() < 0.5  # the core of the hollow twin is not opaque


def test_bark_direction_of_a_cylinder_and_of_isotropic_facets(rng):
    """An 8-sided cylinder's normals are all across its axis: beta = 1, the axis found;
    a fine sphere's normals are isotropic: beta ~ 0 (a polyhedron's, up to its facets)."""
    from tlsvox.truth._mesh import cylinders_mesh
    from tlsvox.truth.meshtruth import bark_direction, normal_moments_per_voxel

    a = np.array([0.3, 0.4, 0.2])
    d = np.array([0.2, -0.3, 0.93])
    d /= np.linalg.norm(d)
    v, t = cylinders_mesh(np.array([[*a, *(a + 0.6 * d), 0.05]]))
    flat, area, mom = normal_moments_per_voxel(v[t], origin=(0, 0, 0), voxel_size=1.0, shape=(1, 1, 1))
    axis, beta = bark_direction(area, mom)
    assert flat.tolist() == [0] and beta[0] == pytest.approx(1.0, abs=1e-9)
    assert abs(axis[0] @ d) == pytest.approx(1.0, abs=1e-9) and axis[0, 2] >= 0
    # unit sphere from a fine UV tessellation, scaled into one voxel
    th, ph = np.meshgrid(np.linspace(0, np.pi, 61), np.linspace(0, 2 * np.pi, 121), indexing="ij")
    p = 0.4 * np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], -1) + 0.5
    q = np.concatenate([np.stack([p[:-1, :-1], p[1:, :-1], p[1:, 1:]], 2).reshape(-1, 3, 3),
                        np.stack([p[:-1, :-1], p[1:, 1:], p[:-1, 1:]], 2).reshape(-1, 3, 3)])
    _, area, mom = normal_moments_per_voxel(q, origin=(0, 0, 0), voxel_size=1.0, shape=(1, 1, 1))
    assert area[0] == pytest.approx(4 * np.pi * 0.4**2, rel=2e-3)
    assert bark_direction(area, mom)[1][0] < 0.01


def test_truth_scene_gives_the_trunk_an_upright_axis():
    """Directional wood of the twin: the trunk's voxels are cylinders (beta near 1) with a
    near-vertical axis; wood_model='isotropic' leaves the directions out."""
    tree = small_tree()
    scene = tree.truth_scene(0.25)
    i, j, k = np.floor((np.array([0.0, 0.0, 0.6]) - scene.origin) / 0.25).astype(int)
    row = np.flatnonzero((scene.ijk == [i, j, k]).all(axis=1))
    assert row.size == 1 and scene.wood[row[0]] > 0
    assert scene.wood_beta[row[0]] > 0.9 and scene.wood_axis[row[0], 2] > 0.9
    assert scene.wood_directional and np.all(scene.wood_beta[scene.wood == 0] == 0)
    iso = tree.truth_scene(0.25, wood_model="isotropic")
    assert not iso.wood_directional
    np.testing.assert_array_equal(iso.wood, scene.wood)
    with pytest.raises(InputError, match="wood_model"):
        tree.truth_scene(0.25, wood_model="cylinders")


def test_solid_wood_fills_the_trunk():
    """solid_wood=True: voxels whose centre lies inside a cylinder are opaque wood with the
    cylinder's axis; the count matches the trunk's volume; the rest is unchanged."""
    tree = small_tree()
    h = 0.05
    plain, solid = tree.truth_scene(h, solid_wood=False), tree.truth_scene(h)  # solid is the default
    origin, shape = tree.truth_grid(h)
    flat, axis = tree.solid_wood_voxels(origin=origin, voxel_size=h, shape=shape)
    c = tree.cylinders
    volume = float(np.sum(np.pi * c[:, 6] ** 2 * np.linalg.norm(c[:, 3:6] - c[:, :3], axis=1)))
    assert len(flat) * h**3 == pytest.approx(volume, rel=0.25)  # overlaps at joints, centre rule
    rows = np.searchsorted(np.ravel_multi_index(solid.ijk.T, shape), flat)
    assert np.all(solid.wood[rows] == pytest.approx(1 - 1e-6)) and np.all(solid.wood_beta[rows] == 0.0)
    np.testing.assert_allclose(solid.wood_axis[rows], axis)
    assert solid.total_leaf_area() == pytest.approx(plain.total_leaf_area(), rel=1e-12)
    assert solid.meta["solid_wood"] and not plain.meta["solid_wood"]
    # the trunk's centre line is solid, its axis upright
    i, j, k = np.floor((np.array([0.0, 0.0, 0.5]) - origin) / h).astype(int)
    row = np.flatnonzero((solid.ijk == [i, j, k]).all(axis=1))
    assert row.size == 1 and solid.wood[row[0]] > 0.99 and solid.wood_axis[row[0], 2] > 0.99


def cylinder_tree(cyl):
    """A SyntheticTree of capped bark cylinders (C, 7) over a ground square, nothing else."""
    from tlsvox.truth._mesh import cylinders_mesh
    from tlsvox.truth.synthetic import SyntheticTree

    cyl = np.asarray(cyl, dtype=float)
    v, t = cylinders_mesh(cyl, caps=True)
    gv = np.array([[-9.0, -9.0, 0.0], [9.0, -9.0, 0.0], [9.0, 9.0, 0.0], [-9.0, 9.0, 0.0]])
    return SyntheticTree(vertices=np.concatenate([v, gv]),
                         triangles=np.concatenate([t, np.array([[0, 1, 2], [0, 2, 3]]) + len(v)]),
                         material=np.r_[np.full(len(t), Material.BARK), np.full(2, Material.GROUND)].astype(np.uint8),
                         cylinders=cyl, ground_z=0.0)


def test_solid_core_carries_its_surface_and_replaces_the_bark_beside_it():
    """A 0.3 m trunk at 0.1 m voxels: its core is solid wood about +z, the cap share
    ``a^T M a / A`` of the bark around each cell is 1 at the top cap's cells (cap only) and
    0 half way up (side only); the core stands for the cylinder, so the bark in the cells
    around it is no turbid wood.  A 0.03 m branch has no core and keeps all its bark."""
    h = 0.1
    tree = cylinder_tree([[0.0, 0.0, 0.0, 0.0, 0.0, 2.0, 0.3], [1.5, 0.0, 0.5, 1.5, 0.0, 1.5, 0.03]])
    scene = tree.truth_scene(h)
    solid = scene.wood_solid
    assert solid.sum() > 100 and np.allclose(scene.wood_axis[solid], [0, 0, 1])
    assert np.all(scene.wood[solid] == pytest.approx(1 - 1e-6))
    z = scene.origin[2] + (scene.ijk[:, 2] + 0.5) * h
    mid = solid & (np.abs(z - 1.0) < 0.3)
    assert np.all(scene.wood_cap[mid] < 1e-12)
    top = solid & (z > 1.9) & (np.hypot(*(scene.origin[:2] + (scene.ijk[:, :2] + 0.5) * h).T) < 0.1)
    assert top.any() and np.all(scene.wood_cap[top] > 0.5)
    x = scene.origin[0] + (scene.ijk[:, 0] + 0.5) * h
    assert np.all(scene.wood[~solid & (x < 1.0)] == 0.0)  # the trunk's bark: its core alone
    thin = ~solid & (x > 1.0)
    assert not np.any(solid & (x > 1.0))
    sigma = -np.log1p(-scene.wood[thin]) / h  # direction-averaged bark area / 4V
    branch_area = 2 * np.pi * 0.03 * 1.0 + 2 * np.pi * 0.03**2
    octagon = 8 * np.sin(np.pi / 8) / np.pi  # the mesh's 8-sided perimeter against the circle's
    assert np.sum(4 * sigma * h**3) == pytest.approx(branch_area * octagon, rel=0.05)
