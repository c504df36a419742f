"""Stage 8 of :func:`~tlsvox.voxel.stages.voxelize` (``undetected="model"``): the leaf hits too weak
for the scanner's detection threshold given back where the current estimate puts them, then traced and
estimated again (:mod:`tlsvox.voxel.detection` holds the model of what goes undetected).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from tlsvox.voxel.beams import voxels_along
from tlsvox.voxel.bricks import BRICK, Bricks
from tlsvox.voxel.detection import unrecorded_echoes
from tlsvox.voxel.estimators import DENSE_FILLS, FillMode, LadEstimate, estimate
from tlsvox.voxel.fills import brick_layer_means, fill_layers, fill_neighbourhood, hull_mask
from tlsvox.voxel.quality import LAD_PLAUSIBLE_MAX
from tlsvox.voxel.stats import VoxelStats
from tlsvox.voxel.trace import Beams, EchoKind

if TYPE_CHECKING:
    from tlsvox.voxel.settings import VoxelizeSettings
    from tlsvox.voxel.stages import Checked, Projection, TraceRun

__all__ = ["give_back_undetected"]


def give_back_undetected(run: TraceRun, parts, beams, stats, lad, checks: Checked, projection: Projection,
                         settings: VoxelizeSettings):
    """Stage 8 (``undetected="model"``): each pulse's expected unrecorded leaf interception given back as
    echoes where the current estimate puts it, traced and estimated again, ``undetected_iterations`` times.

    Returns the last round's sums, its estimate and the meta of the correction.
    """
    grid = run.grid
    per_scan = checks.fill is FillMode.CALIBRATED
    iterations = int(settings.undetected.undetected_iterations)
    detection = checks.detection or []
    rounds = []
    leaf_weight = sum(float(b.echo_weight[b.echo_kind == EchoKind.LEAF].sum()) for b in parts)
    for _ in range(iterations):
        lookup, box = _lad_lookup(grid, lad, stats)
        stats = beams = None  # the last round's sums and beams: not needed again (memory_plan)
        fixed: list = []
        given, added = 0.0, []
        for part, model in zip(parts, detection):
            b, info = unrecorded_echoes(part, grid, lookup, model, checks.leaf_angle, outward=projection.outward,
                                        box=box)
            fixed.append(b)
            given += info["given_back"]
            if run.recorded is not None:
                pulse, ranges = info["added"]
                added.append(grid.flat(voxels_along(grid, part.origin[pulse], part.direction[pulse], ranges)))
        del lookup
        if not per_scan:  # traced scan by scan: no joined copy
            beams = fixed[0] if len(fixed) == 1 else Beams.concat(fixed)
        if run.recorded is not None:  # what echo_voxels(grid, beams) gives, from the given-back echoes alone
            run.rows = Bricks.from_ijk(grid, grid.unflat(np.union1d(run.recorded, np.concatenate(added))))
        stats, scan_stats = run.sums(beams, fixed if per_scan else None)
        fixed = []  # this round's beams: released before the estimate
        # a voxel reached only by what the model leaves of pulse tails is not seen: count beams by weight
        lad = estimate(stats, checks.estimator, checks.fill, settings, scan_stats=scan_stats, weighted_count=True)
        rounds.append(round(given / leaf_weight, 5) if leaf_weight > 0 else 0.0)
    meta = {"rule": checks.undetected.value, "models": [m.to_dict() for m in detection],
            "iterations": iterations, "given_back_share": rounds,
            "note": "given_back_share: unrecorded leaf interception given back, per round, over the recorded leaf "
                    "echo weight"}
    return stats, lad, meta


def _lad_lookup(grid, lad: LadEstimate, stats: VoxelStats | None = None):
    """LAD at flat voxel indices, where the detection model puts the unrecorded interception; and
    the box (2, 3) of the voxels above 0 (None when there is none).

    The seen voxels' estimates; occluded voxels take a fill, since a beam's optical depth runs
    through them too: dense layout, their height layer's mean inside the crown hull
    (:func:`~tlsvox.voxel.estimators.fill_layers`; with ``fill="neighbourhood"`` that fill,
    :func:`~tlsvox.voxel.estimators.fill_neighbourhood`, and with ``fill="calibrated"`` that fill
    times the run's ratio); sparse layout (with ``stats``), the pooled
    estimate of their brick layer's seen crown bricks
    (:func:`~tlsvox.voxel.estimators.brick_layer_means`, the brick fill of ``fill="layer"``),
    for occluded rows and the echo-free voxels of occluded crown bricks alike (looked up per
    brick: nothing of the grid's size is made).  Capped at LAD_PLAUSIBLE_MAX.
    """
    factor = float(lad.options.get("small_voxel_factor", 1.0))
    raw = np.clip(lad.lad_raw, 0.0, LAD_PLAUSIBLE_MAX) * factor
    occ = lad.occluded
    seen = np.where(occ, 0.0, raw)
    if lad.rows is None:
        crown = hull_mask(seen > 0, grid)
        if lad.options.get("fill") in {f.value for f in DENSE_FILLS}:
            raw, filled = fill_neighbourhood(seen, occ, crown)
            ratio = float(lad.options.get("fill_ratio", 1.0))  # fill="calibrated"
            raw = np.where(filled, np.minimum(raw * ratio, LAD_PLAUSIBLE_MAX), raw)
        else:
            raw, _ = fill_layers(seen, occ, crown)
        ijk = np.argwhere(raw > 0)
        flat_values = raw.reshape(-1)
        return (lambda flat: flat_values[flat]), _box_of(grid, ijk)
    rows = lad.rows
    fill_brick = np.zeros(rows.n_bricks)  # the value of an occluded crown brick's voxels, 0 elsewhere
    if stats is not None and lad.brick_occluded is not None:
        crown, bz, mean, has_mean = brick_layer_means(stats, lad.brick_occluded, stats.field("leaf_w"))
        fill_brick = np.where(crown & has_mean[bz], np.clip(mean[bz] * factor, 0.0, LAD_PLAUSIBLE_MAX), 0.0)
        raw = np.where(occ, fill_brick[rows.brick_of_rows()], seen)
        occ_bricks = lad.brick_occluded.reshape(-1) & (fill_brick > 0)
    else:
        occ_bricks = np.zeros(rows.n_bricks, bool)
    ijk = rows.ijk[raw > 0]
    filled = np.flatnonzero(occ_bricks)
    if len(filled):  # the corners of the filled bricks, for the box
        b_ijk = np.column_stack(np.unravel_index(filled, rows.shape)) * BRICK
        ijk = np.vstack([ijk, b_ijk, np.minimum(b_ijk + BRICK - 1, np.array(grid.shape) - 1)])
    keys = grid.flat(rows.ijk)
    order = np.argsort(keys)
    keys, values = keys[order], raw[order]
    shape = np.array(grid.shape)
    bshape = np.array(rows.shape)

    def lookup(flat):
        flat = np.asarray(flat)
        i = np.minimum(np.searchsorted(keys, flat), len(keys) - 1) if len(keys) else np.zeros(flat.shape, np.int64)
        hit = keys[i] == flat if len(keys) else np.zeros(flat.shape, bool)
        v = np.unravel_index(flat, tuple(shape))
        brick = np.ravel_multi_index(tuple(a // BRICK for a in v), tuple(bshape))
        echo_free = np.where(occ_bricks[brick], fill_brick[brick], 0.0)
        return np.where(hit, values[i] if len(keys) else 0.0, echo_free)
    return lookup, _box_of(grid, ijk)


def _box_of(grid, ijk):
    """The box (2, 3), metres, of the voxels ``ijk``; None when there is none."""
    if not len(ijk):
        return None
    return np.array([grid.lower + ijk.min(axis=0) * grid.voxel_size, grid.lower + (ijk.max(axis=0) + 1) * grid.voxel_size])
