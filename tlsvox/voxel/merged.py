"""Merged point clouds: tree scans as people share them.

Most published tree scans are one registered cloud: x, y, z, sometimes
intensity and return numbers, rarely the scan positions, never the empty
pulses.  The beam estimators need beams, so this module rebuilds what it can:

With the scan positions known (:func:`split_by_positions`):

1. Each point is given to a position: by its LAS ``point_source_id`` when the
   file holds as many distinct ids as there are positions (the ids sorted,
   matched to the positions in the order given), else to the nearest
   position (the likeliest by point density, which falls as 1/r^2; whether
   the point was visible from there is not checked).
2. Each position's points become a scan in its own frame (the position the
   origin, the world's axes), their echoes grouped into pulses by return
   number and direction (:func:`tlsvox.voxel.pulses.group_pulses`).
3. The empty pulses (those that left no echo) are estimated per angular
   cell of zenith x azimuth: a terrestrial scanner fires the same number of
   pulses into every such cell (constant zenith and azimuth steps), so a
   cell holding fewer first echoes than that lost the rest as gaps.  The
   pulses a cell should hold come from the scanner's angular step when
   given, else from the step estimated from the cloud (:func:`estimate_step`:
   the next point along each scan line and each row).  Cells hold about
   64 pulses (8 x 8 steps when the steps are equal) and span the position's
   points and half a step beyond; a cell's shortfall is pooled with its
   neighbours' surpluses over 2 x 2 cells first (:func:`_missing`).  Only
   cells inside the angular span of the position's points are filled; the
   missing pulses of a cell are spread over it on a quasi-random (R2)
   lattice, so the result does not depend on a seed.

The estimate is biased where the cloud was thinned or filtered (a thinned
cloud's cells look gappy: too many empty pulses, LAD low), and where points
are given to the wrong position (beams through the wrong voxels).
``meta["merged"]`` of each scan states the rule, the step and the share of
its expected pulses the densest cells hold (about 1 when the step is right).

With no positions (:func:`occupancy_lad`): no beams, so no occlusion
correction.  The leaf area in a voxel is the number of fine cells that hold a
leaf point times the cell's face area, over the mean number of cells a unit
of leaf surface crosses (``|n_x| + |n_y| + |n_z|`` per cell face area,
averaged over the leaf angle distribution: 1.5 for spherical leaves).  It
counts only the leaves the scanners saw.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tlsvox.errors import InputError
from tlsvox.scan import PulseTable, Scan, directions_from_angles

__all__ = ["AngularStep", "MERGED_CELL_STEPS", "assign_points", "crossings_per_area", "empty_pulses", "estimate_step",
           "merge_scans", "merged_warnings", "occupancy_lad", "parse_positions", "read_merged",
           "split_by_positions", "voxelize_occupancy"]

#: an angular cell holds this many squared pulses (8 x 8 steps on a square lattice, 32 x 2 on the VZ-400i's
#: 0.048 x 0.622 deg), about as wide as it is high: enough pulses that one more or less is under 2 %
MERGED_CELL_STEPS = 8


@dataclass(frozen=True)
class AngularStep:
    """A terrestrial scanner's angular resolution: its zenith and azimuth steps, degrees."""

    zenith_deg: float
    azimuth_deg: float

    def __post_init__(self):
        for name in ("zenith_deg", "azimuth_deg"):
            v = getattr(self, name)
            if not (np.isfinite(v) and 0 < v < 10):
                raise InputError(f"the angular step's {name}={v!r} must be a positive angle under 10 degrees "
                                 "(the scanner's resolution, e.g. 0.04; CLI --angular-step 0.04 or 0.048,0.622)")

    @classmethod
    def parse(cls, value) -> AngularStep | None:
        """``None``, one number (both steps), two numbers (zenith, azimuth) or an AngularStep."""
        if value is None or isinstance(value, AngularStep):
            return value
        v = np.atleast_1d(np.asarray(value, dtype=np.float64))
        if v.size == 1:
            return cls(float(v[0]), float(v[0]))
        if v.size == 2:
            return cls(float(v[0]), float(v[1]))
        raise InputError(f"angular step {value!r}: give one angle or zenith,azimuth in degrees (e.g. 0.048,0.622)")


