"""Gaussians fitted to reflectances (EM), and the leaf/wood threshold between them.

The wood echoes form a narrow bright mode; the leaves' mode is wide and skewed
towards the dark side (partial hits and grazing incidence lower the apparent
reflectance of thin leaves more than that of branches).  Two Gaussians then
fail when the leaf mode's bright tail is heavy: the upper Gaussian takes the
tail instead of the wood, and the threshold falls inside the leaves (measured
on a simulated oak scan: 76,000 leaves labelled wood; docs/classify_register.md).
:func:`fit_gaussians` with ``components="bic"`` (the default of
:func:`tlsvox.classify.classify_scan`) fits two and three Gaussians and keeps
the one the Bayesian information criterion prefers (on a scan's hundreds of
thousands of values, three; on two clean modes, two); the brightest Gaussian
is the wood, the others together the leaves.  A test on the two Gaussians'
separation (Ashman's D < 2) was tried and not adopted: it depends on where EM
stops (docs/classify_register.md, *Two or three Gaussians*).

Examples
--------
>>> import numpy as np
>>> rng = np.random.default_rng(0)
>>> x = np.concatenate([rng.normal(0.2, 0.03, 3000), rng.normal(0.4, 0.04, 1000)])
>>> mix = fit_two_gaussians(x)
>>> np.round(mix.means, 2).tolist(), round(leaf_wood_threshold(mix), 2)
([0.2, 0.4], 0.3)
>>> fit_gaussians(x).n_components  # two clean modes: BIC keeps the paper's two
2
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tlsvox.errors import InputError
from voxlidar.choices import Choice

#: The component counts ``components="bic"`` chooses among.
BIC_COMPONENTS = (2, 3)


class ThresholdRule(Choice):
    """Where the leaf/wood threshold goes between the fitted leaf and wood Gaussians."""

    MIDWAY = "midway"  #: halfway between the leaf and wood means (the paper)
    EQUAL_POSTERIOR = "equal_posterior"  #: where the wood and leaf densities are equal (Bayes rule)


@dataclass(frozen=True)
class GaussianMixture:
    """A 1-D Gaussian mixture, components sorted by mean.

    The last (brightest) component is the wood; the others together are the leaves.

    Attributes
    ----------
    weights, means, sigmas : (K,) float64
    log_likelihood : float
        Mean log-likelihood per sample.
    n_iter : int
        EM iterations run.
    bic : float
        Bayesian information criterion, ``-2 ln L + (3K - 1) ln n`` (NaN when not computed).
    """

    weights: np.ndarray
    means: np.ndarray
    sigmas: np.ndarray
    log_likelihood: float
    n_iter: int
    bic: float = float("nan")

    @property
    def n_components(self) -> int:
        return len(self.means)

    @property
    def separation(self) -> float:
        """Ashman's D between the wood (brightest) Gaussian and the next:
        ``|mu_K - mu_K-1| sqrt(2) / sqrt(s_K^2 + s_K-1^2)``; above 2 the two modes are clearly apart
        (Ashman, Bird & Zepf 1994, doi:10.1086/117248).  A diagnostic: see the module docstring."""
        (m0, m1), (s0, s1) = self.means[-2:], self.sigmas[-2:]
        return float(abs(m1 - m0) * np.sqrt(2.0) / np.sqrt(s0 * s0 + s1 * s1))

    @property
    def leaf_mean(self) -> float:
        """Mean of the leaf components together (all but the brightest)."""
        if len(self.means) == 2:
            return float(self.means[0])
        w = self.weights[:-1]
        return float((w * self.means[:-1]).sum() / w.sum())

    def component_pdf(self, x) -> np.ndarray:
        """Weighted component densities, shape (len(x), K)."""
        x = np.asarray(x, dtype=np.float64)[..., None]
        z = (x - self.means) / self.sigmas
        return self.weights * np.exp(-0.5 * z * z) / (np.sqrt(2 * np.pi) * self.sigmas)

    def leaf_wood_pdf(self, x) -> np.ndarray:
        """Weighted leaf (all components but the last, summed) and wood densities, shape (len(x), 2)."""
        c = self.component_pdf(x)
        return np.stack([c[..., :-1].sum(axis=-1), c[..., -1]], axis=-1)

    def pdf(self, x) -> np.ndarray:
        return self.component_pdf(x).sum(axis=-1)


#: The two-component mixture's former name, kept for scripts that import it.
GaussianMixture2 = GaussianMixture


#: Above this many values, EM runs on a histogram of this many equal bins (weighted by their
#: counts): the parameters move by far less than their sampling error (bin width / spread
#: about 1e-3 on reflectance data), and a scan's 300,000 values fit in a fraction of a second.
HISTOGRAM_BINS = 4096


def _em(x: np.ndarray, k: int, max_iter: int, tol: float) -> GaussianMixture:
    """EM for ``k`` 1-D Gaussians, started from the quantiles (2i + 1) / 2k (deterministic)."""
    n = len(x)
    spread = np.std(x)
    start = [25, 75] if k == 2 else 100.0 * (2 * np.arange(k) + 1) / (2 * k)
    mu = np.asarray(np.percentile(x, start), dtype=np.float64)
    if n > HISTOGRAM_BINS:
        counts, edges = np.histogram(x, bins=HISTOGRAM_BINS)
        keep = counts > 0
        x, c = 0.5 * (edges[:-1] + edges[1:])[keep], counts[keep].astype(np.float64)
    else:
        c = np.ones(n)
    sig = np.full(k, spread / 2)
    w = np.full(k, 1.0 / k)
    floor = 1e-3 * spread
    prev = -np.inf
    it = 0
    for it in range(1, max_iter + 1):
        z = (x[:, None] - mu) / sig
        p = w * np.exp(-0.5 * z * z) / (np.sqrt(2 * np.pi) * sig)
        tot = np.maximum(p.sum(axis=1), 1e-300)
        ll = float(np.dot(c, np.log(tot)) / n)
        r = p * (c / tot)[:, None]
        nk = r.sum(axis=0)
        if np.any(nk < 1e-9 * n):
            break
        w = nk / n
        mu = (r * x[:, None]).sum(axis=0) / nk
        sig = np.maximum(np.sqrt((r * (x[:, None] - mu) ** 2).sum(axis=0) / nk), floor)
        if abs(ll - prev) < tol:
            break
        prev = ll
    order = np.argsort(mu)
    bic = -2.0 * prev * n + (3 * k - 1) * np.log(n)
    return GaussianMixture(w[order], mu[order], sig[order], prev, it, float(bic))


def _check_values(values) -> np.ndarray:
    x = np.asarray(values, dtype=np.float64).reshape(-1)
    x = x[np.isfinite(x)]
    if len(x) < 10:
        raise InputError(f"fit_gaussians: need >= 10 finite values, got {len(x)}")
    if np.std(x) <= 0:
        raise InputError("fit_gaussians: all values are equal; there are no two classes to split")
    return x


def parse_components(components) -> int | str:
    """``components`` checked: an integer >= 2 (or its digits as text) or ``"bic"``."""
    text = components.strip().lower() if isinstance(components, str) else None
    if text == "bic":
        return "bic"
    try:
        k = int(text) if text is not None else int(components)
        ok = not isinstance(components, bool) and k >= 2 and (text is not None or k == components)
    except (TypeError, ValueError, OverflowError):
        ok = False
    if not ok:
        raise InputError(f"components={components!r}: give an integer >= 2 (Gaussians fitted) or 'bic' (the "
                         f"better of {', '.join(map(str, BIC_COMPONENTS))} by the Bayesian information criterion)")
    return k


def fit_gaussians(values, *, components: int | str = "bic", max_iter: int = 500,
                  tol: float = 1e-9) -> GaussianMixture:
    """Maximum-likelihood 1-D Gaussian mixture of samples (EM).

    Deterministic: starts from evenly spaced quantiles.  Above
    :data:`HISTOGRAM_BINS` values it runs on their histogram.

    Parameters
    ----------
    values : (N,) float, N >= 10
    components : int >= 2 or 'bic', default 'bic'
        Gaussians fitted; ``'bic'`` fits two and three and keeps the lower
        Bayesian information criterion (Schwarz 1978).
    max_iter : int
        EM iterations at most (:attr:`GaussianMixture.n_iter` says how many ran).
    tol : float
        Stop when the mean log-likelihood changes by less.

    Returns
    -------
    GaussianMixture

    References
    ----------
    Dempster et al. (1977), doi:10.1111/j.2517-6161.1977.tb01600.x
    Schwarz (1978), doi:10.1214/aos/1176344136
    """
    components = parse_components(components)
    x = _check_values(values)
    if components != "bic":
        return _em(x, components, max_iter, tol)
    fits = [_em(x, k, max_iter, tol) for k in BIC_COMPONENTS]
    return min(fits, key=lambda m: m.bic)


def fit_two_gaussians(values, *, max_iter: int = 500, tol: float = 1e-9) -> GaussianMixture:
    """Two Gaussians (:func:`fit_gaussians` with ``components=2``): the paper's fit."""
    return fit_gaussians(values, components=2, max_iter=max_iter, tol=tol)


