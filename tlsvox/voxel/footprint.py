r"""Echo weights from the beam's footprint, for multi-return scans without reflectance.

A wide beam that meets a leaf edge is stopped in part and goes on; counting
each of a pulse's ``n`` returns as ``1/n`` of it then reads the leaf area high
(+43 % on the leaf box of ``docs/voxelize.md`` with the RIEGL VZ-400's beam).
Without a ``beam_fraction`` column or calibrated reflectance, the share a
return stopped is still known in expectation from the beam's geometry
(``echo_weights="geometric"``, CLI ``--echo-weights geometric``).

The model
---------
The beam is the scan's ``K`` equal-power sub-rays
(:func:`tlsvox.truth.scanner.subray_pattern`) at the 1/e^2 radius ``w`` of
the scan's median echo range.  Along it, leaves of the given ellipse (default
5 x 2.5 cm) are met as a Poisson process: each encounter is a leaf placed at
random across the beam (offset and rotation uniform, its normal from the
leaf angle model against the scan's beam directions), which stops the
sub-rays it covers that are still travelling.  A leaf area density ``u``
gives ``u W / (pi a b)`` encounters per metre, ``W`` the mean window across
the beam in which a leaf's centre must lie to be met (its projection
widened by the sub-ray pattern) and ``pi a b`` a leaf's area.  Hits of one
pulse less than the range resolution apart merge into one return (each new
hit joins the return of the hit before it, as the scanner does); a return
whose apparent reflectance ``j rho mu / K`` reads under the detection
threshold (when the scan states one) stops its sub-rays unrecorded.

How much of the beam a return took shows in what is around and behind it:
in a dense cluster the rest of the beam meets another leaf within the
range resolution and the hits merge into one full return; a partial hit
deep in a crown is usually followed by another return, one at the crown's
far edge is not.  So each pulse is described by two numbers from a leaf
area density field: the encounters expected within the range resolution
at its first return (``merge``), and behind it to the end of the grid
(``behind``).  The seeded Monte Carlo follows pulses with the scan's pairs
and gives the mean share of the beam the ``i``-th leaf return of a pulse of
``n`` stopped, per cell of those two numbers' sextiles and quartiles: that
is the echo's weight.  Wood, ground and target returns, wider than the
beam, take what the pulse's leaf returns left (as with ``fraction``).

The field is an estimate: :func:`tlsvox.voxel.stages.voxelize` first
estimates with ``1/n`` (which reads high), then ``GEOMETRIC_ROUNDS`` (2)
times takes the weights from the estimate before and estimates again.  On
the homogeneous leaf box the estimate has settled by the second round; on
the clumped synthetic oak further rounds keep lowering it (the density
inside a voxel is taken as uniform, where the oak's leaves cluster, so
merging is likelier than modelled).  The table and the rule are stated in
the scene's meta (``meta["scans"][i]["echo_weights_model"]``).

What the model also leaves out: leaves facing outwards are taken with
uniform azimuths; one beam radius per scan (its median range).

Examples
--------
>>> m = FootprintModel(n_subrays=7, beam_radius=0.005)
>>> enc = encounters(m, np.random.default_rng(0).uniform(0, 1, 4000), pulses=4000, seed=0)
>>> w = walk(m, enc, merge=np.full(4000, 1.0), behind=np.full(4000, 4.0))
>>> t = share_table(w, n_max=2)
>>> 0.6 < t[1][0] < 0.95 and t[2][0] > t[2][1]
True
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from tlsvox.errors import InputError

__all__ = ["FootprintModel", "LadField", "encounters", "footprint_fractions", "share_table", "walk", "window_area"]

#: simulated pulses per table (the same seed gives the same table)
PULSES = 12_000
#: encounters followed per simulated pulse
MAX_ENCOUNTERS = 40
#: bins of the table: sextiles of the encounters behind the first return, quartiles of those within merging reach
BEHIND_BINS = 6
MERGE_BINS = 4
#: the most returns a pulse is tabulated for; pulses with more take 1/n of the tabulated total
N_MAX = 6


@dataclass(frozen=True)
class FootprintModel:
    """The beam and the leaves of :mod:`tlsvox.voxel.footprint`.

    Parameters
    ----------
    n_subrays : int
        Equal-power parts of the beam (7 for tlsvox's RIEGL VZ-400).
    beam_radius : float, metres
        1/e^2 radius of the beam where its echoes are (the scan's median range).
    leaf_length, leaf_width : float, metres
    range_resolution : float, metres
        Hits of one pulse closer than this merge into one return.
    threshold_db : float or None
        Detection threshold (dB of a white Lambertian target); None: every hit recorded.
    noise_db : float
        Standard deviation of the recorded reflectance, dB.
    leaf_reflectance : float
        Linear reflectance of a leaf at normal incidence (for the threshold).
    source : str
        Where the numbers came from.
    """

    n_subrays: int
    beam_radius: float
    leaf_length: float = 0.05
    leaf_width: float = 0.025
    range_resolution: float = 0.5
    threshold_db: float | None = None
    noise_db: float = 0.0
    leaf_reflectance: float = 0.267
    source: str = "given"

    def __post_init__(self):
        from tlsvox.truth.scanner import _RING_COUNTS

        if self.n_subrays not in _RING_COUNTS:
            raise InputError(f"n_subrays={self.n_subrays!r} must be one of {sorted(_RING_COUNTS)}")
        for name in ("beam_radius", "leaf_length", "leaf_width", "range_resolution", "leaf_reflectance"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise InputError(f"{name}={v!r} must be a finite number > 0 (metres; reflectance linear)")

    @classmethod
    def for_scan(cls, scan, range_m: float, *, leaf_length: float = 0.05, leaf_width: float = 0.025,
                 leaf_reflectance: float | None = None) -> FootprintModel:
        """The beam of the instrument that made ``scan`` (its preset, else the RIEGL VZ-400's) at a range."""
        from tlsvox.truth.scanner import ScannerPreset
        from tlsvox.voxel.weights import NominalReflectance

        stated = dict(scan.meta.get("preset") or {})
        vz400 = ScannerPreset.riegl_vz400()
        known = {k: v for k, v in stated.items() if k in asdict(vz400)}
        preset = ScannerPreset(**{**asdict(vz400), **known})
        nominal = NominalReflectance.for_scan(scan, leaf_reflectance, None)
        thr = stated.get("min_reflectance_db")
        src = "the scan's preset" if known else "the RIEGL VZ-400 preset (the scan states none)"
        return cls(n_subrays=preset.n_subrays,
                   beam_radius=float(preset.beam_radius_exit + preset.half_divergence * range_m),
                   leaf_length=float(leaf_length), leaf_width=float(leaf_width),
                   range_resolution=preset.range_resolution_m, threshold_db=None if thr is None else float(thr),
                   noise_db=preset.reflectance_noise_db, leaf_reflectance=float(nominal.leaf),
                   source=f"{src}; beam at {range_m:.1f} m; "
                          + ("every hit recorded (the scan states no threshold)" if thr is None
                             else f"threshold {float(thr):g} dB"))


@dataclass
class Encounters:
    """Leaf encounters of simulated pulses (:func:`encounters`): what does not depend on ``lam`` or the path."""

    covers: np.ndarray  #: (P, L, K) bool: the sub-rays each encounter's leaf covers
    mu: np.ndarray  #: (P, L) incidence cosine of each encounter's leaf
    unit_depth: np.ndarray  #: (P, L) positions of a unit-rate Poisson process
    detect_draw: np.ndarray  #: (P, L) uniform: the reflectance noise's draw per return


def encounters(model: FootprintModel, mu_values, *, pulses: int = PULSES, max_encounters: int = MAX_ENCOUNTERS,
               seed: int = 0) -> Encounters:
    """Simulated leaf encounters across the beam (seeded; common to every ``lam`` of a fit).

    Parameters
    ----------
    model : FootprintModel
    mu_values : (M,) float in (0, 1]
        Incidence cosines ``|n.d|`` of leaves against beams, not weighted by
        hit chance (each encounter is drawn from them, then accepted in
        proportion to the leaf's window across the beam).
    """
    from tlsvox.truth.scanner import subray_pattern

    mu_values = np.clip(np.asarray(mu_values, dtype=np.float64).reshape(-1), 1e-3, 1.0)
    if not len(mu_values):
        raise InputError("footprint weights need leaf incidence cosines to draw from (none given)")
    rng = np.random.default_rng(seed)
    radius, angle = subray_pattern(model.n_subrays)
    a, b = 0.5 * model.leaf_length, 0.5 * model.leaf_width
    reach = model.beam_radius * radius.max()
    size = pulses * max_encounters
    kept: list[np.ndarray] = []
    while sum(k.shape[1] for k in kept) < size:  # orientations accepted by their window's area (the chance to be met)
        m = rng.choice(mu_values, 3 * size)
        psi = rng.uniform(0.0, 2 * np.pi, 3 * size)
        ex = m * np.sqrt((a * np.cos(psi)) ** 2 + (b * np.sin(psi)) ** 2) + reach
        ey = np.sqrt((a * np.sin(psi)) ** 2 + (b * np.cos(psi)) ** 2) + reach
        ok = rng.uniform(0.0, (a + reach) ** 2, 3 * size) < ex * ey
        kept.append(np.stack([m[ok], psi[ok], ex[ok], ey[ok]]))
    mu, psi, ex, ey = (v[:size].reshape(pulses, max_encounters) for v in np.concatenate(kept, axis=1))
    cx = rng.uniform(-1.0, 1.0, ex.shape) * ex
    cy = rng.uniform(-1.0, 1.0, ey.shape) * ey
    spin = rng.uniform(0.0, 2 * np.pi, pulses)
    px = model.beam_radius * radius[None, :] * np.cos(angle[None, :] + spin[:, None])
    py = model.beam_radius * radius[None, :] * np.sin(angle[None, :] + spin[:, None])
    x = (px[:, None, :] - cx[..., None]) / mu[..., None]  # back in the leaf's plane
    y = py[:, None, :] - cy[..., None]
    cp, sp = np.cos(psi)[..., None], np.sin(psi)[..., None]
    covers = ((x * cp + y * sp) / a) ** 2 + ((-x * sp + y * cp) / b) ** 2 <= 1.0
    unit = np.cumsum(rng.exponential(1.0, (pulses, max_encounters)), axis=1)
    return Encounters(covers, mu, unit, rng.uniform(0.0, 1.0, (pulses, max_encounters)))


@dataclass
class Walked:
    """The recorded returns of simulated pulses (:func:`walk`)."""

    n: np.ndarray  #: (P,) recorded returns per pulse
    share: np.ndarray  #: (P, L) share of the beam each recorded return stopped, in range order
    merge: np.ndarray  #: (P,) encounters expected within the range resolution
    behind: np.ndarray  #: (P,) encounters expected behind the first hit


def walk(model: FootprintModel, enc: Encounters, *, merge, behind) -> Walked:
    """Follow each simulated pulse through its encounters: sub-rays stopped, hits merged into returns.

    Positions are counted in expected encounters (a unit-rate process):
    ``merge`` (P,) is the range resolution in those units, ``behind`` (P,)
    how many are expected behind the pulse's first hit (farther ones are not
    met).
    """
    from scipy.special import ndtr

    p, n_enc, k = enc.covers.shape
    merge = np.broadcast_to(np.asarray(merge, dtype=np.float64), (p,))
    behind = np.broadcast_to(np.asarray(behind, dtype=np.float64), (p,))
    s = enc.unit_depth
    limit = np.full(p, np.inf)  # set at the first hit
    alive = np.ones((p, k), bool)
    share = np.zeros((p, n_enc))
    n = np.zeros(p, np.int64)
    g_last = np.full(p, -np.inf)
    g_j = np.zeros(p)
    g_pow = np.zeros(p)
    rows = np.arange(p)

    def close(mask):
        ok = mask & (g_j > 0)
        if model.threshold_db is not None:
            db = 10.0 * np.log10(np.maximum(g_pow, 1e-30))
            if model.noise_db > 0:
                missed = ndtr((model.threshold_db - db) / model.noise_db)
            else:
                missed = (db < model.threshold_db).astype(np.float64)
            ok &= enc.detect_draw[rows, np.minimum(n, n_enc - 1)] >= missed
        r = rows[ok]
        share[r, n[r]] = g_j[r] / k
        n[r] += 1
        g_j[mask] = 0.0
        g_pow[mask] = 0.0

    for t in range(n_enc):
        met = s[:, t] <= limit
        if not met.any():
            break
        hit = enc.covers[:, t] & alive & met[:, None]
        j = hit.sum(axis=1).astype(np.float64)
        alive &= ~hit
        has = j > 0
        first = has & ~np.isfinite(limit)
        limit[first] = s[first, t] + behind[first]
        new = has & (s[:, t] - g_last > merge)  # the scanner's rule: a gap to the last hit
        close(new)
        g_last[has] = s[has, t]
        g_j[has] += j[has]
        g_pow[has] += j[has] * model.leaf_reflectance * enc.mu[has, t] / k
    close(np.ones(p, bool))
    return Walked(n, share, merge.copy(), behind.copy())


def share_table(walked: Walked, n_max: int = N_MAX, cells=None) -> dict:
    """Mean share of the beam of the i-th return of pulses with n recorded returns, n = 1..n_max.

    With ``cells`` ((P,) cell of each simulated pulse, and their number):
    ``{n: [[share of each return] per cell]}``, a cell with too few simulated
    pulses taking the pulses of every cell; without: ``{n: [share of each
    return]}``.
    """
    out: dict = {}
    for n in range(1, n_max + 1):
        m = walked.n == n
        if m.sum() < 20:
            continue
        pooled = [float(v) for v in walked.share[m, :n].mean(axis=0)]
        if cells is None:
            out[n] = pooled
            continue
        cell, count = cells
        rows = []
        for i in range(count):
            mc = m & (cell == i)
            rows.append([float(v) for v in walked.share[mc, :n].mean(axis=0)] if mc.sum() >= 30 else pooled)
        out[n] = rows
    return out


def window_area(model: FootprintModel, mu_values, *, samples: int = 20_000, seed: int = 0) -> float:
    """Mean area (m2) across the beam in which a leaf's centre must lie to be met (see :func:`encounters`).

    A leaf area density ``u`` then gives ``u * window_area / (pi a b)``
    encounters per metre of beam.
    """
    from tlsvox.truth.scanner import subray_pattern

    radius, _ = subray_pattern(model.n_subrays)
    a, b = 0.5 * model.leaf_length, 0.5 * model.leaf_width
    reach = model.beam_radius * radius.max()
    rng = np.random.default_rng(seed)
    m = rng.choice(np.clip(np.asarray(mu_values, dtype=np.float64).reshape(-1), 1e-3, 1.0), samples)
    psi = rng.uniform(0.0, 2 * np.pi, samples)
    ex = m * np.sqrt((a * np.cos(psi)) ** 2 + (b * np.sin(psi)) ** 2) + reach
    ey = np.sqrt((a * np.sin(psi)) ** 2 + (b * np.cos(psi)) ** 2) + reach
    return float(np.mean(4.0 * ex * ey))


@dataclass(frozen=True)
class LadField:
    """A leaf area density on a grid of cubic voxels (m2/m3), looked up at points."""

    lower: np.ndarray  #: (3,) the grid's lower corner, metres
    voxel_size: float
    lad: np.ndarray  #: (nx, ny, nz) float

    def at(self, xyz) -> np.ndarray:
        """LAD at each point (0 outside the grid)."""
        ijk = np.floor((np.asarray(xyz, dtype=np.float64) - self.lower) / self.voxel_size).astype(np.int64)
        inside = np.all((ijk >= 0) & (ijk < np.asarray(self.lad.shape)), axis=-1)
        out = np.zeros(ijk.shape[:-1])
        out[inside] = self.lad[tuple(ijk[inside].T)]
        return out

    def along(self, origin, directions, start, *, chunk: int = 50_000) -> np.ndarray:
        """The integral of LAD (m2/m2) along each beam from range ``start`` to where it leaves the grid."""
        origin = np.asarray(origin, dtype=np.float64)
        hi = self.lower + self.voxel_size * np.asarray(self.lad.shape)
        far = float(np.max(np.linalg.norm(np.stack(np.meshgrid(*zip(self.lower, hi), indexing="ij"), -1).reshape(-1, 3)
                                          - origin, axis=1)))
        step = 0.5 * self.voxel_size
        out = np.zeros(len(start))
        for a in range(0, len(start), chunk):
            d = np.asarray(directions[a:a + chunk], dtype=np.float64)
            r0 = np.asarray(start[a:a + chunk], dtype=np.float64)
            total = np.zeros(len(r0))
            for t in range(1, int(np.ceil(max(far - float(r0.min()), 0.0) / step)) + 1 if len(r0) else 0):
                total += self.at(origin + d * (r0 + (t - 0.5) * step)[:, None]) * step
            out[a:a + chunk] = total
        return out


def _incidence_cosines(leaf_angle, directions, *, count: int = 4000, seed: int = 0) -> np.ndarray:
    """|n.d| for leaf normals of ``leaf_angle`` (uniform azimuth) against the given beam directions."""
    from voxlidar.leaf_orientation import LeafAngle

    la = LeafAngle.from_dict(leaf_angle)
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, np.pi / 2, 2049)
    cdf = np.concatenate([[0.0], np.cumsum(0.5 * (la.pdf(t[1:]) + la.pdf(t[:-1])) * np.diff(t))])
    incl = np.interp(rng.uniform(0.0, cdf[-1], count), cdf, t) if cdf[-1] > 0 else np.full(count, np.pi / 4)
    az = rng.uniform(0.0, 2 * np.pi, count)
    normal = np.stack([np.sin(incl) * np.cos(az), np.sin(incl) * np.sin(az), np.cos(incl)], axis=1)
    d = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
    d = d[rng.integers(0, len(d), count)]
    return np.abs(np.sum(normal * d, axis=1))


def footprint_fractions(pulse, ranges, kinds, origin, directions, model: FootprintModel, lad: LadField, *,
                        leaf_angle="uniform", seed: int = 0) -> tuple[np.ndarray, dict]:
    """Each echo's expected share of its pulse's beam from the footprint model and a LAD field.

    Parameters
    ----------
    pulse : (N,) int
        Pulse of each echo, sorted by pulse then range.
    ranges : (N,) float, metres
    kinds : (N,) :class:`~tlsvox.voxel.trace.EchoKind`
        Leaf and wood echoes get a share; the others (ground, targets) NaN:
        they take what the pulse has left.
    origin : (3,) float
        The scanner (world frame).
    directions : (P, 3) float
        Each pulse's unit direction in the world frame.
    model : FootprintModel
    lad : LadField
        The leaf area density the encounters come from (a first estimate).
    leaf_angle : LeafAngle, str or dict

    Returns
    -------
    fraction : (N,) float64
    meta : dict
        The model, the window, the table's cells and shares.
    """
    from tlsvox.voxel.trace import EchoKind

    pulse = np.asarray(pulse, dtype=np.int64)
    kinds = np.asarray(kinds)
    directions = np.asarray(directions, dtype=np.float64)
    origin = np.asarray(origin, dtype=np.float64)
    veg = kinds == EchoKind.LEAF  # wood, ground and targets are wider than the beam: they take what is left
    frac = np.full(len(pulse), np.nan)
    if not veg.any():
        return frac, {"rule": "geometric", "note": "no leaf echoes"}
    vp, vr = pulse[veg], np.asarray(ranges, dtype=np.float64)[veg]
    first = np.concatenate([[True], vp[1:] != vp[:-1]])
    starts = np.flatnonzero(first)
    counts = np.diff(np.concatenate([starts, [len(vp)]]))
    rank = np.arange(len(vp)) - np.repeat(starts, counts)
    n_of = np.repeat(counts, counts)
    d1, r1 = directions[vp[starts]], vr[starts]
    mu_values = _incidence_cosines(leaf_angle, d1, seed=seed)
    per_lad = window_area(model, mu_values, seed=seed) / (np.pi * 0.25 * model.leaf_length * model.leaf_width)
    merge = per_lad * model.range_resolution * lad.at(origin + d1 * r1[:, None])
    behind = per_lad * lad.along(origin, d1, r1)
    b_edges = np.quantile(behind, np.linspace(0.0, 1.0, BEHIND_BINS + 1))
    m_edges = np.quantile(merge, np.linspace(0.0, 1.0, MERGE_BINS + 1))

    def cell_of(bh, mg):
        i = np.clip(np.searchsorted(b_edges[1:-1], bh, side="right"), 0, BEHIND_BINS - 1)
        j = np.clip(np.searchsorted(m_edges[1:-1], mg, side="right"), 0, MERGE_BINS - 1)
        return i * MERGE_BINS + j

    enc = encounters(model, mu_values, seed=seed)
    drawn = np.random.default_rng(seed).integers(0, len(starts), len(enc.mu))  # simulated pulses: the scan's pairs
    walked = walk(model, enc, merge=merge[drawn], behind=behind[drawn])
    table = share_table(walked, cells=(cell_of(behind[drawn], merge[drawn]), BEHIND_BINS * MERGE_BINS))
    if not table:
        raise InputError("geometric echo weights: the footprint model gave no returns; check the beam and leaf "
                         "sizes, or use echo_weights='uniform'")
    top = max(table)
    cell = np.repeat(cell_of(behind, merge), counts)
    share = np.empty(len(vp))
    for n in np.unique(n_of):
        m = n_of == n
        if n in table:
            share[m] = np.asarray(table[n])[cell[m], rank[m]]
        else:  # more returns than the simulation gave: the largest tabulated pulse's total, shared evenly
            share[m] = np.asarray(table[top]).sum(axis=1)[cell[m]] / n
    frac[veg] = share
    sim_hist = np.bincount(np.minimum(walked.n, 4), minlength=5)[1:]
    scan_hist = np.bincount(np.minimum(counts, 4), minlength=5)[1:]
    meta = {"rule": "geometric", "model": asdict(model), "encounters_per_lad_m": round(per_lad, 4),
            "behind_edges": [round(float(e), 3) for e in b_edges], "merge_edges": [round(float(e), 3) for e in m_edges],
            "returns_per_pulse": {"scan": [round(float(v), 4) for v in scan_hist / max(scan_hist.sum(), 1)],
                                  "model": [round(float(v), 4) for v in sim_hist / max(sim_hist.sum(), 1)],
                                  "note": "shares of pulses with 1, 2, 3, 4+ vegetation returns"},
            "table_n1": [round(float(v[0]), 4) for v in table[1]] if 1 in table else None,
            "note": "wood as leaves; leaves with uniform azimuths; uniform density within a voxel"}
    return frac, meta
