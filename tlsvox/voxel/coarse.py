"""Leaf area density estimated on a coarser grid, placed on the fine one (``voxelize(lad_voxel_size=...)``).

The turbid-medium estimators need voxels wider than the leaves and crossed by
many beams: with 5 cm leaves in 2 cm voxels every voxel is flagged
``LARGE_LEAVES``, most of the voxels behind a leaf are occluded, and the
estimate loses most of the leaf area (docs/bench/memory.md).  Wood, though,
is solid and well fitted at 2 cm (:mod:`tlsvox.voxel.wood.qsm`).  So the leaves' amount
is estimated where the estimators hold, on a grid ``k`` times coarser (``fill``
and the detection model run there too), and placed on the fine grid, whose
wood, ground and echoes come from the fine run:

- ``even`` (default): every fine voxel takes its coarse voxel's LAD (and
  ``occluded`` flag): the leaves stay turbid at the scale where they were
  estimated, and the fine grid carries the wood;
- ``echoes``: each coarse voxel's leaf area goes to its fine voxels in
  proportion to their leaf echo weight ``w`` (the tracer's ``leaf_w``),

      LAD_f = LAD_c * k^3 * w_f / (sum of w over the children of c),

  at most :func:`opaque_lad` per fine voxel (the excess to its siblings); a
  coarse voxel with leaf area and no leaf echo of its own (filled, or given
  echoes by the detection model) spreads it evenly.

Either way each coarse voxel keeps its leaf area exactly (less what lies below
the ground plane).  The echoes mark the leaf surfaces the scanners saw, not
those they hid behind them, and on the synthetic oak ``echoes`` reads worse
against airborne waveforms than ``even`` (docs/voxelize.md, *Leaf-scale
voxels*).

Examples
--------
>>> ratio_of(0.02, 0.1)
5
"""

from __future__ import annotations

import numpy as np

from tlsvox.errors import InputError

__all__ = ["PLACEMENTS", "combine", "opaque_lad", "ratio_of", "voxelize_coarse_lad"]

PLACEMENTS = ("even", "echoes")  #: how the coarse LAD goes onto the fine grid


def ratio_of(voxel_size, lad_voxel_size) -> int:
    """The whole number ``k`` of fine voxels along a coarse one; an InputError when there is none."""
    try:
        voxel_size, lad_voxel_size = float(voxel_size), float(lad_voxel_size)
    except (TypeError, ValueError):
        raise InputError(f"lad_voxel_size={lad_voxel_size!r} must be a number of metres, a whole multiple of "
                         f"voxel_size={voxel_size!r}") from None
    if not np.isfinite(lad_voxel_size) or lad_voxel_size <= 0:
        raise InputError(f"lad_voxel_size={lad_voxel_size!r} must be a positive size in metres, a whole multiple "
                         f"of voxel_size={voxel_size:g} (e.g. {5 * voxel_size:g})")
    k = lad_voxel_size / voxel_size
    if round(k) < 2 or abs(k - round(k)) > 1e-6 * k:
        raise InputError(f"lad_voxel_size={lad_voxel_size:g} m must be a whole multiple (2 or more) of "
                         f"voxel_size={voxel_size:g} m, so each coarse voxel holds whole fine ones: e.g. "
                         f"{max(2, round(k)) * voxel_size:g}")
    return int(round(k))


