"""A terrestrial laser scanner simulator on Open3D's RaycastingScene (Embree).

Each pulse of the scanner's angular grid is a Gaussian beam sampled by
``n_subrays`` sub-rays of equal power (a centre ray and rings placed at the
power median of their annulus, ring rotated at random per pulse).  Every
sub-ray stops at the first surface it meets.  Sub-ray hits whose ranges lie
within the range resolution of each other merge into one echo, whose range is
the power-weighted mean of its sub-ray ranges (plus Gaussian range noise) and
whose apparent reflectance is the power-weighted sum of
``rho_material * cos(incidence)`` over the sub-rays that hit (so a partial hit
reads lower), written in dB relative to a white Lambertian target.  Each
echo's ``beam_fraction`` is the share of the beam's power its sub-rays carry
(sub-rays that hit / ``n_subrays``): the intercepted fraction that
``voxelize(echo_weights="fraction")`` weights it by.
Retro-reflective targets return ``rho * retro_gain`` whatever the incidence.

Echoes are reported along the pulse's central direction, in the scanner's own
frame; the true world-from-scanner pose is stored beside them.  Every pulse is
kept in the pulse table, those without an echo too.

References
----------
Béland, M. et al. (2014). On seeing the wood from the leaves and the role of
    voxel size in determining leaf area distribution of forests with
    terrestrial LiDAR. Agricultural and Forest Meteorology 184, 82-97.
    doi:10.1016/j.agrformet.2013.09.005
RIEGL VZ-400 data sheet (2014): 0.35 mrad beam divergence, 7 mm exit beam,
    5 mm accuracy, 1550 nm.
"""

from __future__ import annotations

import tomllib
from dataclasses import asdict, dataclass
from importlib import resources

import numpy as np

from tlsvox.errors import InputError
from tlsvox.scan import AngularGrid, PulseTable, Scan, directions_from_angles
from voxlidar.materials import Material, Optics, optics_for

__all__ = ["ScannerPreset", "ScanPose", "simulate_scan", "paper_scan_poses", "subray_pattern",
           "scan_window"]


