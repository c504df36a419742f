"""Beams to trace: laser pulses with their echoes, in one (world) frame.

Every laser pulse is a ray from its origin along its unit direction.  It
carries a weight, initially 1: each recorded echo at range ``r`` removes its
weight (``1/n`` for an ``n``-echo pulse), and the *tail* weight (echoes the
file did not keep, e.g. cut off by a range limit) carries on to the beam's
``max_range``.  A pulse with no echo is a beam of tail weight 1: it is what
tells a voxel that light got through.  :mod:`tlsvox.voxel.trace` traces them.

Examples
--------
>>> beams = Beams.from_rays([0, 0, 0], [[1, 0, 0], [0, 0, 2]], hit_range=[2.5, np.inf])
>>> len(beams), beams.n_echoes, beams.tail.tolist()
(2, 1, [0.0, 1.0])
>>> beams.echo_points().tolist()
[[2.5, 0.0, 0.0]]
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field

import numpy as np

from tlsvox.errors import InputError
from tlsvox.voxel.bricks import Bricks
from tlsvox.voxel.grid import VoxelGrid

__all__ = ["Beams", "EchoKind", "echo_positions", "echo_rows", "echo_voxels", "voxels_along"]


class EchoKind(enum.IntEnum):
    """What an echo means to the tracer."""

    IGNORE = 0  #: noise: neither stops the beam nor counts
    LEAF = 1  #: a leaf hit (the LAD estimators' events)
    WOOD = 2  #: a wood hit (the wood estimators' events)
    OTHER = 3  #: stops the beam but is neither (ground, targets)


@dataclass
class Beams:
    """Beams to trace, in one (world) frame, with their echoes in CSR form.

    Parameters
    ----------
    origin : (B, 3) float64, metres
        Start of each beam.
    direction : (B, 3) float64
        Unit direction of each beam.
    echo_start : (B + 1,) int64
        Echoes of beam ``b`` are rows ``echo_start[b]:echo_start[b + 1]``.
    echo_range : (E,) float64, metres
        Distance of each echo from its beam's origin, increasing within a beam.
    echo_weight : (E,) float64
        Weight each echo removes from its beam (1/n).
    echo_kind : (E,) uint8
        :class:`EchoKind` of each echo (IGNORE echoes must be removed before).
    tail : (B,) float64
        Weight left after the last echo, carried to ``max_range``.
    max_range : (B,) float64, metres
        Where the beam's knowledge ends (>= its last echo's range).
    g : (B,) float64, optional
        G(theta) of each beam for the leaf angle model (default 1).
    scan_index : (B,) int16, optional
        Which scan each beam came from.
    """

    origin: np.ndarray
    direction: np.ndarray
    echo_start: np.ndarray
    echo_range: np.ndarray
    echo_weight: np.ndarray
    echo_kind: np.ndarray
    tail: np.ndarray
    max_range: np.ndarray
    g: np.ndarray | None = None
    scan_index: np.ndarray | None = None
    meta: dict = field(default_factory=dict)

    def __post_init__(self):
        self.direction = np.ascontiguousarray(np.asarray(self.direction, dtype=np.float64).reshape(-1, 3))
        b = len(self.direction)
        origin = np.asarray(self.origin, dtype=np.float64)
        if origin.size == 3 and b != 1:
            origin = np.broadcast_to(origin.reshape(1, 3), (b, 3))
        self.origin = np.ascontiguousarray(origin.reshape(-1, 3))
        if len(self.origin) != b:
            raise InputError(f"beams: origin has {len(self.origin)} rows for {b} directions")
        norms = np.linalg.norm(self.direction, axis=1)
        if b and (not np.all(np.isfinite(self.direction)) or np.any(np.abs(norms - 1) > 1e-6)):
            raise InputError("beams: every direction must be a finite unit vector (normalise them)")
        if not np.all(np.isfinite(self.origin)):
            raise InputError("beams: origins must be finite")
        self.echo_start = np.ascontiguousarray(np.asarray(self.echo_start, dtype=np.int64).reshape(-1))
        if len(self.echo_start) != b + 1 or self.echo_start[0] != 0 or np.any(np.diff(self.echo_start) < 0):
            raise InputError(
                f"beams: echo_start must be ({b + 1},) non-decreasing offsets starting at 0, "
                f"got shape {self.echo_start.shape}"
            )
        e = int(self.echo_start[-1])
        self.echo_range = np.ascontiguousarray(np.asarray(self.echo_range, dtype=np.float64).reshape(-1))
        self.echo_weight = np.ascontiguousarray(np.asarray(self.echo_weight, dtype=np.float64).reshape(-1))
        self.echo_kind = np.ascontiguousarray(np.asarray(self.echo_kind, dtype=np.uint8).reshape(-1))
        for name in ("echo_range", "echo_weight", "echo_kind"):
            if len(getattr(self, name)) != e:
                raise InputError(f"beams: {name} has {len(getattr(self, name))} values for {e} echoes")
        if e and (not np.all(np.isfinite(self.echo_range)) or self.echo_range.min() < 0):
            raise InputError("beams: echo ranges must be finite and >= 0 metres")
        if e and np.any(self.echo_weight < 0):
            raise InputError("beams: echo weights must be >= 0")
        if e and np.any(self.echo_kind > EchoKind.OTHER):
            raise InputError(f"beams: echo_kind must be one of {[int(k) for k in EchoKind]}")
        self.tail = np.ascontiguousarray(np.broadcast_to(np.asarray(self.tail, dtype=np.float64), (b,)))
        self.max_range = np.ascontiguousarray(
            np.broadcast_to(np.asarray(self.max_range, dtype=np.float64), (b,)))
        if np.any(self.tail < 0) or np.any(np.isnan(self.max_range)) or np.any(self.max_range < 0):
            raise InputError("beams: tail weights must be >= 0 and max_range >= 0 (inf allowed)")
        if self.g is None:
            self.g = np.ones(b)
        self.g = np.ascontiguousarray(np.broadcast_to(np.asarray(self.g, dtype=np.float64), (b,)))
        if b and (not np.all(np.isfinite(self.g)) or self.g.min() <= 0):
            raise InputError("beams: g (G(theta) per beam) must be finite and > 0")
        if self.scan_index is not None:
            self.scan_index = np.asarray(self.scan_index, dtype=np.int16).reshape(b)

    def __len__(self) -> int:
        return len(self.direction)

    @property
    def n_echoes(self) -> int:
        return int(self.echo_start[-1])

    @classmethod
    def from_rays(cls, origin, direction, *, hit_range=None, kind=EchoKind.LEAF,
                  max_range=np.inf) -> Beams:
        """Single-echo beams: each stops at ``hit_range`` (inf = no echo).

        Parameters
        ----------
        origin : (3,) or (B, 3) float, metres
        direction : (B, 3) float
            Normalised here.
        hit_range : (B,) float, metres, optional
            Range of the single echo; ``inf`` (or None) for a gap.
        kind : EchoKind or (B,) int
        max_range : float or (B,) float, metres
            How far gap beams are followed.
        """
        d = np.asarray(direction, dtype=np.float64).reshape(-1, 3)
        n = np.linalg.norm(d, axis=1, keepdims=True)
        if np.any(n == 0):
            raise InputError("direction has zero-length rows")
        d = d / n
        b = len(d)
        r = np.full(b, np.inf) if hit_range is None else np.asarray(hit_range, dtype=np.float64).reshape(b)
        hit = np.isfinite(r)
        start = np.concatenate([[0], np.cumsum(hit)])
        kinds = np.broadcast_to(np.asarray(kind, dtype=np.uint8), (b,))[hit]
        mr = np.broadcast_to(np.asarray(max_range, dtype=np.float64), (b,)).copy()
        mr[hit] = np.maximum(mr[hit], r[hit])
        return cls(origin=origin, direction=d, echo_start=start, echo_range=r[hit],
                   echo_weight=np.ones(int(hit.sum())), echo_kind=kinds,
                   tail=(~hit).astype(np.float64), max_range=mr)

    @classmethod
    def concat(cls, parts: list[Beams]) -> Beams:
        """Join beams of several scans (``scan_index`` filled by position)."""
        if not parts:
            raise InputError("no beams to concatenate")
        starts, off = [], 0
        for p in parts:
            starts.append(p.echo_start[:-1] + off)
            off += p.n_echoes
        starts.append(np.array([off]))
        scan_index = np.concatenate([
            p.scan_index if p.scan_index is not None else np.full(len(p), i, np.int16)
            for i, p in enumerate(parts)])
        return cls(
            origin=np.concatenate([p.origin for p in parts]),
            direction=np.concatenate([p.direction for p in parts]),
            echo_start=np.concatenate(starts),
            echo_range=np.concatenate([p.echo_range for p in parts]),
            echo_weight=np.concatenate([p.echo_weight for p in parts]),
            echo_kind=np.concatenate([p.echo_kind for p in parts]),
            tail=np.concatenate([p.tail for p in parts]),
            max_range=np.concatenate([p.max_range for p in parts]),
            g=np.concatenate([p.g for p in parts]),
            scan_index=scan_index,
        )

    def zenith(self) -> np.ndarray:
        """(B,) zenith angle of each beam, radians (0 = straight up)."""
        return np.arccos(np.clip(self.direction[:, 2], -1.0, 1.0))

    def echo_beam(self) -> np.ndarray:
        """(E,) int64: the beam of each echo (from ``echo_start``)."""
        return np.repeat(np.arange(len(self)), np.diff(self.echo_start))

    def echo_points(self) -> np.ndarray:
        """(E, 3) world positions of the echoes."""
        beam = self.echo_beam()
        return self.origin[beam] + self.direction[beam] * self.echo_range[:, None]


def echo_positions(beams: Beams, kinds=(EchoKind.LEAF, EchoKind.WOOD), *, nudge: float = 0.0) -> np.ndarray:
    """(E, 3) world positions of the beams' echoes of ``kinds``, each moved ``nudge`` metres along its beam."""
    sel = np.isin(beams.echo_kind, np.asarray(kinds, dtype=np.uint8))
    b = beams.echo_beam()[sel]
    return beams.origin[b] + beams.direction[b] * (beams.echo_range[sel] + nudge)[:, None]