def voxelize_coarse_lad(call: dict):
    """:func:`~tlsvox.voxel.stages.voxelize` with ``lad_voxel_size``: the coarse run, the fine run, combined.

    ``call`` holds voxelize's arguments.  Returns a VoxelizeResult whose
    ``coarse`` is the coarse run's (its LadEstimate, stats and scene), or the
    larger of the two runs' MemoryPlans with ``plan_only``.
    """
    from tlsvox.scan import Scan
    from tlsvox.voxel.stages import voxelize
    from tlsvox.voxel.trace import Tracer

    k = ratio_of(call["voxel_size"], call["lad_voxel_size"])
    placement = _placement(call.pop("lad_placement"))  # before either run
    scans = call.pop("scans")
    scans = [scans] if isinstance(scans, Scan) else list(scans)  # two runs read them
    H = float(call["lad_voxel_size"])
    call.update(lad_voxel_size=None, tracer=call["tracer"] or Tracer())
    # the coarse run first, on the grid the user's bounds give; the fine grid then covers exactly its
    # voxels (k^3 fine ones each), so no coarse voxel is cut.  The layout asked for is the fine grid's.
    coarse_call = dict(call, voxel_size=H, layout="auto")
    fine_call = dict(call, fill="none", undetected="ignore", snap=False, margin=0.0)
    if call["plan_only"]:
        coarse_plan = voxelize(scans, **coarse_call)
        cg = coarse_plan.grid
        fine_plan = voxelize(scans, **dict(fine_call, bounds=np.array([cg.lower, cg.upper])))
        big = max(coarse_plan, fine_plan, key=lambda p: p.need)
        fg = fine_plan.grid
        note = (f"the scene's grid {' x '.join(map(str, fg.shape))} of {fg.voxel_size:g} m (wood and ground), its LAD "
                f"estimated on {' x '.join(map(str, cg.shape))} of {cg.voxel_size:g} m; the larger of the two runs, "
                f"the {'coarse' if big is coarse_plan else 'fine'} one")
        import dataclasses

        return dataclasses.replace(big, note=note)
    coarse = voxelize(scans, **coarse_call)
    cg = coarse.grid
    outward = str(call["leaf_azimuth"]).lower() == "outward"
    fine = voxelize(scans, **dict(fine_call, bounds=np.array([cg.lower, cg.upper]), ground=coarse.ground,
                                  crown_center=coarse.scene.crown_center if outward else call["crown_center"]))
    return combine(fine, coarse, k, placement)


def _placement(value) -> str:
    """``lad_placement`` checked: one of :data:`PLACEMENTS`."""
    placement = str(value).lower()
    if placement not in PLACEMENTS:
        raise InputError(f"lad_placement={value!r} must be 'even' (each coarse voxel's LAD on all its fine "
                         "voxels) or 'echoes' (its leaf area in proportion to their leaf echo weight)")
    return placement


#: optical depth across a voxel (G = 0.5) above which no beam crosses it (e^-10): leaf area beyond it
#: is not seen by any lidar, so the placement moves it to the voxel's siblings
OPAQUE_TAU = 10.0


def opaque_lad(voxel_size: float) -> float:
    """The LAD, m2/m3, at which a voxel of this size is opaque (:data:`OPAQUE_TAU` with G = 0.5).

    >>> opaque_lad(0.02)
    1000.0
    """
    from voxlidar.scene import LAD_MAX

    return min(OPAQUE_TAU / (0.5 * voxel_size), 0.5 * LAD_MAX)


def _cap(lad, group, n_groups: int, cap: float, rounds: int = 20):
    """LAD above ``cap`` moved to the voxels of the same group below it, in proportion to their LAD.

    Returns the capped LAD and, per group, the excess that no voxel of the group could take
    (every one at the cap), in the same LAD units (to be spread over the group's whole coarse voxel).
    """
    lad = np.asarray(lad, dtype=np.float64).copy()
    left = np.zeros(n_groups)
    for _ in range(rounds):
        excess = np.maximum(lad - cap, 0.0)
        if not excess.any():
            break
        lad = np.minimum(lad, cap)
        spare = np.where(lad < cap, lad, 0.0)
        g_excess = np.bincount(group, weights=excess, minlength=n_groups)
        g_spare = np.bincount(group, weights=spare, minlength=n_groups)
        none = (g_excess > 0) & (g_spare <= 0)
        left += np.where(none, g_excess, 0.0)
        lad += np.where(none[group], 0.0, spare * g_excess[group] / np.maximum(g_spare[group], 1e-300))
    else:  # what still exceeds after the rounds goes to the whole coarse voxel
        excess = np.maximum(lad - cap, 0.0)
        left += np.bincount(group, weights=excess, minlength=n_groups)
        lad = np.minimum(lad, cap)
    return lad, left


def _leaf_weights(stats):
    """(ijk (M, 3), w (M,)) of the voxels holding leaf echo weight, from a dense or sparse trace."""
    w = stats.field("leaf_w")
    if stats.sparse:
        keep = w > 0
        return stats.rows.ijk[keep], w[keep]
    ijk = np.argwhere(w > 0)
    return ijk, w[tuple(ijk.T)]


