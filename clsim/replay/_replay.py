"""Held-out replay of measured pulses: folds, the methods side by side, per-pulse scores.

:func:`cross_validate` splits the pulses into folds (``interleaved``: pulse
``i`` in fold ``i mod k``; ``lines``: one scan line held out at a time, the
scene made from the other lines, which cross the same canopy at other
angles; with more than ``2 k`` lines, every ``k``-th line together).  For each fold, from the training pulses only, it builds

- ``simulation``: the forward model (:mod:`clsim.replay._forward`): a scene
  from the training pulses' echoes, each test pulse simulated as fired, with
  the gain and time offset fitted on training pulses (``calibration_pulses``
  of them, each replayed over a scene made from the other training pulses,
  as a test pulse is);
- ``blair_hofton``: the standard method from ALS echoes
  (:func:`~clsim.replay._baselines.blair_hofton`), its footprint width chosen
  among ``BH_SIGMAS_M`` by predicting each training pulse from the other
  training pulses, its gain the median energy ratio there;
- ``blair_hofton_samples``: the same from the training samples above 3 noise sigma;
- ``nearest``: the nearest training pulse moved onto the test beam (a ceiling);

and scores every test pulse (:func:`~clsim.replay._scores.score_pulse`).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from clsim.errors import InputError
from clsim.replay._baselines import blair_hofton, nearest_pulse
from clsim.replay._scores import score_pulse, summarize
from voxlidar.choices import Choice

__all__ = ["BH_SIGMAS_M", "METHODS", "ReplayResult", "Scheme", "cross_validate", "folds", "peak_counts", "pool_sigma"]

#: Footprint standard deviations (m) the Blair-Hofton baseline chooses from on training pulses.
BH_SIGMAS_M = (0.15, 0.2, 0.3, 0.4, 0.5, 0.75)
#: The methods compared, in table order.
METHODS = ("simulation", "blair_hofton", "blair_hofton_samples", "nearest")


class Scheme(str, Choice):
    """How pulses are held out."""

    INTERLEAVED = "interleaved"  # pulse i in fold i mod k
    LINES = "lines"  # one scan line at a time (every k-th line where there are more than 2k)


def folds(pulses, scheme="interleaved", *, k: int = 5) -> list[tuple[np.ndarray, np.ndarray]]:
    """(test, train) index pairs of a scheme."""
    scheme = Scheme.parse(scheme, "scheme")
    n = len(pulses)
    if scheme is Scheme.INTERLEAVED:
        if not 2 <= int(k) <= n:
            raise InputError(f"k={k!r} folds need 2 <= k <= {n} pulses")
        fold = np.arange(n) % int(k)
    else:
        lines, rank = np.unique(np.asarray(pulses.line), return_inverse=True)
        if len(lines) < 2:
            raise InputError("leave-one-line-out needs pulses from at least 2 scan lines; this file has 1 (use "
                             "--scheme interleaved)")
        # one line per fold; a file of many short lines (a tile cut from a flight) holds out every k-th line
        fold = rank if len(lines) <= 2 * int(k) else rank % int(k)
    return [(np.flatnonzero(fold == f), np.flatnonzero(fold != f)) for f in np.unique(fold)]


def peak_counts(prepared, *, prominence_sigma: float = 3.0, min_fraction: float = 0.05) -> np.ndarray:
    """(N,) significant peaks per record: local maxima standing ``prominence_sigma`` noise sigmas above
    their surroundings and reaching ``min_fraction`` of the record's maximum (multi-echo pulses: >= 2)."""
    from scipy.signal import find_peaks

    out = np.zeros(len(prepared.signal), dtype=np.int64)
    for i, y in enumerate(prepared.signal):
        if y.max() <= 0:
            continue
        pk, _ = find_peaks(y, prominence=prominence_sigma * prepared.noise[i], height=min_fraction * y.max())
        out[i] = len(pk)
    return out


@dataclass
class ReplayResult:
    """One scheme's held-out replay.

    Attributes
    ----------
    scheme : str
    rows : list of dict
        One per test pulse and method: ``pulse, fold, line, peaks, method`` and the scores.
    predictions : dict of method -> (N, S) float64, counts above the baseline, each pulse's held-out prediction
    summary : dict of method -> {"all": dict, "multi": dict} (:func:`~clsim.replay._scores.summarize`)
    folds : list of dict, per fold the settings chosen on its training pulses
    seconds : dict, wall time per method
    settings : dict
    """

    scheme: str
    rows: list
    predictions: dict
    summary: dict
    folds: list
    seconds: dict
    settings: dict = field(default_factory=dict)


def _score(prepared, i, pred):
    n = int(prepared.pulses.n_samples[i])
    m = prepared.mask[i, :n]
    # samples the instrument did not record (gaps between segments) count in neither waveform
    return score_pulse(prepared.signal[i, :n], np.where(m, pred[:n], 0.0), dt_ns=prepared.pulses.dt_ns)