def parse_positions(spec) -> np.ndarray:
    """Scan positions (K, 3) from ``"x,y,z;x,y,z"``, a text file (one ``x y z`` or ``x,y,z`` a line,
    ``#`` comments) or an array."""
    if isinstance(spec, (str, Path)) and Path(spec).is_file():
        rows = []
        for k, line in enumerate(Path(spec).read_text(encoding="utf-8").splitlines(), 1):
            line = line.split("#", 1)[0].strip()
            if not line:
                continue
            parts = line.replace(",", " ").replace(";", " ").split()
            try:
                vals = [float(p) for p in parts[:3]]
            except ValueError:
                raise InputError(f"{spec}: line {k} {line!r} is not x y z of a scan position (metres)") from None
            if len(vals) < 3:
                raise InputError(f"{spec}: line {k} {line!r} has {len(vals)} numbers; a scan position is x y z")
            rows.append(vals)
        pos = np.array(rows, dtype=np.float64).reshape(-1, 3)
        where = f"{spec}"
    elif isinstance(spec, (str, Path)) and (isinstance(spec, Path) or "/" in spec or "\\" in spec
                                            or Path(spec).suffix.lower() in (".txt", ".csv", ".xyz")):
        raise InputError(f"--scan-positions {str(spec)!r}: no such file; give a text file of x y z lines, or the "
                         "positions themselves (x,y,z;x,y,z)")
    elif isinstance(spec, str):
        rows = []
        for part in (p for p in spec.split(";") if p.strip()):
            try:
                vals = [float(x) for x in part.split(",")]
            except ValueError:
                raise InputError(f"--scan-positions {spec!r}: give x,y,z;x,y,z (metres) or a file of x y z "
                                 "lines") from None
            if len(vals) != 3:
                raise InputError(f"--scan-positions {spec!r}: {part.strip()!r} has {len(vals)} numbers; each "
                                 "position needs three numbers x,y,z (separate positions with ';')")
            rows.append(vals)
        pos = np.array(rows, dtype=np.float64).reshape(-1, 3)
        where = "--scan-positions"
    else:
        pos = np.asarray(spec, dtype=np.float64).reshape(-1, 3)
        where = "positions"
    if not len(pos):
        raise InputError(f"{where}: no scan position given; give one x,y,z per scan position")
    if not np.all(np.isfinite(pos)):
        raise InputError(f"{where}: a scan position is not finite")
    if len(np.unique(np.round(pos, 6), axis=0)) < len(pos):
        raise InputError(f"{where}: two scan positions are the same point; give each position once")
    return pos


def merge_scans(scans) -> tuple[Scan, np.ndarray | None]:
    """Scans (each in the world frame: its pose applied, or its coordinates taken as world) as one
    merged Scan in the world frame, and each point's file index when there are several files."""
    scans = list(scans)
    parts = [s.world_xyz() if s.pose is not None else s.xyz for s in scans]

    def cat(name, dtype):
        vals = [getattr(s, name) for s in scans]
        if any(v is None for v in vals):
            return None
        return np.concatenate([np.asarray(v, dtype=dtype) for v in vals])

    for s in scans:
        if s.pulses is not None:
            raise InputError(f"scan {s.name!r} has its pulse table: voxelise it as it is, without --scan-positions "
                             "(the positions are for merged clouds that lost their pulses)")
    merged = Scan(np.vstack(parts), reflectance_db=cat("reflectance_db", np.float32),
                  intensity=cat("intensity", np.float32), return_number=cat("return_number", np.uint8),
                  number_of_returns=cat("number_of_returns", np.uint8),
                  truth_material=cat("truth_material", np.uint8), classification=cat("classification", np.uint8),
                  name=scans[0].name if len(scans) == 1 else "merged",
                  meta={k: v for k, v in scans[0].meta.items() if k in ("classes", "preset", "units")})
    source = np.concatenate([np.full(len(s), i) for i, s in enumerate(scans)]) if len(scans) > 1 else None
    return merged, source


