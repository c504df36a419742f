"""Airborne pulses as beams through the voxel grid: a scene from ALS waveforms.

An airborne pulse is a beam like a terrestrial one: it leaves the sensor,
loses weight at each echo and carries the rest on.  What differs is where the
weights come from.  A full-waveform record tells how much of the beam each
echo stopped: an echo's energy against the energy of a *full hit* (the whole
beam stopped by one target of the same reflectance) is its share of the
beam.  :func:`airborne_beams` turns echo energies into those shares
(``E / E_full``, capped so that a pulse stops at most its whole beam), the
rest of the beam going on to the end of the record, where the knowledge of
the pulse ends.  :func:`voxelize_beams` then traces them (:mod:`tlsvox.voxel.trace`)
and estimates LAD with the same estimators and occlusion rules as for TLS
(:func:`tlsvox.voxel.estimators.estimate_lad`).

Echoes are not classified here: every echo counts as vegetation, so the
result is plant area density (leaves, wood and, where the records reach it,
the ground as a dense lowest layer).  The scene says so in its ``meta``.

Examples
--------
Two vertical pulses over a 1 m layer, each stopping half its beam there:

>>> import numpy as np
>>> beams = airborne_beams(np.array([[0.25, 0.5, 10.0], [0.75, 0.5, 10.0]]), np.array([[0, 0, -1.0]] * 2),
...                        echo_pulse=np.array([0, 1]), echo_range=np.array([9.5, 9.5]),
...                        echo_energy=np.array([1.0, 1.0]), full_energy=2.0, record_end=np.array([10.0, 10.0]))
>>> beams.echo_weight.tolist(), beams.tail.tolist()
([0.5, 0.5], [0.5, 0.5])
"""

from __future__ import annotations

import numpy as np

from tlsvox.errors import InputError
from tlsvox.voxel.beams import Beams, EchoKind
from tlsvox.voxel.grid import VoxelGrid

__all__ = ["airborne_beams", "full_hit_energy", "voxelize_beams"]


def full_hit_energy(pulse_energy, *, percentile: float = 95.0) -> float:
    """The energy of a full hit, from the pulses' total echo energies: their ``percentile``.

    In a forest most records hold the whole beam's return (stopped by the
    canopy or the ground); the upper percentile of the totals stands for a
    pulse whose beam was stopped whole, the lower ones for partial returns
    or beams that went on beyond the record.
    """
    e = np.asarray(pulse_energy, dtype=np.float64).reshape(-1)
    e = e[np.isfinite(e) & (e > 0)]
    if not e.size:
        raise InputError("no pulse has echo energy: a full hit's energy cannot be estimated")
    return float(np.percentile(e, percentile))


