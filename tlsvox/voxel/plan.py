"""The memory a voxelisation will take, before it runs: :func:`memory_plan`.

The tracer keeps its sums either for every voxel of the grid (the dense
layout) or for the voxels holding echoes plus coarse sums per brick (the
sparse layout, :mod:`tlsvox.voxel.bricks`); :func:`memory_plan` counts both
for a set of beams, picks one (``layout="auto"``), and says how to make a grid
fit when neither does.  :func:`undetected_bytes` adds what the detection
correction (``undetected="model"``, :mod:`tlsvox.voxel.detection`) holds.

A run peaks in one of two phases, and the plan's ``need`` is the larger:

- *making the beams* (``build``): each scan's conversion
  (:func:`~tlsvox.voxel.pulses.beams_from_scan`) holds working arrays of
  about its own beams' size again, beside the scans done before; several
  scans are then joined (their beams and the joined copy side by side); and
  the voxels holding echoes are found (:func:`~tlsvox.voxel.beams.echo_voxels`);
- *tracing and estimating* (``run``): the beams, the layout's sums, and what
  ``undetected`` and ``fill`` add.

With several scans of a few hundred thousand voxels the first phase is the
larger (the synthetic oak's two scans at 20 cm: about 0.9 GiB against
0.45 GiB, docs/voxelize.md).  The scans themselves (loaded before
:func:`~tlsvox.voxel.stages.voxelize` starts) are not counted.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tlsvox.errors import InputError
from tlsvox.voxel.bricks import Bricks
from tlsvox.voxel.detection import Undetected
from tlsvox.voxel.estimators import FillMode
from tlsvox.voxel.fills import check_calibration_scans
from tlsvox.voxel.grid import VoxelGrid, format_bytes, memory_limit
from tlsvox.voxel.stats import NF
from tlsvox.voxel.trace import Beams, EchoKind, Tracer, echo_voxels
from voxlidar.choices import Choice

__all__ = ["CALIBRATED_BYTES", "DENSE_AUTO_MAX", "NEIGHBOURHOOD_BYTES", "Layout", "MemoryPlan", "beams_bytes", "build_bytes",
           "memory_plan", "row_bytes", "ALLOCATOR_SHARE", "undetected_bytes", "with_allocator"]

#: estimator work arrays, bytes per voxel (dense) or row (sparse), beside the traced sums
_ESTIMATE_BYTES = 24 * 8
#: ``layout="auto"`` traces densely up to this many bytes (small grids: every voxel's own sums)
DENSE_AUTO_MAX = 1024**3


class Layout(str, Choice):
    """How the tracer keeps its sums (see :mod:`tlsvox.voxel.bricks`)."""

    AUTO = "auto"  #: dense when it takes at most DENSE_AUTO_MAX bytes, else sparse
    DENSE = "dense"  #: every voxel of the grid
    SPARSE = "sparse"  #: voxels holding echoes, plus coarse sums per brick of 8^3 voxels


@dataclass
class MemoryPlan:
    """What tracing and estimating a grid will take, before it runs (bytes)."""

    grid: VoxelGrid
    dense: int  #: bytes of the dense layout
    sparse: int  #: bytes of the sparse layout
    beams: int  #: bytes of the beams themselves
    rows: int  #: voxels holding echoes (the sparse layout's rows)
    limit: int  #: bytes allowed
    layout: Layout  #: the layout chosen
    undetected: int = 0  #: bytes of the ``undetected="model"`` correction on top (0 without it)
    fill: int = 0  #: bytes of ``fill="neighbourhood"``'s temporaries on top (and the per-scan sums of "calibrated")
    build: int = 0  #: peak bytes while the beams are made, joined and their echoes' voxels found
    echoes: int = 0  #: echoes of the beams (voxelize keeps each scan echo's class, 1 byte, through the run)
    note: str = ""  #: what the plan is of, when a run holds more than one grid (``lad_voxel_size``)

    @property
    def run(self) -> int:
        """Bytes while tracing and estimating: the beams (with the echo classes voxelize keeps, 1 byte
        per echo), the layout's sums, and what the options add."""
        return (self.beams + self.echoes + (self.dense if self.layout is Layout.DENSE else self.sparse)
                + self.undetected + self.fill)

    @property
    def need(self) -> int:
        """The run's peak: the larger of making the beams (``build``) and tracing and estimating (``run``),
        and ``ALLOCATOR_SHARE`` of it on top for what the memory allocator keeps."""
        return with_allocator(max(self.build, self.run))

    def sizes(self) -> str:
        """The grid and what each layout costs."""
        nx, ny, nz = self.grid.shape
        extra = f", undetected='model' {format_bytes(self.undetected)}" if self.undetected else ""
        extra += f", the fill {format_bytes(self.fill)}" if self.fill else ""
        return (f"grid {nx} x {ny} x {nz} = {self.grid.n_voxels:,} voxels of {self.grid.voxel_size:g} m; "
                f"{self.rows:,} hold echoes; dense layout {format_bytes(self.dense)}, sparse "
                f"{format_bytes(self.sparse)}, beams {format_bytes(self.beams)}{extra}")

    def describe(self) -> str:
        return ((f"{self.note}: " if self.note else "") + f"{self.sizes()}; the {self.layout.value} layout needs "
                f"{format_bytes(self.need)} of the "
                f"{format_bytes(self.limit)} available (arrays: making the beams {format_bytes(self.build)}, "
                f"tracing and estimating {format_bytes(self.run)}; and {ALLOCATOR_SHARE:.0%} on top for the "
                "allocator)")


