"""Beam tracing through a voxel grid (Amanatides-Woo DDA) on OpenCL.

Every laser pulse is a ray from its origin along its unit direction.  It
carries a weight, initially 1: each recorded echo at range ``r`` removes its
weight (``1/n`` for an ``n``-echo pulse), and the *tail* weight (echoes the
file did not keep, e.g. cut off by a range limit) carries on to the beam's
``max_range``.  A pulse with no echo is a beam of tail weight 1: it is what
tells a voxel that light got through.

Per voxel the tracer accumulates (:data:`FIELDS`, pooled over all beams given):

=============  ==============================================================
``count``      number of beams entering
``n_w``        beam weight entering, N
``leaf_w``     leaf echo weight inside, N_I
``wood_w``     wood echo weight inside
``other_w``    weight stopped by other surfaces (ground, targets)
``path_w``     free path: integral of the beam weight along its path inside
               (entry to echo, or the whole chord), m
``path_wg``    the same times G(theta) of each beam (its leaf projection), m
``leaf_zw``    sum over leaf echoes of weight x (echo range - entry), m
``leaf_zwg``   the same times G(theta)
``wood_zw``    sum over wood echoes of weight x (echo range - entry), m
``chord_w``    entering weight x potential chord delta (as if unobstructed), m
``chord2_w``   entering weight x delta^2, m2
``dir_x/y/z``  entering weight x beam direction (mean direction = dir / n_w)
``leaf_w_g``   leaf echo weight / G(theta)
=============  ==============================================================

With ``rows`` (a :class:`~tlsvox.voxel.bricks.Bricks`), the trace is
*sparse*: full rows only for the listed voxels (those holding echoes) and
seven coarse sums per brick of 8^3 voxels (:mod:`tlsvox.voxel.bricks`), so
memory follows the echoes rather than the grid; the listed voxels' sums are
the dense trace's, bit for bit.

On a CPU device each work-item owns a private copy of the accumulators and
strides over the beams: no atomics, and the sums come out bit-identical from
run to run.  On a GPU the beams run one per work-item with atomic adds.

References
----------
Amanatides, J. & Woo, A. (1987). A fast voxel traversal algorithm for ray
    tracing. Eurographics '87, 3-10. doi:10.2312/egtp.19871000
Béland, M., Widlowski, J.-L., Fournier, R. A. (2014). A model for deriving
    voxel-level tree leaf area density estimates from ground-based LiDAR.
    Environmental Modelling & Software 51, 184-189.
    doi:10.1016/j.envsoft.2013.09.034
Pimont, F., Allard, D., Soma, M., Dupuy, J.-L. (2018). Estimators and
    confidence intervals for plant area density at voxel scale with T-LiDAR.
    Remote Sensing of Environment 215, 343-370. doi:10.1016/j.rse.2018.06.024

Examples
--------
>>> from tlsvox.voxel.grid import VoxelGrid
>>> grid = VoxelGrid((0, 0, 0), 1.0, (3, 1, 1))
>>> beams = Beams.from_rays([[-1, 0.5, 0.5]], [[1, 0, 0]], hit_range=[2.5])
>>> stats = trace(grid, beams)
>>> stats.field("path_w")[:, 0, 0].round(6).tolist()      # 1 m, then 0.5 m to the echo
[1.0, 0.5, 0.0]
>>> stats.field("leaf_w")[:, 0, 0].tolist()
[0.0, 1.0, 0.0]
"""

from __future__ import annotations

import enum
import functools
import time
from dataclasses import dataclass, field
from importlib import resources

import numpy as np

from voxlidar.devices import build_program, choose_device, describe, open_queue, short_reason
from voxlidar.errors import DeviceError as AnyDeviceError

from tlsvox.errors import DeviceError, InputError
from tlsvox.voxel.bricks import BRICK, BRICK_FIELDS, Bricks
from tlsvox.voxel.grid import VoxelGrid, format_bytes, memory_limit