def airborne_beams(origin, direction, *, echo_pulse, echo_range, echo_energy, full_energy: float,
                   record_end, return_path: str = "hotspot") -> Beams:
    """Beams of airborne pulses with echo weights from their energies.

    Parameters
    ----------
    origin : (B, 3) float, metres
        Sensor position of each pulse at emission.
    direction : (B, 3) float
        Beam direction (normalised here).
    echo_pulse : (E,) int
        Pulse of each echo.
    echo_range : (E,) float, metres
        Distance of each echo from its pulse's origin.
    echo_energy : (E,) float
        Each echo's energy (any unit, the unit of ``full_energy``).
    full_energy : float
        The energy of a full hit (:func:`full_hit_energy`).
    record_end : (B,) float, metres
        Range where each record ends: the tail weight is followed that far.
    return_path : {"hotspot", "turbid"}
        How an echo's light came back.  ``hotspot`` (default): through the
        gap it went down (a small footprint's correlated return), so an
        echo's energy share is its share of the beam.  ``turbid``: through
        the canopy again, independently, so a target behind a one-way
        transmittance ``T`` returns ``T^2`` of a full hit: each echo's share
        of the beam is ``sqrt(1 - S_before) - sqrt(1 - S_after)`` with ``S``
        the cumulative energy share along the pulse.

    Returns
    -------
    Beams
        Echo weights ``E / full_energy`` (scaled down where a pulse's sum
        passes 1), kind LEAF; ``meta["capped"]`` counts the pulses scaled.
    """
    d = np.asarray(direction, dtype=np.float64).reshape(-1, 3)
    n = np.linalg.norm(d, axis=1, keepdims=True)
    if np.any(n == 0) or not np.all(np.isfinite(d)):
        raise InputError("direction: every pulse needs a finite, non-zero direction")
    d = d / n
    b = len(d)
    pulse = np.asarray(echo_pulse, dtype=np.int64).reshape(-1)
    rng = np.asarray(echo_range, dtype=np.float64).reshape(-1)
    energy = np.asarray(echo_energy, dtype=np.float64).reshape(-1)
    if not (pulse.size == rng.size == energy.size):
        raise InputError(f"echo_pulse ({pulse.size}), echo_range ({rng.size}) and echo_energy ({energy.size}) need "
                         "one value per echo")
    if pulse.size and (pulse.min() < 0 or pulse.max() >= b):
        raise InputError(f"echo_pulse must index the {b} pulses, got values {pulse.min()}..{pulse.max()}")
    if not (np.isfinite(full_energy) and full_energy > 0):
        raise InputError(f"full_energy must be > 0, got {full_energy!r}")
    if np.any(energy < 0) or not np.all(np.isfinite(energy)):
        raise InputError("echo_energy must be finite and >= 0")
    end = np.broadcast_to(np.asarray(record_end, dtype=np.float64), (b,)).copy()
    order = np.lexsort((rng, pulse))
    pulse, rng, energy = pulse[order], rng[order], energy[order]
    if return_path not in ("hotspot", "turbid"):
        raise InputError(f"return_path={return_path!r} must be 'hotspot' or 'turbid'")
    w, tail, capped = _shares(pulse, energy, float(full_energy), b, return_path)
    start = np.concatenate([[0], np.cumsum(np.bincount(pulse, minlength=b))])
    end = np.maximum(end, np.where(np.bincount(pulse, minlength=b) > 0,
                                   np.maximum.reduceat(np.r_[rng, 0.0], start[:-1]) if rng.size else 0.0, 0.0))
    beams = Beams(origin=origin, direction=d, echo_start=start, echo_range=rng, echo_weight=w,
                  echo_kind=np.full(rng.size, EchoKind.LEAF, np.uint8), tail=tail, max_range=end)
    beams.meta["capped"] = capped
    beams.meta["echo_energy"] = energy  # in the beams' echo order, for a reweighing by material
    beams.meta["full_energy"] = float(full_energy)
    beams.meta["return_path"] = return_path
    return beams


def _shares(pulse, energy, full, b, return_path="hotspot"):
    """Echo weights from ``energy / full`` (per echo, sorted by pulse then range), scaled down where a pulse's
    sum passes 1; the tails; the pulses scaled.  ``turbid``: the energy shares are two-way, the beam's
    one-way transmittance after each echo ``sqrt(1 - cumulative share)``."""
    w = energy / full
    total = np.bincount(pulse, weights=w, minlength=b)
    scale = np.where(total > 1.0, 1.0 / np.maximum(total, 1e-300), 1.0)
    w = w * scale[pulse]
    if return_path == "turbid" and w.size:
        start = np.r_[0, np.cumsum(np.bincount(pulse, minlength=b))[:-1]]
        cum = np.cumsum(w)
        cum -= np.r_[0.0, cum][start][pulse]  # within each pulse
        after = np.sqrt(np.clip(1.0 - cum, 0.0, 1.0))
        before = np.sqrt(np.clip(1.0 - (cum - w), 0.0, 1.0))
        w = before - after
    return w, np.clip(1.0 - np.bincount(pulse, weights=w, minlength=b), 0.0, 1.0), int(np.sum(scale < 1.0))


