r"""The scanner's detection threshold: leaf hits too weak to be recorded, and their correction.

A scanner records an echo only when its apparent reflectance reaches a
threshold (the RIEGL VZ-400: -20 dB, 0.01 of a white Lambertian target).  A
beam of ``n`` equal-power parts that meets a leaf of reflectance ``rho`` at
incidence cosine ``mu`` with ``j`` of its parts returns ``j rho mu / n``: a
leaf seen nearly edge-on, which a beam can only graze, goes unrecorded.  The
share of the beam it stopped then counts as travelling on, so every voxel
behind it sees free path that never was, and LAD comes out low (on the
synthetic oak the unrecorded 1.1 % of the recorded leaf weight costs about 16
points of leaf area in the seen voxels, -3.7 % against -20.2 %:
``docs/bench/lad_terms.md``).

The model (``voxelize(undetected="model")``)
-----------------------------------------------
1. **Missed share** ``q(mu, w)``: of the beam parts that hit a leaf of
   incidence cosine ``mu``, the share in echoes under the threshold, for a
   beam of 1/e^2 radius ``w``.  Leaves are ellipses of the given length and
   width placed at random across the beam (uniform offset, uniform rotation
   in their plane); the beam is the scan's sub-ray pattern
   (:func:`tlsvox.truth.scanner.subray_pattern`), so ``j`` parts hit; the
   echo's reflectance ``j rho mu / n`` carries Gaussian noise of
   ``noise_db``; ``q`` is the ``j``-weighted probability of falling under the
   threshold (a seeded Monte Carlo over placements, :func:`missed_share`).
2. **Unrecorded projection** ``H``: a beam of direction ``d`` crossing leaf
   area density ``u`` is intercepted at rate ``G u`` per metre, of which
   ``H u`` goes unrecorded, with

   .. math:: H(d, w) = \mathrm{E}_{n}\left[\,|n \cdot d|\; q(|n \cdot d|, w)\right]

   over the leaf normals ``n`` of the leaf angle model (uniform azimuth, or
   facing outward from the crown axis), next to
   :math:`G(d) = \mathrm{E}_n |n \cdot d|`.
3. **Where the unrecorded share went**: the part ``T`` of a pulse that no
   echo took (its *tail*) either left the grid or stopped, unrecorded, on a
   leaf.  Along the beam, with optical depth
   :math:`\tau(s) = \int_0^s G u\,ds'` over the grid and :math:`\tau_\infty`
   at its exit, the posterior density of the stop is

   .. math:: p(s) = \frac{H u(s)\, e^{-\tau(s)}\, [s \notin E]}{e^{-\tau_\infty} + \int_0^\infty H u\, e^{-\tau}\,[s' \notin E]\,ds'}

   (the numerator: reaching ``s`` and stopping there unrecorded; the
   denominator: not being recorded at all), ``E`` the stretches within the
   range resolution of a recorded echo of the same pulse, where an
   unrecorded hit would have merged into that echo and been recorded.  A
   pulse with no recorded echo went through a gap with all its parts
   together, so its parts' survival is not ``e^-tau``: its loss is
   ``T min(1, int H u ds)``, spread as ``H u``.  The expected unrecorded stop
   is given back to the beam as ``K`` leaf echoes at the quantiles of ``p``
   (:func:`unrecorded_echoes`), so the estimators count it as interception
   where it happened and no longer as free path behind.
4. The LAD this needs comes from the estimate itself: the first pass without
   the correction, then ``iterations`` passes, each from the previous
   estimate (:func:`tlsvox.voxel.stages.voxelize`), in which a voxel entered
   by less than ``n_min`` pulses' worth of beam weight counts as occluded
   (what reaches it is the leftover of tails, which made it look seen).

The marginal share of the interception lost (what a scan with every echo
kept would show) is ``H / G`` thinned by merging: another part of the pulse
meeting a leaf within the range resolution behind makes the echo recorded,
at rate ``G_any u`` with ``G_any`` the projection for "any part of the beam"
(``spread`` of :func:`missed_share`); the tests compare that with the
scanner.

What the model leaves out: a tail part that would have met wood or the
ground would have been recorded there (so it did not leave the grid); lost
wood and ground echoes; leaf transmittance and non-Lambertian leaves;
clumping inside a voxel (``tau`` takes the voxel's LAD as random foliage).

Examples
--------
>>> m = DetectionModel(threshold_db=-20.0, n_subrays=7, exit_radius=0.0035, half_divergence=1.75e-4,
...                    noise_db=0.0, leaf_reflectance=0.267)
>>> q, spread = missed_share(m, [0.05, 0.9], [0.005])
>>> bool(q[0, 0] > 0.5), float(q[1, 0])      # grazing hits are mostly lost, face-on ones never
(True, 0.0)
"""

