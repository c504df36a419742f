"""Pictures of a plot: the canopy seen from above, coloured by height."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from clsim.errors import InputError
from voxlidar.safeio import check_figure_path, finish_figure

__all__ = ["plot_canopy"]


def plot_canopy(plot, path, *, title: str | None = None, footprints=None) -> Path:
    """Top view of a :class:`~clsim.scenes.PlotScene`: each voxel column coloured by
    the height of its highest voxel above the ground, trunks marked by their
    source (synthetic or scanned), crowns outlined by their equal-area disc.

    Parameters
    ----------
    plot : clsim.scenes.PlotScene
        The plot: its voxel columns, trees and crowns.
    path : str or Path
        Picture file; the format follows the suffix (png, pdf, svg, jpg).
    title : str, optional
    footprints : (N, 2) float, metres, optional
        Points to draw over the canopy (e.g. the pulses' ground targets).

    Returns
    -------
    Path
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Circle
    from mpl_toolkits.axes_grid1 import make_axes_locatable

    check_figure_path("picture", path)
    if not hasattr(plot, "canopy_height"):
        raise InputError(f"plot_canopy draws a clsim.scenes.PlotScene, got {type(plot).__name__}")
    if plot.n_trees == 0:
        raise InputError("the plot has no trees to draw; add_tree(...) first")
    chm = plot.canopy_height()
    h = plot.voxel_size
    x0, y0 = plot.origin_xy
    extent = (x0, x0 + chm.shape[0] * h, y0, y0 + chm.shape[1] * h)
    fig, ax = plt.subplots(figsize=(6.6, 5.8))
    ax.set_facecolor("#d9cfb8")                          # bare ground
    im = ax.imshow(chm.T, origin="lower", extent=extent, cmap="viridis", vmin=0.0,
                   vmax=float(np.nanmax(chm)), interpolation="nearest")
    tab = plot.table()
    for row in tab:
        ax.add_patch(Circle((row["x_m"], row["y_m"]), row["crown_radius_m"], fill=False, lw=0.6,
                            ec="white", alpha=0.8))
    for source, marker, colour, label in (("synthetic", "+", "black", "trunk, synthetic tree"),
                                          ("scene", "^", "red", "trunk, scanned tree (voxel scene)")):
        sel = tab["source"] == source
        if sel.any():
            ax.plot(tab["x_m"][sel], tab["y_m"][sel], marker, color=colour, ms=6, ls="none", label=label)
    if footprints is not None:
        fp = np.asarray(footprints, dtype=float).reshape(-1, 2)
        few = len(fp) <= 100
        ax.plot(fp[:, 0], fp[:, 1], "o" if few else ".", color="orange", ms=7 if few else 1.5, mec="black",
                mew=0.5 if few else 0.0, ls="none", label="pulse targets")
    ax.plot([], [], "o", mfc="none", mec="grey", label="crown (disc of its projected area)")
    ax.legend(loc="upper left", bbox_to_anchor=(0.0, -0.1), ncol=2, fontsize=8, frameon=False)
    ax.set_xlim(extent[0], extent[1])
    ax.set_ylim(extent[2], extent[3])
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    cax = make_axes_locatable(ax).append_axes("right", size="4%", pad=0.1)
    fig.colorbar(im, cax=cax).set_label("canopy height above ground (m)")
    area = plot.width_m * plot.length_m
    ax.set_title(title or (f"{plot.n_trees} trees of {plot.n_models} models, leaf area "
                           f"{plot.total_leaf_area():,.0f} m$^2$ (LAI {plot.total_leaf_area() / area:.2f}), "
                           f"voxel {h:g} m"), fontsize=9)
    return finish_figure(fig, path)
