"""Pictures of a survey: the footprints of a flight line on the ground, the
waveforms along the line (a radargram) and the simulated point cloud."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from clsim.errors import InputError
from voxlidar.safeio import check_figure_path, finish_figure

__all__ = ["plot_footprints", "plot_point_cloud", "plot_radargram"]

#: The simulator's waveform unit (clsim.digitize).
POWER_UNIT = "fraction of emitted energy / ns"


def plot_footprints(pulses, path, *, title: str | None = None, max_points: int = 200_000,
                    draw_track: bool = True) -> Path:
    """Footprint centres of ``pulses`` on the ground (x, y), coloured by scan angle.

    Parameters
    ----------
    pulses : clsim.survey.Pulses
        The pulses of a flight (:func:`clsim.survey.survey_pulses`).
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
    return finish_figure(fig, path)


def _survey(survey):
    """A :class:`clsim.survey.las.SurveyLas` as given, or read from a LAS path."""
    from clsim.survey.las import SurveyLas, read_survey_las

    if isinstance(survey, SurveyLas):
        return survey
    if isinstance(survey, (str, Path)):
        return read_survey_las(survey)
    raise InputError(f"survey must be a SurveyLas (read_survey_las) or the path of a survey .las; "
                     f"got {type(survey).__name__}")


def _along_track(xy, t):
    """Unit flight direction (2,) from a least-squares fit of ``xy`` against time, and each
    point's distance along it (m) from the earliest; +x when the positions do not move."""
    xy = np.asarray(xy, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64)
    u = np.array([1.0, 0.0])
    if t.size > 1 and np.ptp(t) > 0:
        v = np.array([np.polyfit(t, xy[:, k], 1)[0] for k in range(2)])
        if np.hypot(*v) > 0:
            u = v / np.hypot(*v)
    i0 = int(np.argmin(t)) if t.size else 0
    return u, (xy - xy[i0]) @ u if t.size else np.zeros(0)