def ground_regression(veg_energy, ground_energy) -> tuple[float, float] | None:
    """Full hits of vegetation and ground from the pulses' energies (Armston et al. 2013).

    With the beam's share ``1 - P`` stopped by vegetation and ``P`` by the
    ground, a pulse returns ``Ev = Ev_full (1 - P)`` and ``Eg = Eg_full P``
    (the return coming back through the gap it went down: the hot spot of a
    small footprint), so over many pulses ``Ev = Ev_full - (Ev_full / Eg_full) Eg``:
    a straight line whose intercepts are the two full hits.  Fitted by least
    squares on the pulses with any energy; None when the line does not fall
    (too few pulses, or no pulse that both sees ground and vegetation).

    Returns
    -------
    (Ev_full, Eg_full) or None
    """
    ev = np.asarray(veg_energy, dtype=np.float64)
    eg = np.asarray(ground_energy, dtype=np.float64)
    ok = (ev + eg) > 0
    if ok.sum() < 10 or not ((ev[ok] > 0) & (eg[ok] > 0)).any() or np.ptp(eg[ok]) <= 0:
        return None
    slope, intercept = np.polyfit(eg[ok], ev[ok], 1)
    if not (slope < 0 and intercept > 0):
        return None
    return float(intercept), float(intercept / -slope)


def pool_layers(stats, sigma_m: float):
    """The tracer's sums of each voxel pooled with its layer's neighbours (a horizontal Gaussian of
    standard deviation ``sigma_m``), as a new dense :class:`~tlsvox.voxel.stats.VoxelStats`.

    Every field is a sum over beams, so the pooled sums are those of the beams
    near the voxel, each weighted by the Gaussian at its voxel's distance: the
    estimators then read a footprint's worth of beams where one voxel holds
    fewer than one.  Heights are not mixed.
    """
    from scipy.ndimage import gaussian_filter

    from tlsvox.voxel.stats import NF, VoxelStats

    if stats.sparse:
        raise InputError("pool_layers needs a dense trace")
    if not (np.isfinite(sigma_m) and sigma_m >= 0):
        raise InputError(f"pool sigma must be >= 0 metres, got {sigma_m!r}")
    if sigma_m == 0:
        return stats
    g = stats.grid
    s = sigma_m / g.voxel_size
    # gaussian_filter's weights sum to 1; times 2 pi s^2 they are the Gaussian itself (1 at the centre)
    acc = gaussian_filter(stats.acc.reshape(*g.shape, NF), sigma=(s, s, 0, 0), mode="constant", truncate=3.0)
    acc *= 2.0 * np.pi * s * s
    return VoxelStats(g, acc.reshape(-1, NF), stats.n_beams, stats.n_steps, stats.seconds, stats.device)