def assign_points(world, positions, *, source_id=None, rule: str = "auto") -> tuple[np.ndarray, str]:
    """The position each point was seen from (index into ``positions``) and how that was decided.

    ``rule``: ``source-id`` (the sorted distinct ``source_id`` values are the positions in order;
    their count must match), ``nearest``, or ``auto`` (source-id when it fits, else nearest).
    """
    world = np.asarray(world, dtype=np.float64).reshape(-1, 3)
    positions = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    rule = str(rule).lower().replace("_", "-")
    if rule not in ("auto", "source-id", "nearest"):
        raise InputError(f"assignment rule {rule!r}: choose auto, source-id or nearest")
    if rule != "nearest" and source_id is not None:
        ids, inverse = np.unique(np.asarray(source_id).reshape(-1), return_inverse=True)
        if len(ids) == len(positions):
            return inverse.astype(np.int64), (f"by source id ({len(ids)} distinct ids, sorted "
                                              f"{ids.tolist()[:8]}, matched to the positions in the order given)")
        if rule == "source-id":
            raise InputError(f"the cloud holds {len(ids)} distinct source ids ({ids.tolist()[:8]}) for "
                             f"{len(positions)} scan positions: give one position per id, or assign by the "
                             "nearest position (CLI --assign nearest)")
    elif rule == "source-id":
        raise InputError("assignment by source id needs per-point ids (LAS point_source_id, or one file per "
                         "position); the cloud has none: assign by the nearest position (CLI --assign nearest)")
    from scipy.spatial import cKDTree

    _, idx = cKDTree(positions).query(world, k=1)
    return np.asarray(idx, dtype=np.int64), "nearest position (visibility not checked)"


def _angles_deg(u) -> tuple[np.ndarray, np.ndarray]:
    zen = np.degrees(np.arccos(np.clip(u[:, 2], -1.0, 1.0)))
    az = np.degrees(np.arctan2(u[:, 1], u[:, 0])) % 360.0
    return zen, az


def _azimuth_span(az, half: float) -> tuple[float, float]:
    """Start and width (degrees) of the smallest azimuth interval holding every direction, widened by
    ``half`` a step at each end (the whole circle when its largest gap is under two steps)."""
    a = np.sort(az)
    gaps = np.diff(np.r_[a, a[0] + 360.0])
    k = int(np.argmax(gaps))
    if gaps[k] < 4 * half:
        return 0.0, 360.0
    start = a[(k + 1) % len(a)]
    width = (a[k] - start) % 360.0
    return float(start - half), float(min(360.0, width + 2 * half))


def _r2(n: int) -> np.ndarray:
    """The first ``n`` points of the R2 quasi-random sequence on the unit square (Roberts 2018)."""
    g = 1.32471795724474602596  # the plastic number
    k = np.arange(1, n + 1)[:, None]
    return (0.5 + k * np.array([1.0 / g, 1.0 / g ** 2])) % 1.0