def echo_voxels(grid: VoxelGrid, beams: Beams) -> np.ndarray:
    """(K, 3) the distinct voxels of ``grid`` holding a leaf or wood echo of ``beams``.

    An echo on a voxel face may be counted by the kernel on either side, so
    the voxels just before and just after it along its beam are both taken.
    """
    sel = np.isin(beams.echo_kind, np.array([EchoKind.LEAF, EchoKind.WOOD], dtype=np.uint8))
    b = beams.echo_beam()[sel]
    return voxels_along(grid, beams.origin[b], beams.direction[b], beams.echo_range[sel])


def voxels_along(grid: VoxelGrid, origin, direction, ranges) -> np.ndarray:
    """(K, 3) the distinct voxels of ``grid`` holding the points ``origin + direction * ranges``.

    Each point counts in the voxels just before and just after it along its
    ray (one on a voxel face may be counted by the tracer on either side), as
    in :func:`echo_voxels`.
    """
    eps = 1e-6 * grid.voxel_size
    o, d = np.asarray(origin, dtype=np.float64), np.asarray(direction, dtype=np.float64)
    r = np.asarray(ranges, dtype=np.float64)[:, None]
    flat = []
    for s in (-eps, eps):
        ijk = grid.index_of(o + d * (r + s))
        flat.append(grid.flat(ijk[grid.contains_index(ijk)]))
    return grid.unflat(np.unique(np.concatenate(flat)))


def echo_rows(grid: VoxelGrid, beams: Beams) -> Bricks:
    """The rows a sparse trace must list: the voxels holding a leaf or wood echo (:func:`echo_voxels`)."""
    return Bricks.from_ijk(grid, echo_voxels(grid, beams))