__all__ = ["Beams", "EchoKind", "FIELDS", "Tracer", "VoxelStats", "echo_rows", "echo_voxels", "trace", "trace_reference"]

FIELDS = ("count", "n_w", "leaf_w", "wood_w", "other_w", "path_w", "path_wg", "leaf_zw",
          "leaf_zwg", "wood_zw", "chord_w", "chord2_w", "dir_x", "dir_y", "dir_z", "leaf_w_g")
NF = len(FIELDS)
_INDEX = {name: i for i, name in enumerate(FIELDS)}


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
                  max_range=np.inf) -> "Beams":
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
    def concat(cls, parts: "list[Beams]") -> "Beams":
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

    def echo_points(self) -> np.ndarray:
        """(E, 3) world positions of the echoes."""
        beam = np.repeat(np.arange(len(self)), np.diff(self.echo_start))
        return self.origin[beam] + self.direction[beam] * self.echo_range[:, None]


@dataclass
class VoxelStats:
    """Accumulated beam statistics on a grid (see :data:`FIELDS`).

    Attributes
    ----------
    grid : VoxelGrid
    acc : (n_rows, NF) float64
        One row per voxel in flat C order (dense), or per row voxel of
        ``rows`` (sparse); one column per field.
    rows : Bricks or None
        The row voxels of a sparse trace (None: dense).
    bricks : (n_bricks, 4) float64 or None
        Sparse: the coarse sums per brick (:data:`tlsvox.voxel.bricks.BRICK_FIELDS`).
    n_beams : int
    n_steps : int
        Voxel visits (segments of beams inside voxels).
    seconds : float
        Wall time of the trace.
    """

    grid: VoxelGrid
    acc: np.ndarray
    n_beams: int = 0
    n_steps: int = 0
    seconds: float = 0.0
    device: str = ""
    rows: Bricks | None = None
    bricks: np.ndarray | None = None

    @property
    def sparse(self) -> bool:
        return self.rows is not None

    def field(self, name: str) -> np.ndarray:
        """One field: an (nx, ny, nz) view (dense), or (n_rows,) in row order (sparse)."""
        if name not in _INDEX:
            raise InputError(f"field={name!r} is not a tracer field; choose one of {', '.join(FIELDS)}")
        column = self.acc[:, _INDEX[name]]
        return column if self.sparse else column.reshape(self.grid.shape)

    def brick_field(self, name: str) -> np.ndarray:
        """Sparse traces: one coarse field per brick, shape :attr:`Bricks.shape`."""
        if not self.sparse:
            raise InputError("brick_field: this trace is dense; every voxel has its own sums (field)")
        if name not in BRICK_FIELDS:
            raise InputError(f"field={name!r} is not a brick field; choose one of {', '.join(BRICK_FIELDS)}")
        return self.bricks[:, BRICK_FIELDS.index(name)].reshape(self.rows.shape)

    def __add__(self, other: "VoxelStats") -> "VoxelStats":
        if other.grid != self.grid or (self.rows is None) != (other.rows is None) or (
                self.sparse and not (np.array_equal(self.rows.start, other.rows.start)
                                     and np.array_equal(self.rows.key, other.rows.key))):
            raise InputError("cannot add VoxelStats of different grids or rows")
        return VoxelStats(self.grid, self.acc + other.acc, self.n_beams + other.n_beams,
                          self.n_steps + other.n_steps, self.seconds + other.seconds, self.device,
                          self.rows, None if self.bricks is None else self.bricks + other.bricks)

    @property
    def beams_per_second(self) -> float:
        return self.n_beams / self.seconds if self.seconds > 0 else float("nan")


def probe_build(device) -> str | None:
    """The device layer's probe: None when ``device`` (a ``pyopencl.Device``)
    can run the tracer, else the reason.  Builds the kernel; raises on a
    build failure."""
    import pyopencl as cl

    if not describe(device).fp64:
        return "no float64 support (cl_khr_fp64), which the tracer needs"
    ctx = cl.Context([device])
    src = (resources.files("tlsvox") / "kernels" / "trace.cl").read_text()
    build_program(ctx, src, _build_options(atomics=False))
    return None


