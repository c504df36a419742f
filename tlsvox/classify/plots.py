"""Pictures of the classification: reflectance histograms (paper Fig. 3) and
the classified cloud, leaf green and wood brown (paper Fig. 5e)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from tlsvox.classify import Classification, PointClass
from voxlidar.safeio import finish_figure

__all__ = ["plot_reflectance_histograms", "render_classified", "CLASS_COLORS"]

#: RGB in [0, 1] per class
CLASS_COLORS = {
    PointClass.LEAF: (0.20, 0.62, 0.17),
    PointClass.WOOD: (0.50, 0.30, 0.12),
    PointClass.GROUND: (0.72, 0.70, 0.62),
    PointClass.NOISE: (0.75, 0.75, 0.75),
    PointClass.TARGET: (0.95, 0.10, 0.10),
}


def plot_reflectance_histograms(results: list[Classification], path: str | os.PathLike, *,
                                truth: list | None = None, bins: int = 120) -> Path:
    """Histogram of the classification feature per scan with the fitted Gaussians and thresholds.

    The feature is what the leaf/wood threshold split: apparent reflectance
    (``paper``, ``echo``) or neighbourhood-mean reflectance in dB
    (``neighbourhood``, the default), see :class:`tlsvox.classify.Classification`.

    Parameters
    ----------
    results : list of Classification
        One per scan (:func:`tlsvox.classify.classify_scan`).
    path : path-like, PNG
    truth : list of (N_i,) Material ids, optional
        Adds the truth leaf and bark histograms (simulated scans).
    bins : int

    Returns
    -------
    Path
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = len(results)
    fig, axes = plt.subplots(n, 1, figsize=(7.5, 3.0 * n), squeeze=False)
    for k, (c, ax) in enumerate(zip(results, axes[:, 0])):
        veg = np.isin(c.labels, [PointClass.LEAF, PointClass.WOOD, PointClass.NOISE])
        paper = c.feature is None or np.isfinite(c.noise_threshold)
        x_all = c.reflectance if paper else c.feature
        veg &= np.isfinite(x_all)
        val = x_all[veg]
        if paper:
            lo, hi = 0.0, max(0.7, float(np.percentile(val, 99.5)) if len(val) else 0.7)
        else:
            lo, hi = (np.percentile(val, [0.2, 99.8]) if len(val) else (-20.0, 0.0))
        edges = np.linspace(lo, hi, bins + 1)
        ax.hist(val, edges, color="0.6", label="vegetation echoes", density=True)
        if truth is not None:
            t = np.asarray(truth[k])[veg]
            for mat, name, col in ((1, "truth leaf", "tab:green"), (2, "truth bark", "saddlebrown")):
                sel = val[t == mat]
                if len(sel):
                    w = np.full(len(sel), 1.0 / (len(val) * (edges[1] - edges[0])))
                    ax.hist(sel, edges, histtype="step", color=col, weights=w, label=name)
        x = np.linspace(lo, hi, 400)
        comp = c.mixture.leaf_wood_pdf(x)
        n_leaf = c.mixture.n_components - 1
        scale = float(np.mean(val >= c.noise_threshold)) if paper and len(val) else 1.0
        leaf_label = "leaf Gaussian" if n_leaf == 1 else f"leaf Gaussians ({n_leaf}, summed)"
        ax.plot(x, comp[:, 0] * scale, "g-", lw=1.5, label=leaf_label)
        ax.plot(x, comp[:, 1] * scale, "-", color="saddlebrown", lw=1.5, label="wood Gaussian")
        if paper:
            ax.axvline(c.noise_threshold, color="k", ls=":", label=f"noise {c.noise_threshold:.3f}")
        ax.axvline(c.leaf_wood_threshold, color="k", ls="--",
                   label=f"leaf/wood {c.leaf_wood_threshold:.3f} ({c.rule})")
        ax.set_xlim(lo, hi)
        ax.set_ylabel("density")
        ax.set_title(f"{c.scan_name}: {c.method}, {c.feature_label}")
        ax.legend(fontsize=7, loc="upper right")
    axes[-1, 0].set_xlabel("apparent reflectance (1 = white Lambertian target)" if n == 1 and (
        results[0].feature is None or np.isfinite(results[0].noise_threshold)) else "feature (see titles)")
    return finish_figure(fig, path)


def render_classified(xyz, labels, path: str | os.PathLike, *, eye=None, center=None,
                      width: int = 1000, height: int = 1000, point_size: float = 2.0,
                      show=(PointClass.LEAF, PointClass.WOOD), backend: str = "auto") -> str:
    """Render a classified cloud, leaf green and wood brown (headless Open3D).

    Parameters
    ----------
    xyz : (N, 3) float, metres (world or reference frame)
    labels : (N,) PointClass values
    path : path-like, PNG
    eye, center : (3,) float, optional
        Camera; default: from the side at 2.2 times the cloud's extent.
    show : classes drawn (default leaf and wood, as in the paper's Fig. 5e)
    backend : {'auto', 'open3d', 'matplotlib'}
        See :func:`tlsvox.render.render` (matplotlib is the fallback).

    Returns
    -------
    str
        Backend that produced the picture.
    """
    from tlsvox.render import render

    xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
    labels = np.asarray(labels).reshape(-1)
    keep = np.isin(labels, [int(c) for c in show])
    pts, lab = xyz[keep], labels[keep]
    cols = np.zeros((len(pts), 3))
    for c, rgb in CLASS_COLORS.items():
        cols[lab == c] = rgb
    if center is None:
        center = 0.5 * (pts.min(axis=0) + pts.max(axis=0)) if len(pts) else np.zeros(3)
    if eye is None:
        ext = float(np.max(pts.max(axis=0) - pts.min(axis=0))) if len(pts) else 1.0
        eye = np.asarray(center) + np.array([0.0, -2.2 * ext, 0.15 * ext])
    return render([(pts, cols)], path, eye=eye, center=center, width=width, height=height,
                  point_size=point_size, title="classified: leaf green, wood brown", backend=backend)