def _bh_choice(prepared, train, *, kind, sigmas=BH_SIGMAS_M, sample: int = 80, seed: int = 0):
    """Footprint sigma and gain of the Blair-Hofton baseline, from training pulses predicted from the others."""
    rng = np.random.default_rng(seed)
    probe = rng.choice(train, size=min(sample, len(train)), replace=False)
    best = (-np.inf, sigmas[0], 1.0)
    for s in sigmas:
        rs, ratio = [], []
        for i in probe:
            others = train[train != i]
            pred = blair_hofton(prepared, int(i), others, sigma_m=s, kind=kind)
            sc = _score(prepared, int(i), pred)
            rs.append(sc["r"])
            ratio.append(sc["energy_ratio"])
        r = float(np.nanmedian(rs))
        if r > best[0]:
            ratio = np.asarray(ratio)
            ratio = ratio[np.isfinite(ratio) & (ratio > 0)]
            best = (r, s, 1.0 / float(np.median(ratio)) if ratio.size else 1.0)
    return best[1], best[2]


def pool_sigma(prepared, train, beams_per_footprint: float) -> float:
    """The pooling width that gathers ``beams_per_footprint`` training beams: sqrt(k / (2 pi density))."""
    xy = prepared.pulses.bin0[train, :2]
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    area = float(np.prod(np.maximum(hi - lo, 0.5)))
    density = len(train) / area
    return math.sqrt(beams_per_footprint / (2.0 * math.pi * density))


def _check_coverage(p, scene) -> None:
    """One clear error when a given scene covers none of the pulses' records (a frame mismatch)."""
    lo = scene.origin
    hi = scene.origin + scene.voxel_size * np.asarray(scene.shape)
    end = p.bin0 + p.n_samples[:, None] * p.step
    inside = np.all((end[:, :2] >= lo[:2]) & (end[:, :2] <= hi[:2]), axis=1)
    if not inside.any():
        raise InputError(f"the scene covers none of the {len(p)} pulses (scene x, y {lo[:2].round(1).tolist()} .. "
                         f"{hi[:2].round(1).tolist()}; pulses {end[:, :2].min(axis=0).round(1).tolist()} .. "
                         f"{end[:, :2].max(axis=0).round(1).tolist()}): the scene and the file must share a frame "
                         "(place a TLS scene in the airborne frame first: tlsvox georegister)")