def fixed_point_scale(beams: "Beams", voxel_size: float, *, sparse: bool = False) -> float:
    """Scale of the 64-bit fixed-point sums of the atomic (GPU) tracer.

    A beam crosses a voxel once and adds to each field at most its weight W
    (tail + echo weights) times the largest of: 1, the voxel diagonal d, d^2
    (``chord2_w``), g d (``path_wg``, ``leaf_zwg``) and 1/g (``leaf_w_g``);
    ``count`` adds 1.  The scale is the largest power of two that keeps the sum
    of these bounds over all beams below 2^62, so no field can overflow.  A
    million unit-weight beams in 0.2 m voxels give 2^42 (resolution 2e-13).
    A sparse trace's brick sums add up chords across a brick: d is then the
    brick's diagonal.
    """
    if not len(beams):
        return 2.0**40
    d = float(voxel_size) * 3**0.5 * (BRICK if sparse else 1)
    w = beams.tail.copy()
    if beams.n_echoes:
        starts = beams.echo_start[:-1]
        has = beams.echo_start[1:] > starts
        w[has] += np.add.reduceat(beams.echo_weight, starts[has])
    g = beams.g
    term = np.maximum(1.0, w * np.maximum.reduce([np.ones_like(g), np.full_like(g, d), np.full_like(g, d * d),
                                                  g * d, 1.0 / g]))
    return float(2.0 ** np.floor(np.log2(2.0**62 / float(term.sum()))))


