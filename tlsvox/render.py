"""Pictures: headless Open3D renders, with a matplotlib fallback.

Open3D's ``OffscreenRenderer`` (Filament) runs headless on Mesa's software
drivers (llvmpipe / lavapipe).  Where it cannot start (no EGL/Vulkan driver),
:func:`render` falls back to a matplotlib scatter of the same points so that a
figure is always written; the returned value says which renderer was used.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from tlsvox.errors import RenderError
from voxlidar.errors import InputError
from voxlidar.safeio import atomic_write, save_figure

__all__ = ["render", "colormap", "reflectance_colors"]

_RENDERER = {}


def colormap(values, *, vmin=None, vmax=None, name="viridis") -> np.ndarray:
    """Map values to (N, 3) RGB in [0, 1] with a matplotlib colormap."""
    import matplotlib

    v = np.asarray(values, dtype=float)
    lo = np.nanmin(v) if vmin is None else vmin
    hi = np.nanmax(v) if vmax is None else vmax
    x = np.clip((v - lo) / max(hi - lo, 1e-12), 0, 1)
    return matplotlib.colormaps[name](x)[:, :3]


def reflectance_colors(reflectance_db, *, vmin=-20.0, vmax=0.0) -> np.ndarray:
    """Colours for apparent reflectance in dB (dark = low, bright = high)."""
    return colormap(np.nan_to_num(reflectance_db, nan=vmin), vmin=vmin, vmax=vmax, name="inferno")


_SIDE = 1200  # one square renderer per process: Filament hangs when a second one is made


def _o3d_renderer():
    """The process's one OffscreenRenderer (square, ``_SIDE`` pixels)."""
    import open3d as o3d

    if "renderer" not in _RENDERER:
        _RENDERER["renderer"] = o3d.visualization.rendering.OffscreenRenderer(_SIDE, _SIDE)
    r = _RENDERER["renderer"]
    r.scene.clear_geometry()
    return r


def render(items, path, *, eye, center, up=(0.0, 0.0, 1.0), fov_deg=45.0, width=1200, height=900,
           point_size=2.0, background=(1.0, 1.0, 1.0), title=None, colorbar=None, backend="auto") -> str:
    """Render point clouds and meshes to a PNG.

    Parameters
    ----------
    items : list
        Each item is an Open3D geometry (PointCloud or TriangleMesh), or a tuple
        ``(points (N, 3), colors (N, 3))`` for a point cloud.
    path : str or Path
        Output PNG (written atomically).
    eye, center, up : (3,) float
        Camera position, look-at point, up vector (world frame, metres).
    title : str, optional
        Drawn above the picture.
    colorbar : (cmap name, vmin, vmax, label), optional
        A colour scale beside the picture, for colours made with
        :func:`colormap` (the label names the quantity and its unit).
    backend : {"auto", "open3d", "matplotlib"}
        ``auto`` tries Open3D and falls back to matplotlib.

    Returns
    -------
    str
        The backend that produced the picture.
    """
    path = Path(path)
    if backend not in ("auto", "open3d", "matplotlib"):
        raise InputError(f"backend={backend!r} is not known; choose one of: auto, open3d, matplotlib")
    if not items:
        raise InputError("nothing to render: items is empty")
    if backend in ("auto", "open3d") and os.environ.get("VOXLIDAR_NO_O3D_RENDER") != "1":
        try:
            _render_o3d_subprocess(items, path, eye, center, up, fov_deg, width, height, point_size,
                                   background)
            _decorate(path, title, colorbar)
            return "open3d"
        except Exception:  # noqa: BLE001 - any renderer failure falls back to matplotlib
            if backend == "open3d":
                raise
    _render_mpl(items, path, eye, center, width, height, None)
    _decorate(path, title, colorbar)
    return "matplotlib"


RENDER_TIMEOUT_S = 240


def _decorate(path: Path, title, colorbar) -> None:
    """Put a title above a rendered picture and a colour scale beside it."""
    if not title and not colorbar:
        return
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.image as mpimg
    import matplotlib.pyplot as plt

    img = mpimg.imread(path)
    h, w = img.shape[:2]
    top = 50.0 if title else 0.0
    side = 110.0 if colorbar else 0.0
    fig = plt.figure(figsize=((w + side) / 100.0, (h + top) / 100.0), dpi=100)
    ax = fig.add_axes((0.0, 0.0, w / (w + side), h / (h + top)))
    ax.imshow(img)
    ax.set_axis_off()
    if title:
        fig.suptitle(title, fontsize=13, y=1.0 - 10.0 / (h + top), va="top")
    if colorbar:
        name, vmin, vmax, label = colorbar
        cax = fig.add_axes(((w + 15.0) / (w + side), 0.15, 18.0 / (w + side), 0.7 * h / (h + top)))
        sm = matplotlib.cm.ScalarMappable(cmap=name, norm=matplotlib.colors.Normalize(vmin, vmax))
        fig.colorbar(sm, cax=cax).set_label(label)
    save_figure(fig, path, dpi=100)
    plt.close(fig)


