"""Brute-force NumPy reference of the beam tracer (:func:`trace_reference`).

Every ray against every voxel: each voxel's entry and exit come from a slab
test of the ray against that voxel's box, independent of the tracer's DDA
(``tlsvox/kernels/trace.cl``).  The tests compare the two; it is for small
grids only.

Examples
--------
>>> from tlsvox.voxel.beams import Beams
>>> from tlsvox.voxel.grid import VoxelGrid, ray_box
>>> grid = VoxelGrid((0, 0, 0), 1.0, (3, 1, 1))
>>> beams = Beams.from_rays([[-1, 0.5, 0.5]], [[1, 0, 0]], hit_range=[2.5])
>>> trace_reference(grid, beams).field("path_w")[:, 0, 0].round(6).tolist()
[1.0, 0.5, 0.0]
"""

from __future__ import annotations

import time

import numpy as np

from tlsvox.errors import InputError
from tlsvox.voxel.beams import Beams, EchoKind
from tlsvox.voxel.grid import VoxelGrid, ray_box
from tlsvox.voxel.stats import NF, VoxelStats

__all__ = ["trace_reference"]


def trace_reference(grid: VoxelGrid, beams: Beams) -> VoxelStats:
    """Brute-force NumPy reference of :func:`tlsvox.voxel.trace.trace`: every ray against every voxel.

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
        tin, tout = ray_box(o, d, lo, hi)
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
