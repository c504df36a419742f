"""Pictures of a survey: the footprints of a flight line on the ground."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from voxlidar.safeio import check_figure_path, save_figure

from clsim.errors import InputError

__all__ = ["plot_footprints"]


def plot_footprints(pulses, path, *, title: str | None = None, max_points: int = 200_000,
                    draw_track: bool = True) -> Path:
    """Footprint centres of ``pulses`` on the ground (x, y), coloured by scan angle.

    Parameters
    ----------
    pulses : clsim.survey.Pulses
    path : str or Path
        Picture file; the format follows the suffix (png, pdf, svg, jpg).
    title : str, optional
    max_points : int
        Draw at most this many pulses (evenly thinned).
    draw_track : bool
        Draw the platform's nadir track.

    Returns
    -------
    Path
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    check_figure_path("picture", path)                  # before any work
    if len(pulses) == 0:
        raise InputError("no pulses to draw; survey_pulses returned an empty selection")
    step = max(1, int(np.ceil(len(pulses) / max(1, int(max_points)))))
    p = pulses[::step]
    fig, ax = plt.subplots(figsize=(6.4, 5.6))
    lim = float(np.max(np.abs(pulses.scan_angle_deg))) or 1.0
    # a point's area roughly its footprint, at least a pixel
    sc = ax.scatter(p.target[:, 0], p.target[:, 1], c=p.scan_angle_deg, s=2.0, cmap="coolwarm",
                    vmin=-lim, vmax=lim, linewidths=0, rasterized=True)
    if draw_track:
        ax.plot(p.position[:, 0], p.position[:, 1], color="k", lw=0.8, label="nadir track")
        ax.legend(loc="upper right", fontsize=8)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    from mpl_toolkits.axes_grid1 import make_axes_locatable

    cax = make_axes_locatable(ax).append_axes("right", size="4%", pad=0.1)   # as tall as the map
    cb = fig.colorbar(sc, cax=cax)
    cb.set_label("scan angle across track (deg, + right of flight)")
    dur = float(pulses.time_s[-1] - pulses.time_s[0])
    ax.set_title(title or f"{len(pulses):,} footprints over {dur:.2f} s", fontsize=10)
    fig.tight_layout()
    out = save_figure(fig, Path(path))
    plt.close(fig)
    return out
