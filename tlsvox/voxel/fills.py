"""Occluded voxels filled: the crown's hull, the height-layer fill, the neighbourhood fill and its
calibration on the scans themselves (``fill=`` of :func:`~tlsvox.voxel.estimators.estimate_lad`).

The estimators (:mod:`tlsvox.voxel.estimators`) give each seen voxel its LAD and flag the
occluded ones; these functions say what an occluded voxel of the crown gets instead of 0
(docs/voxelize.md, *Occluded voxels*).
"""

from __future__ import annotations

import numpy as np

from tlsvox.errors import InputError
from tlsvox.voxel.stats import TINY as _TINY
from tlsvox.voxel.stats import VoxelStats, safe_divide

__all__ = ["CALIBRATION_MIN_VOXELS", "FILL_MIN_SEEN", "FILL_RADII", "brick_layer_means", "check_calibration_scans",
           "cross_scan_ratio", "fill_layers", "fill_neighbourhood", "hull_mask"]


def check_calibration_scans(n: int) -> None:
    """Raise the one-line error of ``fill="calibrated"`` when fewer than two scans are given."""
    if int(n) < 2:
        raise InputError("fill='calibrated' measures its ratio on the voxels one scan sees and the others hide: it "
                         f"needs two or more scans, got {n}; with one scan use fill='neighbourhood' "
                         "(CLI --fill neighbourhood)")


def brick_layer_means(stats: VoxelStats, brick_occluded, hits):
    """Sparse traces: the crown bricks and the pooled LAD of each brick layer's seen crown bricks.

    The crown is the hull of the bricks holding leaf echoes (``hits`` > 0 per
    row); a brick layer's value is ``sum(leaf hits) / sum(G x free path)`` over
    its seen crown bricks (the maximum-likelihood LAD of those bricks taken as
    one medium).

    Returns crown (n_bricks,) bool, each brick's layer (n_bricks,), the
    layers' LAD (n_layers,) and whether a layer has a seen crown brick.
    """
    rows = stats.rows
    row_brick = rows.brick_of_rows()
    occ = np.asarray(brick_occluded, bool).reshape(-1)
    seed_bricks = np.zeros(rows.n_bricks, bool)
    seed_bricks[row_brick[np.asarray(hits) > _TINY]] = True
    crown = hull_mask(seed_bricks.reshape(rows.shape), None).reshape(-1)
    bz = np.unravel_index(np.arange(rows.n_bricks), rows.shape)[2]
    seen = crown & ~occ
    n_layers = rows.shape[2]
    hits_per_brick = np.bincount(row_brick, weights=hits, minlength=rows.n_bricks)
    mean = safe_divide(np.bincount(bz[seen], weights=hits_per_brick[seen], minlength=n_layers),
                       np.bincount(bz[seen], weights=stats.brick_field("path_wg").reshape(-1)[seen], minlength=n_layers))
    has_mean = np.bincount(bz[seen], minlength=n_layers) > 0
    return crown, bz, mean, has_mean


