r"""Leaf area density (LAD) estimators on traced beam statistics.

All estimators read the per-voxel sums of :mod:`tlsvox.voxel.trace` (weights ``w``:
a pulse of ``n`` echoes gives each echo ``1/n``).  ``G`` is the projection
function of the leaf angle model (:mod:`voxlidar.leaf_orientation`), evaluated per beam
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
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from tlsvox.errors import InputError
from tlsvox.voxel.fills import (  # estimate_lad applies the fills
    FILL_MIN_SEEN,
    FILL_RADII,
    _fill_bricks,
    _scan_stats_list,
    cross_scan_ratio,
    fill_layers,
    fill_neighbourhood,
    hull_mask,
)
from tlsvox.voxel.stats import TINY as _TINY
from tlsvox.voxel.stats import safe_divide
from tlsvox.voxel.trace import VoxelStats
from voxlidar.choices import Choice

__all__ = ["ESTIMATORS", "Estimator", "FillMode", "Flag", "LadEstimate", "Sums", "brick_occlusion", "estimate", "estimate_lad"]



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


@dataclass(frozen=True)
class Sums:
    """What every estimator reads of a voxel's traced sums (:mod:`tlsvox.voxel.stats`), per voxel."""

    field: Callable[[str], np.ndarray]  #: ``stats.field``: any raw sum by name
    count: np.ndarray  #: beams entering
    n_w: np.ndarray  #: beam weight entering
    hits: np.ndarray  #: leaf echo weight stopped inside
    n_eff: np.ndarray  #: beam weight not censored by wood or ground
    path: np.ndarray  #: weighted free path, metres
    path_g: np.ndarray  #: weighted G x free path
    mean_chord: np.ndarray  #: mean potential chord, metres
    g_eff: np.ndarray  #: path-weighted G
    interception: np.ndarray  #: hits / n_eff in [0, 1]
    saturated: np.ndarray  #: every uncensored beam stopped (bool)

    @classmethod
    def of(cls, stats: VoxelStats) -> Sums:
        f = stats.field
        count, n_w, hits = f("count"), f("n_w"), f("leaf_w")
        path, path_g = f("path_w"), f("path_wg")
        n_eff = np.maximum(n_w - (f("wood_w") + f("other_w")), 0.0)  # beams not censored by wood or ground
        return cls(field=f, count=count, n_w=n_w, hits=hits, n_eff=n_eff, path=path, path_g=path_g,
                   mean_chord=safe_divide(f("chord_w"), n_w), g_eff=safe_divide(path_g, path),
                   interception=np.clip(safe_divide(hits, n_eff), 0.0, 1.0),
                   saturated=(hits > _TINY) & (hits >= n_eff * (1 - 1e-9)))


def _bcmle(s: Sums):
    """Pimont et al. (2018): the bias-corrected maximum likelihood."""
    lad = np.maximum(safe_divide(s.hits, s.path_g) - safe_divide(s.field("leaf_zwg") * s.n_w, s.path_g**2 * s.count),
                     0.0)
    return lad, safe_divide(lad, np.sqrt(s.hits))


def _voxlad(s: Sums):
    """Béland et al. (2014): each hit's 1/G over the free path."""
    lad = safe_divide(s.field("leaf_w_g"), s.path)
    return lad, safe_divide(lad, np.sqrt(s.hits))


def _beer_lambert(s: Sums):
    """Gap fraction through the voxel's mean chord; saturated voxels as one more beam would leave."""
    n_beams = safe_divide(s.n_eff * s.count, s.n_w)  # beams (not weight) not censored
    one_minus = np.where(s.saturated, safe_divide(1.0, 2 * n_beams + 2), 1.0 - s.interception)
    one_minus = np.where(one_minus > 0, one_minus, 1.0)
    lad = safe_divide(safe_divide(-np.log(one_minus), s.mean_chord), s.g_eff)
    var_i = safe_divide(s.interception * (1 - s.interception), n_beams)
    return lad, safe_divide(np.sqrt(safe_divide(var_i, one_minus**2)), s.mean_chord * s.g_eff)


def _contact_frequency(s: Sums):
    """Interceptions per metre of chord, over G."""
    n_beams = safe_divide(s.n_eff * s.count, s.n_w)
    lad = safe_divide(safe_divide(s.interception, s.mean_chord), s.g_eff)
    std = safe_divide(np.sqrt(safe_divide(s.interception * (1 - s.interception), n_beams)), s.mean_chord * s.g_eff)
    return lad, std


#: each estimator's function of the sums, returning (LAD, its standard error) per voxel: adding an
#: estimator is one function, one member of :class:`Estimator` and one entry here
ESTIMATORS = {Estimator.BCMLE: _bcmle, Estimator.VOXLAD: _voxlad, Estimator.BEER_LAMBERT: _beer_lambert,
              Estimator.CONTACT_FREQUENCY: _contact_frequency}


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

    sums = Sums.of(stats)
    lad, std = ESTIMATORS[est](sums)
    count, n_w, hits, path = sums.count, sums.n_w, sums.hits, sums.path
    mean_chord, g_eff, saturated = sums.mean_chord, sums.g_eff, sums.saturated.copy()

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
    explored = safe_divide(path, stats.field("chord_w"))
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


def estimate(stats: VoxelStats, estimator: Estimator, fill: FillMode, settings, *, scan_stats=None,
             weighted_count: bool = False) -> LadEstimate:
    """Stage 7 of :func:`~tlsvox.voxel.stages.voxelize`: :func:`estimate_lad` with the run's
    :class:`~tlsvox.voxel.settings.VoxelizeSettings` (its ``model`` group's thresholds)."""
    m = settings.model
    return estimate_lad(stats, estimator=estimator, n_min=m.n_min, min_explored=m.min_explored,
                        leaf_size=m.leaf_size, small_voxel_factor=m.small_voxel_factor, fill=fill,
                        weighted_count=weighted_count, scan_stats=scan_stats)


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
