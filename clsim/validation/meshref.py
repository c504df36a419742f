"""Explicit-geometry reference: the airborne pulse traced against the tree's mesh.

The same sensor, beam, time window, binning, pulse convolution and
normalisation as :class:`clsim.Simulator` (it reuses :func:`prepare_run` and
:func:`assemble_result`); only the transport differs.  Photons are traced
against the triangles themselves with Open3D's Embree ray caster: every leaf
is a bi-Lambertian facet (reflection on the incident side, transmission
through it), bark and ground are Lambertian.  Next-event estimation casts a
shadow ray to the receiver from every scattering event; a shadow ray that
meets any triangle is blocked (a leaf transmits diffusely, not along the
ray).  Survival weighting and Russian roulette as in the voxel transport.

Because the receiver sits at the source (monostatic), the return path of a
single-scattering event retraces the incoming one, which was free: the mesh
reference therefore shows the hot spot that a turbid medium misses (see
docs/method.md).  For a Boolean canopy of random leaves (LAD u, thickness H,
projection G) over a Lambertian ground, nadir, single scattering:

- ground energy  = (A/R^2)(rho_g/pi) exp(-G u H)         (one-way, not two-way)
- canopy energy  = (A/R^2) Gamma_b (1 - exp(-G u H)) / G   (Gamma_b = rho_l/(3 pi) for spherical leaves)

which the tests check.

References
----------
Kuusk, A. (1991). The hot spot effect in plant canopy reflectance. In Myneni &
    Ross (eds), Photon-Vegetation Interactions, Springer, 139-159.
    doi:10.1007/978-3-642-75389-3_5
"""

from __future__ import annotations

import time

import numpy as np

from clsim.errors import InputError
from clsim.sensor import C_M_PER_NS
from clsim.transport.reference_geometry import beam_directions, cosine_dir, receiver_view, row_dot
from clsim.transport.reference_walk import RR_SURVIVE, RR_THRESHOLD
from clsim.transport.result import assemble_result
from clsim.transport.setup import STAT_NAMES, PhotonTally, prepare_run
from voxlidar.materials import Material

__all__ = ["MeshReferenceSimulator"]

_S = {n: i for i, n in enumerate(STAT_NAMES)}
EPS = 2e-4  # m: offset off a surface, well above float32 rounding at scene scale