from __future__ import annotations

import functools
from dataclasses import asdict, dataclass

import numpy as np

from tlsvox.errors import InputError
from tlsvox.voxel.beams import Beams, EchoKind
from tlsvox.voxel.grid import ray_box
from voxlidar.choices import Choice

__all__ = ["DetectionModel", "Undetected", "missed_share", "projection_tables", "unrecorded_echoes"]

#: leaf echoes given back per pulse tail (at the quantiles of where the unrecorded stop lies)
ECHOES_PER_TAIL = 4
#: samples along the beams walked at once by :func:`unrecorded_echoes` (its working memory)
CHUNK_SAMPLES = 4_000_000
#: beam-part positions tried per (mu, w) cell of the missed-share table
PLACEMENTS = 6000


class Undetected(str, Choice):
    """What the estimators do about leaf hits under the scanner's detection threshold."""

    IGNORE = "ignore"  #: nothing: an unrecorded hit counts as beam travelling on (biased low)
    MODEL = "model"  #: give the expected unrecorded interception back (see the module docstring)


@dataclass(frozen=True)
class DetectionModel:
    """What decides whether a leaf hit is recorded.

    Parameters
    ----------
    threshold_db : float
        Smallest apparent reflectance recorded, dB of a white Lambertian target.
    n_subrays : int
        Equal-power parts of the beam (the scan's sub-rays; 7 for tlsvox's VZ-400).
    exit_radius : float, metres
        1/e^2 beam radius at the scanner.
    half_divergence : float, radians
        Growth of the radius per metre of range.
    noise_db : float
        Standard deviation of the recorded reflectance, dB.
    leaf_reflectance : float
        Reflectance of a leaf at normal incidence (linear).
    leaf_length, leaf_width : float, metres
        The leaves' ellipse (default: the synthetic oak's 5 x 2.5 cm).
    range_resolution : float, metres
        Hits of one pulse closer than this merge into one echo (their powers add).
    source : str
        Where the numbers came from (stated in the output).
    """

    threshold_db: float
    n_subrays: int
    exit_radius: float
    half_divergence: float
    noise_db: float
    leaf_reflectance: float
    leaf_length: float = 0.05
    leaf_width: float = 0.025
    range_resolution: float = 0.5
    source: str = "given"

    def __post_init__(self):
        from tlsvox.truth.scanner import _RING_COUNTS

        if not np.isfinite(self.threshold_db):
            raise InputError(f"detection threshold_db={self.threshold_db!r} must be a finite number of dB "
                             "(the RIEGL VZ-400: -20)")
        if self.n_subrays not in _RING_COUNTS:
            raise InputError(f"n_subrays={self.n_subrays!r} must be one of {sorted(_RING_COUNTS)}")
        for name in ("exit_radius", "half_divergence", "noise_db", "range_resolution"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v >= 0):
                raise InputError(f"{name}={v!r} must be a finite number >= 0")
        for name in ("leaf_reflectance", "leaf_length", "leaf_width"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise InputError(f"{name}={v!r} must be a finite number > 0 (leaf size in metres, "
                                 "reflectance linear)")

    @classmethod
    def for_scan(cls, scan, *, threshold_db: float | None = None, leaf_reflectance: float | None = None,
                 leaf_length: float = 0.05, leaf_width: float = 0.025) -> DetectionModel:
        """The model of the instrument that made ``scan`` (its preset in ``scan.meta``), with overrides.

        What the scan's preset does not state (all of it, when the scan
        states none) comes from the RIEGL VZ-400 preset
        (:meth:`tlsvox.truth.scanner.ScannerPreset.riegl_vz400`), but the
        detection threshold: raises :class:`InputError` when the scan does not
        state it and none is given.
        """
        from tlsvox.truth.scanner import ScannerPreset
        from tlsvox.voxel.weights import NominalReflectance

        stated = dict(scan.meta.get("preset") or {})
        thr = threshold_db if threshold_db is not None else stated.get("min_reflectance_db")
        if thr is None:
            raise InputError(f"undetected='model': scan {scan.name!r} does not state its detection threshold; "
                             "give detection_threshold_db= (CLI --detection-threshold-db), e.g. -20 for the "
                             "RIEGL VZ-400, or use undetected='ignore'")
        vz400 = ScannerPreset.riegl_vz400()
        known = {k: v for k, v in stated.items() if k in asdict(vz400)}
        preset = ScannerPreset(**{**asdict(vz400), **known})
        nominal = NominalReflectance.for_scan(scan, leaf_reflectance, None)
        missing = [k for k in ("n_subrays", "beam_exit_diameter_m", "divergence_mrad", "reflectance_noise_db",
                               "range_resolution_m") if k not in known]
        src = ("the scan's preset" if not missing else
               "the RIEGL VZ-400 preset (the scan states none)" if not known else
               f"the scan's preset, with {', '.join(missing)} of the RIEGL VZ-400")
        return cls(threshold_db=float(thr), n_subrays=preset.n_subrays, exit_radius=preset.beam_radius_exit,
                   half_divergence=preset.half_divergence, noise_db=preset.reflectance_noise_db,
                   leaf_reflectance=float(nominal.leaf), leaf_length=float(leaf_length),
                   leaf_width=float(leaf_width), range_resolution=preset.range_resolution_m,
                   source=f"{src}; leaf reflectance {nominal.leaf:g} ({nominal.source})")

    def beam_radius(self, range_m):
        """1/e^2 beam radius (m) at a range."""
        return self.exit_radius + self.half_divergence * np.asarray(range_m, dtype=np.float64)

    def to_dict(self) -> dict:
        return asdict(self)


def _undetected_probability(model: DetectionModel, j, mu):
    """P(an echo of j beam parts on a leaf at incidence cosine mu reads under the threshold)."""
    from scipy.special import ndtr

    power = np.asarray(j, dtype=np.float64) * model.leaf_reflectance * np.asarray(mu, dtype=np.float64) \
        / model.n_subrays
    db = 10.0 * np.log10(np.maximum(power, 1e-30))
    if model.noise_db > 0:
        return ndtr((model.threshold_db - db) / model.noise_db)
    return (db < model.threshold_db).astype(np.float64)


def missed_share(model: DetectionModel, mu, w, *, placements: int = PLACEMENTS, seed: int = 0) -> np.ndarray:
    """q(mu, w): share of the beam parts hitting a leaf at incidence cosine mu that go unrecorded.

    Parameters
    ----------
    model : DetectionModel
    mu : (M,) float in [0, 1]
    w : (W,) float, metres
        1/e^2 beam radius.
    placements : int
        Random leaf placements per cell (offset, rotation in the leaf plane,
        rotation of the beam pattern); the same ``seed`` gives the same table.

    Returns
    -------
    q : (M, W) float64 in [0, 1]
    spread : (M, W) float64, >= 1
        The chance that at least one beam part meets a leaf over the expected
        share of the beam it intercepts: how much wider a leaf looks to "any
        part of the beam" than to the beam's power (merging, see the module
        docstring).
    """
    from tlsvox.truth.scanner import subray_pattern

    mu = np.clip(np.asarray(mu, dtype=np.float64).reshape(-1), 0.0, 1.0)
    w = np.asarray(w, dtype=np.float64).reshape(-1)
    radius, angle = subray_pattern(model.n_subrays)
    a, b = 0.5 * model.leaf_length, 0.5 * model.leaf_width
    rng = np.random.default_rng(seed)
    # the same placements for every cell (common random numbers: a smooth table)
    psi = rng.uniform(0.0, 2 * np.pi, placements)
    spin = rng.uniform(0.0, 2 * np.pi, placements)
    ux, uy = rng.uniform(-1.0, 1.0, (2, placements))
    cp, sp = np.cos(psi), np.sin(psi)
    out = np.zeros((len(mu), len(w)))
    spread = np.ones((len(mu), len(w)))
    for k, wk in enumerate(w):
        px = wk * radius[None, :] * np.cos(angle[None, :] + spin[:, None])  # (P, n): beam parts
        py = wk * radius[None, :] * np.sin(angle[None, :] + spin[:, None])
        reach = wk * radius.max()
        for i, m in enumerate(mu):
            if m <= 0.0:
                out[i, k] = 1.0
                spread[i, k] = np.nan
                continue
            # the leaf's projection: its tilt direction shrinks by mu
            ex = m * np.sqrt(a * a * cp * cp + b * b * sp * sp) + reach
            ey = np.sqrt(a * a * sp * sp + b * b * cp * cp) + reach
            cx, cy = ux * ex, uy * ey
            x = (px - cx[:, None]) / m  # back in the leaf plane
            y = py - cy[:, None]
            xa = x * cp[:, None] + y * sp[:, None]
            yb = -x * sp[:, None] + y * cp[:, None]
            inside = (xa / a) ** 2 + (yb / b) ** 2 <= 1.0
            j = inside.sum(axis=1)
            # each placement stands for an area ex * ey of offsets
            weight = j * ex * ey
            total = weight.sum()
            if total <= 0:
                out[i, k] = float(_undetected_probability(model, 1, m))
                continue
            out[i, k] = float((weight * _undetected_probability(model, j, m)).sum() / total)
            spread[i, k] = float(((j > 0) * ex * ey).sum() * model.n_subrays / total)
    # edge-on: the limit of the last finite cells
    for k in range(len(w)):
        bad = ~np.isfinite(spread[:, k])
        if bad.any():
            spread[bad, k] = spread[~bad, k][0] if (~bad).any() else 1.0
    return out, spread


@functools.lru_cache(maxsize=16)
def _missed_table(model: DetectionModel, w_lo: float, w_hi: float, n_w: int, seed: int = 0):
    mu = np.concatenate([np.linspace(0.0, 0.5, 101), np.linspace(0.5, 1.0, 26)[1:]])
    w = np.linspace(w_lo, w_hi, n_w) if n_w > 1 else np.array([w_lo])
    q, spread = missed_share(model, mu, w, seed=seed)
    return mu, w, q, spread


def projection_tables(model: DetectionModel, leaf_angle, *, ranges, outward: bool = False,
                      n_theta: int = 91, n_c: int = 33, n_w: int = 6, nodes: int = 512, seed: int = 0):
    """H, the unrecorded projection, tabulated for the beams of one scan.

    Parameters
    ----------
    model : DetectionModel
    leaf_angle : LeafAngle
    ranges : (2,) float, metres
        Smallest and largest range where the scan's beams cross the grid.
    outward : bool
        Leaves facing outward from the crown axis (as
        :func:`tlsvox.voxel.pulses.outward_g_table`): the table has a second
        axis, the cosine c between the beam's horizontal direction and the
        outward direction; else leaves of uniform azimuth (``n_c`` = 1).
    seed : int
        Seed of the placements of :func:`missed_share`.

    Returns
    -------
    h : (n_theta, n_c, n_w) float64
        H over beam zenith [0, pi] x c in [-1, 1] (or one column) x beam radius.
    g_any : (n_theta, n_c, n_w) float64
        The same average of ``|n.d| spread`` (:func:`missed_share`): the
        projection for "any part of the beam meets a leaf", >= G.  The walk
        (:func:`unrecorded_echoes`) needs only ``h``; ``g_any`` gives the
        marginal lost share thinned by merging, which the tests compare with
        the scanner (the module docstring; about half of this function's
        0.1 s per call).
    w : (n_w,) float64
        The beam radii of the last axis, metres.
    """
    from voxlidar.leaf_orientation import LeafAngle

    la = LeafAngle.from_dict(leaf_angle)
    lo, hi = (float(v) for v in ranges)
    w_lo, w_hi = float(model.beam_radius(max(lo, 0.0))), float(model.beam_radius(max(hi, lo)))
    # one radius node where the radii do not differ (a zero divergence, or one range)
    mu_nodes, w, q, spread = _missed_table(model, w_lo, w_hi, n_w if w_hi > w_lo else 1, int(seed))
    tl = np.asarray(la.ppf((np.arange(nodes) + 0.5) / nodes), dtype=np.float64)
    theta = np.linspace(0.0, np.pi, n_theta)
    sin_l, cos_l = np.sin(tl), np.cos(tl)
    cols = n_c if outward else 1
    h_tab = np.empty((n_theta, cols, len(w)))
    s_tab = np.empty((n_theta, cols, len(w)))
    phi = np.cos(2 * np.pi * (np.arange(64) + 0.5) / 64)
    c = np.linspace(-1.0, 1.0, n_c)
    for i, th in enumerate(theta):
        if outward:
            mu = np.abs(np.outer(c * np.sin(th), sin_l) + np.cos(th) * cos_l)  # (n_c, nodes)
        else:
            mu = np.abs(np.sin(th) * np.outer(phi, sin_l) + np.cos(th) * cos_l[None, :]).reshape(1, -1)
        for k in range(len(w)):
            h_tab[i, :, k] = (mu * np.interp(mu, mu_nodes, q[:, k])).mean(axis=1)
            s_tab[i, :, k] = (mu * np.interp(mu, mu_nodes, spread[:, k])).mean(axis=1)
    return h_tab, s_tab, w


def _bilinear_g(table, theta, c):
    """G of outward leaves from :func:`tlsvox.voxel.pulses.outward_g_table`, as the tracer reads it
    (:func:`_interp_h` on the table with one radius)."""
    return np.maximum(_interp_h(table[:, :, None], np.zeros(1), theta, c, np.zeros(np.shape(theta))), 1e-6)


def _interp_h(h, w_nodes, theta, c, w):
    """H at (theta, c, w), linear in each axis (c ignored for a one-column table)."""
    nt, nc, nw = h.shape
    u = np.clip(theta / np.pi, 0.0, 1.0) * (nt - 1)
    ti = np.minimum(np.floor(u).astype(np.int64), nt - 2)
    tf = u - ti
    if nc > 1:
        v = (np.clip(c, -1.0, 1.0) + 1.0) * 0.5 * (nc - 1)
        ci = np.minimum(np.floor(v).astype(np.int64), nc - 2)
        cf = v - ci
    else:
        ci = np.zeros(np.shape(theta), np.int64)
        cf = np.zeros(np.shape(theta))
    if nw > 1 and w_nodes[-1] > w_nodes[0]:
        x = np.clip((w - w_nodes[0]) / (w_nodes[-1] - w_nodes[0]), 0.0, 1.0) * (nw - 1)
        wi = np.minimum(np.floor(x).astype(np.int64), nw - 2)
        wf = x - wi
    else:
        wi = np.zeros(np.shape(theta), np.int64)
        wf = np.zeros(np.shape(theta))
    out = 0.0
    for dt, ft in ((0, 1 - tf), (1, tf)):
        for dc, fc in ((0, 1 - cf), (min(1, nc - 1), cf)):
            for dw, fw in ((0, 1 - wf), (min(1, nw - 1), wf)):
                out = out + ft * fc * fw * h[ti + dt, ci + dc, wi + dw]
    return out


def unrecorded_echoes(beams, grid, lad_of, model: DetectionModel, leaf_angle, *, outward=None, box=None,
                      echoes_per_tail: int = ECHOES_PER_TAIL, step: float | None = None,
                      chunk_samples: int = CHUNK_SAMPLES):
    """The beams with the expected unrecorded leaf interception given back as leaf echoes.

    Parameters
    ----------
    beams : Beams
        One scan's beams (world frame, ``g`` = G(theta) per beam).
    grid : VoxelGrid
    lad_of : callable
        ``lad_of(flat_index) -> LAD`` (m2/m3, 0 where none) for voxels of ``grid``.
    model : DetectionModel
    leaf_angle : LeafAngle
    outward : (G table, crown centre (x, y)), optional
        Outward-facing leaves, as given to the tracer.
    echoes_per_tail : int
        Leaf echoes each pulse's unrecorded share is split into.
    box : (2, 3) float, metres, optional
        Where the LAD is above 0 (default the grid): beams are followed inside it.
    step : float, metres
        Sampling step along the beams (default one voxel size; each sample
        stands for its stretch of the beam).

    Returns
    -------
    beams : Beams
        New beams: the tails lessened, the given-back echoes added (LEAF).
    info : dict
        ``given_back`` (beam weight given back as leaf echoes), ``tail``
        (the tails' weight before), ``pulses`` (pulses that gave some back),
        ``added`` (the given-back echoes: pulse indices into ``beams`` and ranges).
    """

    h = float(grid.voxel_size)
    ds = h if step is None else float(step)
    lo, hi = np.asarray(grid.lower, float), np.asarray(grid.upper, float)
    b_lo, b_hi = (lo, hi) if box is None else (np.maximum(np.asarray(box[0], float), lo),
                                              np.minimum(np.asarray(box[1], float), hi))
    origin = np.asarray(beams.origin, dtype=np.float64)
    d = beams.direction
    t0, t1 = ray_box(origin, d, b_lo, b_hi)
    t1 = np.minimum(t1, beams.max_range)
    t0 = np.maximum(t0, 0.0)
    todo = np.flatnonzero((beams.tail > 1e-9) & (t1 > t0))
    none = (np.zeros(0, np.int64), np.zeros(0))
    if not len(todo):
        return beams, {"given_back": 0.0, "tail": float(beams.tail.sum()), "pulses": 0, "added": none}
    htab, _, w_nodes = projection_tables(model, leaf_angle, ranges=(float(t0[todo].min()), float(t1[todo].max())),
                                      outward=outward is not None)
    theta_all = beams.zenith()
    given = np.zeros(len(beams))
    new_r, new_b = [], []
    n_steps = np.ceil((t1[todo] - t0[todo]) / ds).astype(np.int64)
    bounds = np.searchsorted(np.cumsum(n_steps), np.arange(1, int(n_steps.sum() // chunk_samples) + 2)
                             * chunk_samples)
    start = 0
    for stop in list(bounds) + [len(todo)]:
        stop = min(int(stop), len(todo))
        if stop <= start:
            continue
        sel = todo[start:stop]
        ns = n_steps[start:stop]
        m = int(ns.max())
        k = np.arange(m)[None, :]
        valid = k < ns[:, None]
        dsb = (t1[sel] - t0[sel]) / ns  # per-beam step
        t = t0[sel][:, None] + (k + 0.5) * dsb[:, None]
        # voxel of each sample (float32 is exact enough for the index: the grid is far below 2^24 voxels)
        rel = ((origin[sel] - lo) / h).astype(np.float32)
        dv = (d[sel] / h).astype(np.float32)
        ijk = np.empty(t.shape + (3,), np.int32)
        inside = valid.copy()
        tt = t.astype(np.float32)
        for a in range(3):
            ia = np.floor(rel[:, a:a + 1] + dv[:, a:a + 1] * tt).astype(np.int32)
            inside &= (ia >= 0) & (ia < grid.shape[a])
            ijk[..., a] = ia
        u = np.zeros(t.shape)
        u[inside] = lad_of(grid.flat(ijk[inside]))
        busy = (u > 0).any(axis=1)
        if not busy.any():
            start = stop
            continue
        # only the beams that meet leaves, and only their samples in leafy voxels, need G and H
        sel, ns, dsb, t, u, ijk = sel[busy], ns[busy], dsb[busy], t[busy], u[busy], ijk[busy]
        m = int(ns.max())
        k = k[:, :m]
        t, u, ijk = t[:, :m], u[:, :m], ijk[:, :m]
        sel_r, sel_c = np.nonzero(u > 0)
        theta = theta_all[sel][sel_r]
        tv = t[sel_r, sel_c]
        if outward is not None:
            gtab, cc = outward
            centre = grid.centers(ijk[sel_r, sel_c])[:, :2]
            rx, ry = centre[:, 0] - cc[0], centre[:, 1] - cc[1]
            rr = np.hypot(rx, ry)
            dx, dy = d[sel, 0][sel_r], d[sel, 1][sel_r]
            dh = np.hypot(dx, dy)
            ok = (rr > 1e-9) & (dh > 1e-9)
            c = np.where(ok, (rx * dx + ry * dy) / np.maximum(rr * dh, 1e-12), 0.0)
            gv = np.where(ok, _bilinear_g(gtab, theta, c), beams.g[sel][sel_r])
        else:
            c = np.zeros(len(theta))
            gv = beams.g[sel][sel_r]
        wb = model.beam_radius(tv)
        g = np.zeros(t.shape)
        hh = np.zeros(t.shape)
        g[sel_r, sel_c] = gv
        hh[sel_r, sel_c] = np.minimum(_interp_h(htab, w_nodes, theta, c, wb), gv)
        kappa = g * u * dsb[:, None]
        tau = np.cumsum(kappa, axis=1) - 0.5 * kappa
        lost = hh * u * dsb[:, None] * np.exp(-tau)
        n_e = beams.echo_start[sel + 1] - beams.echo_start[sel]
        # an unrecorded hit within the range resolution of a recorded echo of the same pulse would
        # have merged into it: none there
        if n_e.sum():
            row = np.repeat(np.arange(len(sel)), n_e)
            e_idx = np.repeat(beams.echo_start[sel], n_e) + np.arange(n_e.sum()) - np.repeat(np.cumsum(n_e) - n_e, n_e)
            r_e = beams.echo_range[e_idx]
            first = np.clip(np.ceil((r_e - model.range_resolution - t0[sel][row]) / dsb[row] - 0.5), 0, m)
            last = np.clip(np.floor((r_e + model.range_resolution - t0[sel][row]) / dsb[row] - 0.5) + 1, 0, m)
            mark = np.zeros((len(sel), m + 1), np.int32)
            np.add.at(mark, (row, first.astype(np.int64)), 1)
            np.add.at(mark, (row, last.astype(np.int64)), -1)
            lost = np.where(np.cumsum(mark, axis=1)[:, :m] > 0, 0.0, lost)
        lost_total = lost.sum(axis=1)
        z = np.exp(-kappa.sum(axis=1)) + lost_total
        share = np.where(z > 0, lost_total / np.maximum(z, 1e-300), 0.0)
        # a pulse with no recorded echo went through a gap: its parts travelled together, so one
        # part's survival is no longer e^-tau but (nearly) certain, and what it lost is what the
        # rest of the beam grazed on the way: H u along the whole path
        empty = n_e == 0
        if empty.any():
            flat_lost = hh[empty] * u[empty] * dsb[empty][:, None]
            lost[empty] = flat_lost
            share[empty] = np.minimum(flat_lost.sum(axis=1), 1.0)
        amount = beams.tail[sel] * np.clip(share, 0.0, 1.0)
        keep = amount > 1e-9
        if np.any(keep):
            cdf = np.cumsum(lost[keep], axis=1)
            cdf /= cdf[:, -1:]
            qs = (np.arange(echoes_per_tail) + 0.5) / echoes_per_tail
            idx = (cdf[:, :, None] < qs[None, None, :]).sum(axis=1)  # (K_beams, echoes)
            idx = np.minimum(idx, ns[keep][:, None] - 1)
            rows = np.arange(int(keep.sum()))[:, None]
            new_r.append(t[keep][rows, idx].reshape(-1))
            new_b.append(np.repeat(sel[keep], echoes_per_tail))
            given[sel[keep]] = amount[keep]
        start = stop
    tail_before = float(beams.tail.sum())
    info = {"given_back": float(given.sum()), "tail": tail_before, "pulses": int(np.count_nonzero(given)),
            "added": none}
    if not new_r:
        return beams, info
    add_r = np.concatenate(new_r)
    add_b = np.concatenate(new_b)
    info["added"] = (add_b, add_r)
    add_w = given[add_b] / echoes_per_tail
    old_b = beams.echo_beam()
    all_b = np.concatenate([old_b, add_b])
    all_r = np.concatenate([beams.echo_range, add_r])
    order = np.lexsort((all_r, all_b))
    counts = np.bincount(all_b, minlength=len(beams))
    new = Beams(origin=beams.origin, direction=beams.direction,
                echo_start=np.concatenate([[0], np.cumsum(counts)]),
                echo_range=all_r[order],
                echo_weight=np.concatenate([beams.echo_weight, add_w])[order],
                echo_kind=np.concatenate([beams.echo_kind, np.full(len(add_b), EchoKind.LEAF, np.uint8)])[order],
                tail=np.clip(beams.tail - given, 0.0, 1.0), max_range=beams.max_range, g=beams.g,
                scan_index=beams.scan_index)
    return new, info