def memory_plan(grid: VoxelGrid, beams: Beams, tracer: Tracer, *, layout="auto", voxels=None,
                max_bytes: int | None = None, check: bool = True, undetected="ignore", fill="none",
                scans: int = 1) -> MemoryPlan:
    """The bytes each layout would take for ``beams`` on ``grid``, and the layout to use.

    With ``check``, raises :class:`InputError` (with the sizes and the fix)
    when the chosen layout does not fit ``max_bytes`` (default: 80 % of the
    available memory).  ``undetected="model"`` adds what the detection
    correction holds on top (:func:`undetected_bytes`), ``fill="neighbourhood"``
    its box filters' temporaries (``NEIGHBOURHOOD_BYTES`` per voxel; dense only),
    ``fill="calibrated"`` those, each of the ``scans``' own sums and the
    ratio's work arrays (``CALIBRATED_BYTES`` per voxel;
    :func:`~tlsvox.voxel.estimators.cross_scan_ratio`).
    """
    layout = Layout.parse(layout, "layout")
    limit = memory_limit(max_bytes)
    n_rows = len(echo_voxels(grid, beams) if voxels is None else voxels)
    n_bricks = int(np.prod(Bricks.shape_of(grid)))
    per_row = row_bytes(tracer)
    dense = grid.n_voxels * per_row
    sparse = n_rows * per_row + n_bricks * (tracer.bytes_per_brick() + 8) + Bricks.bytes_for(n_rows, n_bricks)
    beam_bytes = beams_bytes(beams)
    held = beam_bytes + beams.n_echoes  # the run's bytes beside the layout and the options
    model = Undetected.parse(undetected, "undetected") is Undetected.MODEL
    if layout is Layout.AUTO:
        extra = undetected_bytes(grid, beams, beam_bytes, Layout.DENSE, n_rows) if model else 0
        fits = dense <= DENSE_AUTO_MAX and with_allocator(held + extra + dense) <= limit
        layout = Layout.DENSE if fits else Layout.SPARSE
    extra = undetected_bytes(grid, beams, beam_bytes, layout, n_rows) if model else 0
    fill = FillMode.parse(fill, "fill")
    fill_bytes = 0
    if layout is Layout.DENSE and fill in (FillMode.NEIGHBOURHOOD, FillMode.CALIBRATED):
        fill_bytes = grid.n_voxels * NEIGHBOURHOOD_BYTES
        if fill is FillMode.CALIBRATED:
            check_calibration_scans(scans)
            fill_bytes += grid.n_voxels * (CALIBRATED_BYTES + int(scans) * NF * 8)
    plan = MemoryPlan(grid, dense, sparse, beam_bytes, n_rows, limit, layout, extra, fill_bytes, build_bytes(beams),
                      beams.n_echoes)
    # the check runs once the beams are made (voxelize): what lies ahead is the trace and the estimate
    ahead = with_allocator(plan.run)
    if check and ahead > limit:
        sparse_need = with_allocator(sparse + held + (undetected_bytes(grid, beams, beam_bytes, Layout.SPARSE, n_rows)
                                                      if model else 0))
        fix = ("layout='sparse' (CLI --layout sparse; with fill='layer'), "
               if layout is Layout.DENSE and sparse_need <= limit else "")
        if model and with_allocator(plan.run - plan.undetected) <= limit:
            fix += "undetected='ignore', "
        if fill is FillMode.CALIBRATED and with_allocator(
                plan.run - plan.fill + grid.n_voxels * NEIGHBOURHOOD_BYTES) <= limit:
            fix += "fill='neighbourhood', "
        factor = (ahead / max(limit, 1)) ** (1 / 3)
        raise InputError(f"{plan.sizes()}; tracing and estimating with the {layout.value} layout need "
                         f"{format_bytes(ahead)} but only "
                         f"{format_bytes(limit)} is available; use {fix}a voxel_size of at least "
                         f"{grid.voxel_size * factor:.3g} m, or a smaller region (bounds=...)")
    return plan


