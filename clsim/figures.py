"""The clsim pictures: simulated waveforms and photon paths (the paper's Fig. 8 and 9), the
picked pulses of `clsim pick` and the decomposed waveforms of `clsim waveforms decompose`.

Open3D is imported only inside :func:`render_traces`; matplotlib inside each
function, so importing this module stays light.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from clsim.errors import InputError
from clsim.sensor import C_M_PER_NS
from voxlidar.safeio import finish_figure

__all__ = ["plot_decomposition", "plot_picks", "plot_result", "plot_traces", "plot_waveforms", "render_traces",
           "settings_caption", "trace_paths"]


def trace_paths(result, top: float):
    """The recorded photon paths of ``result``, each (k, 4): x, y, z (m) and event type.

    The approach from the sensor (hundreds of metres) is cut at height ``top``
    so that the canopy stays visible.
    """
    for tr in result.traces:
        p = tr[tr[:, 3] > -9].astype(np.float64)
        if len(p) < 2:
            continue
        d = p[1, :3] - p[0, :3]
        if p[0, 2] > top and d[2] < 0:
            p[0, :3] = p[1, :3] + d * (top - p[1, 2]) / d[2]
        yield p


def plot_waveforms(curves, path, *, ground_time_ns=None, title=None, height_axis=True,
                   caption: str | None = None) -> Path:
    """Overlay waveforms, drawn against height above ground when ``ground_time_ns`` is given.

    Parameters
    ----------
    curves : list of (label, SimulationResult) or (label, time_ns, waveform)
    path : PNG path (written atomically)
    ground_time_ns : float, optional
        Ground return time on the beam axis; the x axis becomes height (m).
    caption : str, optional
        Text under the axes; default the settings of the first curve that is
        a SimulationResult (:func:`settings_caption`).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5.5, 6.0))
    for item in curves:
        if len(item) == 2:
            label, res = item
            t, w = res.time_ns, res.waveform
        else:
            label, t, w = item
        if ground_time_ns is not None and height_axis:
            y = (ground_time_ns - np.asarray(t)) * C_M_PER_NS / 2.0
            ax.plot(w, y, lw=1.3, label=label)
        else:
            ax.plot(t, w, lw=1.3, label=label)
    if ground_time_ns is not None and height_axis:
        ax.set_ylabel("height above ground (m)")
        ax.set_xlabel("received power (fraction of emitted energy / ns)")
        ax.set_ylim(-2.0, None)
        ax.axhline(0.0, color="0.6", lw=0.6)
    else:
        ax.set_xlabel("time after emission (ns)")
        ax.set_ylabel("received power (fraction of emitted energy / ns)")
    ax.ticklabel_format(axis="x", style="sci", scilimits=(0, 0))
    if title:
        ax.set_title(title, fontsize=10)
    ax.legend(fontsize=8)
    if caption is None:
        caption = next((settings_caption(item[1].settings) for item in curves
                        if len(item) == 2 and getattr(item[1], "settings", None)), None)
    return finish_figure(fig, path, caption=caption)


def render_traces(result, scene, path, *, max_voxels: int = 40_000, approach_m: float = 8.0,
                  width: int = 1000, height: int = 1100) -> str:
    """Headless Open3D render of photon paths over the voxel scene (paper Fig. 8).

    Parameters
    ----------
    result : SimulationResult
        Run with ``trace=N`` (first events of N photons).
    scene : tlsvox.Scene
    path : PNG path
    approach_m : float
        The incoming leg is drawn from this height above the scene's top.

    Returns
    -------
    str
        The renderer used (``open3d`` or ``matplotlib``).
    """
    import open3d as o3d

    from tlsvox.render import colormap, render, voxel_mesh

    if result.traces is None:
        raise InputError("the result has no photon traces; run with trace=N")
    c = scene.centers()
    keep = np.argsort(-scene.lad)[:max_voxels]
    cols = colormap(np.log10(np.maximum(scene.lad[keep], 1e-3)), vmin=-1.5, vmax=1.0, name="Greens")
    cols = 0.35 + 0.5 * cols  # pale, so the paths stand out
    items = [voxel_mesh(c[keep], scene.voxel_size, cols, shrink=0.6)]
    lo, hi = scene.extent
    top = hi[2] + approach_m
    pts, lines, colors = [], [], []
    palette = {1: (0.1, 0.6, 0.1), 2: (0.5, 0.3, 0.1), 3: (0.4, 0.4, 0.4), 0: (0.1, 0.2, 0.9)}
    for p in trace_paths(result, top):
        base = len(pts)
        pts.extend(p[:, :3].tolist())
        for k in range(len(p) - 1):
            lines.append([base + k, base + k + 1])
            colors.append((0.85, 0.1, 0.1) if k == 0 else palette.get(int(p[k, 3]), (0.9, 0.4, 0.0)))
    if lines:
        ls = o3d.geometry.LineSet(o3d.utility.Vector3dVector(np.asarray(pts)),
                                  o3d.utility.Vector2iVector(np.asarray(lines, dtype=np.int32)))
        ls.colors = o3d.utility.Vector3dVector(np.asarray(colors))
        items.append(ls)
    centre = 0.5 * (lo + hi)
    centre[2] = 0.5 * (lo[2] + top)
    span = float(max(hi[0] - lo[0], top - lo[2]))
    eye = centre + np.array([0.0, -1.6 * span, 0.25 * span])
    n = sum(1 for _ in trace_paths(result, top))
    return render(items, path, eye=eye, center=centre, width=width, height=height,
                  title=f"{n} photon paths: first leg red, then leaf green, wood brown, ground grey, escape blue",
                  colorbar=("Greens", -1.5, 1.0, "voxels: log10 LAD (m²/m³)"))