def cross_validate(prepared, *, scheme="interleaved", k: int = 5, photons: int = 2000, seed: int = 0,
                   voxel_size: float = 0.25, beams_per_footprint: float = 3.0, calibration_pulses: int = 100,
                   max_order: int = 3, hotspot: bool = True, methods=METHODS, scene=None, simulator=None,
                   progress: bool = False) -> ReplayResult:
    """Held-out replay of every pulse by each method (see the module docstring).

    Parameters
    ----------
    prepared : Prepared
        :func:`clsim.replay.prepare` of the measured file.
    scheme : {"interleaved", "lines"}
    k : int
        Folds of ``interleaved``.
    photons : int
        Photons per simulated pulse.
    seed : int
        Seeds the simulation (pulse ``i``: ``seed + i``) and the training probes.
    voxel_size : float, metres
        The scene's voxels.
    beams_per_footprint : float
        The scene pools each voxel's sums over a horizontal Gaussian that holds
        this many training beams (:func:`tlsvox.voxel.airborne.pool_layers`).
    calibration_pulses : int
        Training pulses simulated to fit the gain and time offset (at most
        half of them), over a scene made from the other training pulses.
    max_order, hotspot
        As :func:`~clsim.replay._forward.simulate_pulses`.
    methods : sequence of str
        A subset of :data:`METHODS`.
    scene : voxlidar.scene.Scene, optional
        Replay over this scene (e.g. one made from TLS scans of the same
        trees, georegistered to the file) instead of one made from each fold's
        training pulses; the gain and time offset are still fitted on each
        fold's training pulses.
    simulator : clsim.Simulator, optional
    progress : bool

    Returns
    -------
    ReplayResult
    """
    from clsim.replay._forward import calibrate, scene_from_pulses, simulate_pulses

    methods = tuple(methods)
    bad = [m for m in methods if m not in METHODS]
    if bad:
        raise InputError(f"unknown methods {bad}; choose from {list(METHODS)}")
    p = prepared.pulses
    n, width = prepared.signal.shape
    peaks = peak_counts(prepared)
    preds = {m: np.zeros((n, width)) for m in methods}
    seconds = {m: 0.0 for m in methods}
    fold_info = []
    splits = folds(p, scheme, k=k)
    if "simulation" in methods and scene is not None:
        _check_coverage(p, scene)
    if "simulation" in methods and simulator is None:
        from clsim.transport.simulator import Simulator

        simulator = Simulator()
    tracer = None
    it = enumerate(splits)
    if progress:
        from tqdm.auto import tqdm

        it = tqdm(list(it), desc=f"replay ({Scheme.parse(scheme, 'scheme').value})", unit="fold", leave=False)
    rng = np.random.default_rng(seed)
    uncovered = np.zeros(n, dtype=bool)  # test pulses whose beam leaves their fold's scene
    for f, (test, train) in it:
        info = {"fold": int(f), "test": int(len(test)), "train": int(len(train))}
        if "simulation" in methods:
            t0 = time.perf_counter()
            if tracer is None and scene is None:
                from tlsvox.voxel.trace import Tracer

                tracer = Tracer()
            cal = np.sort(rng.choice(train, size=min(calibration_pulses, len(train) // 2), replace=False))
            if scene is None:
                pool = pool_sigma(prepared, train, beams_per_footprint)
                fold_scene = scene_from_pulses(prepared, train, voxel_size=voxel_size, pool_m=pool, tracer=tracer)
                # the calibration pulses are replayed over a scene made without them, as the test pulses are:
                # over their own echoes they would read brighter and the gain would come out low
                rest = np.setdiff1d(train, cal)
                cal_scene = scene_from_pulses(prepared, rest, voxel_size=voxel_size, pool_m=pool, tracer=tracer)
            else:
                pool, fold_scene, cal_scene = float("nan"), scene, scene
            fit = calibrate(prepared, simulate_pulses(prepared, cal_scene, cal, simulator=simulator, photons=photons,
                                                      seed=seed, max_order=max_order, hotspot=hotspot,
                                                      outside="skip"))
            sim = simulate_pulses(prepared, fold_scene, test, simulator=simulator, photons=photons, seed=seed,
                                  max_order=max_order, hotspot=hotspot, outside="skip")
            preds["simulation"][test] = sim.waveforms(prepared, gain=fit.gain, lag=fit.lag)
            uncovered[sim.outside] = True
            seconds["simulation"] += time.perf_counter() - t0
            info["simulation"] = dict(fit.to_dict(), pool_m=round(pool, 4), voxels=int(fold_scene.n_voxels),
                                      full_hit_energy=(fold_scene.meta.get("airborne") or {}).get("full_hit_energy"))
        for m, kind in (("blair_hofton", "echoes"), ("blair_hofton_samples", "samples")):
            if m not in methods:
                continue
            t0 = time.perf_counter()
            sigma, gain = _bh_choice(prepared, train, kind=kind, seed=seed + f)
            for i in test:
                preds[m][i] = gain * blair_hofton(prepared, int(i), train, sigma_m=sigma, kind=kind)
            seconds[m] += time.perf_counter() - t0
            info[m] = {"sigma_m": sigma, "gain": gain}
        if "nearest" in methods:
            t0 = time.perf_counter()
            for i in test:
                preds["nearest"][i] = nearest_pulse(prepared, int(i), train)
            seconds["nearest"] += time.perf_counter() - t0
        info["test_pulses"] = test.tolist()
        fold_info.append(info)
    fold_of = np.zeros(n, dtype=np.int64)
    for f, (test, _) in enumerate(splits):
        fold_of[test] = f
    rows, summary = [], {}
    for m in methods:
        mine = []
        for i in range(n):
            sc = _score(prepared, i, preds[m][i])
            row = {"pulse": i, "fold": int(fold_of[i]), "line": int(p.line[i]), "peaks": int(peaks[i]),
                   "covered": bool(not uncovered[i]), "method": m}
            row.update(sc)
            mine.append(row)
        rows.extend(mine)
        # every method is summarised on the same pulses: those the scene of their fold covers
        mine = [r for r in mine if r["covered"]]
        multi = [r for r in mine if r["peaks"] >= 2]
        summary[m] = {"all": summarize(mine), "multi": summarize(multi) if multi else None}
    settings = dict(scheme=Scheme.parse(scheme, "scheme").value, k=int(k), photons=int(photons), seed=int(seed),
                    voxel_size=float(voxel_size), beams_per_footprint=float(beams_per_footprint),
                    calibration_pulses=int(calibration_pulses), max_order=int(max_order), hotspot=bool(hotspot),
                    divergence_mrad=p.divergence_mrad, multi_echo_pulses=int(np.sum(peaks >= 2)),
                    scene="given" if scene is not None else "from each fold's training pulses",
                    uncovered_pulses=int(uncovered.sum()))
    return ReplayResult(scheme=settings["scheme"], rows=rows, predictions=preds, summary=summary, folds=fold_info,
                        seconds=seconds, settings=settings)
