"""Leaf inclination histograms: G(theta) of a histogram, the beta fit, and the EM inversion of
the observations (step 3 of the package docstring)."""

from __future__ import annotations

import numpy as np

from tlsvox.errors import InputError
from voxlidar.leaf_orientation import LeafAngle, ross_kernel

HALF_PI = 0.5 * np.pi


def histogram_G(edges, density, theta) -> np.ndarray:
    """G(theta) of a piecewise-constant inclination density.

    Parameters
    ----------
    edges : (B + 1,) float, radians
    density : (B,) float, 1/rad
    theta : array_like, radians

    Returns
    -------
    ndarray, shape of ``theta``
    """
    edges = np.asarray(edges, float)
    density = np.asarray(density, float)
    t = np.linspace(0.0, HALF_PI, 4001)
    mid = 0.5 * (t[1:] + t[:-1])
    f = density[np.clip(np.searchsorted(edges, mid, side="right") - 1, 0, len(density) - 1)]
    th = np.atleast_1d(np.asarray(theta, float))
    g = (ross_kernel(th.ravel()[:, None], mid[None, :]) * f[None, :] * np.diff(t)[None, :]).sum(axis=1)
    return g.reshape(np.shape(theta)) if np.ndim(theta) else float(g[0])


def fit_beta(prob, edges=None) -> LeafAngle:
    """Beta leaf angle distribution with the histogram's mean and variance.

    Parameters
    ----------
    prob : (B,) float
        Probability per bin (normalised here).
    edges : (B + 1,) float, radians, optional
        Bin edges; default B equal bins on [0, pi/2].

    Returns
    -------
    LeafAngle
        ``kind="beta"``; of x = 2t/pi with mean m and variance v,
        ``nu = m k``, ``mu = (1 - m) k``, ``k = m (1 - m) / v - 1`` (the
        variance includes the within-bin spread, so a flat histogram gives
        mu = nu = 1).
    """
    p = np.clip(np.asarray(prob, float), 0.0, None)
    if p.sum() <= 0:
        raise InputError("fit_beta: the histogram is empty (no leaf normals); give more leaf echoes")
    p = p / p.sum()
    edges = np.linspace(0.0, HALF_PI, len(p) + 1) if edges is None else np.asarray(edges, float)
    x0, x1 = edges[:-1] / HALF_PI, edges[1:] / HALF_PI
    m = float(np.sum(p * 0.5 * (x0 + x1)))
    ex2 = float(np.sum(p * (x0 * x0 + x0 * x1 + x1 * x1) / 3.0))
    v = max(ex2 - m * m, 1e-6)
    k = max(m * (1.0 - m) / v - 1.0, 1e-3)
    return LeafAngle("beta", mu=max((1.0 - m) * k, 1e-3), nu=max(m * k, 1e-3))


def _em(rows, shape, iterations):
    """Maximum-likelihood EM for the leaf-area distribution with the occlusion and azimuth mixes.

    ``rows`` are (f, m, a, histogram, kernel) with the indices of the row's
    inclination distribution, occlusion mix and azimuth mix and its kernel
    ``K[model, level, true bin, column]``; the histogram is modelled as Poisson
    with mean ``s sum az[a] mix[m] f[f] K`` (``s`` the leaf area the row's
    echoes see, fitted).  The three are updated together by the multiplicative
    EM (Richardson-Lucy) step on the expected complete counts.  ``shape`` =
    (number of f, of mixes, of azimuth mixes).  Returns (f (nf, B), mix
    (nm, L), az (na, A)).
    """
    n_f, n_m, n_a = shape
    n_mod, n_lev, n_bins, _ = rows[0][4].shape
    f = np.full((n_f, n_bins), 1.0 / n_bins)
    mix = np.full((n_m, n_lev), 1.0 / n_lev)
    az = np.full((n_a, n_mod), 1.0 / n_mod)
    flat = [(fi, mi, ai, h, K.reshape(-1, K.shape[-1]), K.sum(axis=-1)) for fi, mi, ai, h, K in rows]
    for _ in range(iterations):
        num = [np.zeros_like(f), np.zeros_like(mix), np.zeros_like(az)]
        den = [np.zeros_like(f), np.zeros_like(mix), np.zeros_like(az)]
        for fi, mi, ai, h, K, sens in flat:
            x = az[ai][:, None, None] * mix[mi][None, :, None] * f[fi][None, None, :]
            pred = x.ravel() @ K
            scale = h[pred > 0].sum() / max(pred.sum(), 1e-300)  # data the model cannot give does not count
            ratio = np.where(pred > 0, h / np.maximum(scale * pred, 1e-300), 0.0)
            back = (K @ ratio).reshape(x.shape) * x * scale  # expected complete counts
            s = sens * scale
            num[0][fi] += back.sum(axis=(0, 1))
            den[0][fi] += np.einsum("a,l,alb->b", az[ai], mix[mi], s)
            num[1][mi] += back.sum(axis=(0, 2))
            den[1][mi] += np.einsum("a,b,alb->l", az[ai], f[fi], s)
            num[2][ai] += back.sum(axis=(1, 2))
            den[2][ai] += np.einsum("l,b,alb->a", mix[mi], f[fi], s)
        f, mix, az = (np.where(d_ > 0, n_ / np.maximum(d_, 1e-300), 0.0) for n_, d_ in zip(num, den))
        f, mix, az = (v / np.maximum(v.sum(axis=1, keepdims=True), 1e-300) for v in (f, mix, az))
    return f, mix, az


def _weighted(fits, masks, n_bins):
    h = np.zeros(n_bins)
    for f, m in zip(fits, masks):
        m = m & f.ok
        h += np.bincount(f.meas_bin[m], weights=f.weight[m], minlength=n_bins)
    return h / h.sum() if h.sum() > 0 else h