def _render_o3d_subprocess(items, path, eye, center, up, fov, width, height, point_size, background):
    """Render in a child process: Filament on software Vulkan can hang after several
    large scenes in one process; a child with a deadline keeps the caller safe."""
    import json
    import subprocess
    import sys
    import tempfile

    import open3d as o3d

    with tempfile.TemporaryDirectory(prefix="voxlidar-render-") as tmp:
        tmp = Path(tmp)
        files = []
        for k, item in enumerate(items):
            if isinstance(item, tuple):
                f = tmp / f"g{k}.npz"
                np.savez(f, points=np.asarray(item[0], np.float64), colors=np.asarray(item[1], np.float64))
            elif isinstance(item, o3d.geometry.TriangleMesh):
                f = tmp / f"g{k}.ply"
                o3d.io.write_triangle_mesh(str(f), item, write_ascii=False)
            elif isinstance(item, o3d.geometry.LineSet):
                f = tmp / f"g{k}.lines.npz"
                np.savez(f, points=np.asarray(item.points), lines=np.asarray(item.lines),
                         colors=np.asarray(item.colors))
            else:
                f = tmp / f"g{k}.npz"
                pts = np.asarray(item.points)
                cols = np.asarray(item.colors) if item.has_colors() else np.full((len(pts), 3), 0.3)
                np.savez(f, points=pts, colors=cols)
            files.append(str(f))
        spec = dict(files=files, path=str(Path(path).resolve()), eye=list(map(float, eye)),
                    center=list(map(float, center)), up=list(map(float, up)), fov=float(fov), width=int(width),
                    height=int(height), point_size=float(point_size), background=list(map(float, background)))
        (tmp / "spec.json").write_text(json.dumps(spec))
        done = subprocess.run([sys.executable, "-m", "tlsvox.render", str(tmp / "spec.json")],
                              capture_output=True, text=True, timeout=RENDER_TIMEOUT_S)
        if done.returncode != 0 or not Path(path).exists():
            raise RenderError(f"the off-screen Open3D renderer failed: {done.stderr[-500:]}; "
                              "backend='matplotlib' draws without it")


def _load_items(files):
    import open3d as o3d

    items = []
    for f in files:
        if f.endswith(".lines.npz"):
            z = np.load(f)
            ls = o3d.geometry.LineSet(o3d.utility.Vector3dVector(z["points"]), o3d.utility.Vector2iVector(z["lines"]))
            ls.colors = o3d.utility.Vector3dVector(z["colors"])
            items.append(ls)
        elif f.endswith(".ply"):
            items.append(o3d.io.read_triangle_mesh(f))
        else:
            z = np.load(f)
            items.append((z["points"], z["colors"]))
    return items


def _as_o3d(item):
    import open3d as o3d

    if isinstance(item, tuple):
        pts, cols = item
        pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(pts, dtype=np.float64)))
        pc.colors = o3d.utility.Vector3dVector(np.asarray(cols, dtype=np.float64))
        return pc
    return item