def voxelize_beams(beams: Beams, *, voxel_size: float, bounds=None, estimator="bcmle", n_min: int = 2,
                   min_explored: float = 0.0, leaf_angle="spherical", pool_m: float = 0.0, widen=(2.0, 4.0),
                   ground=None, ground_tolerance: float = 0.3, reweigh: bool = True, tracer=None,
                   progress: bool = False):
    """A plant-area scene from beams whose echoes all count as vegetation.

    Parameters
    ----------
    beams : Beams
        E.g. :func:`airborne_beams`.
    voxel_size : float, metres
    bounds : (2, 3) float, metres, optional
        Default: the echoes' box.
    estimator : str
        As :func:`tlsvox.voxel.estimators.estimate_lad`.
    n_min, min_explored
        Occlusion rule (a voxel entered by fewer than ``n_min`` beams is
        occluded); airborne records are sparse, so the default asks for 2.
    leaf_angle : str or LeafAngle
        For G(theta) (default spherical: nothing in airborne data tells the
        leaf angles).
    pool_m : float, metres
        Pool each voxel's sums with its layer's neighbours (:func:`pool_layers`,
        a horizontal Gaussian of this standard deviation) before estimating:
        airborne pulses lie tens of centimetres apart, so a small voxel is
        crossed by less than one beam; pooling keeps the vertical resolution
        and borrows the beams of a footprint around.  0: each voxel alone.
    widen : sequence of float
        With ``pool_m``: a voxel still occluded (fewer than ``n_min`` beams'
        worth) takes the estimate pooled over ``pool_m`` times each of these
        factors in turn, the narrowest that sees it (the finest footprint with
        enough beams); it stays flagged ``occluded``.
    ground : None, "ransac" or float
        None (default): the ground echoes count as vegetation like every other
        (a dense lowest layer, as a replay of the same records wants).
        ``"ransac"``: a plane fitted to the lowest echo of each 1 m column
        (:func:`tlsvox.ground.fit_ground`, inliers within ``ground_tolerance``,
        within 20 degrees of level), or a given height in metres: echoes
        within ``ground_tolerance`` of it stop their beams as ground, not
        vegetation, the scene gets the plane's height as ``ground_z`` and
        keeps no voxel below it.
    ground_tolerance : float, metres
        Half the ground echoes' band about the plane (airborne ranges are
        coarser than TLS ones: a 1 ns sample is 0.15 m).
    reweigh : bool
        With a ground and beams from :func:`airborne_beams`: the full hits of
        vegetation and of ground apart, from the pulses' energies
        (:func:`ground_regression`; leaves and soil reflect differently, so
        one full hit for both puts the canopy's share off by their ratio),
        the echo weights recomputed from them; kept as given when the fit
        fails (said in ``meta["airborne"]["full_hits"]``).
    tracer : Tracer, optional
    progress : bool

    Returns
    -------
    voxlidar.scene.Scene
        LAD (plant area density) per voxel; ``occluded``; ``meta["airborne"]``
        with the beams, echoes and the occluded share.
    """
    from tlsvox.voxel.estimators import estimate_lad
    from tlsvox.voxel.trace import Tracer
    from voxlidar.leaf_orientation import LeafAngle
    from voxlidar.scene import Scene

    if not (np.isfinite(voxel_size) and voxel_size > 0):
        raise InputError(f"voxel_size must be > 0 metres, got {voxel_size!r}")
    if beams.n_echoes == 0:
        raise InputError("the beams have no echoes: nothing to voxelise")
    la = LeafAngle.from_dict(leaf_angle)
    # G of each beam's angle from the vertical (G(theta) = G(pi - theta): down or up alike)
    beams.g = np.clip(np.asarray(la.G(np.arccos(np.abs(beams.direction[:, 2]))), dtype=np.float64), 1e-6, None)
    pts = beams.echo_points()
    # the plane from echoes that stopped at least 5 % of their beam: a decomposition's faint misfits around a
    # strong ground echo (a few per mille of it, on noise-free records) must not pull it down
    strong = pts[beams.echo_weight >= 0.05]
    plane = _ground_plane(ground, strong if len(strong) >= 3 else pts, ground_tolerance)
    fulls = None
    if plane is not None:
        on = plane.distance(pts) <= float(ground_tolerance)  # on the ground, or below it
        beams.echo_kind = np.where(on, np.uint8(EchoKind.OTHER), beams.echo_kind).astype(np.uint8)
        fulls = _reweigh(beams, on) if reweigh else None
        if bounds is None and (~on).any():  # the vegetation's box, down to the ground
            veg = pts[~on]
            pts = np.vstack([veg, [[*veg[0, :2], plane.z_center]]])
    lo, hi = (pts.min(axis=0), pts.max(axis=0)) if bounds is None else np.asarray(bounds, dtype=np.float64)
    grid = VoxelGrid.from_bounds(lo, hi, voxel_size=voxel_size, snap=True)
    grid.check_memory(200, what="tracing airborne beams")
    tracer = tracer or Tracer()
    raw = tracer.trace(grid, beams, progress=progress)
    stats = pool_layers(raw, float(pool_m))
    lad = estimate_lad(stats, estimator=estimator, n_min=n_min, min_explored=min_explored, leaf_size=None)
    values = lad.lad.copy()
    todo = lad.occluded.copy()
    widened = 0
    for factor in (widen if pool_m > 0 else ()):
        if not todo.any():
            break
        wide = estimate_lad(pool_layers(raw, float(pool_m) * float(factor)), estimator=estimator, n_min=n_min,
                            min_explored=min_explored, leaf_size=None)
        take = todo & ~wide.occluded
        values[take] = wide.lad[take]
        widened += int(take.sum())
        todo &= ~take
    keep = (values > 0) | lad.occluded
    if plane is not None:  # nothing at or below the ground
        top = grid.lower[2] + (np.arange(grid.shape[2]) + 1) * grid.voxel_size
        keep &= (top > plane.z_center)[None, None, :]
    ijk = np.argwhere(keep)
    sel = tuple(ijk.T)
    reached = int(np.count_nonzero(stats.field("count") > 0))
    meta = {"airborne": {"beams": len(beams), "pool_m": float(pool_m), "widened_voxels": widened,
                         "return_path": beams.meta.get("return_path", "hotspot"),
                         "widen": [float(f) for f in widen], "echoes": beams.n_echoes, "capped_pulses": beams.meta.get("capped"),
                         "occluded_voxels": int(lad.occluded[sel].sum()), "voxels": len(ijk),
                         "reached_voxels": reached,
                         "note": "every echo counted as vegetation: lad is plant area density (leaves, wood, and the "
                                 "ground where the records reach it)"},
            "estimator": str(getattr(lad.estimator, "value", lad.estimator)), "flags": lad.counts()}
    if plane is not None:
        meta["airborne"]["ground_echoes"] = int(np.sum(beams.echo_kind == EchoKind.OTHER))
        meta["airborne"]["full_hits"] = (fulls or {"rule": "one full hit for every echo (the vegetation/ground "
                                                           "regression was not used or did not fit)"})
        meta["airborne"]["note"] = ("every echo off the ground counted as vegetation: lad is plant area density "
                                    "(leaves and wood)")
        meta["ground"] = {"coefficients": list(plane.coefficients), "z_center": plane.z_center,
                          "tolerance_m": float(ground_tolerance)}
    return Scene(origin=grid.lower, voxel_size=grid.voxel_size, shape=grid.shape, ijk=ijk, lad=values[sel],
                 occluded=lad.occluded[sel], lad_std=lad.lad_std[sel], leaf_angle=la,
                 ground_z=None if plane is None else plane.z_center, meta=meta)


