"""Checks of a voxelisation's result: quality warnings, and scores against a known truth."""

from __future__ import annotations

import numpy as np

from tlsvox.errors import InputError

__all__ = ["LAD_PLAUSIBLE_MAX", "LINE_FIT_MIN", "OCCLUDED_SHARE_MAX", "quality_warnings", "score_lad", "score_seen"]


#: Quality gates (``tlsvox voxelize`` warns; with ``--strict`` it fails).
LAD_PLAUSIBLE_MAX = 20.0  #: m2/m3: dense crowns reach a few, leaf clusters rarely 10
OCCLUDED_SHARE_MAX = 0.5  #: of the stored voxels
LINE_FIT_MIN = 0.9  #: of first echoes on their reconstructed scan line


def quality_warnings(lad, occluded, infos) -> list[str]:
    """Signs that a voxelisation went wrong, one sentence each, with the likely cause.

    Parameters
    ----------
    lad : (M,) float, m2/m3, and occluded : (M,) bool
        The stored voxels.
    infos : list of dict
        Per-scan pulse bookkeeping (``pulses``, ``empty``; ``line_fit`` where empty pulses were rebuilt).

    Examples
    --------
    >>> quality_warnings(np.array([1.0, 25.0]), np.array([False, False]), [])[0][:34]
    '1 voxels have LAD above 20 m2/m3 ('
    """
    out = []
    lad = np.asarray(lad, dtype=np.float64)
    occluded = np.asarray(occluded, dtype=bool)
    # a scan whose every pulse left an echo: the misses were not exported (a merged cloud, an echo-only export)
    full = [info for info in infos if info.get("pulses", 0) > 0 and info.get("empty", 1) == 0]
    for info in full:
        out.append(f"scan {info.get('scan', '?')!r} has no empty pulses: each of its {info['pulses']} pulses left "
                   "an echo, so the pulses that went through were not exported, and every voxel its beams cross "
                   "looks full (LAD biased high); give the scan's pulse table, or rebuild its empty pulses from "
                   "the angular grid (--angular-grid)")
    high = lad > LAD_PLAUSIBLE_MAX
    if high.any():
        cause = ("the scans without empty pulses above are the likely cause" if full else
                 "check the angular grid, the voxel size and the scan's units")
        out.append(f"{int(high.sum())} voxels have LAD above {LAD_PLAUSIBLE_MAX:g} m2/m3 (max {lad.max():.0f}), "
                   f"more than any canopy holds: {cause}")
    if occluded.size and occluded.mean() > OCCLUDED_SHARE_MAX:
        out.append(f"{100 * occluded.mean():.0f} % of the stored voxels are occluded (no estimate): add scan "
                   "positions, or use a larger voxel size")
    for info in infos:
        fit = info.get("line_fit")
        if fit is not None and fit < LINE_FIT_MIN:
            out.append(f"scan {info.get('scan', '?')!r}: only {100 * fit:.0f} % of its first echoes lie on the "
                       f"reconstructed scan lines (expected above {100 * LINE_FIT_MIN:.0f} %): the angular grid "
                       "(--angular-grid) is probably wrong, so the rebuilt empty pulses are too")
    return out


def score_lad(lad, truth, *, mask=None, voxel_volume: float = 1.0) -> dict:
    """Compare a LAD grid with the truth.

    Parameters
    ----------
    lad, truth : (nx, ny, nz) float, m2/m3
    mask : (nx, ny, nz) bool, optional
        Voxels scored for RMSE and bias (e.g. not occluded); default all.
    voxel_volume : float, m3
        For total leaf areas.

    Returns
    -------
    dict
        ``total_area``, ``true_area`` (m2, all voxels), ``area_error`` (relative),
        ``rmse``, ``bias`` (m2/m3, in ``mask``), ``n_scored``.

    Examples
    --------
    >>> s = score_lad(np.array([1.0, 2.0]), np.array([1.0, 1.0]))
    >>> s["area_error"], s["bias"]
    (0.5, 0.5)
    """
    lad = np.asarray(lad, dtype=np.float64)
    truth = np.asarray(truth, dtype=np.float64)
    if lad.shape != truth.shape:
        raise InputError(f"lad {lad.shape} and truth {truth.shape} must have the same shape")
    m = np.ones(lad.shape, bool) if mask is None else np.asarray(mask, bool)
    diff = (lad - truth)[m]
    ta, tt = float(lad.sum() * voxel_volume), float(truth.sum() * voxel_volume)
    return {"total_area": ta, "true_area": tt, "area_error": (ta - tt) / tt if tt > 0 else float("nan"),
            "rmse": float(np.sqrt(np.mean(diff**2))) if diff.size else 0.0,
            "bias": float(np.mean(diff)) if diff.size else 0.0, "n_scored": int(m.sum())}


def score_seen(lad, occluded, truth, *, voxel_volume: float = 1.0) -> tuple[dict, dict]:
    """:func:`score_lad` over all voxels, and over the voxels not flagged occluded.

    The second counts only voxels not flagged ``occluded`` that hold leaf area in
    the estimate or the truth (the demo's "voxels not flagged occluded" row).

    Returns
    -------
    (dict, dict)
        All voxels; seen voxels (``total_area`` and ``true_area`` over those only).

    Examples
    --------
    >>> lad, truth = np.array([1.0, 2.0, 0.0]), np.array([1.0, 1.0, 3.0])
    >>> all_, seen = score_seen(lad, np.array([False, False, True]), truth)
    >>> round(all_["area_error"], 2), seen["area_error"]
    (-0.4, 0.5)
    """
    lad = np.asarray(lad, dtype=np.float64)
    truth = np.asarray(truth, dtype=np.float64)
    seen = ~np.asarray(occluded, bool) & ((lad > 0) | (truth > 0))
    return (score_lad(lad, truth, voxel_volume=voxel_volume),
            score_lad(np.where(seen, lad, 0.0), np.where(seen, truth, 0.0), mask=seen, voxel_volume=voxel_volume))