def combine(fine, coarse, k: int, placement: str = "even"):
    """The fine run's scene with the coarse run's leaf area placed on it (module docstring)."""
    from tlsvox.voxel.stages import VoxelizeResult, below_ground
    from voxlidar.scene import Scene

    placement = _placement(placement)
    g, cg = fine.grid, coarse.grid
    if not (np.allclose(cg.lower, g.lower) and abs(cg.voxel_size - k * g.voxel_size) < 1e-9 * cg.voxel_size
            and tuple(g.shape) == tuple(k * n for n in cg.shape)):
        raise InputError(f"the coarse grid {cg.shape} x {cg.voxel_size:g} m does not cover the fine one {g.shape} x "
                         f"{g.voxel_size:g} m voxel for voxel (internal error: please report it)")
    cs = coarse.scene
    c_keys = cg.flat(cs.ijk)
    order = np.argsort(c_keys)
    c_keys = c_keys[order]
    c_lad, c_occ = cs.lad[order], cs.occluded[order]
    c_std = cs.lad_std[order] if cs.lad_std is not None else np.zeros(len(order))

    def lookup(keys, values):
        if not len(c_keys):
            return np.zeros(len(keys), values.dtype)
        i = np.minimum(np.searchsorted(c_keys, keys), len(c_keys) - 1)
        return np.where(c_keys[i] == keys, values[i], np.zeros(1, values.dtype))

    cap = opaque_lad(g.voxel_size)
    n_over = 0
    if placement == "echoes":
        # fine voxels holding leaf echoes: their parent's leaf area in proportion to their echo weight
        a_ijk, f_w = _leaf_weights(fine.stats)
        parent = cg.flat(a_ijk // k)
        p_keys, p_inv = np.unique(parent, return_inverse=True)
        share = f_w / np.bincount(p_inv, weights=f_w)[p_inv] * k**3
        p_lad = lookup(parent, c_lad)
        a_lad, left = _cap(p_lad * share, p_inv, len(p_keys), cap)
        a_std = lookup(parent, c_std) * a_lad / np.maximum(p_lad, 1e-300)
        a_occ = lookup(parent, c_occ)
        # the coarse voxels with leaf area and no fine leaf echo, and what the cap left of the others
        # (their leaf echoes' voxels all opaque): spread evenly over their children
        bare = ((c_lad > 0) | c_occ) & ~np.isin(c_keys, p_keys)
        over = left > 0
        n_over = int(over.sum())
        b_keys = np.concatenate([c_keys[bare], p_keys[over]])
        b_lad = np.concatenate([c_lad[bare], left[over] / k**3])
        b_std = np.concatenate([c_std[bare], lookup(p_keys[over], c_std) * left[over] / np.maximum(
            lookup(p_keys[over], c_lad) * k**3, 1e-300)])
        b_occ = np.concatenate([c_occ[bare], lookup(p_keys[over], c_occ)])
        n_even = int(bare.sum())
    else:  # even
        a_ijk, a_lad, a_std, a_occ = np.zeros((0, 3), np.int64), np.zeros(0), np.zeros(0), np.zeros(0, bool)
        sel = (c_lad > 0) | c_occ  # occluded ones too: their children were not seen either
        b_keys, b_lad, b_std, b_occ = c_keys[sel], c_lad[sel], c_std[sel], c_occ[sel]
        n_even = int(sel.sum())
    # the evenly spread coarse voxels' children, child c of parent p at row p * k^3 + c
    off = np.stack(np.meshgrid(*(np.arange(k),) * 3, indexing="ij"), axis=-1).reshape(-1, 3).astype(np.int32)
    b_ijk = (cg.unflat(b_keys).astype(np.int32)[:, None, :] * k + off[None, :, :]).reshape(-1, 3)
    k3 = k**3
    b_lad_f = np.repeat(b_lad, k3)
    b_std_f = np.repeat(b_std, k3)
    b_occ_f = np.repeat(b_occ.astype(bool), k3)
    b_wood = np.zeros(len(b_ijk))
    a_wood = np.zeros(len(a_ijk))

    # wood from the fine scene (its LAD there is replaced), put on the leaf voxel it shares, if any
    fs = fine.scene
    wood_sel = fs.wood > 0 if fs.wood is not None else np.zeros(fs.n_voxels, bool)
    w_ijk, w_val = fs.ijk[wood_sel].astype(np.int64), fs.wood[wood_sel]
    free = np.ones(len(w_ijk), bool)
    if len(w_ijk) and len(a_ijk):
        a_keys = g.flat(a_ijk)
        a_order = np.argsort(a_keys)
        wk = g.flat(w_ijk)
        i = np.minimum(np.searchsorted(a_keys[a_order], wk), len(a_keys) - 1)
        found = a_keys[a_order][i] == wk
        a_wood[a_order[i[found]]] = w_val[found]
        free &= ~found
    if len(w_ijk) and len(b_keys):
        b_order = np.argsort(b_keys)
        pk = cg.flat(w_ijk // k)
        i = np.minimum(np.searchsorted(b_keys[b_order], pk), len(b_keys) - 1)
        found = free & (b_keys[b_order][i] == pk)
        local = w_ijk % k
        row = b_order[i] * k3 + (local[:, 0] * k + local[:, 1]) * k + local[:, 2]
        b_wood[row[found]] = w_val[found]
        free &= ~found
    ijk = np.concatenate([a_ijk.astype(np.int32), b_ijk, w_ijk[free].astype(np.int32)])
    del b_ijk
    lad = np.concatenate([a_lad, b_lad_f, np.zeros(int(free.sum()))])
    std = np.concatenate([a_std, b_std_f, np.zeros(int(free.sum()))])
    occ = np.concatenate([a_occ.astype(bool), b_occ_f, np.zeros(int(free.sum()), bool)])
    wood = np.concatenate([a_wood, b_wood, w_val[free]])
    del b_lad_f, b_std_f, b_occ_f, b_wood
    if fine.ground is not None:  # nothing below the ground plane (as voxelize stores it)
        below = below_ground(g, ijk, fine.ground)
        lad[below] = 0.0
        std[below] = 0.0
        occ &= ~below
    keep = (lad > 0) | (wood > 0) | occ
    if not keep.all():
        ijk, lad, std, occ, wood = ijk[keep], lad[keep], std[keep], occ[keep], wood[keep]
    if placement == "echoes":  # a capped coarse voxel's rest went to all its children: one row per voxel
        keys, first, inv = np.unique(g.flat(ijk), return_index=True, return_inverse=True)
        if len(keys) < len(ijk):
            n = len(keys)
            lad, std = np.bincount(inv, weights=lad, minlength=n), np.bincount(inv, weights=std, minlength=n)
            merged = np.zeros(n)
            np.maximum.at(merged, inv, wood)
            wood = merged
            occ = np.bincount(inv, weights=occ, minlength=n) > 0
            ijk = ijk[first]
    area_fine = float(lad.sum() * g.voxel_volume)
    area_coarse = float(cs.lad.sum() * cg.voxel_volume)

    timings = {**{f"fine_{name}": v for name, v in fine.timings.items()},
               **{f"coarse_{name}": v for name, v in coarse.timings.items()},
               "trace": fine.timings.get("trace", 0.0) + coarse.timings.get("trace", 0.0),
               "total": fine.timings.get("total", 0.0) + coarse.timings.get("total", 0.0)}
    meta = dict(coarse.scene.meta)
    meta.update(
        wood_method=fs.meta.get("wood_method"), wood_scale=fs.meta.get("wood_scale"), layout=fs.meta.get("layout"),
        memory_plan=fs.meta.get("memory_plan"), tracer=fs.meta.get("tracer"), beams=fs.meta.get("beams"),
        voxel_steps=fs.meta.get("voxel_steps"), timings=timings,
        lad_voxel_size={"size": cg.voxel_size, "ratio": k, "placement": placement, "layout": cs.meta.get("layout"),
                        "memory_plan": cs.meta.get("memory_plan"),
                        "rule": ("LAD estimated on the coarse grid, each coarse voxel's LAD on all its fine voxels"
                                 if placement == "even" else
                                 "LAD estimated on the coarse grid; each coarse voxel's leaf area placed on its fine "
                                 "voxels in proportion to their leaf echo weight (evenly where it has none), at "
                                 f"most {cap:g} m2/m3 (opaque) each"),
                        "spread_evenly": n_even, "opaque_spread": n_over,
                        "flags": "meta['flags'] counts the coarse grid's voxels, where the LAD was estimated",
                        "leaf_area_coarse": area_coarse, "leaf_area_fine": area_fine})
    meta.pop("occluded_bricks", None)
    if fs.meta.get("occluded_bricks") is not None:
        meta["occluded_bricks"] = fs.meta["occluded_bricks"]
    # LAD in small voxels holding a leaf is large by nature: the quality gates apply to the coarse grid
    # (whose own narrow-voxel warning, if any, names a coarser lad_voxel_size)
    meta["warnings"] = list(coarse.scene.meta.get("warnings", []))
    scene = Scene(origin=g.lower, voxel_size=g.voxel_size, shape=g.shape, ijk=ijk, lad=lad, wood=wood,
                  wood_kind=fs.wood_kind, occluded=occ, lad_std=std, leaf_angle=cs.leaf_angle,
                  leaf_azimuth=cs.leaf_azimuth, crown_center=cs.crown_center, ground_z=fs.ground_z, meta=meta)
    return VoxelizeResult(scene, g, fine.stats, fine.lad, fine.wood, fine.ground, fine.scans, timings, coarse=coarse)
