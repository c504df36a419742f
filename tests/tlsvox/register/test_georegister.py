"""Georegistration: recover a known rigid transform between a TLS-like and an
airborne-like sampling of the same procedural scene (trunks, crown blobs,
undulating ground), sampled differently (dense uniform surface samples vs
first hits of near-vertical rays with range noise)."""

from __future__ import annotations

import numpy as np
import pytest

from clsim.errors import InputError
from tlsvox.register.georegister import georegister, rotation_error_deg, transform_points, yaw_matrix

o3d = pytest.importorskip("open3d")


def _scene_mesh(rng):
    """Two trees (cylinder trunk + ellipsoid crown blobs) on undulating ground, map frame."""
    parts = []
    ground = o3d.geometry.TriangleMesh.create_box(60.0, 60.0, 0.01)
    ground = ground.subdivide_midpoint(number_of_iterations=5)
    v = np.asarray(ground.vertices)
    v[:, :2] -= 30.0
    v[:, 2] = 0.6 * np.sin(v[:, 0] / 6.0) * np.cos(v[:, 1] / 8.0) + 0.02 * v[:, 0]
    ground.vertices = o3d.utility.Vector3dVector(v)
    parts.append(ground)
    for (tx, ty, h) in ((-4.0, 2.0, 9.0), (6.0, -3.0, 12.0)):
        trunk = o3d.geometry.TriangleMesh.create_cylinder(radius=0.25, height=h, resolution=24)
        trunk.translate((tx, ty, h / 2.0))
        parts.append(trunk)
        for _ in range(5):
            r = rng.uniform(1.2, 2.4)
            blob = o3d.geometry.TriangleMesh.create_sphere(radius=r, resolution=16)
            blob.scale(1.0, center=(0, 0, 0))
            bv = np.asarray(blob.vertices) * np.array([1.0, rng.uniform(0.6, 1.0), 0.7])
            blob.vertices = o3d.utility.Vector3dVector(bv)
            off = rng.normal(0.0, 1.6, 3) * np.array([1, 1, 0.5])
            blob.translate((tx + off[0], ty + off[1], h - 1.5 + off[2]))
            parts.append(blob)
    mesh = parts[0]
    for p in parts[1:]:
        mesh += p
    mesh.compute_triangle_normals()
    return mesh


def _airborne(mesh, rng, spacing=0.45, altitude=300.0, noise=0.02):
    """First hits of rays from ~300 m above, scan angle varying across track."""
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(mesh))
    gx, gy = np.meshgrid(np.arange(-25, 25, spacing), np.arange(-25, 25, spacing))
    ground_pts = np.column_stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)])
    ground_pts[:, :2] += rng.uniform(-spacing / 2, spacing / 2, (gx.size, 2))
    # flight line along y at x = -40 m: scan angles about 3-12 deg off nadir
    sensor = np.column_stack([np.full(gx.size, -40.0), ground_pts[:, 1],
                              np.full(gx.size, altitude)])
    d = ground_pts - sensor
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    rays = o3d.core.Tensor(np.hstack([sensor, d]).astype(np.float32))
    ans = scene.cast_rays(rays)
    t = ans["t_hit"].numpy().astype(np.float64)
    ok = np.isfinite(t)
    t = t[ok] + rng.normal(0.0, noise, ok.sum())
    return sensor[ok] + d[ok] * t[:, None]


def _surface_samples(mesh, n, rng):
    """Area-uniform random points on the mesh (seeded: TLS-like dense sampling)."""
    v = np.asarray(mesh.vertices)
    f = np.asarray(mesh.triangles)
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
    tri = rng.choice(f.shape[0], size=n, p=area / area.sum())
    u, w = rng.random(n), rng.random(n)
    flip = u + w > 1
    u[flip], w[flip] = 1 - u[flip], 1 - w[flip]
    return a[tri] + u[:, None] * (b[tri] - a[tri]) + w[:, None] * (c[tri] - a[tri])


@pytest.fixture(scope="module")
def clouds():
    rng = np.random.default_rng(20150415)
    mesh = _scene_mesh(rng)
    offset = np.array([512_345.25, 4_767_890.75, 132.4])  # map (UTM-like) coordinates
    tls_map = _surface_samples(mesh, 120_000, rng) + offset
    tls_map = tls_map + rng.normal(0.0, 0.005, tls_map.shape)
    als = _airborne(mesh, rng) + offset
    # the TLS scan lives in its own frame: truth maps TLS frame -> map frame
    truth = yaw_matrix(37.0)
    tilt = np.eye(4)
    a = np.radians(0.3)
    tilt[1:3, 1:3] = [[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]
    truth = tilt @ truth
    truth[:3, 3] = offset
    tls_local = transform_points(np.linalg.inv(truth), tls_map)
    return tls_local, als, truth


def test_recovers_known_transform_from_rough_guess(clouds):
    tls_local, als, truth = clouds
    # initial guess: yaw 14 deg off (compass), 1.5 m off in x/y, 0.4 m in z (GNSS)
    init = yaw_matrix(-14.0, center=truth[:3, 3]) @ truth
    init[:3, 3] += [1.2, -0.9, 0.4]
    res = georegister(tls_local, als, init=init, yaw_range_deg=25.0, yaw_step_deg=5.0,
                      voxel_size=0.2)
    # error of the recovered transform at the scene's points (worst case over the cloud)
    moved = transform_points(res.transform, tls_local)
    target = transform_points(truth, tls_local)
    err = np.linalg.norm(moved - target, axis=1)
    rot = rotation_error_deg(res.transform, truth)
    print(f"max point error {err.max():.4f} m, rotation error {rot:.4f} deg, "
          f"fitness {res.fitness:.3f}, rmse {res.inlier_rmse:.4f}, yaw {res.yaw_offset_deg}")
    assert err.max() < 0.05
    assert rot < 0.2
    assert res.fitness > 0.9


def test_yaw_search_is_what_recovers_a_large_yaw_error(clouds):
    """ICP alone stays in the wrong minimum 90 deg off; the yaw search escapes it."""
    tls_local, als, truth = clouds
    init = yaw_matrix(90.0, center=truth[:3, 3]) @ truth
    plain = georegister(tls_local, als, init=init, yaw_range_deg=0.0, voxel_size=0.2)
    assert rotation_error_deg(plain.transform, truth) > 10.0
    searched = georegister(tls_local, als, init=init, yaw_range_deg=100.0, yaw_step_deg=10.0,
                           voxel_size=0.2)
    assert rotation_error_deg(searched.transform, truth) < 0.2
    assert searched.fitness > plain.fitness


def test_bad_input():
    pts = np.zeros((50, 3))
    with pytest.raises(InputError, match="4x4"):
        georegister(pts, pts, init=np.eye(3))
    with pytest.raises(InputError, match="rigid"):
        georegister(pts, pts, init=np.diag([2.0, 2.0, 2.0, 1.0]))
    with pytest.raises(InputError, match=r"\(N, 3\)"):
        georegister(np.zeros((50, 2)), pts)