def leaf_wood_threshold(mix: GaussianMixture, *, rule: str | ThresholdRule = ThresholdRule.MIDWAY) -> float:
    """Threshold between the leaf components of ``mix`` and its wood (brightest) component.

    ``midway``: halfway between the leaf mean (the weighted mean of all
    components but the last) and the wood mean; with two Gaussians
    ``(mu0 + mu1) / 2``.  ``equal_posterior``: the point between those two means
    where the wood density ``w_K N(x; mu_K, s_K)`` equals the sum of the
    others (the brightest such point); the midpoint when there is none (one
    side swamps the other everywhere).
    """
    rule = ThresholdRule.parse(rule, "rule")
    m0, m1 = mix.leaf_mean, float(mix.means[-1])
    if rule is ThresholdRule.MIDWAY:
        return float(0.5 * (m0 + m1))
    if mix.n_components == 2:
        (w0, w1), (s0, s1), (a0, a1) = mix.weights, mix.sigmas, mix.means
        # log w0 - log s0 - (x-m0)^2/2s0^2 = log w1 - log s1 - (x-m1)^2/2s1^2
        a = 1 / (2 * s1**2) - 1 / (2 * s0**2)
        b = a0 / s0**2 - a1 / s1**2
        c = a1**2 / (2 * s1**2) - a0**2 / (2 * s0**2) + np.log(w0 / s0) - np.log(w1 / s1)
        roots = np.array([-c / b]) if abs(a) < 1e-15 * max(abs(b), 1e-300) else np.roots([a, b, c])
        roots = np.real(roots[np.isreal(roots)])
        inside = roots[(roots > m0) & (roots < m1)]
        return float(inside[0]) if len(inside) else float(0.5 * (m0 + m1))
    x = np.linspace(m0, m1, 4001)
    leaf, wood = mix.leaf_wood_pdf(x).T
    d = np.log(np.maximum(wood, 1e-300)) - np.log(np.maximum(leaf, 1e-300))
    change = np.flatnonzero((d[:-1] < 0) & (d[1:] >= 0))
    if len(change) == 0:
        return float(0.5 * (m0 + m1))
    j = change[-1]
    return float(x[j] + (x[j + 1] - x[j]) * (-d[j]) / (d[j + 1] - d[j]))
