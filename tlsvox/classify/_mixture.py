"""Two Gaussians fitted to reflectances (EM), and the leaf/wood threshold between them.

Examples
--------
>>> import numpy as np
>>> rng = np.random.default_rng(0)
>>> x = np.concatenate([rng.normal(0.2, 0.03, 3000), rng.normal(0.4, 0.04, 1000)])
>>> mix = fit_two_gaussians(x)
>>> np.round(mix.means, 2).tolist(), round(leaf_wood_threshold(mix), 2)
([0.2, 0.4], 0.3)
"""

from __future__ import annotations

from dataclasses import dataclass
import numpy as np
from tlsvox.errors import InputError
from voxlidar.choices import Choice


class ThresholdRule(Choice):
    """Where the leaf/wood threshold goes between the two fitted Gaussians."""

    MIDWAY = "midway"  #: halfway between the two means (the paper)
    EQUAL_POSTERIOR = "equal_posterior"  #: where w1 N1 = w2 N2 (Bayes rule)


@dataclass(frozen=True)
class GaussianMixture2:
    """Two-component 1-D Gaussian mixture, component 0 the lower mean."""

    weights: np.ndarray
    means: np.ndarray
    sigmas: np.ndarray
    log_likelihood: float
    n_iter: int

    def component_pdf(self, x) -> np.ndarray:
        """Weighted component densities, shape (len(x), 2)."""
        x = np.asarray(x, dtype=np.float64)[..., None]
        z = (x - self.means) / self.sigmas
        return self.weights * np.exp(-0.5 * z * z) / (np.sqrt(2 * np.pi) * self.sigmas)

    def pdf(self, x) -> np.ndarray:
        return self.component_pdf(x).sum(axis=-1)


def fit_two_gaussians(values, *, max_iter: int = 500, tol: float = 1e-9) -> GaussianMixture2:
    """Maximum-likelihood two-Gaussian mixture of 1-D samples (EM).

    Deterministic: starts from the lower and upper quartiles.

    Parameters
    ----------
    values : (N,) float, N >= 10
    max_iter : int
    tol : float
        Stop when the mean log-likelihood changes by less.

    Returns
    -------
    GaussianMixture2

    References
    ----------
    Dempster et al. (1977), doi:10.1111/j.2517-6161.1977.tb01600.x
    """
    x = np.asarray(values, dtype=np.float64).reshape(-1)
    x = x[np.isfinite(x)]
    if len(x) < 10:
        raise InputError(f"fit_two_gaussians: need >= 10 finite values, got {len(x)}")
    spread = np.std(x)
    if spread <= 0:
        raise InputError("fit_two_gaussians: all values are equal; there are no two classes to split")
    q1, q3 = np.percentile(x, [25, 75])
    mu = np.array([q1, q3], dtype=np.float64)
    sig = np.full(2, spread / 2)
    w = np.array([0.5, 0.5])
    floor = 1e-3 * spread
    prev = -np.inf
    it = 0
    for it in range(1, max_iter + 1):
        z = (x[:, None] - mu) / sig
        p = w * np.exp(-0.5 * z * z) / (np.sqrt(2 * np.pi) * sig)
        tot = p.sum(axis=1)
        tot = np.maximum(tot, 1e-300)
        ll = float(np.mean(np.log(tot)))
        r = p / tot[:, None]
        nk = r.sum(axis=0)
        if np.any(nk < 1e-9 * len(x)):
            break
        w = nk / len(x)
        mu = (r * x[:, None]).sum(axis=0) / nk
        sig = np.maximum(np.sqrt((r * (x[:, None] - mu) ** 2).sum(axis=0) / nk), floor)
        if abs(ll - prev) < tol:
            break
        prev = ll
    order = np.argsort(mu)
    return GaussianMixture2(w[order], mu[order], sig[order], prev, it)


def leaf_wood_threshold(mix: GaussianMixture2, *, rule: "str | ThresholdRule" = ThresholdRule.MIDWAY) -> float:
    """Threshold between the two components of ``mix``.

    ``midway``: ``(mu0 + mu1) / 2``.  ``equal_posterior``: the root between
    the means of ``w0 N(x; mu0, s0) = w1 N(x; mu1, s1)``; the midpoint when
    there is none (one component swamps the other everywhere).
    """
    rule = ThresholdRule.parse(rule, "rule")
    m0, m1 = mix.means
    if rule is ThresholdRule.MIDWAY:
        return float(0.5 * (m0 + m1))
    (w0, w1), (s0, s1) = mix.weights, mix.sigmas
    # log w0 - log s0 - (x-m0)^2/2s0^2 = log w1 - log s1 - (x-m1)^2/2s1^2
    a = 1 / (2 * s1**2) - 1 / (2 * s0**2)
    b = m0 / s0**2 - m1 / s1**2
    c = m1**2 / (2 * s1**2) - m0**2 / (2 * s0**2) + np.log(w0 / s0) - np.log(w1 / s1)
    roots = np.array([-c / b]) if abs(a) < 1e-15 * max(abs(b), 1e-300) else np.roots([a, b, c])
    roots = np.real(roots[np.isreal(roots)])
    inside = roots[(roots > m0) & (roots < m1)]
    if len(inside) == 0:
        return float(0.5 * (m0 + m1))
    return float(inside[0])