def private_copies(requested: int, per_copy_bytes: int, max_alloc_bytes: int) -> int:
    """How many private accumulator copies one device buffer can hold (at least 1)."""
    return max(1, min(int(requested), int(max_alloc_bytes) // max(int(per_copy_bytes), 1)))


def _build_options(*, atomics: bool, sparse: bool = False) -> list[str]:
    return [f"-DNF={NF}"] + (["-DUSE_ATOMICS"] if atomics else []) + (["-DSPARSE"] if sparse else [])


class Tracer:
    """Owns an OpenCL context, queue and the built tracing program.

    Parameters
    ----------
    device : voxlidar.devices.DeviceInfo, pyopencl.Device or str, optional
        Default: ``VOXLIDAR_DEVICE``, ``PYOPENCL_CTX``, or the best device
        that builds the tracer (:func:`voxlidar.devices.choose_device`).
    atomics : bool, optional
        Force the atomic (GPU) or private-copy (CPU) accumulation; default by
        device type.
    copies : int, optional
        Private copies in CPU mode (default: the device's compute units).
    """

    def __init__(self, device=None, *, atomics: bool | None = None, copies: int | None = None):
        try:
            self.info = choose_device(device, kernels=("tlsvox",))
        except AnyDeviceError as err:
            raise DeviceError(str(err)) from None
        self.device = self.info.device
        try:
            self.context, self.queue = open_queue(self.info)
        except AnyDeviceError as err:
            raise DeviceError(str(err)) from None
        is_cpu = not self.info.is_gpu
        # atomics need 64-bit compare-and-swap; without it, private copies
        self.atomics = (not is_cpu and self.info.int64_atomics) if atomics is None else bool(atomics)
        if self.atomics and not self.info.int64_atomics:
            raise DeviceError(f"OpenCL device {self.info.label!r} has no 64-bit atomics "
                              "(cl_khr_int64_base_atomics); fix: Tracer(atomics=False)")
        self.copies = 1 if self.atomics else int(copies or self.device.max_compute_units)
        self._kernels = {}
        self.kernel = self._kernel(sparse=False)

    def _kernel(self, *, sparse: bool):
        """The tracing kernel of one layout, built on first use."""
        import pyopencl as cl

        if sparse not in self._kernels:
            src = (resources.files("tlsvox") / "kernels" / "trace.cl").read_text()
            try:
                program = build_program(self.context, src, _build_options(atomics=self.atomics, sparse=sparse))
            except cl.Error as err:
                raise DeviceError(f"the tracer kernel does not build on {self.info.label}: {short_reason(err)}; "
                                  "fix: choose another device (clsim devices)") from err
            self._kernels[sparse] = cl.Kernel(program, "trace_beams")
        return self._kernels[sparse]

    @property
    def name(self) -> str:
        mode = "atomics" if self.atomics else f"{self.copies} private copies"
        return f"{self.device.name.strip()} ({mode})"

    def bytes_per_voxel(self) -> int:
        """Device accumulators plus the host result, bytes per voxel (dense) or per row (sparse)."""
        return NF * 8 * (self.copies + 1)

    def bytes_per_brick(self) -> int:
        """Sparse traces: the coarse sums of one brick, with the host result, plus its row offset."""
        return len(BRICK_FIELDS) * 8 * (self.copies + 1) + 4

    def trace(self, grid: VoxelGrid, beams: Beams, *, rows: Bricks | None = None, outward=None,
              chunk: int = 262144, progress: bool = False, max_bytes: int | None = None) -> VoxelStats:
        """Trace ``beams`` through ``grid``; see the module docstring.

        Parameters
        ----------
        grid : VoxelGrid
        beams : Beams
        rows : Bricks, optional
            Trace sparsely: full sums for these voxels only, coarse sums per
            brick (see the module docstring).  Every voxel holding a leaf or
            wood echo must be listed (:func:`echo_rows` makes such a list).
        outward : (table, (x, y)), optional
            Leaves facing outward from a vertical crown axis through (x, y):
            G per voxel from ``table``
            (:func:`tlsvox.voxel.pulses.outward_g_table`) at the beam's zenith
            and the cosine between its horizontal direction and the voxel
            centre's outward direction, instead of the beam's ``g``.
        chunk : int
            Beams per kernel launch (the progress bar advances per chunk).
        progress : bool
            Show a tqdm progress bar.
        max_bytes : int, optional
            Memory limit for the accumulators (default: what is available).
        """
        import pyopencl as cl

        if not isinstance(grid, VoxelGrid):
            raise InputError(f"grid must be a VoxelGrid, got {type(grid).__name__}")
        if not isinstance(beams, Beams):
            raise InputError(f"beams must be a Beams, got {type(beams).__name__}")
        if rows is not None and (not isinstance(rows, Bricks) or rows.grid != grid):
            raise InputError("rows must be the Bricks of this grid (tlsvox.voxel.trace.echo_rows(grid, beams))")
        limit = self.device.max_mem_alloc_size
        n_rows = grid.n_voxels if rows is None else rows.n_rows
        per_copy = n_rows * NF * 8
        copies = 1 if self.atomics else private_copies(self.copies, per_copy, limit)
        if rows is None:
            grid.check_memory(NF * 8 * (copies + 1), max_bytes=max_bytes, what="tracer accumulators")
        else:
            check_bytes(rows.n_rows * NF * 8 * (copies + 1) + rows.n_bricks * self.bytes_per_brick(),
                        max_bytes, f"the sparse tracer ({rows.n_rows:,} rows, {rows.n_bricks:,} bricks)")
        acc_bytes = per_copy * copies
        if acc_bytes > limit:
            raise InputError(
                f"tracer accumulators need {format_bytes(acc_bytes)} in one buffer but the OpenCL "
                f"device {self.device.name.strip()!r} allows at most {format_bytes(limit)}; "
                "use a larger voxel_size or a smaller region"
            )
        gout = None
        if outward is not None:
            table, centre = outward
            gout = np.ascontiguousarray(np.maximum(np.asarray(table, dtype=np.float64), 1e-6))
            centre = np.asarray(centre, dtype=np.float64).reshape(-1)
            if gout.ndim != 2 or min(gout.shape) < 2 or not np.all(np.isfinite(gout)) or centre.shape != (2,) \
                    or not np.all(np.isfinite(centre)):
                raise InputError("outward must be (table of G, at least 2 x 2, finite; crown centre x, y)")
            outward = (gout, centre)
        bound = beams
        if self.atomics and gout is not None:  # the smallest G bounds leaf_w / G
            bound = Beams(beams.origin, beams.direction, beams.echo_start, beams.echo_range, beams.echo_weight,
                          beams.echo_kind, beams.tail, beams.max_range, g=np.minimum(beams.g, gout.min()))
        fx_scale = fixed_point_scale(bound, grid.voxel_size, sparse=rows is not None) if self.atomics else 1.0
        if self.atomics and fx_scale < 2.0**20:
            raise InputError(f"the atomic tracer's fixed-point sums would keep only 2^{np.log2(fx_scale):.0f} "
                             "steps per unit for these beams (weights or 1/G very large); "
                             "fix: Tracer(atomics=False), which sums in float64")
        try:
            return self._trace(grid, beams, rows, outward, copies=copies, n_rows=n_rows, fx_scale=fx_scale,
                               chunk=chunk, progress=progress)
        except cl.Error as err:
            raise DeviceError(f"the tracer failed on {self.info.label}: {short_reason(err)}; fix: a larger "
                              "voxel_size or a smaller region, or another device (clsim devices)") from err

    def _trace(self, grid, beams, rows, outward, *, copies, n_rows, fx_scale, chunk, progress) -> VoxelStats:
        import pyopencl as cl

        mf = cl.mem_flags
        ctx, q = self.context, self.queue
        t_start = time.perf_counter()

        def buf(a):
            a = np.ascontiguousarray(a)
            if a.nbytes == 0:
                a = np.zeros(1, dtype=a.dtype)
            # a CPU device reads the host arrays where they are (no second copy of the beams)
            where = mf.COPY_HOST_PTR if self.atomics else mf.USE_HOST_PTR
            return cl.Buffer(ctx, mf.READ_ONLY | where, hostbuf=a)

        bufs = [buf(beams.origin), buf(beams.direction), buf(beams.echo_start), buf(beams.echo_range),
                buf(beams.echo_weight), buf(beams.echo_kind), buf(beams.tail), buf(beams.max_range),
                buf(beams.g)]
        sparse = rows is not None
        n_bricks = rows.n_bricks if sparse else 1
        layout = [buf(rows.start if sparse else np.zeros(2, np.int32)),
                  buf(rows.key if sparse else np.zeros(1, np.uint16))]
        gout, centre = outward if outward is not None else (np.zeros((2, 2)), np.zeros(2))
        leaves = [buf(gout), np.int32(gout.shape[0]), np.int32(gout.shape[1]), np.float64(centre[0]),
                  np.float64(centre[1]), np.int32(outward is not None)]

        def accumulators(shape):
            """Zeroed sums: on the device (atomics), or host memory the CPU kernel writes in place."""
            if self.atomics:
                nbytes = max(int(np.prod(shape[1:])) * 8, 8)
                dev = cl.Buffer(ctx, mf.READ_WRITE, size=nbytes)
                cl.enqueue_fill_buffer(q, dev, np.float64(0.0), 0, nbytes)
                return dev, None
            host = np.zeros(shape, dtype=np.float64)
            return cl.Buffer(ctx, mf.READ_WRITE | mf.USE_HOST_PTR, hostbuf=host), host

        acc_dev, host_acc = accumulators((copies, n_rows, NF))
        bacc_dev, host_bacc = accumulators((copies, n_bricks, len(BRICK_FIELDS)))
        steps_dev = cl.Buffer(ctx, mf.READ_WRITE, size=8 * copies)
        cl.enqueue_fill_buffer(q, steps_dev, np.uint64(0), 0, 8 * copies)
        lo = grid.lower
        nx, ny, nz = grid.shape
        n = len(beams)
        kernel = self._kernel(sparse=sparse)
        bar = None
        if progress:
            from tqdm.auto import tqdm

            bar = tqdm(total=n, unit="beam", unit_scale=True, desc="tracing", leave=False)
        try:
            for b0 in range(0, n, chunk):
                b1 = min(n, b0 + chunk)
                gsize = (copies,) if not self.atomics else (b1 - b0,)
                lsize = (1,) if not self.atomics else None
                kernel(q, gsize, lsize, np.int64(b0), np.int64(b1), *bufs,
                       np.float64(lo[0]), np.float64(lo[1]), np.float64(lo[2]),
                       np.float64(grid.voxel_size), np.int32(nx), np.int32(ny), np.int32(nz),
                       np.float64(fx_scale), *layout, *leaves, np.int64(n_rows), np.int64(n_bricks),
                       acc_dev, bacc_dev, steps_dev)
                q.finish()
                if bar is not None:
                    bar.update(b1 - b0)
        finally:
            if bar is not None:
                bar.close()
        steps = np.empty(copies, dtype=np.uint64)
        cl.enqueue_copy(q, steps, steps_dev)

        def collect(dev, host, shape):
            """The sums as float64: fixed point scaled back (atomics), or the private copies added."""
            if self.atomics:
                fixed = np.empty(shape, dtype=np.int64)
                cl.enqueue_copy(q, fixed, dev)
                q.finish()
                total = fixed.astype(np.float64) / fx_scale
            else:
                mapped, _ = cl.enqueue_map_buffer(q, dev, cl.map_flags.READ, 0, host.shape, host.dtype,
                                                  is_blocking=True)
                total = np.array(mapped[0])
                for c in range(1, copies):
                    total += mapped[c]
                del mapped
            dev.release()
            return total

        total = collect(acc_dev, host_acc, (n_rows, NF))
        bricks = collect(bacc_dev, host_bacc, (n_bricks, len(BRICK_FIELDS)))
        seconds = time.perf_counter() - t_start
        return VoxelStats(grid, total, n_beams=n, n_steps=int(steps.sum()), seconds=seconds,
                          device=self.name, rows=rows, bricks=bricks if sparse else None)


def check_bytes(need: int, max_bytes: int | None, what: str, *, fraction: float = 0.8) -> int:
    """Raise before allocating ``need`` bytes beyond ``max_bytes`` (default: ``fraction`` of what is available)."""
    limit = memory_limit(max_bytes, fraction=fraction)
    if need > limit:
        raise InputError(f"{what} needs {format_bytes(need)} but only {format_bytes(limit)} is available; "
                         "use a larger voxel_size or a smaller region (bounds=...)")
    return need


def echo_positions(beams: Beams, kinds=(EchoKind.LEAF, EchoKind.WOOD), *, nudge: float = 0.0) -> np.ndarray:
    """(E, 3) world positions of the beams' echoes of ``kinds``, each moved ``nudge`` metres along its beam."""
    sel = np.isin(beams.echo_kind, np.asarray(kinds, dtype=np.uint8))
    b = np.repeat(np.arange(len(beams)), np.diff(beams.echo_start))[sel]
    return beams.origin[b] + beams.direction[b] * (beams.echo_range[sel] + nudge)[:, None]


def echo_voxels(grid: VoxelGrid, beams: Beams) -> np.ndarray:
    """(K, 3) the distinct voxels of ``grid`` holding a leaf or wood echo of ``beams``.

    An echo on a voxel face may be counted by the kernel on either side, so
    the voxels just before and just after it along its beam are both taken.
    """
    eps = 1e-6 * grid.voxel_size
    ijk = np.vstack([grid.index_of(echo_positions(beams, nudge=s)) for s in (-eps, eps)])
    ijk = ijk[grid.contains_index(ijk)]
    return grid.unflat(np.unique(grid.flat(ijk)))


def echo_rows(grid: VoxelGrid, beams: Beams) -> Bricks:
    """The rows a sparse trace must list: the voxels holding a leaf or wood echo (:func:`echo_voxels`)."""
    return Bricks.from_ijk(grid, echo_voxels(grid, beams))


@functools.lru_cache(maxsize=2)
def _default_tracer() -> Tracer:
    return Tracer()


def trace(grid: VoxelGrid, beams: Beams, *, tracer: Tracer | None = None, **kwargs) -> VoxelStats:
    """Trace ``beams`` through ``grid`` with ``tracer`` (default: a shared one).

    See :meth:`Tracer.trace` for the keyword options.
    """
    return (tracer or _default_tracer()).trace(grid, beams, **kwargs)


def _slab(o, d, lo, hi):
    """Per-voxel entry/exit (vectorised slab test) of one ray against boxes."""
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / d
        ta = (lo - o) * inv
        tb = (hi - o) * inv
    tmin = np.where(d == 0, np.where((o >= lo) & (o < hi), -np.inf, np.inf), np.minimum(ta, tb))
    tmax = np.where(d == 0, np.where((o >= lo) & (o < hi), np.inf, -np.inf), np.maximum(ta, tb))
    return tmin.max(axis=1), tmax.min(axis=1)


def trace_reference(grid: VoxelGrid, beams: Beams) -> VoxelStats:
    """Brute-force NumPy reference of :func:`trace`: every ray against every voxel.

    Independent of the DDA: each voxel's entry and exit come from a slab test
    of the ray against that voxel's box.  O(beams x voxels); for tests and
    small grids only.
    """
    if grid.n_voxels * len(beams) > 5e7:
        raise InputError(
            f"trace_reference is brute force: {len(beams)} beams x {grid.n_voxels} voxels is too "
            "many; use trace() or a smaller case"
        )
    t_start = time.perf_counter()
    h = grid.voxel_size
    ijk = grid.unflat(np.arange(grid.n_voxels))
    lo = grid.lower + ijk * h
    hi = lo + h
    acc = np.zeros((grid.n_voxels, NF))
    steps = 0
    for b in range(len(beams)):
        o, d, g = beams.origin[b], beams.direction[b], beams.g[b]
        s0, s1 = beams.echo_start[b], beams.echo_start[b + 1]
        rng_, wts, kinds = beams.echo_range[s0:s1], beams.echo_weight[s0:s1], beams.echo_kind[s0:s1]
        w0 = beams.tail[b] + wts.sum()
        tin, tout = _slab(o, d, lo, hi)
        tin = np.maximum(tin, 0.0)
        end = np.inf
        if beams.tail[b] > 0:
            end = beams.max_range[b]
            tout = np.minimum(tout, end)
        for v in np.nonzero(tout - tin > 1e-12 * h)[0]:
            a, z = tin[v], tout[v]
            w_in = w0 - wts[rng_ < a].sum()
            if w_in <= 1e-12:
                continue
            inside = (rng_ >= a) & ((rng_ < z) | ((z == end) & (rng_ <= z)))
            # free path: integral of the step-wise weight from a to z
            pts = np.concatenate([[a], rng_[inside], [z]])
            wseg = w_in - np.concatenate([[0.0], np.cumsum(wts[inside])])
            wseg = np.where(wseg < 1e-12, 0.0, wseg)
            path = float(np.sum(wseg * np.diff(pts)))
            row = acc[v]
            row[0] += 1
            row[1] += w_in
            leaf = inside & (kinds == EchoKind.LEAF)
            wood = inside & (kinds == EchoKind.WOOD)
            other = inside & (kinds == EchoKind.OTHER)
            row[2] += wts[leaf].sum()
            row[3] += wts[wood].sum()
            row[4] += wts[other].sum()
            row[5] += path
            row[6] += g * path
            lz = float(np.sum(wts[leaf] * (rng_[leaf] - a)))
            row[7] += lz
            row[8] += g * lz
            row[9] += float(np.sum(wts[wood] * (rng_[wood] - a)))
            row[10] += w_in * (z - a)
            row[11] += w_in * (z - a) ** 2
            row[12:15] += w_in * d
            row[15] += wts[leaf].sum() / g
            steps += 1
    return VoxelStats(grid, acc, n_beams=len(beams), n_steps=steps,
                      seconds=time.perf_counter() - t_start, device="numpy brute force")