def _reweigh(beams, on_ground) -> dict | None:
    """Echo weights from separate full hits of vegetation and ground (:func:`ground_regression`), in place."""
    energy = beams.meta.get("echo_energy")
    if energy is None or len(energy) != beams.n_echoes:
        return None
    b = len(beams)
    pulse = beams.echo_beam()
    eg = np.bincount(pulse, weights=np.where(on_ground, energy, 0.0), minlength=b)
    ev = np.bincount(pulse, weights=np.where(on_ground, 0.0, energy), minlength=b)
    fit = ground_regression(ev, eg)
    if fit is None:
        return None
    full = np.where(on_ground, fit[1], fit[0])
    beams.echo_weight, beams.tail, beams.meta["capped"] = _shares(pulse, energy, full, b,
                                                                  beams.meta.get("return_path", "hotspot"))
    return {"rule": "vegetation and ground full hits from the pulses' energies (Armston et al. 2013)",
            "vegetation": fit[0], "ground": fit[1], "ratio_vegetation_over_ground": fit[0] / fit[1]}


def _ground_plane(ground, points, tolerance):
    from tlsvox.ground import GroundPlane, fit_ground

    if ground is None or isinstance(ground, GroundPlane):
        return ground
    if isinstance(ground, str):
        if ground.lower() == "none":
            return None
        if ground.lower() == "ransac":  # within 20 degrees of level (a strip's lowest points line up across it too)
            return fit_ground(points, distance_threshold=float(tolerance), max_tilt_deg=20.0)
    try:
        z = float(ground)
    except (TypeError, ValueError):
        raise InputError(f"ground={ground!r} must be None, 'none', 'ransac' or a height in metres") from None
    if not np.isfinite(z):
        raise InputError(f"ground={ground!r} must be a finite height in metres")
    return GroundPlane.horizontal(z)