#: share of the arrays' peak the process takes on top: the memory allocator keeps freed memory for reuse (the
#: synthetic oak's two scans: peak RSS 1.18 and 1.13 times the arrays' peak measured with tracemalloc, at 20 cm
#: and at 10 cm dense), and the interpreter's small objects
ALLOCATOR_SHARE = 0.2


def with_allocator(nbytes: float) -> int:
    """``nbytes`` of arrays and what the allocator takes beside them (``ALLOCATOR_SHARE``)."""
    return int(np.ceil((1.0 + ALLOCATOR_SHARE) * nbytes))

_BEAM_FIELDS = ("origin", "direction", "echo_start", "echo_range", "echo_weight", "echo_kind", "tail", "max_range",
                "g", "scan_index")
#: :func:`~tlsvox.voxel.pulses.beams_from_scan`: bytes per pulse it holds beyond the beams it returns (the
#: directions before the pose, the echo counts, weight sums and last ranges, 72; the direction norms and the
#: G lookup's temporaries, about 32; 128 measured with tracemalloc on the synthetic oak's scans) ...
_CONVERT_PULSE_BYTES = 136
#: ... and per echo (the ranges, the noise mask, the sort order; 25)
_CONVERT_ECHO_BYTES = 32
#: :meth:`~tlsvox.voxel.beams.Beams.concat`: bytes per pulse beyond the parts and the joined beams (the echo
#: offsets, 8; the direction norm check, 32; 48 measured)
_JOIN_PULSE_BYTES = 56
#: :func:`~tlsvox.voxel.beams.echo_voxels`: bytes per leaf or wood echo (its pulse index, origin, direction and
#: range, 64; per nudge along the beam the position and the voxel-index temporaries, about 120; the in-grid
#: flat indices, 16; 217 measured on scans of leaf echoes only)
_FIND_ECHO_BYTES = 232


def row_bytes(tracer: Tracer) -> int:
    """Bytes per voxel (dense) or row (sparse) at the larger of the trace (the tracer's accumulators and
    its result) and the estimate (the result and the estimators' work arrays): the accumulators are
    freed before the estimate starts."""
    return max(tracer.bytes_per_voxel(), NF * 8 + _ESTIMATE_BYTES)


def beams_bytes(beams: Beams) -> int:
    """Bytes of the arrays of ``beams``."""
    return int(sum(np.asarray(getattr(beams, k)).nbytes for k in _BEAM_FIELDS if getattr(beams, k) is not None))