def settings_caption(settings: dict) -> str:
    """The run's settings in two lines, for a figure's caption.

    Examples
    --------
    >>> print(settings_caption({"sensor": {"name": "ahab-chiroptera-i", "altitude_m": 400, "off_nadir_deg": 15,
    ...       "divergence_mrad": 0.5}, "mode": "exact", "detect": "nee", "photons": 1000, "seed": 3,
    ...       "max_order": 3, "hotspot": True, "target": [1.0, 2.0],
    ...       "scene": {"voxel_size": 0.2, "n_voxels": 10, "leaf_angle": {"name": "uniform"}}}))
    sensor ahab-chiroptera-i, 400 m, 15 deg off nadir, 0.5 mrad; aimed at x 1.00, y 2.00 m
    exact/nee, 1,000 photons, seed 3, up to 3 scatterings, hot spot on; scene 10 voxels of 0.2 m, leaf angles uniform
    """
    sn = settings.get("sensor", {})
    sc = settings.get("scene", {})
    parts = [f"sensor {sn.get('name', '?')}"]
    for key, unit in (("altitude_m", "m"), ("off_nadir_deg", "deg off nadir"), ("divergence_mrad", "mrad")):
        if key in sn:
            parts.append(f"{sn[key]:g} {unit}")
    line1 = ", ".join(parts)
    target = settings.get("target")
    if target is not None and len(target) >= 2:
        line1 += f"; aimed at x {target[0]:.2f}, y {target[1]:.2f} m"
    la = sc.get("leaf_angle", {})
    line2 = (f"{settings.get('mode', '?')}/{settings.get('detect', '?')}, {settings.get('photons', 0):,} photons, "
             f"seed {settings.get('seed', '?')}, up to {settings.get('max_order', '?')} scatterings, hot spot "
             f"{'on' if settings.get('hotspot') else 'off'}")
    if sc:
        line2 += (f"; scene {sc.get('n_voxels', 0):,} voxels of {sc.get('voxel_size', float('nan')):g} m, "
                  f"leaf angles {la.get('name', '?') if isinstance(la, dict) else la}")
    return line1 + "\n" + line2


def plot_result(res, path) -> Path:
    """Waveform (total and per order) as a PNG, written atomically."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4))
    ax.plot(res.time_ns, res.waveform, "k", lw=1.5, label="total")
    for k, row in enumerate(res.by_order):
        ax.plot(res.time_ns, row, lw=0.8, label=f"order {k + 1}")
    nz = np.nonzero(res.waveform > 1e-3 * res.waveform.max())[0] if res.waveform.max() > 0 else []
    if len(nz):
        ax.set_xlim(res.time_ns[nz[0]] - 5, res.time_ns[nz[-1]] + 5)
    s = res.settings
    ax.set_title(f"{s['sensor']['name']}: {s['mode']}/{s['detect']}, {s['photons']:,} photons")
    ax.set_xlabel("time after emission (ns)")
    ax.set_ylabel("received power (fraction of emitted energy / ns)")
    ax.legend(fontsize=8)
    return finish_figure(fig, path, caption=settings_caption(s))


def plot_traces(res, scene, path, *, max_voxels: int = 20000) -> Path:
    """Photon paths (``res.traces``) over the scene's voxels, 3-D, as a PNG (paper Fig. 8)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if res.traces is None:
        raise InputError("the result has no photon traces; run with trace=N")
    fig = plt.figure(figsize=(6, 7))
    ax = fig.add_subplot(projection="3d")
    c = scene.centers()
    if len(c):
        pick = np.random.default_rng(0).choice(len(c), min(len(c), max_voxels), replace=False)
        ax.scatter(*c[pick].T, s=1, c="green", alpha=0.15)
    lo, hi = scene.extent
    top = hi[2] + 0.5 * (hi[2] - lo[2])
    colours = {1: "green", 2: "saddlebrown", 3: "grey", 0: "blue"}
    for pts in trace_paths(res, top):
        esc = pts[:, 3] == 0
        pts[esc, :3] = np.clip(pts[esc, :3], lo - 1.0, [hi[0] + 1, hi[1] + 1, top])
        ax.plot(*pts[:, :3].T, lw=0.6, color="red", alpha=0.6)
        for typ, col in colours.items():
            sel = pts[:, 3] == typ
            if sel.any():
                ax.scatter(*pts[sel, :3].T, s=4, color=col)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_zlabel("z (m)")
    ax.set_title(f"{len(res.traces)} photon paths")
    return finish_figure(fig, path, caption=settings_caption(res.settings))