def plot_radargram(survey, path, *, max_scan_angle_deg: float | None = 0.5, n_columns: int = 600,
                   fill_m: float = 2.0, log: bool = False, show_returns: bool = True, power_unit: str = POWER_UNIT,
                   title: str | None = None, caption: str | None = None) -> Path:
    """Waveforms along the flight line: along-track distance against height, colour = power.

    Each selected pulse's samples are placed at their heights
    (:meth:`SurveyLas.sample_positions`) and resampled onto a height grid one
    sample's height apart; each of ``n_columns`` bins of along-track
    distance shows the waveform of its pulse nearest nadir. A bin no pulse fell in shows the nearest bin that
    has one when that lies within ``fill_m`` (scan lines cross the track
    apart), else it stays blank (grey).

    Parameters
    ----------
    survey : SurveyLas or path
        The survey whose waveforms are drawn: from :func:`clsim.survey.read_survey_las`
        (with its waveform packets), or a survey ``.las`` with its ``.wdp``.
    path : str or Path
        Picture file (png, pdf, svg, jpg).
    max_scan_angle_deg : float or None
        Draw the pulses within this scan angle of nadir (a profile under the
        track); None: every pulse.
    n_columns : int
        Along-track bins.
    fill_m : float
        Largest along-track gap (m) bridged by the nearest pulse's column.
    log : bool
        Logarithmic colour scale.
    show_returns : bool
        Mark the returns (white dots) of the drawn pulses.
    power_unit : str
        The waveforms' unit, for the colour bar.

    Returns
    -------
    Path
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import LogNorm, Normalize

    check_figure_path("picture", path)
    s = _survey(survey)
    if int(n_columns) < 1:
        raise InputError(f"n_columns must be >= 1; got {n_columns!r}")
    if s.n_pulses == 0:
        raise InputError("the survey has no waveform to draw (every pulse was written without a "
                         "point: write_survey_las(..., empty='withheld') keeps them)")
    sel = np.arange(s.n_pulses)
    if max_scan_angle_deg is not None:
        sel = np.flatnonzero(np.abs(s.pulse_scan_angle_deg) <= float(max_scan_angle_deg))
        if sel.size == 0:
            raise InputError(f"no pulse within {max_scan_angle_deg} deg of nadir (scan angles "
                             f"{s.pulse_scan_angle_deg.min():.1f} to {s.pulse_scan_angle_deg.max():.1f} "
                             "deg); pass a larger max_scan_angle_deg or None for all pulses")
    n_s = s.waveforms.shape[1]
    j = np.arange(n_s, dtype=np.float64)
    z = s.origin[sel, 2][:, None] + j[None, :] * s.step[sel, 2][:, None]      # (P, S) heights
    dz = float(np.median(np.abs(s.step[sel, 2]))) or 1.0
    z_lo, z_hi = float(z.min()), float(z.max())
    rows = max(2, min(4000, int(np.ceil((z_hi - z_lo) / dz)) + 1))
    grid = np.linspace(z_lo, z_hi, rows)
    u, along = _along_track(s.origin[sel, :2], s.pulse_gps_time[sel])
    a_lo, a_hi = float(along.min()), float(along.max())
    cols = max(1, min(int(n_columns), sel.size))
    col = np.clip(((along - a_lo) / ((a_hi - a_lo) or 1.0) * cols).astype(int), 0, cols - 1)
    img = np.full((rows, cols), np.nan)
    cnt = np.bincount(col, minlength=cols)
    # per column the pulse nearest nadir: one waveform, not a blend across the track
    best = np.lexsort((np.abs(s.pulse_scan_angle_deg[sel]), col))
    first = best[np.r_[True, col[best][1:] != col[best][:-1]]]
    for k in first:
        zk, wk = z[k], s.waveforms[sel[k]]
        o = np.argsort(zk)
        img[:, col[k]] = np.interp(grid, zk[o], wk[o], left=np.nan, right=np.nan)
    width = ((a_hi - a_lo) or 1.0) / cols
    filled = np.flatnonzero(cnt > 0)
    near = filled[np.clip(np.searchsorted(filled, np.arange(cols)), 0, filled.size - 1)]
    left = filled[np.clip(np.searchsorted(filled, np.arange(cols)) - 1, 0, filled.size - 1)]
    near = np.where(np.abs(left - np.arange(cols)) < np.abs(near - np.arange(cols)), left, near)
    fill = (cnt == 0) & (np.abs(near - np.arange(cols)) * width <= float(fill_m))
    img[:, fill] = img[:, near[fill]]
    vals = img[np.isfinite(img)]
    top = float(np.percentile(vals, 99.9)) if vals.size else 1.0
    top = top if top > 0 else (float(vals.max()) if vals.size and vals.max() > 0 else 1.0)
    if log:
        pos = vals[vals > 0]
        norm = LogNorm(vmin=max(float(pos.min()) if pos.size else top * 1e-4, top * 1e-4), vmax=top)
        img = np.where(img > 0, img, np.nan)
    else:
        norm = Normalize(vmin=min(0.0, float(vals.min()) if vals.size else 0.0), vmax=top)
    fig, ax = plt.subplots(figsize=(8.0, 4.6))
    cmap = plt.get_cmap("magma").with_extremes(bad="0.85")
    im = ax.imshow(img, origin="lower", aspect="auto", cmap=cmap, norm=norm,
                   extent=(a_lo, a_hi if a_hi > a_lo else a_lo + 1.0, z_lo - dz / 2, z_hi + dz / 2),
                   interpolation="nearest")
    if show_returns:
        on = np.isin(s.pulse, sel[first]) & ~s.synthetic
        if on.any():
            i0 = int(np.argmin(s.pulse_gps_time[sel]))
            xy0 = s.origin[sel[i0], :2]
            ax.scatter((s.xyz[on, :2] - xy0) @ u, s.xyz[on, 2], s=2.0, c="cyan", alpha=0.8,
                       linewidths=0, label="returns", rasterized=True)
            ax.legend(loc="upper right", fontsize=8, facecolor="0.5", framealpha=0.6)
    ax.set_xlabel("along-track distance (m)")
    ax.set_ylabel("height (m)")
    cb = fig.colorbar(im, ax=ax, pad=0.02)
    cb.set_label(f"received power ({power_unit})")
    what = (f"within {max_scan_angle_deg:g} deg of nadir" if max_scan_angle_deg is not None
            else "all pulses")
    ax.set_title(title or f"radargram: {sel.size:,} pulses {what}, {cols} columns", fontsize=10)
    return finish_figure(fig, path, caption=caption)


def plot_point_cloud(survey, path, *, color: str = "height", include_withheld: bool = False,
                     max_points: int = 300_000, title: str | None = None,
                     caption: str | None = None) -> Path:
    """The returns seen from above (x, y) and from the side (along track, height).

    Parameters
    ----------
    survey : SurveyLas or path
        The survey whose returns are drawn: from :func:`clsim.survey.read_survey_las`,
        or a survey ``.las``.
    path : str or Path
        Picture file (png, pdf, svg, jpg).
    color : {"height", "return"}
        Colour by height (m) or by return number.
    include_withheld : bool
        Also draw the stand-in points of pulses without a return.
    max_points : int
        Draw at most this many points (evenly thinned).

    Returns
    -------
    Path
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from mpl_toolkits.axes_grid1 import make_axes_locatable

    check_figure_path("picture", path)
    if color not in ("height", "return"):
        raise InputError(f"color must be 'height' or 'return'; got {color!r}")
    s = _survey(survey)
    keep = np.ones(len(s.xyz), bool) if include_withheld else ~s.withheld
    idx = np.flatnonzero(keep)
    if idx.size == 0:
        raise InputError("no points to draw (every pulse is without a return); pass "
                         "include_withheld=True to draw the stand-in points")
    idx = idx[::max(1, int(np.ceil(idx.size / max(1, int(max_points)))))]
    xyz = s.xyz[idx]
    u, along = _along_track(xyz[:, :2], s.gps_time[idx])
    if color == "height":
        c, label, cmap = xyz[:, 2], "height (m)", "viridis"
        norm = None
    else:
        from matplotlib.colors import BoundaryNorm

        k = int(s.return_number[idx].max())
        c, label, cmap = s.return_number[idx], "return number", plt.get_cmap("tab10", k)
        norm = BoundaryNorm(np.arange(0.5, k + 1.0), k)
    fig, (top, side) = plt.subplots(1, 2, figsize=(11.0, 4.8),
                                    gridspec_kw={"width_ratios": [1.0, 1.4]})
    order = np.argsort(xyz[:, 2])                      # highest drawn last, on top
    sc = top.scatter(xyz[order, 0], xyz[order, 1], c=np.asarray(c)[order], s=1.0, cmap=cmap,
                     norm=norm, linewidths=0, rasterized=True)
    top.set_aspect("equal")
    top.set_xlabel("x (m)")
    top.set_ylabel("y (m)")
    top.set_title("top view", fontsize=9)
    side.scatter(along, xyz[:, 2], c=c, s=1.0, cmap=cmap, norm=norm, linewidths=0,
                 rasterized=True)
    side.set_xlabel(f"along-track distance (m; flight direction {np.degrees(np.arctan2(u[1], u[0])):.0f} "
                    "deg from +x)")
    side.set_ylabel("height (m)")
    side.set_title("side view", fontsize=9)
    cax = make_axes_locatable(side).append_axes("right", size="3%", pad=0.08)
    cb = fig.colorbar(sc, cax=cax)
    cb.set_label(label)
    if color == "return":
        cb.set_ticks(np.arange(1, int(s.return_number[idx].max()) + 1))
    n_ret = int((~s.synthetic[idx]).sum())
    fig.suptitle(title or f"simulated point cloud: {idx.size:,} points ({n_ret:,} returns) of "
                 f"{s.n_pulses:,} pulses", fontsize=10)
    return finish_figure(fig, path, caption=caption)
