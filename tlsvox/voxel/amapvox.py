"""AMAPVox ``.vox`` text files: export a :class:`~voxlidar.scene.Scene`, import one.

The ``.vox`` layout (AMAPVox; read by DART and HELIOS++) is a text header and
one row per voxel of the whole grid::

    VOXEL SPACE
    #min_corner: x0 y0 z0
    #max_corner: x1 y1 z1
    #split: nx ny nz
    #type: TLS #res: h #MAX_PAD: m
    #voxlidar: {"leaf_angle": ..., "ground_z": ...}      (optional, ours)
    i j k PadBVTotal nbSampling ... (space-separated column names)
    0 0 0 0.53 ...

``PadBVTotal`` is the plant (here: leaf) area density in m2/m3, ``NaN`` where
it could not be estimated.  Corners are the grid box's corners in metres.
Columns this package writes: ``PadBVTotal``, ``wood``, ``occluded`` (0/1),
``lad_std``, and for a scene with directional bark (``Scene.wood_directional``)
``wood_beta`` and the bark axis ``wood_axis_x wood_axis_y wood_axis_z``, and for
one with solid wood ``wood_solid`` (0/1) and ``wood_cap``; the
``#voxlidar:`` line keeps the leaf angle model, ground, wood kind, crown
centre and the materials' optics.  On import, unknown columns are ignored, a
missing ``occluded`` column is taken from ``NaN`` PAD values, and ``#res`` may
also come from the corners and split.

Examples
--------
>>> import tempfile, os
>>> from voxlidar.scene import Scene
>>> s = Scene(origin=(0, 0, 0), voxel_size=0.5, shape=(2, 1, 1), ijk=[[1, 0, 0]], lad=[2.0])
>>> path = os.path.join(tempfile.mkdtemp(), "t.vox")
>>> _ = write_vox(s, path)
>>> float(read_vox(path).dense("lad")[1, 0, 0])
2.0
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from tlsvox.errors import InputError
from voxlidar.safeio import atomic_write
from voxlidar.scene import Scene

__all__ = ["read_vox", "write_vox"]

COLUMNS = ("PadBVTotal", "wood", "occluded", "lad_std")
#: AMAPVox's own columns, in its order (``write_vox(amapvox_columns=True)``)
AMAPVOX_COLUMNS = ("PadBVTotal", "angleMean", "bsEntering", "bsIntercepted", "bsPotential", "ground_distance",
                   "lMeanTotal", "lgTotal", "nbEchos", "nbSampling", "transmittance", "attenuation",
                   "attenuationBiasCorrection")
#: written only for a scene with directional bark
WOOD_DIR_COLUMNS = ("wood_beta", "wood_axis_x", "wood_axis_y", "wood_axis_z")
SOLID_COLUMNS = ("wood_solid", "wood_cap")


#: grids above this many voxels are refused by :func:`write_vox` (the format lists every voxel, as text)
VOX_MAX_VOXELS = 20_000_000


def write_vox(scene: Scene, path: str | os.PathLike, *, max_pad: float | None = None,
              metadata: bool = True, amapvox_columns: bool = False) -> Path:
    """Write ``scene`` as an AMAPVox ``.vox`` file (atomic).

    Parameters
    ----------
    scene : Scene
    path : str or PathLike
    max_pad : float, optional
        ``#MAX_PAD`` header value (default: the scene's largest LAD, at least 1).
    metadata : bool
        Add the ``#voxlidar:`` line with the leaf angle model, ground and
        wood kind (ignored by other readers that skip unknown ``#`` lines).
    amapvox_columns : bool
        Write AMAPVox's own 13 columns first, in its order (``PadBVTotal
        angleMean bsEntering bsIntercepted bsPotential ground_distance
        lMeanTotal lgTotal nbEchos nbSampling transmittance attenuation
        attenuationBiasCorrection``), then this package's: readers that parse
        by position (HELIOS++'s detailed voxels) need that order.  The beam
        statistics a scene does not keep are 0; ``ground_distance`` is the
        voxel centre's height over ``ground_z``, ``attenuation`` ``G u`` with
        G = 0.5 and ``transmittance`` ``exp(-G u h)``.
    """
    if not isinstance(scene, Scene):
        raise InputError(f"scene must be a tlsvox Scene, got {type(scene).__name__}")
    nx, ny, nz = scene.shape
    n_cells = int(nx) * int(ny) * int(nz)
    if n_cells > VOX_MAX_VOXELS:
        raise InputError(f"a .vox file lists every voxel of the grid: {nx} x {ny} x {nz} = {n_cells:,} lines "
                         f"(more than {VOX_MAX_VOXELS:,}); keep the scene file (.npz), which stores only the "
                         "voxels that hold something, or voxelise coarser for the .vox")
    lad = scene.dense("lad")
    wood = scene.dense("wood")
    occ = scene.dense("occluded")
    std = scene.dense("lad_std") if scene.lad_std is not None else np.zeros(scene.shape)
    pad = np.where(occ & (lad == 0), np.nan, lad)
    lo, hi = scene.extent
    mp = float(max_pad) if max_pad is not None else max(1.0, float(np.max(lad, initial=0.0)))
    ii, jj, kk = np.meshgrid(np.arange(nx), np.arange(ny), np.arange(nz), indexing="ij")
    cols = [ii.ravel(), jj.ravel(), kk.ravel(), pad.ravel(), wood.ravel(), occ.ravel().astype(int), std.ravel()]
    names: tuple[str, ...] = COLUMNS
    fmt = ["%d", "%d", "%d", "%.9g", "%.9g", "%d", "%.9g"]
    if amapvox_columns:
        zc = lo[2] + (kk.ravel() + 0.5) * scene.voxel_size
        ground = zc - (scene.ground_z if scene.ground_z is not None else lo[2])
        att = 0.5 * np.nan_to_num(pad.ravel())
        zero = np.zeros(n_cells)
        own = [pad.ravel(), zero, zero, zero, zero, ground, zero, zero, zero.astype(int), zero.astype(int),
               np.exp(-att * scene.voxel_size), att, zero]
        cols = cols[:3] + own + cols[4:]
        names = AMAPVOX_COLUMNS + COLUMNS[1:]
        fmt = fmt[:3] + ["%.9g"] * 8 + ["%d", "%d"] + ["%.9g"] * 3 + fmt[4:]
    if scene.wood_directional:
        beta = scene.dense("wood_beta")
        axis = scene.dense("wood_axis")
        cols += [beta.ravel()] + [axis[..., c].ravel() for c in range(3)]
        names, fmt = names + WOOD_DIR_COLUMNS, fmt + ["%.9g"] * 4
    if np.any(scene.wood_solid):
        cols += [scene.dense("wood_solid").ravel().astype(int), scene.dense("wood_cap").ravel()]
        names, fmt = names + SOLID_COLUMNS, fmt + ["%d", "%.9g"]
    header = [
        "VOXEL SPACE",
        f"#min_corner: {lo[0]:.6f} {lo[1]:.6f} {lo[2]:.6f}",
        f"#max_corner: {hi[0]:.6f} {hi[1]:.6f} {hi[2]:.6f}",
        f"#split: {nx} {ny} {nz}",
        f"#type: TLS #res: {scene.voxel_size:.6f} #MAX_PAD: {mp:g}",
    ]
    if metadata:
        meta = {"leaf_angle": scene.leaf_angle.to_dict(), "leaf_azimuth": scene.leaf_azimuth,
                "ground_z": scene.ground_z, "wood_kind": scene.wood_kind,
                "crown_center": scene.crown_center.tolist(), "materials": scene.materials}
        header.append("#voxlidar: " + json.dumps(meta))
    header.append("i j k " + " ".join(names))

    def write(tmp):
        with open(tmp, "w") as fh:
            fh.write("\n".join(header) + "\n")
            np.savetxt(fh, np.column_stack(cols), fmt=fmt)

    return atomic_write(path, write)


def _numbers(line: str, key: str, path) -> list[float]:
    try:
        return [float(v) for v in line.split(":", 1)[1].split()[:3]]
    except (ValueError, IndexError) as err:
        raise InputError(f"{str(path)!r}: bad {key} line {line.strip()!r} in .vox header") from err


def read_vox(path: str | os.PathLike, *, pad_column: str = "PadBVTotal") -> Scene:
    """Read an AMAPVox ``.vox`` file into a :class:`~voxlidar.scene.Scene`.

    Parameters
    ----------
    path : str or PathLike
    pad_column : str
        Column holding the area density (AMAPVox: ``PadBVTotal``).

    Raises
    ------
    InputError
        When the file is missing, has no ``VOXEL SPACE`` header, or lacks
        the corners, split or the PAD column.
    """
    path = Path(path)
    if not path.exists():
        raise InputError(f".vox file {str(path)!r} does not exist")
    header: dict = {}
    names = None
    n_header = 0
    with open(path) as fh:
        first = fh.readline()
        n_header = 1
        if not first.startswith("VOXEL SPACE"):
            raise InputError(f"{str(path)!r} is not an AMAPVox .vox file (first line {first.strip()!r}, "
                             "expected 'VOXEL SPACE')")
        for line in fh:
            n_header += 1
            s = line.strip()
            if s.startswith("#"):
                low = s.lower()
                if low.startswith("#min_corner"):
                    header["min"] = _numbers(s, "#min_corner", path)
                elif low.startswith("#max_corner"):
                    header["max"] = _numbers(s, "#max_corner", path)
                elif low.startswith("#split"):
                    header["split"] = [int(v) for v in _numbers(s, "#split", path)]
                elif low.startswith("#voxlidar:"):
                    header["meta"] = json.loads(s.split(":", 1)[1])
                if "#res:" in low:
                    try:
                        header["res"] = float(low.split("#res:", 1)[1].split()[0])
                    except (ValueError, IndexError):
                        pass
                continue
            names = s.split()
            break
    for key in ("min", "max", "split"):
        if key not in header:
            raise InputError(f"{str(path)!r}: the .vox header has no #{key}_corner/#split line")
    if not names or names[:3] != ["i", "j", "k"] or pad_column not in names:
        raise InputError(f"{str(path)!r}: expected a column header 'i j k ... {pad_column} ...', got {names!r}")
    lo, hi = np.array(header["min"]), np.array(header["max"])
    shape = np.array(header["split"])
    res = header.get("res")
    sizes = (hi - lo) / shape
    if res is None:
        res = float(sizes[0])
    if not np.allclose(sizes, res, rtol=1e-4):
        raise InputError(f"{str(path)!r}: voxels are not cubes of {res} m (corners/split give {sizes.tolist()}); "
                         "tlsvox scenes need cubic voxels")
    data = np.loadtxt(path, skiprows=n_header, ndmin=2)
    if data.shape[1] != len(names):
        raise InputError(f"{str(path)!r}: rows have {data.shape[1]} values for {len(names)} columns")
    col = {n: data[:, i] for i, n in enumerate(names)}
    ijk = data[:, :3].astype(np.int64)
    pad = col[pad_column]
    bad = np.isfinite(pad) & (pad < 0)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise InputError(f"{str(path)!r}: {int(bad.sum())} voxels have a negative {pad_column} (first: voxel "
                         f"{ijk[i].tolist()}, {pad[i]:g}); an area density cannot be negative: fix the file "
                         "(AMAPVox writes NaN where it has no estimate)")
    occluded = col["occluded"].astype(bool) if "occluded" in col else ~np.isfinite(pad)
    lad = np.where(np.isfinite(pad), pad, 0.0)
    wood = col.get("wood", np.zeros(len(lad)))
    std = col.get("lad_std")
    keep = (lad > 0) | occluded | (wood > 0)
    if "wood_solid" in col:  # a solid voxel is wood whatever its turbid amount
        keep |= col["wood_solid"] > 0
    meta = header.get("meta", {})
    kw = {}
    if meta:
        kw = dict(leaf_angle=meta.get("leaf_angle", "uniform"), leaf_azimuth=meta.get("leaf_azimuth", "uniform"),
                  ground_z=meta.get("ground_z"), wood_kind=meta.get("wood_kind", "probability"),
                  crown_center=meta.get("crown_center", [0.0, 0.0]))
        if "materials" in meta:
            kw["materials"] = meta["materials"]
    if all(c in col for c in WOOD_DIR_COLUMNS):
        kw["wood_beta"] = col["wood_beta"][keep]
        kw["wood_axis"] = np.column_stack([col[c][keep] for c in WOOD_DIR_COLUMNS[1:]])
    if all(c in col for c in SOLID_COLUMNS):
        kw["wood_solid"] = col["wood_solid"][keep].astype(bool)
        kw["wood_cap"] = col["wood_cap"][keep]
    return Scene(origin=lo, voxel_size=res, shape=tuple(shape), ijk=ijk[keep], lad=lad[keep],
                 wood=wood[keep], occluded=occluded[keep],
                 lad_std=None if std is None else np.nan_to_num(std[keep]), meta={"source": str(path)}, **kw)