def plot_picks(path, scene, centres, colors, chosen, results, sensor, *, photons: int, seed: int,
               name: str = "") -> Path:
    """The scene seen from the side with the picked voxels marked, beside their waveforms against height
    (``clsim pick --plot``).

    Parameters
    ----------
    path : str or Path
        Picture file; the format follows the suffix (png, pdf, svg, jpg).
    scene : voxlidar.scene.Scene
    centres : (M, 3) float, metres
        Voxel centres drawn; ``colors`` (M, 3) their colours.
    chosen : list of int
        Indices into ``centres`` of the picked voxels (a nadir pulse each).
    results : list of SimulationResult
        One per picked voxel.
    sensor : Sensor
    photons, seed : int
        What the pulses were run with (for the title).
    name : str
        The scene file's name (for the title).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 5.5), gridspec_kw={"width_ratios": [1.1, 1]})
    a.scatter(centres[:, 0], centres[:, 2], s=4, c=colors, alpha=0.5, linewidths=0)
    ground = scene.ground_z if scene.ground_z is not None else float(centres[:, 2].min())
    for k, i in enumerate(chosen):
        x = centres[i, 0]
        a.plot([x, x], [ground, centres[:, 2].max() + 1.0], color=f"C{k}", lw=1.2)
        a.plot(x, centres[i, 2], "o", color=f"C{k}", ms=7, mec="k")
    a.set_xlabel("x (m)")
    a.set_ylabel("height z (m)")
    a.set_title("the scene (voxels by LAD) and the picked pulses", fontsize=10)
    a.set_aspect("equal", adjustable="datalim")
    tg = 2.0 * sensor.range_m / C_M_PER_NS
    for k, (i, r) in enumerate(zip(chosen, results)):
        h = (tg - r.time_ns) * C_M_PER_NS / 2.0 + (scene.ground_z or 0.0)
        b.plot(r.waveform, h, color=f"C{k}", lw=1.2, label=f"voxel {i}")
    b.set_xlabel("received power (fraction of emitted energy / ns)")
    b.set_ylabel("height z (m)")
    b.ticklabel_format(axis="x", style="sci", scilimits=(0, 0))
    b.set_title(f"{sensor.name}, nadir, {photons:,} photons, seed {seed}", fontsize=10)
    b.legend(fontsize=8)
    fig.suptitle(f"clsim pick: {name}", fontsize=11)
    return finish_figure(fig, path)


def plot_decomposition(path, wf, results, count: int, source: str = "") -> Path:
    """The first ``count`` decomposed waveforms: samples, the fitted sum and each echo
    (``clsim waveforms decompose --plot``).

    Parameters
    ----------
    path : str or Path
        Picture file; the format follows the suffix (png, pdf, svg, jpg).
    wf : the waveforms read by ``clsim waveforms`` (``waves``, ``dt_ns``, ``pulse_id``, ``kind``)
    results : list of Components or None
        One per waveform (None: not decomposed).
    count : int
    source : str
        The file's name (for the title).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from clsim.waveforms.decompose import gaussian_sum

    idx = [i for i, c in enumerate(results) if c is not None][:max(1, count)]
    fig, axes = plt.subplots(len(idx), 1, figsize=(7, 1.8 * len(idx)), squeeze=False,
                             sharex=False)
    for ax, i in zip(axes[:, 0], idx):
        c = results[i]
        t = np.arange(wf.waves[i].size) * wf.dt_ns[i]
        tf = np.linspace(t[0], t[-1], 8 * t.size)
        ax.plot(t, wf.waves[i], ".", ms=3, color="k", label="samples")
        ax.plot(tf, c.model(tf), "-", color="C3", lw=1.2, label="fit")
        for k in range(len(c)):
            ax.plot(tf, c.baseline + gaussian_sum(tf, c.amplitude[k:k + 1],
                                                  c.location_ns[k:k + 1], c.sigma_ns[k:k + 1]),
                    "--", lw=0.8)
        ax.set_ylabel(f"pulse {wf.pulse_id[i]}\n(counts)", fontsize=8)
        ax.set_title(f"waveform {i}: {len(c)} echo{'es' if len(c) != 1 else ''}", fontsize=8, loc="left")
    axes[-1, 0].set_xlabel("time from first sample (ns)")
    axes[0, 0].legend(loc="upper right", fontsize=7)
    fig.suptitle(f"Gaussian decomposition of {source or wf.kind}: samples, fit and its echoes", fontsize=10)
    return finish_figure(fig, path)
