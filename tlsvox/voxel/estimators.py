r"""Leaf area density (LAD) estimators on traced beam statistics.

All estimators read the per-voxel sums of :mod:`tlsvox.voxel.trace` (weights ``w``:
a pulse of ``n`` echoes gives each echo ``1/n``).  ``G`` is the projection
function of the leaf angle model (:mod:`voxlidar.leafangle`), evaluated per beam
at its zenith angle during tracing, so scans seen from different angles pool
exactly.

``bcmle`` (default) - bias-corrected maximum likelihood on free path lengths
(Pimont et al. 2018, eq. 32; AMAPVox ``attenuation_FPL_unbiasedMLE``). Free
paths inside a voxel are exponential with rate ``G u`` and censored at the
voxel exit, so the MLE of the LAD ``u`` is :math:`H / \sum w G z`; the
first-order bias correction subtracts the second term:

.. math:: \hat u = \frac{\sum_{hits} w}{W_G}
          - \frac{\left(\sum_{hits} w\,G\,z\right)\left(\sum w\right)}{W_G^{2}\; n},
          \qquad W_G = \sum w\,G\,z,

``n`` the number of beams entering; clamped at 0.  Without censoring this is
exactly the unbiased :math:`(n-1)/\sum z`.

``voxlad`` - Béland et al. (2014): :math:`u = \sum_s (N_{I,s}/G_s) / \sum z`.

``beer_lambert`` - :math:`u = -\ln(1 - I)/(G\,\bar\delta)`, ``I = N_I/N``, the
mean potential chord :math:`\bar\delta`; ``I = 1`` is replaced by
:math:`1 - 1/(2N + 2)`, i.e. :math:`\ln(2N+2)/(G\bar\delta)`.

``contact_frequency`` - :math:`u = I / (G\,\bar\delta)`.

For the last two ``G`` is the path-weighted mean of the beams' G.  Beams
stopped by wood or ground are censored: they count in the free paths but are
not leaf events (and leave the Beer-Lambert denominator).

Flags (:class:`Flag`, a bit mask per voxel; never NaN or inf in the values):

- ``FEW_BEAMS``: fewer than ``n_min`` beams entered (occluded);
- ``LOW_EXPLORED``: the beams explored less than ``min_explored`` of the
  voxel's depth (free path / potential chord; occluded);
- ``SATURATED``: every beam that entered was stopped by leaves (the estimate
  is a lower bound);
- ``LARGE_LEAVES``: the mean chord is under ``large_leaf_ratio`` leaf sizes,
  where the turbid-medium assumption behind all four estimators fails;
- ``FILLED``: an occluded voxel given its height layer's mean (Béland 2014).

A sparse trace (:mod:`tlsvox.voxel.bricks`) gives every estimate per row
voxel (those holding echoes), as 1-D arrays in row order; the voxels without
echoes have LAD 0 and are judged seen or occluded by their brick's sums
(:func:`brick_occlusion`), and the layer fill works on bricks: the crown
hull is the hull of the bricks holding leaf echoes, each brick layer's seen
crown gives a pooled estimate, and an occluded brick inside the crown gives
its echo-free voxels that value (``extra_ijk``, ``extra_lad``).

References
----------
Pimont, F., Allard, D., Soma, M., Dupuy, J.-L. (2018). Estimators and
    confidence intervals for plant area density at voxel scale with T-LiDAR.
    Remote Sensing of Environment 215, 343-370. doi:10.1016/j.rse.2018.06.024
Béland, M., Baldocchi, D. D., Widlowski, J.-L., Fournier, R. A., Verstraete,
    M. M. (2014). On seeing the wood from the leaves and the role of voxel size
    in determining leaf area distribution of forests with terrestrial LiDAR.
    Agricultural and Forest Meteorology 184, 82-97.
    doi:10.1016/j.agrformet.2013.09.005
Vincent, G. et al. (2017). Sensitivity of voxel-based estimations of leaf area
    density to LiDAR sampling. Remote Sensing of Environment 193, 248-260
    (AMAPVox). doi:10.1016/j.rse.2017.02.009

Examples
--------
>>> Estimator.parse("bcmle", "estimator").value
'bcmle'
>>> Estimator.parse("BL", "estimator")
Traceback (most recent call last):
...
voxlidar.errors.InputError: estimator='BL' is not known; choose one of: bcmle, voxlad, beer_lambert, contact_frequency
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field

import numpy as np

from tlsvox.errors import InputError
from tlsvox.voxel.trace import VoxelStats
from voxlidar.choices import Choice

__all__ = ["Estimator", "FillMode", "Flag", "LadEstimate", "brick_layer_means", "brick_occlusion", "estimate_lad",
           "cross_scan_ratio", "fill_layers", "fill_neighbourhood", "hull_mask"]

_TINY = 1e-12


class Estimator(str, Choice):
    """LAD estimators (see the module docstring)."""

    BCMLE = "bcmle"
    VOXLAD = "voxlad"
    BEER_LAMBERT = "beer_lambert"
    CONTACT_FREQUENCY = "contact_frequency"



class FillMode(str, Choice):
    """What to do with occluded voxels."""

    NONE = "none"  #: leave them at 0, flagged
    LAYER = "layer"  #: mean LAD of the visible voxels of the same height layer (Béland 2014)
    NEIGHBOURHOOD = "neighbourhood"  #: mean LAD of the nearest seen crown voxels (:func:`fill_neighbourhood`)
    #: the neighbourhood fill times the ratio the scans themselves give where one of them is hidden and the
    #: others see (:func:`cross_scan_ratio`)
    CALIBRATED = "calibrated"


#: fills that need every voxel's own sums (the dense layout)
DENSE_FILLS = (FillMode.NEIGHBOURHOOD, FillMode.CALIBRATED)


def check_calibration_scans(n: int) -> None:
    """Raise the one-line error of ``fill="calibrated"`` when fewer than two scans are given."""
    if int(n) < 2:
        raise InputError("fill='calibrated' measures its ratio on the voxels one scan sees and the others hide: it "
                         f"needs two or more scans, got {n}; with one scan use fill='neighbourhood' "
                         "(CLI --fill neighbourhood)")


class Flag(enum.IntFlag):
    """Per-voxel quality flags (bit mask, uint8)."""

    FEW_BEAMS = 1
    LOW_EXPLORED = 2
    SATURATED = 4
    LARGE_LEAVES = 8
    FILLED = 16

    @classmethod
    def describe(cls, value: int) -> str:
        """Names of the bits set in ``value`` (``"ok"`` when none)."""
        names = [f.name.lower() for f in cls if value & f]
        return "|".join(names) if names else "ok"


OCCLUDED = Flag.FEW_BEAMS | Flag.LOW_EXPLORED


@dataclass
class LadEstimate:
    """Per-voxel LAD estimate on a grid (dense arrays of ``grid.shape``).

    Attributes
    ----------
    (Sparse traces: every array is (n_rows,) in row order, see ``rows``.)
    lad : float64, m2/m3
        The estimate, 0 in occluded voxels unless filled, times
        ``small_voxel_factor``.  Always finite and >= 0.
    lad_std : float64, m2/m3
        Standard error (conservative for weighted echoes: Var(N_I) <= N_I).
    lad_raw : float64, m2/m3
        The estimator's value before occlusion masking, fill and factor.
    flags : uint8
        :class:`Flag` bits.
    g_eff : float64
        Path-weighted mean G of the beams (0 where no beam).
    """

    lad: np.ndarray
    lad_std: np.ndarray
    lad_raw: np.ndarray
    flags: np.ndarray
    g_eff: np.ndarray
    estimator: Estimator
    options: dict = field(default_factory=dict)
    rows: object = None  #: the Bricks of a sparse trace (None: dense arrays of the grid's shape)
    brick_occluded: np.ndarray | None = None  #: sparse: bricks whose echo-free voxels are occluded
    extra_ijk: np.ndarray | None = None  #: sparse fill: echo-free voxels given their layer's mean, (K, 3)
    extra_lad: np.ndarray | None = None  #: their LAD, (K,), m2/m3

    @property
    def occluded(self) -> np.ndarray:
        """bool: voxels flagged FEW_BEAMS or LOW_EXPLORED."""
        return (self.flags & int(OCCLUDED)) != 0

    def counts(self) -> dict:
        """Number of voxels carrying each flag."""
        return {f.name.lower(): int(np.count_nonzero(self.flags & f)) for f in Flag}


def safe_divide(a, b):
    """a / b where b > tiny, else 0 (never NaN or inf)."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    out = np.zeros(np.broadcast(a, b).shape)
    np.divide(a, b, out=out, where=b > _TINY)
    return out