class MeshReferenceSimulator:
    """Monte Carlo photon transport against an explicit triangle mesh (CPU, Embree).

    Parameters
    ----------
    chunk : int
        Photons traced together (bounds memory).

    Examples
    --------
    >>> from tlsvox.truth.synthetic import make_leaf_slab
    >>> from clsim.sensor import Sensor
    >>> slab = make_leaf_slab(lad=0.5, size=(3, 3, 1), origin=(-1.5, -1.5, 1.0), seed=1, ground=True)
    >>> res = MeshReferenceSimulator().run(slab, Sensor(), photons=2000, seed=1, max_order=1)
    >>> res.energy()[0] > 0
    True
    """

    device_name = "Open3D Embree (CPU), explicit mesh"

    def __init__(self, *, chunk: int = 1 << 16):
        self.chunk = int(chunk)

    def run(self, tree, sensor, *, photons: int, seed: int, max_order: int = 3, leaf_off: bool = False,
            batches: int = 16, bin_ns: float = 0.05, target=None, twin=None, twin_voxel_size: float = 0.5):
        """Simulate the waveform of one pulse over a mesh.

        Parameters
        ----------
        tree : tlsvox.truth.synthetic.SyntheticTree
            The mesh with a material per triangle (targets are ignored).
        sensor : clsim.sensor.Sensor
        photons, seed, max_order, leaf_off, batches, bin_ns, target
            As :meth:`clsim.Simulator.run` (detection is always NEE).
        twin : tlsvox.Scene, optional
            Voxel twin of the mesh, used only for the run's geometry (time
            window, default target) and materials; default
            ``tree.truth_scene(twin_voxel_size)``.

        Returns
        -------
        clsim.transport.simulator.SimulationResult
        """
        twin = twin if twin is not None else tree.truth_scene(twin_voxel_size)
        setup = prepare_run(twin, sensor, photons=photons, seed=seed, mode="exact", detect="nee",
                            max_order=max_order, leaf_off=leaf_off, batches=batches, bin_ns=bin_ns,
                            target=target)
        if setup.detect is not PhotonTally.NEE:  # pragma: no cover - prepare_run kept it
            raise InputError("the mesh reference detects by next-event estimation only")
        rc, tri_mat = self._raycaster(tree, leaf_off)
        opt = setup.settings["optics"]
        R = np.zeros(int(max(Material)) + 1)
        T = np.zeros_like(R)
        R[Material.LEAF], T[Material.LEAF] = opt["leaf"]
        R[Material.BARK], T[Material.BARK] = opt["bark"]
        R[Material.GROUND] = opt["ground"][0]
        ctx = _Context(setup, rc, tri_mat, R, T, np.random.default_rng(seed))
        t0 = time.perf_counter()
        for start in range(0, setup.photons, self.chunk):
            ctx.simulate(np.arange(start, min(start + self.chunk, setup.photons)))
        elapsed = time.perf_counter() - t0
        return assemble_result(setup, ctx.hist, ctx.stats, None, elapsed, self.device_name)

    @staticmethod
    def _raycaster(tree, leaf_off):
        import open3d as o3d

        key = f"_meshref_rc_{int(leaf_off)}"
        cached = tree.__dict__.get(key)
        if cached is not None:
            return cached
        keep = np.isin(tree.material, [Material.BARK, Material.GROUND] + ([] if leaf_off else [Material.LEAF]))
        if not keep.any():
            raise InputError("the mesh has no leaf, bark or ground triangles to trace against")
        mesh = o3d.t.geometry.TriangleMesh()
        mesh.vertex.positions = o3d.core.Tensor(np.asarray(tree.vertices, np.float32))
        mesh.triangle.indices = o3d.core.Tensor(np.asarray(tree.triangles[keep], np.int32))
        rc = o3d.t.geometry.RaycastingScene()
        rc.add_triangles(mesh)
        cached = (rc, np.asarray(tree.material[keep], np.int64))
        tree.__dict__[key] = cached
        return cached


