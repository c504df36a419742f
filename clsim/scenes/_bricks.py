"""How the simulator reads a plot: bricks its tree instances share.

:class:`SharedBricks` holds :class:`~clsim.scenes.PlotScene`'s brick
methods: each tree model is packed into bricks once per anchor offset modulo
``BRICK`` (:mod:`clsim.transport.bricks`), a brick cell that one instance
alone occupies points at its model's pool slot, and cells where crowns meet
get a brick of their own, merged by :func:`merge_voxels` as
:meth:`PlotScene.to_scene` merges them (so both hold bit-identical values).
"""

from __future__ import annotations

import numpy as np

from clsim.transport.bricks import BRICK, BrickGrid, build_bricks
from voxlidar.scene import Scene

__all__ = ["SharedBricks", "ceil_div", "merge_voxels"]


def ceil_div(a, b):
    """Integer ceil(a / b), elementwise."""
    return -(-np.asarray(a) // b)


def merge_voxels(ijk, lad, wood, occluded, lad_std, shape, wood_kind):
    """Merge voxels given more than once (crowns that overlap), in the order given.

    LAD (and ``area_density`` wood) add; wood probabilities combine as
    ``1 - prod(1 - p)``; ``occluded`` is any; ``lad_std`` adds in quadrature.
    A voxel given once keeps its values bit for bit.

    Returns
    -------
    ijk, lad, wood, occluded, lad_std (or None), n_merged
    """
    shape = np.asarray(shape, dtype=np.int64)
    flat = ijk[:, 0] + shape[0] * (ijk[:, 1] + shape[1] * ijk[:, 2])
    order = np.argsort(flat, kind="stable")            # instance order kept inside a voxel
    f = flat[order]
    start = np.flatnonzero(np.r_[True, f[1:] != f[:-1]]) if len(f) else np.zeros(0, np.int64)
    n = np.diff(np.r_[start, len(f)])
    multi = n > 1
    first = order[start]

    def combine(values, how):
        out = values[first].copy()
        if multi.any():
            v = values[order]
            out[multi] = how(v, start)[multi]
        return out

    lad_m = combine(lad, np.add.reduceat)
    if wood_kind == "probability":
        wood_m = combine(wood, lambda v, s: 1.0 - np.multiply.reduceat(1.0 - v, s))
    else:
        wood_m = combine(wood, np.add.reduceat)
    occ_m = combine(occluded, np.logical_or.reduceat)
    std_m = None if lad_std is None else combine(lad_std, lambda v, s: np.sqrt(np.add.reduceat(v * v, s)))
    return ijk[first], lad_m, wood_m, occ_m, std_m, int(multi.sum())


class SharedBricks:
    """The brick methods of :class:`~clsim.scenes.PlotScene` (a mix-in: it reads the
    plot's models, instances, grid and cache)."""

    def _model_bricks(self, mi: int, residual, leaf_off: bool):
        """The model's bricks with its anchor at ``residual`` (mod BRICK): (BrickGrid, pad)."""
        m = self._models[mi]
        key = (tuple(int(v) for v in residual), bool(leaf_off))
        if key not in m.bricks:
            pad = BRICK * ceil_div(np.maximum(-m.lo, 0), BRICK)
            local = m.rel + np.asarray(residual) + pad
            shape = np.maximum(local.max(axis=0) + 1 if len(local) else 1, 1)
            s = Scene(origin=(0.0, 0.0, 0.0), voxel_size=self.voxel_size, shape=shape, ijk=local,
                      lad=m.lad, wood=m.wood, wood_kind=self.wood_kind or "probability")
            m.bricks[key] = (build_bricks(s, leaf_off=leaf_off), pad)
        return m.bricks[key]

    def brick_grid(self, *, leaf_off: bool = False) -> BrickGrid:
        """The plot as the simulator reads it (:class:`~clsim.transport.bricks.BrickGrid`).

        With ``share=True`` a brick cell occupied by one tree points at its
        model's pool slot (one pool copy per model and anchor offset modulo
        BRICK); cells where trees meet get a merged brick.  With
        ``share=False``: ``build_bricks(self.to_scene())``.  Cached until a
        tree is added.
        """
        key = ("bricks", bool(leaf_off), self.share)
        if key not in self._cache:
            if self.share:
                self._cache[key] = self._shared_bricks(bool(leaf_off))
            else:
                self._cache[key] = build_bricks(self.to_scene(), leaf_off=leaf_off)
        return self._cache[key]

    def _shared_bricks(self, leaf_off: bool) -> BrickGrid:
        B3 = BRICK**3
        bshape = ceil_div(np.asarray(self.shape, dtype=np.int64), BRICK)
        cells, owner, slot, variant = [], [], [], []
        variants: dict = {}
        grids = []
        for t, (mi, _, _) in enumerate(self._inst):
            a3 = self._anchor3(t)
            r = a3 % BRICK
            g, pad = self._model_bricks(mi, r, leaf_off)
            occ = np.flatnonzero(g.index >= 0)
            if not occ.size:
                continue
            bl = np.stack(np.unravel_index(occ, tuple(g.brick_shape), order="F"), axis=1)
            bp = bl + (a3 - r - pad) // BRICK
            vk = variants.setdefault((int(mi), tuple(int(v) for v in r)), len(variants))
            if vk == len(grids):
                grids.append(g)
            cells.append(bp[:, 0] + bshape[0] * (bp[:, 1] + bshape[1] * bp[:, 2]))
            owner.append(np.full(occ.size, t))
            slot.append(g.index[occ].astype(np.int64))
            variant.append(np.full(occ.size, vk))
        index = np.full(int(np.prod(bshape)), -1, dtype=np.int32)
        flags: dict = {}
        if not cells:
            return BrickGrid(brick=BRICK, brick_shape=bshape.astype(np.int32), index=index,
                             pool=np.zeros((0, 2), np.float32), flags=flags)
        cells, owner = np.concatenate(cells), np.concatenate(owner)
        slot, variant = np.concatenate(slot), np.concatenate(variant)
        uniq, inv, counts = np.unique(cells, return_inverse=True, return_counts=True)
        alone = counts[inv] == 1
        # pool part 1: the model bricks that some cell holds alone, one copy per (model, offset)
        pieces, base = [], 0
        for vk, g in enumerate(grids):
            use = alone & (variant == vk)
            if not use.any():
                continue
            used, new = np.unique(slot[use], return_inverse=True)
            pieces.append(g.pool.reshape(-1, B3, 2)[used].reshape(-1, 2))
            index[cells[use]] = (base + new).astype(np.int32)
            base += len(used)
            for k, v in g.flags.items():
                flags[k] = flags.get(k, 0) + v
        # pool part 2: cells where trees meet, merged as to_scene() merges them
        shared_cells = uniq[counts > 1]
        n_merged_bricks = 0
        if shared_cells.size:
            trees = np.unique(owner[~alone])
            mini, _ = self._merged(trees, shared_cells, bshape)
            g = build_bricks(mini, leaf_off=leaf_off)
            n_merged_bricks = g.n_bricks
            sel = np.flatnonzero(g.index >= 0)
            index[sel] = g.index[sel] + base
            pieces.append(g.pool)
            for k, v in g.flags.items():
                flags[k] = flags.get(k, 0) + v
        pool = np.concatenate(pieces) if pieces else np.zeros((0, 2), np.float32)
        flags["merged_bricks"] = n_merged_bricks
        return BrickGrid(brick=BRICK, brick_shape=bshape.astype(np.int32), index=index, pool=pool,
                         flags=flags)

    def memory(self, *, leaf_off: bool = False) -> dict:
        """Bytes the simulator's scene takes, shared against copied.

        Returns
        -------
        dict
            ``index_bytes``; ``pool_bytes`` of :meth:`brick_grid`; ``copied_pool_bytes``
            of one brick per occupied cell (what ``build_bricks(to_scene())``
            holds); ``bricks``, ``occupied_cells``, ``merged_bricks``, ``models``,
            ``trees``.
        """
        g = self.brick_grid(leaf_off=leaf_off)
        occupied = int(np.count_nonzero(g.index >= 0))
        per_brick = BRICK**3 * 2 * np.dtype(np.float32).itemsize
        return dict(index_bytes=int(g.index.nbytes), pool_bytes=int(g.pool.nbytes),
                    copied_pool_bytes=occupied * per_brick, bricks=g.n_bricks, occupied_cells=occupied,
                    merged_bricks=int(g.flags.get("merged_bricks", 0)), models=self.n_models,
                    trees=self.n_trees)