def empty_pulses(directions, step: AngularStep | None = None, *, cell_steps=None) -> tuple[np.ndarray, dict]:
    """Directions (M, 3) of the pulses that left no echo, from the first echoes' ``directions`` (unit
    vectors from the scanner), and what the estimate rests on (see the module docstring).
    ``cell_steps`` (zenith, azimuth) sets the cells' size in scanner steps."""
    u = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
    if len(u) < 16:
        raise InputError(f"{len(u)} pulses from this position: too few to estimate its empty pulses (16 or more)")
    zen, az = _angles_deg(u)
    given = step is not None
    if step is None:
        step = estimate_step(u)
    if cell_steps is None:  # about MERGED_CELL_STEPS^2 pulses in a cell about as wide as it is high
        n = MERGED_CELL_STEPS ** 2
        ka = max(1, int(round(np.sqrt(n * step.zenith_deg / step.azimuth_deg))))
        kz = max(1, int(round(n / ka)))
        cell_steps = (kz, ka)
    cz, ca = cell_steps[0] * step.zenith_deg, cell_steps[1] * step.azimuth_deg
    expected = float(cell_steps[0] * cell_steps[1])
    source = (f"the angular step {step.zenith_deg:.4g} x {step.azimuth_deg:.4g} deg "
              + ("(given)" if given else "(estimated from the cloud: the next point along each scan line and "
                                         "row; give the scanner's own with --angular-step)"))
    counts, (fz, fa), z0, a0, nz, na, ca = _cell_counts(zen, az, cz, ca, step)
    share = np.outer(fz, fa).ravel()
    missing = _missing(expected * share - counts, nz, na)
    cells = np.nonzero(missing)[0]
    reps = missing[cells]
    n_new = int(reps.sum())
    if n_new > 50_000_000:
        raise InputError(f"{n_new:,} empty pulses estimated for one position: the angular step is too fine for "
                         "this cloud (give the scanner's own, e.g. --angular-step 0.04) or the cloud covers the "
                         "whole sphere at a fine step; crop it to the trees")
    cell = np.repeat(cells, reps)
    # the k-th missing pulse of a cell at the k-th R2 point of the cell
    first = np.repeat(np.cumsum(reps) - reps, reps)
    k = np.arange(n_new) - first
    frac = _r2(int(reps.max()) if n_new else 0)[k] if n_new else np.zeros((0, 2))
    zi, ai = cell // na, cell % na
    new = directions_from_angles(np.radians(z0 + (zi + frac[:, 0] * fz[zi]) * cz),  # an edge cell's pulses on
                                 np.radians(a0 + (ai + frac[:, 1] * fa[ai]) * ca))  # its part inside the span
    held = (counts > 0) & (share > 0.99)
    coverage = float(np.percentile(counts[held], 90) / expected) if held.any() and expected > 0 else float("nan")
    info = {"pulses_per_cell": float(expected), "cell_deg": [float(cz), float(ca)], "cells": int(nz * na),
            "cells_with_echoes": int(np.count_nonzero(counts)), "empty_pulses": n_new,
            "returned_pulses": int(len(u)), "expected_from": source,
            "coverage_p90": round(coverage, 3),
            "zenith_span_deg": [float(z0), float(z0 + nz * cz)], "azimuth_span_deg": [float(a0), float(na * ca)]}
    return new, info


