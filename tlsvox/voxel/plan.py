"""The memory a voxelisation will take, before it runs: :func:`memory_plan`.

The tracer keeps its sums either for every voxel of the grid (the dense
layout) or for the voxels holding echoes plus coarse sums per brick (the
sparse layout, :mod:`tlsvox.voxel.bricks`); :func:`memory_plan` counts both
for a set of beams, picks one (``layout="auto"``), and says how to make a grid
fit when neither does.  :func:`undetected_bytes` adds what the detection
correction (``undetected="model"``, :mod:`tlsvox.voxel.detection`) holds.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tlsvox.errors import InputError
from tlsvox.voxel.bricks import Bricks
from tlsvox.voxel.detection import Undetected
from tlsvox.voxel.estimators import FillMode
from tlsvox.voxel.grid import VoxelGrid, format_bytes, memory_limit
from tlsvox.voxel.trace import Beams, Tracer, echo_voxels
from voxlidar.choices import Choice

__all__ = ["DENSE_AUTO_MAX", "NEIGHBOURHOOD_BYTES", "Layout", "MemoryPlan", "memory_plan", "undetected_bytes"]

#: estimator work arrays, bytes per voxel (dense) or row (sparse), on top of the tracer's
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
    fill: int = 0  #: bytes of ``fill="neighbourhood"``'s temporaries on top (0 for the other fills)

    @property
    def need(self) -> int:
        return (self.beams + (self.dense if self.layout is Layout.DENSE else self.sparse) + self.undetected
                + self.fill)

    def sizes(self) -> str:
        """The grid and what each layout costs."""
        nx, ny, nz = self.grid.shape
        extra = f", undetected='model' {format_bytes(self.undetected)}" if self.undetected else ""
        extra += f", fill='neighbourhood' {format_bytes(self.fill)}" if self.fill else ""
        return (f"grid {nx} x {ny} x {nz} = {self.grid.n_voxels:,} voxels of {self.grid.voxel_size:g} m; "
                f"{self.rows:,} hold echoes; dense layout {format_bytes(self.dense)}, sparse "
                f"{format_bytes(self.sparse)}, beams {format_bytes(self.beams)}{extra}")

    def describe(self) -> str:
        return (f"{self.sizes()}; the {self.layout.value} layout needs {format_bytes(self.need)} of the "
                f"{format_bytes(self.limit)} available")


def memory_plan(grid: VoxelGrid, beams: Beams, tracer: Tracer, *, layout="auto", voxels=None,
                max_bytes: int | None = None, check: bool = True, undetected="ignore", fill="none") -> MemoryPlan:
    """The bytes each layout would take for ``beams`` on ``grid``, and the layout to use.

    With ``check``, raises :class:`InputError` (with the sizes and the fix)
    when the chosen layout does not fit ``max_bytes`` (default: 80 % of the
    available memory).  ``undetected="model"`` adds what the detection
    correction holds on top (:func:`undetected_bytes`), ``fill="neighbourhood"``
    its box filters' temporaries (``NEIGHBOURHOOD_BYTES`` per voxel; dense only).
    """
    layout = Layout.parse(layout, "layout")
    limit = memory_limit(max_bytes)
    n_rows = len(echo_voxels(grid, beams) if voxels is None else voxels)
    n_bricks = int(np.prod(Bricks.shape_of(grid)))
    per_row = tracer.bytes_per_voxel() + _ESTIMATE_BYTES
    dense = grid.n_voxels * per_row
    sparse = n_rows * per_row + n_bricks * (tracer.bytes_per_brick() + 8) + Bricks.bytes_for(n_rows, n_bricks)
    beam_bytes = sum(np.asarray(getattr(beams, k)).nbytes for k in
                     ("origin", "direction", "echo_start", "echo_range", "echo_weight", "echo_kind", "tail",
                      "max_range", "g"))
    model = Undetected.parse(undetected, "undetected") is Undetected.MODEL
    if layout is Layout.AUTO:
        extra = undetected_bytes(grid, beams, beam_bytes, Layout.DENSE, n_rows) if model else 0
        layout = Layout.DENSE if dense <= min(DENSE_AUTO_MAX, limit - beam_bytes - extra) else Layout.SPARSE
    extra = undetected_bytes(grid, beams, beam_bytes, layout, n_rows) if model else 0
    neighbourhood = FillMode.parse(fill, "fill") is FillMode.NEIGHBOURHOOD and layout is Layout.DENSE
    plan = MemoryPlan(grid, dense, sparse, beam_bytes, n_rows, limit, layout, extra,
                      grid.n_voxels * NEIGHBOURHOOD_BYTES if neighbourhood else 0)
    if check and plan.need > limit:
        sparse_need = sparse + beam_bytes + (undetected_bytes(grid, beams, beam_bytes, Layout.SPARSE, n_rows)
                                             if model else 0)
        fix = ("layout='sparse' (CLI --layout sparse; with fill='layer'), "
               if layout is Layout.DENSE and sparse_need <= limit else "")
        if model and plan.need - plan.undetected <= limit:
            fix += "undetected='ignore', "
        factor = (plan.need / max(limit, 1)) ** (1 / 3)
        raise InputError(f"{plan.sizes()}; the {layout.value} layout needs {format_bytes(plan.need)} but only "
                         f"{format_bytes(limit)} is available; use {fix}a voxel_size of at least "
                         f"{grid.voxel_size * factor:.3g} m, or a smaller region (bounds=...)")
    return plan


#: ``fill="neighbourhood"`` (:func:`~tlsvox.voxel.estimators.fill_neighbourhood`): bytes per voxel of its
#: copies and box-filter temporaries (60 measured with tracemalloc; a margin for scipy's buffers)
NEIGHBOURHOOD_BYTES = 96
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