def build_bytes(beams: Beams) -> int:
    """Peak bytes while :func:`~tlsvox.voxel.stages.voxelize` makes ``beams`` (an estimate with a margin).

    The scans are the runs of ``beams.scan_index`` (one scan without it; two
    scans of the same index in a row count as one, which over-counts).  Each
    scan's conversion holds the beams of the scans before it, its own beams
    and its working arrays; several scans are then joined (the parts and the
    joined copy side by side); last, the voxels holding leaf and wood echoes
    are found beside the beams.
    """
    n, n_echoes = len(beams), beams.n_echoes
    total = beams_bytes(beams)
    per_echo = sum(np.asarray(getattr(beams, k)).itemsize for k in ("echo_range", "echo_weight", "echo_kind"))
    per_pulse = (total - n_echoes * per_echo) / max(n, 1)
    si = beams.scan_index
    edges = [0, *([] if si is None or n == 0 else (np.flatnonzero(si[1:] != si[:-1]) + 1).tolist()), n]
    done, peak = 0.0, 0.0
    for b0, b1 in zip(edges[:-1], edges[1:]):
        echoes = int(beams.echo_start[b1] - beams.echo_start[b0])
        own = (b1 - b0) * per_pulse + echoes * per_echo
        peak = max(peak, done + own + (b1 - b0) * _CONVERT_PULSE_BYTES + echoes * _CONVERT_ECHO_BYTES)
        done += own
    if len(edges) > 2:  # joined: the parts and the joined copy
        peak = max(peak, 2 * total + n * _JOIN_PULSE_BYTES)
    leaf_wood = int(np.count_nonzero(np.isin(beams.echo_kind, (EchoKind.LEAF, EchoKind.WOOD))))
    # the voxels holding echoes, found beside the beams (and a mask over all echoes)
    return int(max(peak, total + leaf_wood * _FIND_ECHO_BYTES + n_echoes))


#: ``fill="neighbourhood"`` (:func:`~tlsvox.voxel.estimators.fill_neighbourhood`): bytes per voxel of its
#: copies and box-filter temporaries (60 measured with tracemalloc; a margin for scipy's buffers)
NEIGHBOURHOOD_BYTES = 96
#: ``fill="calibrated"``: bytes per voxel of the ratio's work beyond the neighbourhood fill's (the others'
#: sums and two estimates at a time; 282 measured with tracemalloc on a 60^3 grid, and a margin); each
#: scan's own sums (NF x 8 bytes a voxel) are counted beside it
CALIBRATED_BYTES = 320
#: bytes per sample of the detection model's walk along the beams (:func:`unrecorded_echoes`: sample
#: positions, voxel indices, LAD, masks and their subsets), times its chunk of samples
_SAMPLE_BYTES = 112
#: bytes per added echo: range, weight, kind, and the pulse index and sort order while merging
_ECHO_BYTES = 8 + 8 + 1 + 8 + 8
#: dense layout: the LAD lookup of each round (raw, seen and filled LAD, the fill's temporaries,
#: the crown hull), bytes per voxel
_LOOKUP_BYTES = 5 * 8 + 1


def undetected_bytes(grid: VoxelGrid, beams: Beams, beam_bytes: int, layout, n_rows: int) -> int:
    """What ``undetected="model"`` holds beyond the plan's beams and sums (bytes, an upper bound).

    Each round keeps the scans' own beams, makes a corrected copy of every
    scan's beams and joins them (so two more copies of the beams, each with up
    to ``ECHOES_PER_TAIL`` added echoes per pulse with a tail), walks the beams
    in chunks of ``CHUNK_SAMPLES`` samples (one per voxel crossed), and looks the LAD up per voxel
    (dense: a few arrays of the grid; sparse: per row, and rows gain the
    voxels where echoes are given back, at most one per added echo).
    """
    from tlsvox.voxel.detection import CHUNK_SAMPLES, ECHOES_PER_TAIL

    with_tail = int(np.count_nonzero(np.asarray(beams.tail) > 1e-9))
    added = with_tail * ECHOES_PER_TAIL * _ECHO_BYTES
    crossing = int(np.ceil(np.linalg.norm(np.array(grid.shape, dtype=np.float64)))) + 1  # samples per beam, at most
    walk = min(CHUNK_SAMPLES, with_tail * crossing) * _SAMPLE_BYTES
    if Layout.parse(layout, "layout") is Layout.DENSE:
        lookup = grid.n_voxels * _LOOKUP_BYTES
    else:
        lookup = (n_rows + with_tail * ECHOES_PER_TAIL) * 3 * 8
    return int(2 * (beam_bytes + added) + walk + lookup)