def _missing(deficit, nz: int, na: int) -> np.ndarray:
    """Empty pulses per cell (nz * na,) from each cell's signed deficit (expected minus held).

    A lattice that the cells do not divide evenly (a tilted scanner, a step read a little off) moves
    pulses between neighbouring cells: one holds a pulse too many, the next one too few.  Clipping each
    cell at zero would count every such shortfall as a gap, so the deficits are first summed over
    blocks of 2 x 2 cells (a surplus cancels a neighbour's shortfall), clipped there, and the block's
    empty pulses shared among its cells in proportion to their own shortfalls (cumulative rounding:
    the totals kept)."""
    d = np.asarray(deficit, dtype=np.float64).reshape(nz, na)
    pz, pa = nz + nz % 2, na + na % 2
    full = np.zeros((pz, pa))
    full[:nz, :na] = d
    blocks = full.reshape(pz // 2, 2, pa // 2, 2)
    total = np.clip(blocks.sum(axis=(1, 3)), 0, None)
    short = np.clip(blocks, 0, None)
    norm = short.sum(axis=(1, 3))
    share = np.divide(short, norm[:, None, :, None], out=np.zeros_like(short), where=norm[:, None, :, None] > 0)
    want = (share * total[:, None, :, None]).transpose(0, 2, 1, 3).ravel()  # block by block
    counts = np.diff(np.rint(np.r_[0.0, np.cumsum(want)])).astype(np.int64)
    out = counts.reshape(pz // 2, pa // 2, 2, 2).transpose(0, 2, 1, 3).reshape(pz, pa)
    return np.clip(out[:nz, :na], 0, None).ravel()


def estimate_step(directions, sample: int = 50000) -> AngularStep:
    """A scanner's zenith and azimuth steps from its points' directions: the median over (a seeded
    sample of) points of the offset to the next point down its scan line (zenith) and to the next
    along its row (azimuth), in degrees: lines and rows told apart by stretching the other axis."""
    from scipy.spatial import cKDTree

    u = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
    zen, az = _angles_deg(u)
    keep = (zen > 5) & (zen < 175)  # the azimuths crowd at the poles
    zen, az = zen[keep], az[keep]
    if len(zen) < 16:
        raise InputError("too few points away from the zenith to estimate the angular step; give it "
                         "(--angular-step DEG)")
    pts = np.column_stack([zen, az])
    q = np.arange(len(pts)) if len(pts) <= sample else np.sort(
        np.random.default_rng(0).choice(len(pts), sample, replace=False))
    d1 = float(np.median(cKDTree(pts).query(pts[q], k=2)[0][:, 1]))  # about the smaller step
    if not d1 > 0:
        raise InputError("the cloud's points repeat their directions; no angular step can be read from them: "
                         "give it (--angular-step DEG)")

    def next_along(axis: int) -> float:
        # the other axis stretched until most points' nearest neighbours lie on their own scan line (or
        # row): little, so that the coordinates' scatter across the line stays small against the step
        for stretch in (2.0, 8.0, 32.0, 128.0):
            scaled = pts.copy()
            scaled[:, 1 - axis] *= stretch
            _, nb = cKDTree(scaled).query(scaled[q], k=5)
            off = pts[nb[:, 1:]] - pts[q, None]
            off[..., 1] = (off[..., 1] + 180.0) % 360.0 - 180.0
            ahead = (off[..., axis] > 1e-6) & (np.abs(off[..., 1 - axis]) < 0.5 * d1)
            v = np.where(ahead, off[..., axis], np.inf).min(axis=1)  # the next point ahead, not the nearer of two
            if np.mean(np.isfinite(v)) >= 0.5:
                return float(np.median(v[np.isfinite(v)]))
        return float("nan")

    zstep, astep = next_along(0), next_along(1)
    if not (np.isfinite(zstep) and np.isfinite(astep)):
        raise InputError("the cloud's directions show no regular scan pattern to estimate the angular step "
                         "from; give it (--angular-step DEG)")
    return AngularStep(zstep, astep)


def _cell_counts(zen, az, cz: float, ca: float, step: AngularStep):
    """First echoes per angular cell over the span of the directions (half a step beyond the outer
    ones): counts (nz * na,), the share of each zenith row (nz,) and azimuth column (na,) of cells
    inside the span, the span's start, its cell counts and the azimuth cell size."""
    z0 = float(zen.min()) - step.zenith_deg / 2
    z_end = float(zen.max()) + step.zenith_deg / 2
    nz = max(int(np.ceil((z_end - z0) / cz - 1e-9)), 1)
    a0, width = _azimuth_span(az, step.azimuth_deg / 2)
    if width >= 360.0:
        na = max(int(round(360.0 / ca)), 1)
        ca = 360.0 / na
    else:
        na = max(int(np.ceil(width / ca - 1e-9)), 1)
    iz = np.clip(((zen - z0) / cz).astype(np.int64), 0, nz - 1)
    ia = np.clip((((az - a0) % 360.0) / ca).astype(np.int64), 0, na - 1)
    counts = np.bincount(iz * na + ia, minlength=nz * na)
    fz = np.clip((z_end - (z0 + np.arange(nz) * cz)) / cz, 0.0, 1.0)
    fa = np.clip((width - np.arange(na) * ca) / ca, 0.0, 1.0)
    return counts, (fz, fa), z0, a0, nz, na, ca


def split_by_positions(merged: Scan, positions, *, source_id=None, assign: str = "auto", step=None,
                       cell_steps=None, progress: bool = False) -> list[Scan]:
    """One scan per position from a merged world-frame cloud, each with a pulse table rebuilt (its
    echoes grouped into pulses, its empty pulses estimated): what :func:`tlsvox.voxelize` needs.

    Each scan's ``meta["merged"]`` states how its points were assigned and how its empty pulses
    were estimated; its pose is the position (no rotation: the world's axes).
    """
    from tlsvox.voxel.pulses import group_pulses

    positions = parse_positions(positions)
    step = AngularStep.parse(step)
    world = merged.world_xyz() if merged.pose is not None else merged.xyz
    owner, how = assign_points(world, positions, source_id=source_id, rule=assign)
    out = []
    it = range(len(positions))
    if progress:
        from tqdm.auto import tqdm

        it = tqdm(it, desc="positions", unit="position", leave=False)
    for k in it:
        sel = np.nonzero(owner == k)[0]
        if len(sel) < 16:
            raise InputError(f"scan position {k} {positions[k].tolist()} has {len(sel)} points of the cloud "
                             f"(assigned {how}): give only positions the cloud was scanned from, in its "
                             "coordinates")
        xyz = world[sel] - positions[k]
        r = np.linalg.norm(xyz, axis=1)
        if np.any(r < 1e-3):
            raise InputError(f"scan position {k} {positions[k].tolist()}: {int(np.sum(r < 1e-3))} points lie on "
                             "it; a position is where the scanner stood, not a point of the cloud")

        def sub(v):
            return None if v is None else v[sel]

        part = Scan(xyz, reflectance_db=sub(merged.reflectance_db), intensity=sub(merged.intensity),
                    return_number=sub(merged.return_number), number_of_returns=sub(merged.number_of_returns),
                    truth_material=sub(merged.truth_material), classification=sub(merged.classification),
                    scan_id=k, name=f"{merged.name}@{k}", meta=dict(merged.meta))
        groups = group_pulses(part)
        try:
            new, info = empty_pulses(groups.direction, step, cell_steps=cell_steps)
        except InputError as err:
            raise InputError(f"scan position {k} {np.round(positions[k], 3).tolist()}: {err} (is it where the "
                             "scanner stood, in the cloud's coordinates?)") from None
        dirs = np.vstack([groups.direction, new])
        n_echoes = np.concatenate([np.minimum(groups.n_nominal, 255), np.zeros(len(new), np.int64)])
        part.pulse_id = groups.pulse_of_echo
        part.pulses = PulseTable(dirs, n_echoes)
        pose = np.eye(4)
        pose[:3, 3] = positions[k]
        part.pose = pose
        part.meta["merged"] = {"position": positions[k].tolist(), "assigned": how, "points": int(len(sel)),
                               "orphans": int(groups.orphans), **info}
        out.append(part)
    return out


def crossings_per_area(leaf_angle, n: int = 512) -> float:
    """Mean ``|n_x| + |n_y| + |n_z|`` of the leaf normals (azimuths uniform): the cube faces a unit of
    leaf surface crosses per unit face area.  Spherical leaves: 1.5; horizontal: 1; vertical: 4/pi."""
    from voxlidar.leaf_orientation import LeafAngle

    la = LeafAngle.from_dict(leaf_angle)
    t = np.asarray(la.ppf((np.arange(n) + 0.5) / n), dtype=np.float64)
    return float(np.mean(np.cos(t) + (4.0 / np.pi) * np.sin(t)))


def occupancy_lad(points, grid, *, cell: float, leaf_angle="uniform") -> np.ndarray:
    """LAD (m2/m3, ``grid.shape``) from the fine cells of size ``cell`` (metres) that hold a leaf point:
    occupied cells x cell^2 / crossings_per_area(leaf_angle) / voxel volume (module docstring)."""
    cell = float(cell)
    if not (np.isfinite(cell) and 0 < cell <= grid.voxel_size):
        raise InputError(f"occupancy cell {cell!r} m must be positive and no larger than the voxel "
                         f"({grid.voxel_size:g} m; e.g. --occupancy-cell 0.02)")
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    lad = np.zeros(grid.shape)
    if not len(p):
        return lad
    fine = np.unique(np.floor((p - grid.lower) / cell).astype(np.int64), axis=0)
    centre = grid.lower + (fine + 0.5) * cell
    ijk = np.floor((centre - grid.lower) / grid.voxel_size).astype(np.int64)
    inside = np.all((ijk >= 0) & (ijk < np.asarray(grid.shape)), axis=1)
    np.add.at(lad, tuple(ijk[inside].T), 1.0)
    return lad * cell ** 2 / crossings_per_area(leaf_angle) / grid.voxel_volume


#: the scene meta's label of a scene made without beams
OCCUPANCY_NOTE = ("no scan positions: leaf area from the fine cells holding leaf points (no beams, occlusion not "
                  "corrected: leaves no scan saw are missing; tlsvox.voxel.merged)")


def voxelize_occupancy(scan: Scan, settings=None, *, cell: float | None = None, classes=None, **kwargs):
    """A scene from a merged world-frame cloud whose scan positions are unknown (:func:`occupancy_lad`).

    The ground, the grid, the echo classes and the leaf angle model come from ``settings`` (or the
    keyword arguments) as for :func:`tlsvox.voxelize`; the estimator, fill and occlusion settings do
    not apply (there are no beams).  Wood is the wood points' occupied cells per voxel stretched to
    [0, 1] as ``count_stretch`` does.  ``cell`` (metres) defaults to the leaf points' spacing (median
    nearest neighbour) rounded up to 5 mm, at least 1 cm: a cell finer than the sampling leaves most
    leaf cells without a point.  ``scene.meta["estimator"]`` is ``"occupancy"`` and
    ``scene.meta["occupancy"]`` says what that means.  Returns a
    :class:`~tlsvox.voxel.stages.VoxelizeResult` (no trace: ``stats`` and ``lad`` are None).
    """
    import time

    from tlsvox.voxel.settings import VoxelizeSettings
    from tlsvox.voxel.stages import VoxelizeResult, below_ground, make_grid, scene_ground, world_echoes
    from tlsvox.voxel.trace import EchoKind
    from tlsvox.voxel.wood.voxels import WoodEstimate, WoodMethod, count_stretch
    from voxlidar.leaf_orientation import LeafAngle
    from voxlidar.scene import Scene

    t0 = time.perf_counter()
    kwargs.pop("progress", None)
    s = VoxelizeSettings.from_kwargs(settings, scanner_frame=True, **kwargs)
    if scan.pose is None:
        scan.pose = np.eye(4)  # the merged cloud is in the world frame
    echoes = world_echoes([scan], None if classes is None else [classes], s)
    plane = scene_ground(echoes, s)
    grid = make_grid(echoes, plane, s)
    world, kinds = echoes.world[0], echoes.kinds[0]
    la = LeafAngle.from_dict(s.model.leaf_angle)
    spacing = _point_spacing(world[kinds == EchoKind.LEAF])
    if cell is None:
        cell = max(0.01, np.ceil(spacing * 200 - 1e-9) / 200) if np.isfinite(spacing) else 0.02
        cell = float(min(cell, grid.voxel_size))
    lad = occupancy_lad(world[kinds == EchoKind.LEAF], grid, cell=cell, leaf_angle=la)
    wood_cells = occupancy_lad(world[kinds == EchoKind.WOOD], grid, cell=cell, leaf_angle="horizontal")
    wood, scale = count_stretch(wood_cells, percentile=s.model.wood_percentile)
    ijk = np.argwhere((lad > 0) | (wood > 0))
    sel = tuple(ijk.T)
    lad_v, wood_v = lad[sel], wood[sel]
    if plane is not None:
        lad_v = np.where(below_ground(grid, ijk, plane), 0.0, lad_v)
    keep = (lad_v > 0) | (wood_v > 0)
    ijk, lad_v, wood_v = ijk[keep], lad_v[keep], wood_v[keep]
    warnings = []
    if np.isfinite(spacing) and spacing > cell:
        warnings.append(f"the leaf points lie {spacing:.3g} m apart (median nearest neighbour), more than the "
                        f"occupancy cell of {cell:g} m: most leaf cells hold no point and the leaf area reads "
                        f"low; use a cell of at least the spacing (--occupancy-cell {np.ceil(spacing * 200) / 200:g})")
    cc = (grid.centers(ijk)[:, :2] * lad_v[:, None]).sum(axis=0) / lad_v.sum() if lad_v.sum() > 0 else np.zeros(2)
    total = time.perf_counter() - t0
    infos: list = [{"scan": scan.name, "echoes": len(scan), "echo_weights": "none"}]
    meta = {"estimator": "occupancy", "occupancy": {"cell_m": cell, "crossings_per_area": crossings_per_area(la),
                                                   "leaf_point_spacing_m": spacing, "note": OCCUPANCY_NOTE},
            "options": {}, "flags": {"occluded": 0, "voxels": int(len(ijk))}, "wood_method": "count_stretch",
            "wood_scale": scale, "scans": infos,
            "timings": {"total": total}, "tracer": None, "beams": 0, "voxel_steps": 0, "warnings": warnings,
            "leaf_angle": la.to_dict(), "layout": "dense", "echo_weights": ["none"],
            "undetected": {"rule": "ignore"},
            "ground": None if plane is None else {"coefficients": list(plane.coefficients),
                                                  "tilt_deg": plane.tilt_deg, "inlier_rmse": plane.inlier_rmse},
            "settings": s.to_dict()}
    scene = Scene(origin=grid.lower, voxel_size=grid.voxel_size, shape=grid.shape, ijk=ijk, lad=lad_v, wood=wood_v,
                  wood_kind="probability", occluded=np.zeros(len(ijk), bool), lad_std=np.zeros(len(ijk)),
                  leaf_angle=la, leaf_azimuth=s.model.leaf_azimuth, crown_center=cc,
                  ground_z=None if plane is None else plane.z_center, meta=meta)
    wood_est = WoodEstimate(wood, "probability", WoodMethod.COUNT_STRETCH, scale)
    return VoxelizeResult(scene, grid, None, None, wood_est, plane, infos, {"total": total})


def _point_spacing(points, sample: int = 20000) -> float:
    """Median nearest-neighbour distance of (a seeded sample of) ``points``, metres."""
    from scipy.spatial import cKDTree

    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if len(p) < 2:
        return float("nan")
    q = p if len(p) <= sample else p[np.random.default_rng(0).choice(len(p), sample, replace=False)]
    d, _ = cKDTree(p).query(q, k=2)
    return float(np.median(d[:, 1]))


def read_merged(paths) -> tuple[Scan, np.ndarray | None]:
    """Point cloud files (any format :func:`tlsvox.readers.read_any` reads; each in the world frame:
    a pose sidecar applied, else its coordinates as they are) as one merged world-frame Scan, and
    each point's source: the file's index when there are several files, else a LAS file's own
    ``point_source_id`` when it holds more than one value (None otherwise)."""
    from tlsvox.readers import ScanFormat, read_any, scan_format

    paths = [Path(p) for p in paths]
    scans = [read_any(p, scan_id=i, min_points=1) for i, p in enumerate(paths)]
    merged, source = merge_scans(scans)
    if len(paths) == 1 and scan_format(paths[0]) in (ScanFormat.LAS, ScanFormat.LAZ):
        import laspy

        ids = np.asarray(laspy.read(str(paths[0])).point_source_id)
        if len(np.unique(ids)) > 1:
            source = ids
    return merged, source


def merged_warnings(parts) -> list[str]:
    """One sentence when several positions' points were split by the nearest position, and one for
    each rebuilt position whose angular cells hold far from the pulses its step implies (the cloud
    thinned, the step wrong, or points given to the wrong position)."""
    out = []
    if len(parts) > 1 and any("nearest" in (p.meta.get("merged") or {}).get("assigned", "") for p in parts):
        out.append(f"the points were given to the nearest of {len(parts)} scan positions: the far sides of the crowns "
                   "are then traced from the wrong scanner and their cells read as gaps (on the demo's oak the leaf "
                   "area falls by two thirds, docs/bench/merged.md); give one file per position or a LAS "
                   "point_source_id per position")
    for p in parts:
        m = p.meta.get("merged") or {}
        cov = m.get("coverage_p90")
        if cov is None or not np.isfinite(cov) or 0.75 <= cov <= 1.33:
            continue
        cause = ("the cloud was thinned or filtered, the angular step is finer than the scanner's, or the position "
                 "was given points another one saw (too many empty pulses: LAD reads low)" if cov < 0.75 else
                 "the angular step is coarser than the scanner's, or points of other positions were given to it")
        out.append(f"scan position {np.round(m['position'], 3).tolist()}: its fullest angular cells hold {cov:.2f} times the "
                   f"{m['pulses_per_cell']:g} pulses per cell that {m['expected_from']} implies: {cause}; "
                   "give the scanner's step (--angular-step) and one file or source id per position")
    return out