def _fill_bricks(lad, occluded, stats, brick_occluded, hits, small_voxel_factor):
    """The layer fill on a sparse trace, by bricks.

    The crown is the hull of the bricks holding leaf echoes.  Each brick layer
    (8 voxel layers) gets the pooled estimate of its seen crown bricks,
    ``sum(leaf hits) / sum(G x free path)`` (the maximum-likelihood LAD of
    those bricks taken as one medium); it fills the layer's occluded rows in
    the crown and the echo-free voxels of its occluded crown bricks.  (The
    dense fill averages per-voxel estimates instead: with the voxels'
    own visibility unknown, pooling is what the brick sums support.)

    Returns the rows' LAD, which rows were filled, and the filled echo-free
    voxels with their LAD (already times ``small_voxel_factor``).
    """
    from tlsvox.voxel.bricks import BRICK

    rows = stats.rows
    row_brick = rows.brick_of_rows()
    occ = brick_occluded.reshape(-1)
    crown, bz, mean, has_mean = brick_layer_means(stats, brick_occluded, hits)
    row_layer = bz[row_brick]
    filled = occluded & crown[row_brick] & has_mean[row_layer]
    lad = np.where(filled, mean[row_layer], lad)
    ijk = rows.brick_voxels(np.flatnonzero(crown & occ))
    if len(ijk):
        ijk = ijk[~np.isin(rows.grid.flat(ijk), rows.grid.flat(rows.ijk))]
    value = mean[ijk[:, 2] // BRICK] * float(small_voxel_factor) if len(ijk) else np.zeros(0)
    keep = value > 0
    return lad, filled, ijk[keep], value[keep]


#: ``fill="neighbourhood"``: half-widths (voxels) of the cubes tried, smallest first
FILL_RADII = (1, 2, 4, 8)
#: ``fill="neighbourhood"``: seen crown voxels a cube must hold to give its mean
FILL_MIN_SEEN = 5


def fill_neighbourhood(lad, occluded, mask, *, radii=FILL_RADII, min_seen: int = FILL_MIN_SEEN):
    """Fill occluded crown voxels with the mean LAD of the nearest seen crown voxels.

    For each occluded voxel of ``mask``, the cubes of half-width ``r`` in
    ``radii`` voxels around it are tried, smallest first; the first holding at
    least ``min_seen`` seen voxels of ``mask`` gives their mean LAD (seen empty
    voxels count, as 0).  Voxels no cube serves take their height layer's mean
    (:func:`fill_layers`).  Foliage is spatially correlated at the scale of
    shoots and clusters, which a crown-wide layer mean averages away: the
    voxels a dense cluster occludes are its own core and the space behind it,
    and their nearest seen voxels are that cluster's outskirts.

    Parameters
    ----------
    lad : (nx, ny, nz) float
        LAD with occluded voxels at 0.
    occluded, mask : (nx, ny, nz) bool
        Occluded voxels; voxels of the crown (only these fill and are filled).
    radii : sequence of int
    min_seen : int

    Returns
    -------
    filled_lad : (nx, ny, nz) float64
    filled : (nx, ny, nz) bool
        Voxels that received a value.

    Examples
    --------
    >>> lad = np.zeros((5, 1, 1)); lad[:2] = 2.0; lad[3] = 1.0
    >>> occ = np.zeros((5, 1, 1), bool); occ[2] = True
    >>> out, filled = fill_neighbourhood(lad, occ, np.ones((5, 1, 1), bool), radii=(1, 2), min_seen=2)
    >>> float(out[2, 0, 0]), bool(filled[2, 0, 0])
    (1.5, True)
    """
    from scipy import ndimage

    if int(min_seen) != min_seen or min_seen < 1:
        raise InputError(f"min_seen={min_seen!r} must be an integer >= 1 (seen voxels a cube needs to give its mean)")
    radii = tuple(radii)
    if not radii or any(int(r) != r or r < 1 for r in radii):
        raise InputError(f"radii={radii!r} must be positive integers (cube half-widths in voxels, e.g. (1, 2, 4, 8))")
    lad = np.array(lad, dtype=np.float64)
    occluded = np.asarray(occluded, bool)
    mask = np.asarray(mask, bool)
    seen = mask & ~occluded
    target = occluded & mask
    todo = target.copy()
    values = np.where(seen, lad, 0.0)
    weight = seen.astype(np.float64)
    for r in radii:
        if not todo.any():
            break
        k = 2 * int(r) + 1
        # box sums (mean times volume; rounded, the counts are whole numbers)
        total = ndimage.uniform_filter(values, size=k, mode="constant") * k**3
        count = np.rint(ndimage.uniform_filter(weight, size=k, mode="constant") * k**3)
        ok = todo & (count >= min_seen)
        lad[ok] = np.maximum(total[ok] / count[ok], 0.0)  # the filter's running sums may round below 0
        todo &= ~ok
    filled = target & ~todo
    if todo.any():  # the layer's mean over its seen voxels (not over those filled above)
        rest, by_layer = fill_layers(np.where(seen, lad, 0.0), occluded, mask)
        by_layer &= todo
        lad = np.where(by_layer, rest, lad)
        filled |= by_layer
    return lad, filled


#: ``fill="calibrated"``: fewer calibration voxels than this leave the ratio at 1 (and say so)
CALIBRATION_MIN_VOXELS = 20


def cross_scan_ratio(scan_stats, mask, *, estimator="bcmle", n_min: int = 5, min_explored: float = 0.05,
                     weighted_count: bool = False) -> dict:
    """How much leaf area hidden voxels hold against the neighbourhood fill, measured on the scans themselves.

    A voxel that the other scans cannot see but one scan can is a hidden
    voxel whose LAD is known.  For each scan ``b`` (leave one out): the
    voxels of ``mask`` that all the scans but ``b`` leave occluded, that
    their neighbourhood fill reaches (:func:`fill_neighbourhood` of their
    pooled sums) and that ``b`` sees; their LAD from ``b``'s sums, against
    what that fill gives them.  The ratio of the two leaf areas, pooled over
    the scans, is the factor the fill of the voxels that no scan sees is
    multiplied by (``fill="calibrated"``).  With two scans, "all the scans
    but b" is the other scan.  Only the two-scan case is measured on known
    answers (docs/voxelize.md, *Occluded voxels*).

    Why: the voxels that stay hidden are mostly the cores of dense leaf
    clusters, denser than the seen voxels around them whose mean the
    neighbourhood fill takes (on the synthetic oak it gives them 64-71 % of
    their leaf area).  What some scans cannot see and another can is hidden
    for the same reason, so the scans themselves say how to scale the fill;
    no truth enters.  The one constant is the floor of
    ``CALIBRATION_MIN_VOXELS`` voxels under which no ratio is taken.

    Parameters
    ----------
    scan_stats : sequence of VoxelStats
        Each scan's own sums on one dense grid (two or more).
    mask : (nx, ny, nz) bool
        The crown (the fill's mask).
    estimator, n_min, min_explored, weighted_count
        As :func:`estimate_lad` (the same occlusion rule as the run).

    Returns
    -------
    dict
        ``ratio`` (1.0 when fewer than ``CALIBRATION_MIN_VOXELS`` voxels
        calibrate, with ``calibrated`` False), ``calibrated``, ``measured`` (the
        ratio of the voxels found, NaN when the fill gave them nothing), ``voxels``
        (calibration voxels over all scans), ``seen_m2`` (their leaf area
        from the scan that sees them) and ``filled_m2`` (what the fill of the
        others gave them), and ``per_scan`` (the same per seeing scan).

    Examples
    --------
    >>> from tlsvox.voxel.grid import VoxelGrid
    >>> from tlsvox.voxel.stats import NF
    >>> g = VoxelGrid((0, 0, 0), 1.0, (2, 1, 1))
    >>> empty = VoxelStats(g, np.zeros((2, NF)))
    >>> r = cross_scan_ratio([empty, empty], np.ones((2, 1, 1), bool))
    >>> r["ratio"], r["calibrated"]
    (1.0, False)
    """
    from tlsvox.voxel.estimators import estimate_lad  # the estimators apply the fills: imported when called

    stats = _scan_stats_list(scan_stats, None)
    grid = stats[0].grid
    mask = np.asarray(mask, bool)
    if mask.shape != grid.shape:
        raise InputError(f"cross_scan_ratio: mask has shape {mask.shape}, the grid {grid.shape}")
    kw = dict(estimator=estimator, n_min=n_min, min_explored=min_explored, leaf_size=None,
              weighted_count=weighted_count)
    vol = grid.voxel_volume
    per_scan, seen_total, filled_total, voxels = [], 0.0, 0.0, 0
    own = [estimate_lad(s, **kw) for s in stats]
    for b, lad_b in enumerate(own):
        # all the scans but b: with two, the other scan's own estimate
        lad_o = own[1 - b] if len(stats) == 2 else estimate_lad(
            VoxelStats(grid, sum(s.acc for k, s in enumerate(stats) if k != b)), **kw)
        filled_o, reached = fill_neighbourhood(lad_o.lad, lad_o.occluded, mask)
        sel = lad_o.occluded & reached & ~lad_b.occluded & mask
        seen_m2 = float(lad_b.lad[sel].sum() * vol)
        filled_m2 = float(filled_o[sel].sum() * vol)
        per_scan.append({"voxels": int(sel.sum()), "seen_m2": round(seen_m2, 3), "filled_m2": round(filled_m2, 3)})
        seen_total += seen_m2
        filled_total += filled_m2
        voxels += int(sel.sum())
    measured = float(seen_total / filled_total) if filled_total > 0 else float("nan")
    ok = voxels >= CALIBRATION_MIN_VOXELS and filled_total > 0
    return {"ratio": measured if ok else 1.0, "calibrated": bool(ok), "measured": measured, "voxels": voxels,
            "seen_m2": round(seen_total, 3), "filled_m2": round(filled_total, 3), "per_scan": per_scan}


def _scan_stats_list(scan_stats, stats) -> list:
    """``scan_stats`` as a list of two or more dense VoxelStats on one grid (``stats``'s, when given)."""
    try:
        out = list(scan_stats)
    except TypeError:
        raise InputError(f"scan_stats must be a list of VoxelStats (one per scan), got {type(scan_stats).__name__}") from None
    check_calibration_scans(len(out))
    bad = [type(s).__name__ for s in out if not isinstance(s, VoxelStats)]
    if bad:
        raise InputError(f"scan_stats must hold VoxelStats (one per scan), got {', '.join(sorted(set(bad)))}")
    if any(s.sparse for s in out):
        raise InputError("fill='calibrated' needs dense sums (every voxel's own): use layout='dense'")
    grid = out[0].grid if stats is None else stats.grid
    if any(s.grid != grid for s in out):
        raise InputError("scan_stats lie on a different grid from the run's; trace every scan on the run's grid")
    return out


def fill_layers(lad, occluded, mask):
    """Fill occluded voxels with the mean LAD of their height layer (Béland 2014).

    Parameters
    ----------
    lad : (nx, ny, nz) float
        LAD with occluded voxels at 0.
    occluded : (nx, ny, nz) bool
    mask : (nx, ny, nz) bool
        Voxels that belong to the crown; only these are filled and averaged.

    Returns
    -------
    filled_lad : (nx, ny, nz) float64
    filled : (nx, ny, nz) bool
        Voxels that received a value (occluded, in the mask, and in a layer
        with at least one visible crown voxel).
    """
    lad = np.array(lad, dtype=np.float64)
    occluded = np.asarray(occluded, bool)
    mask = np.asarray(mask, bool)
    visible = mask & ~occluded
    n_vis = visible.sum(axis=(0, 1))
    mean = safe_divide(np.where(visible, lad, 0.0).sum(axis=(0, 1)), n_vis)
    filled = occluded & mask & (n_vis > 0)[None, None, :]
    lad = np.where(filled, np.broadcast_to(mean[None, None, :], lad.shape), lad)
    return lad, filled


def hull_mask(seed, grid) -> np.ndarray:
    """Voxels inside the convex hull of the voxels where ``seed`` is True.

    Parameters
    ----------
    seed : (nx, ny, nz) bool
        E.g. voxels with leaf hits.
    grid : VoxelGrid

    Returns
    -------
    (nx, ny, nz) bool
        False everywhere when fewer than 4 non-coplanar seed voxels exist.
    """
    from scipy.spatial import ConvexHull, Delaunay, QhullError

    seed = np.asarray(seed, bool)
    ijk = np.argwhere(seed)
    out = np.zeros(seed.shape, bool)
    if len(ijk) < 4:
        return out
    # voxel corners, so a single layer of voxels still has a volume
    corners = (ijk[:, None, :] + np.array([[a, b, c] for a in (0, 1) for b in (0, 1) for c in (0, 1)])[None])
    pts = corners.reshape(-1, 3).astype(np.float64)
    try:
        hull = ConvexHull(pts)
        tri = Delaunay(pts[hull.vertices])
    except QhullError:
        return out
    lo = ijk.min(axis=0)
    hi = ijk.max(axis=0) + 1
    sub = np.argwhere(np.ones(hi - lo, bool)) + lo
    inside = tri.find_simplex(sub + 0.5) >= 0
    out[tuple(sub[inside].T)] = True
    return out