def _render_o3d(items, path, eye, center, up, fov, width, height, point_size, background):
    import open3d as o3d

    r = _o3d_renderer()
    r.scene.set_background(list(background) + [1.0])
    for k, item in enumerate(items):
        g = _as_o3d(item)
        mat = o3d.visualization.rendering.MaterialRecord()
        if isinstance(g, o3d.geometry.TriangleMesh):
            # Lighting is baked into the vertex colours and everything is drawn unlit:
            # Filament on Mesa's software Vulkan hangs when lit meshes and unlit
            # points share a renderer.
            g = o3d.geometry.TriangleMesh(g)
            g.compute_vertex_normals()
            n = np.asarray(g.vertex_normals)
            base = np.asarray(g.vertex_colors) if g.has_vertex_colors() else np.full((len(n), 3), 0.6)
            light = np.array([-0.45, -0.55, 0.70]) / np.linalg.norm([-0.45, -0.55, 0.70])
            shade = 0.45 + 0.55 * np.abs(n @ light)
            g.vertex_colors = o3d.utility.Vector3dVector(np.clip(base * shade[:, None], 0.0, 1.0))
            mat.shader = "defaultUnlit"
        elif isinstance(g, o3d.geometry.LineSet):
            mat.shader = "unlitLine"
            mat.line_width = 2.0
        else:
            mat.shader = "defaultUnlit"
            mat.point_size = float(point_size)
        r.scene.add_geometry(f"g{k}", g, mat)
    r.setup_camera(float(fov), np.asarray(center, float), np.asarray(eye, float), np.asarray(up, float))
    from PIL import Image

    img = Image.fromarray(np.asarray(r.render_to_image()))
    # centre-crop the square picture to the requested aspect, then scale
    aspect = width / height
    if aspect >= 1.0:
        keep = int(round(_SIDE / aspect))
        box = (0, (_SIDE - keep) // 2, _SIDE, (_SIDE - keep) // 2 + keep)
    else:
        keep = int(round(_SIDE * aspect))
        box = ((_SIDE - keep) // 2, 0, (_SIDE - keep) // 2 + keep, _SIDE)
    img = img.crop(box).resize((int(width), int(height)))
    fmt = "JPEG" if Path(path).suffix.lower() in (".jpg", ".jpeg") else "PNG"
    atomic_write(path, lambda tmp: img.convert("RGB").save(tmp, format=fmt))


def _render_mpl(items, path, eye, center, width, height, title):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    pts_all, col_all = [], []
    for item in items:
        if isinstance(item, tuple):
            pts, cols = item
        elif hasattr(item, "lines"):  # LineSet: its end points, in red
            pts = np.asarray(item.points)
            cols = np.tile([0.85, 0.1, 0.1], (len(pts), 1))
        else:  # Open3D geometry
            if hasattr(item, "points"):
                pts = np.asarray(item.points)
                cols = np.asarray(item.colors) if item.has_colors() else np.full((len(pts), 3), 0.3)
            else:
                pts = np.asarray(item.vertices)
                cols = (np.asarray(item.vertex_colors) if item.has_vertex_colors()
                        else np.full((len(pts), 3), 0.3))
        pts_all.append(np.asarray(pts))
        col_all.append(np.asarray(cols))
    pts = np.concatenate(pts_all)
    cols = np.concatenate(col_all)
    if len(pts) > 400_000:
        keep = np.random.default_rng(0).choice(len(pts), 400_000, replace=False)
        pts, cols = pts[keep], cols[keep]
    # project on the plane facing the camera
    view = np.asarray(center, float) - np.asarray(eye, float)
    view /= np.linalg.norm(view)
    right = np.cross(view, [0.0, 0.0, 1.0])
    right /= max(np.linalg.norm(right), 1e-12)
    upv = np.cross(right, view)
    depth = (pts - eye) @ view
    order = np.argsort(-depth)
    fig, ax = plt.subplots(figsize=(width / 150, height / 150), dpi=150)
    ax.scatter((pts @ right)[order], (pts @ upv)[order], c=cols[order], s=0.3, linewidths=0)
    ax.set_aspect("equal")
    ax.set_axis_off()
    if title:
        ax.set_title(title)
    save_figure(fig, path, dpi=fig.dpi)
    plt.close(fig)


def voxel_mesh(centers, size: float, colors, *, shrink: float = 0.9):
    """Open3D TriangleMesh of axis-aligned cubes (one per voxel), coloured per voxel.

    Parameters
    ----------
    centers : (M, 3) float, metres
    size : float, metres
        Voxel edge; cubes are drawn ``shrink`` times smaller so that they read apart.
    colors : (M, 3) float in [0, 1]
    """
    import open3d as o3d

    c = np.asarray(centers, dtype=np.float64).reshape(-1, 3)
    col = np.asarray(colors, dtype=np.float64).reshape(-1, 3)
    corners = np.array([[x, y, z] for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (-0.5, 0.5)]) * size * shrink
    faces = np.array([[0, 2, 1], [1, 2, 3], [4, 5, 6], [5, 7, 6], [0, 1, 4], [1, 5, 4],
                      [2, 6, 3], [3, 6, 7], [0, 4, 2], [2, 4, 6], [1, 3, 5], [3, 7, 5]])
    verts = (c[:, None, :] + corners[None]).reshape(-1, 3)
    tris = (faces[None] + 8 * np.arange(len(c))[:, None, None]).reshape(-1, 3)
    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(verts), o3d.utility.Vector3iVector(tris))
    mesh.vertex_colors = o3d.utility.Vector3dVector(np.repeat(col, 8, axis=0))
    mesh.compute_vertex_normals()
    return mesh


if __name__ == "__main__":  # child process of _render_o3d_subprocess
    import json
    import sys

    _spec = json.loads(Path(sys.argv[1]).read_text())
    _render_o3d(_load_items(_spec["files"]), Path(_spec["path"]), _spec["eye"], _spec["center"], _spec["up"],
                _spec["fov"], _spec["width"], _spec["height"], _spec["point_size"], _spec["background"])
