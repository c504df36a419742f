"""The regular voxel grid that beams are traced through.

A :class:`VoxelGrid` is an axis-aligned box of ``shape = (nx, ny, nz)`` cubic
voxels of edge ``voxel_size`` whose lower corner is ``origin``.  Voxel
``(i, j, k)`` spans ``origin + (i, j, k) * voxel_size`` to
``origin + (i + 1, j + 1, k + 1) * voxel_size``; its flat index is
``(i * ny + j) * nz + k`` (C order, the order of ``np.ravel``).

Before anything large is allocated, :meth:`VoxelGrid.check_memory` compares
the bytes a computation needs with a limit (the memory the machine has
available, or ``max_bytes``) and raises :class:`~tlsvox.errors.InputError`
with both numbers, so a 2 cm grid over a forest plot fails at once with an
explanation instead of after minutes of swapping.

Examples
--------
>>> g = VoxelGrid.from_bounds([0, 0, 0], [1.0, 1.0, 0.5], voxel_size=0.25)
>>> g.shape, g.n_voxels
((4, 4, 2), 32)
>>> g.index_of([[0.3, 0.9, 0.1]]).tolist()
[[1, 3, 0]]
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from tlsvox.errors import InputError

__all__ = ["VoxelGrid", "available_memory_bytes", "format_bytes", "memory_limit", "ray_box"]


def available_memory_bytes() -> int:
    """Memory the operating system reports as available, bytes.

    Reads ``MemAvailable`` from ``/proc/meminfo`` (Linux); elsewhere falls back
    to ``os.sysconf`` (free physical pages) and, failing that, returns 16 GiB.
    """
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    try:
        return int(os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))
    except (ValueError, OSError, AttributeError):
        return 16 * 1024**3


def memory_limit(max_bytes: int | None = None, *, fraction: float = 0.8) -> int:
    """The bytes a computation may take: ``max_bytes`` when given, else ``fraction`` of what is available."""
    return int(max_bytes) if max_bytes is not None else int(fraction * available_memory_bytes())


def format_bytes(n: float) -> str:
    """Human-readable byte count (``1.5 GiB``)."""
    n = float(n)
    for unit in ("B", "KiB", "MiB", "GiB", "TiB"):
        if abs(n) < 1024 or unit == "TiB":
            return f"{n:.1f} {unit}" if unit != "B" else f"{int(n)} B"
        n /= 1024
    return f"{n:.1f} TiB"  # pragma: no cover


def ray_box(origin, direction, lower, upper) -> tuple[np.ndarray, np.ndarray]:
    """Where rays enter and leave axis-aligned boxes (the slab test).

    Parameters
    ----------
    origin, direction : (..., 3) float
        Rays (``direction`` need not be unit length: distances are in its units).
    lower, upper : (..., 3) float
        Boxes; broadcast against the rays (one ray against many boxes, or many rays against one).

    Returns
    -------
    t_in, t_out : (...,) float
        Entry and exit along each ray (``t_in > t_out`` where it misses; may be
        negative: the box lies behind, or holds, the origin).  A ray parallel to
        a slab lies in it when ``lower <= origin < upper`` on that axis.

    Examples
    --------
    >>> t_in, t_out = ray_box([[-1.0, 0.5, 0.5]], [[1.0, 0.0, 0.0]], [0, 0, 0], [2, 1, 1])
    >>> float(t_in[0]), float(t_out[0])
    (1.0, 3.0)
    """
    o, d = np.asarray(origin, dtype=np.float64), np.asarray(direction, dtype=np.float64)
    lo, hi = np.asarray(lower, dtype=np.float64), np.asarray(upper, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / d
        ta = (lo - o) * inv
        tb = (hi - o) * inv
    inside = (o >= lo) & (o < hi)
    tmin = np.where(d == 0, np.where(inside, -np.inf, np.inf), np.minimum(ta, tb))
    tmax = np.where(d == 0, np.where(inside, np.inf, -np.inf), np.maximum(ta, tb))
    return tmin.max(axis=-1), tmax.min(axis=-1)


@dataclass(frozen=True)
class VoxelGrid:
    """A regular grid of cubic voxels.

    Parameters
    ----------
    origin : (3,) float, metres
        World coordinates of the grid's lower corner.
    voxel_size : float, metres
        Edge length of every voxel (> 0).
    shape : (3,) int
        Number of voxels along x, y and z (each >= 1).
    """

    origin: tuple
    voxel_size: float
    shape: tuple

    def __post_init__(self):
        origin = np.asarray(self.origin, dtype=np.float64).reshape(-1)
        if origin.shape != (3,) or not np.all(np.isfinite(origin)):
            raise InputError(f"origin must be 3 finite numbers (metres), got {self.origin!r}")
        size = float(self.voxel_size)
        if not (np.isfinite(size) and size > 0):
            raise InputError(
                f"voxel_size must be a positive number of metres, got {self.voxel_size!r}; "
                "e.g. voxel_size=0.2"
            )
        shape = tuple(int(v) for v in np.asarray(self.shape).reshape(-1))
        if len(shape) != 3 or min(shape) < 1:
            raise InputError(f"shape must be 3 integers >= 1, got {self.shape!r}")
        object.__setattr__(self, "origin", tuple(float(v) for v in origin))
        object.__setattr__(self, "voxel_size", size)
        object.__setattr__(self, "shape", shape)

    # -- construction ----------------------------------------------------------
    @classmethod
    def from_bounds(cls, lower, upper, *, voxel_size: float, margin: float = 0.0,
                    snap: bool = True) -> VoxelGrid:
        """The smallest grid of ``voxel_size`` voxels covering a box.

        Parameters
        ----------
        lower, upper : (3,) float, metres
            Corners of the box to cover (``upper >= lower``).
        voxel_size : float, metres
        margin : float, metres
            Added on every side before covering.
        snap : bool
            Snap the origin to a multiple of ``voxel_size`` (grids of the same
            voxel size then line up across runs and scans).
        """
        lo = np.asarray(lower, dtype=np.float64).reshape(-1)
        hi = np.asarray(upper, dtype=np.float64).reshape(-1)
        if lo.shape != (3,) or hi.shape != (3,) or not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
            raise InputError(f"lower and upper must be 3 finite numbers each, got {lower!r}, {upper!r}")
        if np.any(hi < lo):
            raise InputError(f"upper {hi.tolist()} must be >= lower {lo.tolist()} on every axis")
        size = float(voxel_size)
        if not (np.isfinite(size) and size > 0):
            raise InputError(f"voxel_size must be a positive number of metres, got {voxel_size!r}")
        lo = lo - margin
        hi = hi + margin
        if snap:
            lo = np.floor(lo / size) * size
        shape = np.maximum(np.ceil((hi - lo) / size - 1e-9).astype(np.int64), 1)
        return cls(origin=tuple(lo), voxel_size=size, shape=tuple(int(v) for v in shape))

    @classmethod
    def from_points(cls, points, *, voxel_size: float, margin: float = 0.0) -> VoxelGrid:
        """The grid covering a point cloud ``points`` (N, 3), metres."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        if len(p) == 0:
            raise InputError("points is empty: cannot size a grid from no points; pass bounds instead")
        return cls.from_bounds(p.min(axis=0), p.max(axis=0), voxel_size=voxel_size, margin=margin)

    # -- geometry -----------------------------------------------------------------
    @property
    def n_voxels(self) -> int:
        nx, ny, nz = self.shape
        return int(nx) * int(ny) * int(nz)

    @property
    def lower(self) -> np.ndarray:
        """(3,) lower corner, metres."""
        return np.asarray(self.origin, dtype=np.float64)

    @property
    def upper(self) -> np.ndarray:
        """(3,) upper corner, metres."""
        return self.lower + self.voxel_size * np.asarray(self.shape, dtype=np.float64)

    @property
    def voxel_volume(self) -> float:
        """Volume of one voxel, m3."""
        return self.voxel_size**3

    def index_of(self, points) -> np.ndarray:
        """(N, 3) int64 voxel indices of points (may lie outside the grid)."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        return np.floor((p - self.lower) / self.voxel_size).astype(np.int64)

    def contains_index(self, ijk) -> np.ndarray:
        """(N,) bool: which indices lie inside the grid."""
        ijk = np.asarray(ijk).reshape(-1, 3)
        return np.all((ijk >= 0) & (ijk < np.asarray(self.shape)), axis=1)

    def flat(self, ijk) -> np.ndarray:
        """Flat C-order index of (N, 3) voxel indices."""
        ijk = np.asarray(ijk, dtype=np.int64).reshape(-1, 3)
        return np.ravel_multi_index(ijk.T, self.shape)

    def unflat(self, flat) -> np.ndarray:
        """(N, 3) int64 indices of flat C-order indices."""
        return np.stack(np.unravel_index(np.asarray(flat, dtype=np.int64), self.shape), axis=1)

    def centers(self, ijk=None) -> np.ndarray:
        """Voxel centres (N, 3), metres, of ``ijk`` (all voxels when None)."""
        if ijk is None:
            ijk = self.unflat(np.arange(self.n_voxels))
        return self.lower + (np.asarray(ijk, dtype=np.float64) + 0.5) * self.voxel_size

    def layer_heights(self) -> np.ndarray:
        """(nz,) height of each voxel layer's centre, metres."""
        return self.origin[2] + (np.arange(self.shape[2]) + 0.5) * self.voxel_size

    # -- memory ---------------------------------------------------------------------
    def bytes_needed(self, bytes_per_voxel: float) -> int:
        """Bytes an array of ``bytes_per_voxel`` per voxel takes on this grid."""
        return int(np.ceil(self.n_voxels * float(bytes_per_voxel)))

    def check_memory(self, bytes_per_voxel: float, *, max_bytes: int | None = None,
                     what: str = "voxel arrays", fraction: float = 0.8) -> int:
        """Raise before allocating when the grid would not fit in memory.

        Parameters
        ----------
        bytes_per_voxel : float
            Bytes the computation needs per voxel (all arrays together).
        max_bytes : int, optional
            Limit to check against; default ``fraction`` of the memory the
            system reports available.
        what : str
            What is being allocated, named in the message.

        Returns
        -------
        int
            The bytes needed.

        Raises
        ------
        InputError
            With the bytes needed, the limit, and how to fix it.
        """
        need = self.bytes_needed(bytes_per_voxel)
        limit = memory_limit(max_bytes, fraction=fraction)
        if need > limit:
            nx, ny, nz = self.shape
            factor = (need / max(limit, 1)) ** (1 / 3)
            raise InputError(
                f"voxel grid {nx} x {ny} x {nz} = {self.n_voxels:,} voxels of "
                f"{self.voxel_size:g} m needs {format_bytes(need)} for {what} "
                f"({bytes_per_voxel:g} bytes per voxel) but only {format_bytes(limit)} is "
                f"available; use a voxel_size of at least {self.voxel_size * factor:.3g} m, "
                "or a smaller region (bounds=...)"
            )
        return need