@dataclass(frozen=True)
class ScannerPreset:
    """Instrument parameters (angles in degrees, lengths in metres)."""

    #: preset name (tlsvox/presets/NAME.toml)
    name: str = "riegl-vz400"
    #: laser wavelength, nm (chooses the materials' reflectance)
    wavelength_nm: float = 1550.0
    #: angular steps of the scan grid, degrees
    zenith_step_deg: float = 0.06
    azimuth_step_deg: float = 0.06
    #: beam diameter at the exit aperture, m, and full divergence, mrad
    beam_exit_diameter_m: float = 0.007
    divergence_mrad: float = 0.35
    #: range noise (1 sigma) of an echo, m
    range_noise_m: float = 0.005
    #: two hits of one pulse closer than this along the beam give one echo, m
    range_resolution_m: float = 0.5
    #: apparent-reflectance noise (1 sigma), dB, and the detection threshold, dB
    reflectance_noise_db: float = 0.3
    min_reflectance_db: float = -20.0
    #: ranges recorded, m
    min_range_m: float = 1.5
    max_range_m: float = 350.0
    #: sub-rays sampling the Gaussian beam (a centre ray plus full rings)
    n_subrays: int = 7
    #: margin of the scan window around the scene, degrees
    window_margin_deg: float = 2.0

    def __post_init__(self):
        for name in ("zenith_step_deg", "azimuth_step_deg", "beam_exit_diameter_m", "range_resolution_m",
                     "max_range_m", "wavelength_nm"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise InputError(f"ScannerPreset.{name}={v!r} must be a finite number > 0; "
                                 f"e.g. zenith_step_deg=0.06 for the RIEGL VZ-400")
        for name in ("divergence_mrad", "range_noise_m", "reflectance_noise_db", "min_range_m",
                     "window_margin_deg"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v >= 0):
                raise InputError(f"ScannerPreset.{name}={v!r} must be a finite number >= 0")
        if self.n_subrays not in _RING_COUNTS:
            raise InputError(f"ScannerPreset.n_subrays={self.n_subrays!r} must be one of "
                             f"{sorted(_RING_COUNTS)} (a centre ray plus full rings)")

    @classmethod
    def load(cls, name_or_path: str = "riegl-vz400", **overrides) -> ScannerPreset:
        """A preset from ``tlsvox/presets/NAME.toml`` or a TOML path, with overrides."""
        text = None
        try:
            text = resources.files("tlsvox").joinpath("presets", f"{name_or_path}.toml").read_text()
        except (FileNotFoundError, IsADirectoryError, NotADirectoryError):
            pass
        if text is None:
            try:
                with open(name_or_path, encoding="utf-8") as fh:
                    text = fh.read()
            except OSError as err:
                raise InputError(f"scanner preset {name_or_path!r} is neither a built-in preset "
                                 f"(riegl-vz400) nor a readable TOML file") from err
        doc = tomllib.loads(text)
        doc.update(overrides)
        return cls(**doc)

    @classmethod
    def riegl_vz400(cls, **overrides) -> ScannerPreset:
        """The RIEGL VZ-400 preset (the paper's scanner)."""
        return cls.load("riegl-vz400", **overrides)

    @property
    def beam_radius_exit(self) -> float:
        return 0.5 * self.beam_exit_diameter_m

    @property
    def half_divergence(self) -> float:
        """Half-angle beam divergence, radians (beam radius grows by this per metre)."""
        return 0.5e-3 * self.divergence_mrad

    def beam_radius(self, range_m):
        """1/e^2 beam radius (m) at a range."""
        return self.beam_radius_exit + self.half_divergence * np.asarray(range_m)


@dataclass(frozen=True)
class ScanPose:
    """Scanner position (m) and orientation (deg): world = T(position) Rz(yaw) Ry(pitch) Rx(roll)."""

    position: tuple = (0.0, 0.0, 1.7)
    yaw_deg: float = 0.0
    pitch_deg: float = 0.0
    roll_deg: float = 0.0

    def matrix(self) -> np.ndarray:
        """(4, 4) world-from-scanner transform."""
        y, p, r = np.deg2rad([self.yaw_deg, self.pitch_deg, self.roll_deg])
        rz = np.array([[np.cos(y), -np.sin(y), 0], [np.sin(y), np.cos(y), 0], [0, 0, 1]])
        ry = np.array([[np.cos(p), 0, np.sin(p)], [0, 1, 0], [-np.sin(p), 0, np.cos(p)]])
        rx = np.array([[1, 0, 0], [0, np.cos(r), -np.sin(r)], [0, np.sin(r), np.cos(r)]])
        m = np.eye(4)
        m[:3, :3] = rz @ ry @ rx
        m[:3, 3] = np.asarray(self.position, dtype=float)
        return m


def paper_scan_poses(tree=None) -> list[ScanPose]:
    """The two default scan positions, as in the paper: ~20 m and ~10 m, 1.7 m high.

    The positions are on different sides of the crown centre, each with an
    arbitrary yaw and a small tilt (unknown in the field, known here).
    """
    c = np.zeros(3) if tree is None else np.asarray(tree.crown_center, dtype=float)
    a1, a2 = np.deg2rad(-100.0), np.deg2rad(25.0)
    return [
        ScanPose(position=(c[0] + 20 * np.cos(a1), c[1] + 20 * np.sin(a1), 1.7), yaw_deg=37.0,
                 pitch_deg=0.4, roll_deg=-0.3),
        ScanPose(position=(c[0] + 10 * np.cos(a2), c[1] + 10 * np.sin(a2), 1.7), yaw_deg=-121.0,
                 pitch_deg=-0.25, roll_deg=0.5),
    ]


_RING_COUNTS = {1: (), 7: (6,), 19: (6, 12), 37: (6, 12, 18)}


def subray_pattern(n_subrays: int) -> tuple[np.ndarray, np.ndarray]:
    """Equal-power sub-ray positions of a Gaussian beam, in units of the 1/e^2 radius.

    The beam's enclosed power is ``P(r) = 1 - exp(-2 r^2)``, so ``s = r^2`` is
    exponential with rate 2.  The centre ray stands for the central disc that
    holds 1/n of the power; each ring of m rays stands for the next annulus
    holding m/n, placed at the annulus's RMS radius, so that the rays keep the
    beam's second moment (up to the centre disc's share, below 1/(15 n)).

    Returns
    -------
    radius : (n,) float
    angle : (n,) float, radians
    """
    if n_subrays not in _RING_COUNTS:
        raise InputError(f"n_subrays={n_subrays!r} must be one of {sorted(_RING_COUNTS)}")
    radius, angle = [0.0], [0.0]
    done = 1
    for ring, m in enumerate(_RING_COUNTS[n_subrays]):
        p0, p1 = done / n_subrays, (done + m) / n_subrays
        a = -0.5 * np.log(1.0 - p0)
        if p1 >= 1.0:
            mean_s = a + 0.5
        else:
            b = -0.5 * np.log(1.0 - p1)
            ea, eb = np.exp(-2 * a), np.exp(-2 * b)
            mean_s = (a * ea - b * eb) / (ea - eb) + 0.5
        radius += [np.sqrt(mean_s)] * m
        angle += list(2 * np.pi * np.arange(m) / m + (np.pi / m) * (ring % 2))
        done += m
    return np.array(radius), np.array(angle)


def scan_window(points_world, pose: np.ndarray, preset: ScannerPreset) -> AngularGrid:
    """The angular grid (scanner frame) that covers ``points_world`` plus the margin."""
    r = pose[:3, :3]
    local = (np.asarray(points_world, float) - pose[:3, 3]) @ r
    rng_xy = np.hypot(local[:, 0], local[:, 1])
    zen = np.degrees(np.arctan2(rng_xy, local[:, 2]))
    az = np.degrees(np.arctan2(local[:, 1], local[:, 0]))
    m = preset.window_margin_deg
    zmin, zmax = max(zen.min() - m, 0.0), min(zen.max() + m, 180.0)
    # azimuths relative to the centre direction; full circle if the points surround the scanner
    c = np.degrees(np.arctan2(local[:, 1].mean(), local[:, 0].mean()))
    rel = (az - c + 180.0) % 360.0 - 180.0
    if rel.max() - rel.min() > 300.0:
        a0, span = 0.0, 360.0 - preset.azimuth_step_deg
    else:
        a0, span = c + rel.min() - m, rel.max() - rel.min() + 2 * m
    n_z = int(np.floor((zmax - zmin) / preset.zenith_step_deg)) + 1
    n_a = int(np.floor(span / preset.azimuth_step_deg)) + 1
    return AngularGrid(zmin, preset.zenith_step_deg, n_z, a0, preset.azimuth_step_deg, n_a)


def _window_points(tree) -> np.ndarray:
    lo, hi = tree.bounds(vegetation_only=True)
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    if getattr(tree, "ground_z", None) is not None:
        corners[:, 2] = np.where(corners[:, 2] == lo[2], min(lo[2], tree.ground_z), corners[:, 2])
    extra = np.asarray(getattr(tree, "targets", np.zeros((0, 3))))
    return np.concatenate([corners, extra]) if len(extra) else corners


def simulate_scan(tree, *, pose: ScanPose | np.ndarray, preset: ScannerPreset | None = None,
                  seed: int = 0, window: AngularGrid | None = None,
                  optics: dict | None = None, scan_id: int = 0, name: str | None = None,
                  chunk_pulses: int = 100_000, progress: bool = True) -> Scan:
    """Scan a mesh (a :class:`~tlsvox.truth.synthetic.SyntheticTree`) from one position.

    Parameters
    ----------
    tree : SyntheticTree
        Mesh with a material per triangle.
    pose : ScanPose or (4, 4) array
        True world-from-scanner pose.
    preset : ScannerPreset, optional
        Instrument (default: RIEGL VZ-400).
    seed : int
        Seeds the ring rotations, range noise and reflectance noise.
    window : AngularGrid, optional
        Angular grid in the scanner frame; default: the tree's bounding box and
        targets plus the preset's margin.
    optics : dict, optional
        ``{Material: Optics}``; default: tabulated values at the wavelength.

    Returns
    -------
    Scan
        Echoes in the scanner frame with ``reflectance_db``, ``truth_material``,
        ``beam_fraction``, ``pulse_id``, return numbers, ``pose_true`` and the
        full pulse table.
    """
    import open3d as o3d
    from tqdm.auto import tqdm

    preset = preset or ScannerPreset.riegl_vz400()
    pose_m = pose.matrix() if isinstance(pose, ScanPose) else np.asarray(pose, dtype=float)
    if pose_m.shape != (4, 4):
        raise InputError(f"pose must be a ScanPose or a 4x4 matrix, got shape {pose_m.shape}")
    if len(tree.triangles) == 0:
        raise InputError("the tree is empty (no triangles): nothing to scan; build it with make_tree()")
    position = pose_m[:3, 3]
    if hasattr(tree, "point_inside_wood") and tree.point_inside_wood(position):
        raise InputError(f"scanner position {position.round(3).tolist()} lies inside a trunk or branch; "
                         "move the scanner out of the wood")
    if getattr(tree, "ground_z", None) is not None and position[2] <= tree.ground_z:
        raise InputError(f"scanner position z={position[2]:.3f} m is at or below the ground "
                         f"(z={tree.ground_z}); raise it (instrument height ~1.7 m)")
    table = optics or optics_for(preset.wavelength_nm)
    for mat, o in table.items():
        if not isinstance(o, Optics):
            raise InputError(f"optics[{mat!r}] must be an Optics(reflectance, transmittance)")
    grid = window or scan_window(_window_points(tree), pose_m, preset)
    rng = np.random.default_rng(seed)

    # material properties per triangle
    n_mat = int(max(Material)) + 1
    rho = np.zeros(n_mat)
    retro = np.ones(n_mat)
    for mat, o in table.items():
        rho[int(mat)] = o.reflectance
        retro[int(mat)] = o.retro_gain
    tri_mat = np.asarray(tree.material, dtype=np.int64)

    scene = tree.raycasting_scene()

    zen, az = grid.angles()
    d_scan = directions_from_angles(zen, az)
    rot = pose_m[:3, :3]
    sub_r, sub_a = subray_pattern(preset.n_subrays)
    k = len(sub_r)
    n_p = len(d_scan)
    n_echo = np.zeros(n_p, np.uint8)
    out = {key: [] for key in ("range", "refl", "mat", "pulse", "rank", "count", "fraction")}

    bar = tqdm(total=n_p, desc=f"scan {name or scan_id}", unit="pulse", unit_scale=True,
               disable=not progress, leave=False)
    for start in range(0, n_p, chunk_pulses):
        sl = slice(start, min(start + chunk_pulses, n_p))
        d_w = d_scan[sl] @ rot.T
        m = len(d_w)
        helper = np.where(np.abs(d_w[:, 2:3]) < 0.9, [[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]])
        u = np.cross(d_w, helper)
        u /= np.linalg.norm(u, axis=1, keepdims=True)
        v = np.cross(d_w, u)
        spin = rng.uniform(0, 2 * np.pi, m)
        ang = sub_a[None, :] + spin[:, None]
        off = (sub_r[None, :, None] * (np.cos(ang)[:, :, None] * u[:, None, :]
                                        + np.sin(ang)[:, :, None] * v[:, None, :]))  # (m, k, 3)
        org = position[None, None, :] + preset.beam_radius_exit * off
        dirs = d_w[:, None, :] + preset.half_divergence * off
        dirs /= np.linalg.norm(dirs, axis=2, keepdims=True)
        rays = np.concatenate([org, dirs], axis=2).reshape(-1, 6).astype(np.float32)
        hit = scene.cast_rays(o3d.core.Tensor(rays))
        t = hit["t_hit"].numpy().reshape(m, k).astype(np.float64)
        prim = hit["primitive_ids"].numpy().reshape(m, k).astype(np.int64)
        nrm = hit["primitive_normals"].numpy().reshape(m, k, 3).astype(np.float64)
        valid = np.isfinite(t) & (t >= preset.min_range_m) & (t <= preset.max_range_m)
        prim_safe = np.where(valid, prim, 0)
        mat = np.where(valid, tri_mat[prim_safe], 0)
        cosi = np.abs(np.einsum("mkc,mkc->mk", nrm, dirs))
        power = np.where(retro[mat] > 1.0, rho[mat] * retro[mat], rho[mat] * cosi) / k
        power = np.where(valid, power, 0.0)
        t = np.where(valid, t, np.inf)
        _merge_echoes(t, power, mat, valid, start, preset, rng, out, n_echo)
        bar.update(m)
    bar.close()

    ranges = np.concatenate(out["range"]) if out["range"] else np.zeros(0)
    pulse = np.concatenate(out["pulse"]) if out["pulse"] else np.zeros(0, np.int64)
    xyz = d_scan[pulse] * ranges[:, None]
    pulses = PulseTable(direction=d_scan, n_echoes=n_echo, origin=np.zeros(3), grid=grid)

    def cat(key, dt):
        return np.concatenate(out[key]).astype(dt) if out[key] else np.zeros(0, dt)

    return Scan(
        xyz=xyz, reflectance_db=cat("refl", np.float32), return_number=cat("rank", np.uint8),
        number_of_returns=cat("count", np.uint8), pulse_id=pulse, truth_material=cat("mat", np.uint8),
        beam_fraction=cat("fraction", np.float32),
        pose=None, pose_true=pose_m, pulses=pulses, scan_id=scan_id, name=name or f"scan{scan_id}",
        meta={"preset": asdict(preset), "seed": int(seed), "simulated": True},
    )


def _merge_echoes(t, power, mat, valid, pulse0, preset, rng, out, n_echo):
    """Group sub-ray hits of each pulse into echoes (vectorised over pulses)."""
    m, k = t.shape
    order = np.argsort(t, axis=1)
    t = np.take_along_axis(t, order, 1)
    power = np.take_along_axis(power, order, 1)
    mat = np.take_along_axis(mat, order, 1)
    valid = np.take_along_axis(valid, order, 1)
    gap = np.ones_like(valid)
    with np.errstate(invalid="ignore"):  # inf - inf between two misses
        gap[:, 1:] = (t[:, 1:] - t[:, :-1]) > preset.range_resolution_m
    # with t sorted, each new group starts where the gap to the previous hit is large
    new = valid & gap
    gid_local = np.cumsum(new, axis=1) - 1  # group index within the pulse
    rows, cols = np.nonzero(valid)
    if not len(rows):
        return
    gid = rows * k + gid_local[rows, cols]
    uniq, inv = np.unique(gid, return_inverse=True)
    p = power[rows, cols]
    ptot = np.bincount(inv, weights=p)
    share = np.bincount(inv, minlength=len(uniq)) / k  # equal-power sub-rays: the beam share intercepted
    keep_power = ptot > 0
    rng_w = np.bincount(inv, weights=p * t[rows, cols]) / np.where(keep_power, ptot, 1.0)
    # truth material: that of the strongest contributing sub-ray
    best = np.full(len(uniq), -1.0)
    best_mat = np.zeros(len(uniq), np.int64)
    order_p = np.argsort(p)
    best[inv[order_p]] = p[order_p]
    best_mat[inv[order_p]] = mat[rows, cols][order_p]
    refl_db = 10.0 * np.log10(np.maximum(ptot, 1e-30))
    if preset.reflectance_noise_db > 0:
        refl_db = refl_db + rng.normal(0.0, preset.reflectance_noise_db, len(uniq))
    rng_noisy = rng_w + (rng.normal(0.0, preset.range_noise_m, len(uniq)) if preset.range_noise_m > 0 else 0.0)
    detected = keep_power & (refl_db >= preset.min_reflectance_db)
    pulse_local = uniq // k
    pl, rg, rf, bm = pulse_local[detected], rng_noisy[detected], refl_db[detected], best_mat[detected]
    fr = share[detected]
    counts = np.bincount(pl, minlength=m)
    # rank within pulse: groups come sorted by (pulse, range) since gid is ordered by range
    first = np.concatenate([[0], np.cumsum(counts)[:-1]])
    rank = np.arange(len(pl)) - first[pl] + 1
    n_echo[pulse0:pulse0 + m] = np.minimum(counts, 255)
    out["range"].append(rg)
    out["refl"].append(rf)
    out["mat"].append(bm)
    out["pulse"].append(pl.astype(np.int64) + pulse0)
    out["rank"].append(rank)
    out["count"].append(counts[pl])
    out["fraction"].append(fr)

