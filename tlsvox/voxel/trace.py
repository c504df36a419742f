"""Beam tracing through a voxel grid (Amanatides-Woo DDA) on OpenCL.

Each beam (:class:`~tlsvox.voxel.beams.Beams`: a pulse with its echoes and
the weight they remove) is walked voxel by voxel, and every voxel it enters
gets the per-voxel sums of :data:`~tlsvox.voxel.stats.FIELDS` (a
:class:`~tlsvox.voxel.stats.VoxelStats`), pooled over all beams given.

With ``rows`` (a :class:`~tlsvox.voxel.bricks.Bricks`), the trace is
*sparse*: full rows only for the listed voxels (those holding echoes) and
seven coarse sums per brick of 8^3 voxels (:mod:`tlsvox.voxel.bricks`), so
memory follows the echoes rather than the grid; the listed voxels' sums are
the dense trace's, bit for bit.

On a CPU device each work-item owns a private copy of the accumulators and
strides over the beams: no atomics, and the sums come out bit-identical from
run to run.  On a GPU the beams run one per work-item with atomic adds.
The brute-force NumPy reference the tests compare with is
:func:`tlsvox.voxel.trace_reference.trace_reference`.

``Beams``, ``EchoKind``, ``FIELDS``, ``VoxelStats``, ``echo_rows``,
``echo_voxels`` and ``trace_reference`` are importable from here too.

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

import functools
import time
from importlib import resources

import numpy as np

from tlsvox.errors import DeviceError, InputError
from tlsvox.voxel.beams import Beams, EchoKind, echo_rows, echo_voxels
from tlsvox.voxel.bricks import BRICK, BRICK_FIELDS, Bricks
from tlsvox.voxel.grid import VoxelGrid, format_bytes, memory_limit
from tlsvox.voxel.stats import FIELDS, NF, VoxelStats
from tlsvox.voxel.trace_reference import trace_reference
from voxlidar.devices import build_program, choose_device, describe, open_queue, short_reason
from voxlidar.errors import DeviceError as AnyDeviceError

__all__ = ["Beams", "EchoKind", "FIELDS", "Tracer", "VoxelStats", "echo_rows", "echo_voxels", "trace", "trace_reference"]


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


def fixed_point_scale(beams: Beams, voxel_size: float, *, sparse: bool = False) -> float:
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
              g_layer=None, chunk: int = 262144, progress: bool = False,
              max_bytes: int | None = None) -> VoxelStats:
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
        g_layer : (nz,) int, optional
            Leaf angles per crown layer: ``outward``'s table is then
            (layers, n_theta, n_c + 1), one table per layer whose rows end in
            the layer's azimuth-averaged G (read where the cosine is undefined:
            a vertical beam, a voxel on the axis), and ``g_layer[k]`` the layer
            of the voxels of z index ``k``.  Azimuthally uniform leaves: a
            table the same in every c
            (:func:`tlsvox.voxel.pulses.layer_g_tables`).
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
        if g_layer is not None and outward is None:
            raise InputError("g_layer (leaf angles per layer) needs outward=(tables, centre): one G table per layer")
        if outward is not None:
            table, centre = outward
            gout = np.ascontiguousarray(np.maximum(np.asarray(table, dtype=np.float64), 1e-6))
            centre = np.asarray(centre, dtype=np.float64).reshape(-1)
            dims, cols = (2, 2) if g_layer is None else (3, 3)
            if gout.ndim != dims or gout.shape[-2] < 2 or gout.shape[-1] < cols or not np.all(np.isfinite(gout)) \
                    or centre.shape != (2,) or not np.all(np.isfinite(centre)):
                raise InputError("outward must be (table of G, at least 2 x 2, or layers x 2 x 3 with g_layer "
                                 "(layer_g_tables), finite; crown centre x, y)")
            if g_layer is not None:
                raw = np.asarray(g_layer)
                if raw.shape != (grid.shape[2],) or raw.dtype.kind not in "iu" or raw.min() < 0 \
                        or raw.max() >= gout.shape[0]:
                    raise InputError(f"g_layer must give an integer layer in 0..{gout.shape[0] - 1} for each of "
                                     f"the grid's {grid.shape[2]} z indices")
                g_layer = np.ascontiguousarray(raw, dtype=np.int32)
            outward = (gout, centre, g_layer)
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
        gout, centre, g_layer = outward if outward is not None else (np.zeros((2, 2)), np.zeros(2), None)
        mode = 0 if outward is None else (1 if g_layer is None else 3)
        n_c = gout.shape[-1] - (1 if g_layer is not None else 0)  # per layer: the last column is G averaged
        leaves = [buf(gout), np.int32(gout.shape[-2]), np.int32(n_c), np.float64(centre[0]),
                  np.float64(centre[1]), np.int32(mode), buf(np.zeros(1, np.int32) if g_layer is None else g_layer)]

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


@functools.lru_cache(maxsize=2)
def _default_tracer() -> Tracer:
    return Tracer()


def trace(grid: VoxelGrid, beams: Beams, *, tracer: Tracer | None = None, **kwargs) -> VoxelStats:
    """Trace ``beams`` through ``grid`` with ``tracer`` (default: a shared one).

    See :meth:`Tracer.trace` for the keyword options.
    """
    return (tracer or _default_tracer()).trace(grid, beams, **kwargs)