def estimate_lad(stats: VoxelStats, *, estimator="bcmle", n_min: int = 5, min_explored: float = 0.05,
                 leaf_size: float | None = 0.05, large_leaf_ratio: float = 2.0,
                 small_voxel_factor: float = 1.0, fill="none", fill_mask=None,
                 weighted_count: bool = False, scan_stats=None) -> LadEstimate:
    """Estimate LAD per voxel from traced beam statistics.

    Parameters
    ----------
    stats : VoxelStats
        Output of :func:`tlsvox.voxel.trace.trace` (beams with ``g = G(theta)``).
    estimator : str or Estimator
        ``bcmle`` (default), ``voxlad``, ``beer_lambert``, ``contact_frequency``.
    n_min : int
        Fewer beams entering flags the voxel ``FEW_BEAMS`` (occluded).
    min_explored : float in [0, 1]
        Free path / potential chord below this flags ``LOW_EXPLORED`` (occluded).
    leaf_size : float or None, metres
        Characteristic leaf size; None disables the ``LARGE_LEAVES`` flag.
    large_leaf_ratio : float
        ``LARGE_LEAVES`` when the mean chord < ratio x leaf_size.
    small_voxel_factor : float
        Multiplies every LAD (the paper used 0.95 for small voxels; default 1).
    fill : {"none", "layer", "neighbourhood", "calibrated"}
        ``layer``: occluded voxels inside ``fill_mask`` get the mean LAD of the
        visible voxels of their height layer inside ``fill_mask``.
        ``neighbourhood`` (dense traces): the mean LAD of the seen voxels of
        ``fill_mask`` in the smallest cube around them that holds at least
        ``FILL_MIN_SEEN`` of them (:func:`fill_neighbourhood`).
        ``calibrated`` (dense traces, two or more scans in ``scan_stats``):
        that mean times the ratio :func:`cross_scan_ratio` measures on the
        voxels one scan hides and the others see.
    fill_mask : (nx, ny, nz) bool, optional
        Where filling is allowed (the crown); default :func:`hull_mask` of the
        voxels with leaf hits.
    weighted_count : bool
        Also flag ``FEW_BEAMS`` where the beam weight entering (``n_w``, in
        pulses) is under ``n_min``: voxels reached only by the leftovers of
        pulse tails (``voxelize(undetected="model")``).  Sparse traces judge
        their echo-free voxels alike per brick (:func:`brick_occlusion`).
    scan_stats : list of VoxelStats, optional
        ``fill="calibrated"``: each scan's own sums on the same grid (``stats``
        is their sum).

    Returns
    -------
    LadEstimate
    """
    est = Estimator.parse(estimator, "estimator")
    fill = FillMode.parse(fill, "fill")
    if not isinstance(stats, VoxelStats):
        raise InputError(f"stats must be the VoxelStats of a trace, got {type(stats).__name__}")
    if fill is FillMode.CALIBRATED:
        if scan_stats is None:
            raise InputError("fill='calibrated' needs each scan's own sums (scan_stats=[...]; voxelize passes them)"
                             "; with one scan use fill='neighbourhood'")
        scan_stats = _scan_stats_list(scan_stats, stats)
    if int(n_min) < 1:
        raise InputError(f"n_min={n_min!r} must be an integer >= 1 (beams per voxel), e.g. 5")
    if not 0.0 <= float(min_explored) <= 1.0:
        raise InputError(f"min_explored={min_explored!r} must lie in [0, 1], e.g. 0.05")
    if not (np.isfinite(small_voxel_factor) and small_voxel_factor > 0):
        raise InputError(f"small_voxel_factor={small_voxel_factor!r} must be > 0 (paper: 0.95; none: 1)")
    if leaf_size is not None and not (np.isfinite(leaf_size) and leaf_size > 0):
        raise InputError(f"leaf_size={leaf_size!r} must be > 0 metres or None")

    f = stats.field
    count = f("count")
    n_w = f("n_w")
    hits = f("leaf_w")
    stopped_other = f("wood_w") + f("other_w")
    path = f("path_w")
    path_g = f("path_wg")
    chord_w = f("chord_w")
    g_eff = safe_divide(path_g, path)
    mean_chord = safe_divide(chord_w, n_w)
    n_eff = np.maximum(n_w - stopped_other, 0.0)  # beams not censored by wood or ground
    interception = np.clip(safe_divide(hits, n_eff), 0.0, 1.0)
    saturated = (hits > _TINY) & (hits >= n_eff * (1 - 1e-9))

    if est is Estimator.BCMLE:
        lad = safe_divide(hits, path_g) - safe_divide(f("leaf_zwg") * n_w, path_g**2 * count)
        lad = np.maximum(lad, 0.0)
        std = safe_divide(lad, np.sqrt(hits))
    elif est is Estimator.VOXLAD:
        lad = safe_divide(f("leaf_w_g"), path)
        std = safe_divide(lad, np.sqrt(hits))
    elif est is Estimator.BEER_LAMBERT:
        n_beams = safe_divide(n_eff * count, n_w)  # beams (not weight) not censored
        one_minus = np.where(saturated, safe_divide(1.0, 2 * n_beams + 2), 1.0 - interception)
        one_minus = np.where(one_minus > 0, one_minus, 1.0)
        lam = safe_divide(-np.log(one_minus), mean_chord)
        lad = safe_divide(lam, g_eff)
        var_i = safe_divide(interception * (1 - interception), n_beams)
        std = safe_divide(np.sqrt(safe_divide(var_i, one_minus**2)), mean_chord * g_eff)
    else:  # contact frequency
        n_beams = safe_divide(n_eff * count, n_w)
        lad = safe_divide(safe_divide(interception, mean_chord), g_eff)
        std = safe_divide(np.sqrt(safe_divide(interception * (1 - interception), n_beams)), mean_chord * g_eff)

    # bcmle/voxlad where every hit sat at the entry face (no free path): fall back on the
    # saturated Beer-Lambert value rather than dividing by zero
    degenerate = (hits > _TINY) & (path <= _TINY)
    if np.any(degenerate):
        fallback = safe_divide(safe_divide(np.log(2 * count + 2), mean_chord), np.where(g_eff > 0, g_eff, 0.5))
        lad = np.where(degenerate, fallback, lad)
        saturated |= degenerate

    flags = np.zeros(count.shape, dtype=np.uint8)
    few = count < n_min
    if weighted_count:
        few |= n_w < n_min
    flags[few] |= np.uint8(Flag.FEW_BEAMS)
    explored = safe_divide(path, chord_w)
    flags[~few & (explored < min_explored)] |= np.uint8(Flag.LOW_EXPLORED)
    flags[saturated] |= np.uint8(Flag.SATURATED)
    if leaf_size is not None:
        flags[(count > 0) & (mean_chord < large_leaf_ratio * leaf_size)] |= np.uint8(Flag.LARGE_LEAVES)

    lad_raw = np.nan_to_num(lad, nan=0.0, posinf=0.0, neginf=0.0)
    std = np.nan_to_num(std, nan=0.0, posinf=0.0, neginf=0.0)
    occluded = (flags & int(OCCLUDED)) != 0
    out = np.where(occluded, 0.0, lad_raw)
    std = np.where(occluded, 0.0, std)
    sparse = {}
    if stats.sparse:
        sparse = dict(rows=stats.rows, brick_occluded=brick_occlusion(stats, n_min=n_min, min_explored=min_explored,
                                                                      weighted_count=weighted_count))
        if fill in DENSE_FILLS:
            raise InputError(f"fill={fill.value!r} needs every voxel's own sums (the dense layout): use "
                             "layout='dense' (CLI --layout dense), or fill='layer', which the sparse layout "
                             "does per brick layer")
        if fill is FillMode.LAYER:
            if fill_mask is not None:
                raise InputError("fill_mask is for dense traces; a sparse trace fills inside the hull of its "
                                 "leaf bricks")
            out, filled, sparse["extra_ijk"], sparse["extra_lad"] = _fill_bricks(
                out, occluded, stats, sparse["brick_occluded"], hits, small_voxel_factor)
            flags[filled] |= np.uint8(Flag.FILLED)
    elif fill is not FillMode.NONE:
        mask = hull_mask(hits > _TINY, stats.grid) if fill_mask is None else np.asarray(fill_mask, bool)
        if mask.shape != out.shape:
            raise InputError(f"fill_mask must have the grid's shape {out.shape}, got {mask.shape}")
        if fill is FillMode.LAYER:
            out, filled = fill_layers(out, occluded, mask)
        else:
            out, filled = fill_neighbourhood(out, occluded, mask)
        if fill is FillMode.CALIBRATED:
            calibration = cross_scan_ratio(scan_stats, mask, estimator=est, n_min=n_min, min_explored=min_explored,
                                           weighted_count=weighted_count)
            out = np.where(filled, out * calibration["ratio"], out)
        flags[filled] |= np.uint8(Flag.FILLED)
    out = out * float(small_voxel_factor)
    std = std * float(small_voxel_factor)
    options = dict(n_min=int(n_min), min_explored=float(min_explored), leaf_size=leaf_size,
                   large_leaf_ratio=float(large_leaf_ratio), small_voxel_factor=float(small_voxel_factor),
                   fill=fill.value, weighted_count=bool(weighted_count))
    if fill in DENSE_FILLS:
        options.update(fill_radii=list(FILL_RADII), fill_min_seen=FILL_MIN_SEEN)
    if fill is FillMode.CALIBRATED:
        options.update(fill_ratio=calibration["ratio"], fill_calibration=calibration)
    return LadEstimate(lad=out, lad_std=std, lad_raw=lad_raw, flags=flags, g_eff=g_eff,
                       estimator=est, options=options, **sparse)


def brick_occlusion(stats: VoxelStats, *, n_min: int = 5, min_explored: float = 0.05,
                    weighted_count: bool = False) -> np.ndarray:
    """Sparse traces: (bx, by, bz) bool, the bricks whose echo-free voxels count as occluded.

    The rule of the voxel flags, on the brick's sums: fewer than ``n_min``
    beams entered its voxels on average (visits over the brick's voxels
    inside the grid), with ``weighted_count`` also less than ``n_min``
    pulses' worth of beam weight on average (``visits_w`` over the voxels:
    the dense rule ``n_w < n_min`` on the brick's mean voxel), or they
    explored less than ``min_explored`` of the voxels they crossed (free
    path over potential chord).
    """
    voxels = stats.rows.voxels_in_grid()
    per_voxel = stats.brick_field("visits") / voxels
    explored = safe_divide(stats.brick_field("path_w"), stats.brick_field("chord_w"))
    occluded = (per_voxel < n_min) | (explored < min_explored)
    if weighted_count:
        occluded |= stats.brick_field("visits_w") / voxels < n_min
    return occluded


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