class _Context:
    """Tallies of one run; photons are traced in chunks, all orders vectorised."""

    def __init__(self, setup, rc, tri_mat, R, T, rng):
        self.s = setup
        self.rc, self.tri_mat, self.R, self.T, self.rng = rc, tri_mat, R, T, rng
        p = setup.p
        self.sensor = np.asarray(setup.settings["sensor_position"], dtype=np.float64)
        self.axis = np.asarray(p["axis"], np.float64)
        self.e1, self.e2 = np.asarray(p["e1"], np.float64), np.asarray(p["e2"], np.float64)
        self.sigma = float(p["beam_sigma"])
        self.tan2_fov = float(np.tan(1e-3 * setup.sensor.fov_mrad)) ** 2
        self.norm = setup.range_ref_m**2
        self.edges = setup.edges_ns
        B, K, F = setup.batches, setup.max_order, len(self.edges) - 1
        self.hist = np.zeros((B, K, 2, F))
        self.stats = np.zeros((B, len(STAT_NAMES)))

    def cast(self, o, d):
        import open3d as o3d

        rays = np.concatenate([o, d], axis=1).astype(np.float32)
        hit = self.rc.cast_rays(o3d.core.Tensor(rays))
        t = hit["t_hit"].numpy().astype(np.float64)
        prim = hit["primitive_ids"].numpy().astype(np.int64)
        n = hit["primitive_normals"].numpy().astype(np.float64)
        return t, prim, n

    def add_stat(self, name, b, values):
        np.add.at(self.stats[:, _S[name]], b, values)

    def tally(self, b, order, kind, t_ns, value):
        s = (t_ns - self.edges[0]) / (self.edges[1] - self.edges[0])
        F = len(self.edges) - 1
        ok = (s >= 0) & (s < F)
        np.add.at(self.hist, (b[ok], order - 1, kind[ok], s[ok].astype(np.int64)), value[ok])
        np.add.at(self.stats[:, _S["outside_window"]], b[~ok], value[~ok])

    def simulate(self, ids):
        s, rng = self.s, self.rng
        n = len(ids)
        batch = ids % s.batches
        u = rng.random((n, 2))
        d = beam_directions(self.axis, self.e1, self.e2, self.sigma, 1.0 - u[:, 0], u[:, 1])
        x = np.tile(self.sensor, (n, 1))
        L = np.zeros(n)
        w = np.ones(n)
        alive = np.arange(n)
        for k in range(1, s.max_order + 2):
            if not alive.size:
                break
            a = alive
            t, prim, nrm = self.cast(x[a], d[a])
            esc = ~np.isfinite(t)
            ie = a[esc]
            up = d[ie, 2] >= 0
            self.add_stat("escaped_up", batch[ie[up]], w[ie[up]])
            self.add_stat("escaped_down", batch[ie[~up]], w[ie[~up]])
            a, t, prim, nrm = a[~esc], t[~esc], prim[~esc], nrm[~esc]
            mat = self.tri_mat[prim]
            x[a] += d[a] * t[:, None]
            L[a] += t
            self.stats[0, _S["events"]] += a.size
            if k == 1:
                gd = mat == Material.GROUND
                self.add_stat("ground_direct", batch[a[gd]], w[a[gd]])
            if k > s.max_order:
                self.add_stat("truncated", batch[a], w[a])
                break
            # oriented normal on the incident side
            m = np.where((row_dot(nrm, d[a]) > 0)[:, None], -nrm, nrm)
            R, T = self.R[mat], self.T[mat]
            self.nee(a, x, L, w, m, mat, R, T, k, batch)
            if k == s.max_order:
                self.add_stat("truncated", batch[a], w[a])
                break
            uu = rng.random((a.size, 4))
            alb = R + T
            dead = alb <= 0
            self.add_stat("absorbed", batch[a[dead]], w[a[dead]])
            self.add_stat("absorbed", batch[a[~dead]], w[a[~dead]] * (1.0 - alb[~dead]))
            reflect = uu[:, 0] * alb < R
            w[a] *= alb
            low = ~dead & (w[a] < RR_THRESHOLD)
            surv = low & (uu[:, 3] * RR_SURVIVE < w[a])
            kill = low & ~surv
            self.add_stat("rr_added", batch[a[surv]], RR_SURVIVE - w[a[surv]])
            w[a[surv]] = RR_SURVIVE
            self.add_stat("rr_killed", batch[a[kill]], w[a[kill]])
            keep = ~dead & ~kill
            mm = np.where(reflect[:, None], m, -m)
            a, mm, uu = a[keep], mm[keep], uu[keep]
            d[a] = cosine_dir(mm, uu[:, 1], uu[:, 2])
            x[a] += mm * EPS  # leave the surface on the chosen side
            alive = a

    def nee(self, a, x, L, w, m, mat, R, T, k, batch):
        r, drx, cosr, c, f, ok = receiver_view(self.sensor, self.axis, self.tan2_fov, x[a], m, R, T)
        if not ok.any():
            return
        i = a[ok]
        side = np.where(c[ok] > 0, 1.0, -1.0)[:, None] * m[ok]
        origin = x[i] + side * EPS
        self.stats[0, _S["shadow_rays"]] += i.size
        t, _, _ = self.cast(origin, drx[ok])
        free = ~(t < r[ok])
        val = w[i] * f[ok] * cosr[ok] * self.norm / r[ok] ** 2
        kind = (mat[ok] == Material.GROUND).astype(np.int64)
        sel = free
        self.stats[0, _S["detections"]] += int(sel.sum())
        self.tally(batch[i[sel]], k, kind[sel], (L[i] + r[ok])[sel] / C_M_PER_NS, val[sel])
