"""Model selection: prune insignificant echoes, add resolved ones while the BIC falls."""

from __future__ import annotations

import numpy as np
from scipy.ndimage import gaussian_filter1d

from clsim.waveforms.decompose._detection import _half_width
from clsim.waveforms.decompose._fitting import _MIN_SIGMA_SAMPLES, _fit, _split, _standard_errors
from clsim.waveforms.decompose._model import gaussian_sum


class _AmplitudeRule:
    """Significance by amplitude: an echo must rise ``thr`` above the baseline; residual
    peaks are sought in the residual smoothed by ``smooth`` samples."""

    #: the lone fit of a residual feature decides whether it is resolved
    width = None

    def __init__(self, thr: float, smooth: float):
        self.thr, self.smooth = float(thr), float(smooth)

    def weak(self, a, s):
        return a < self.thr

    def residual(self, r, skipped):
        rs = gaussian_filter1d(r, max(self.smooth, 1.0))
        rs[skipped] = -np.inf
        return rs, self.thr


def _bic(rss: float, n: int, n_params: int) -> float:
    return n * np.log(max(rss, 1e-300) / n) + n_params * np.log(n)



def _resolved(m: np.ndarray, s: np.ndarray, a: np.ndarray, j: int) -> bool:
    """Whether echo ``j`` is resolved from each other echo (Sparrow's criterion).

    Two echoes are resolved when their sum shows two features, two maxima or a
    maximum and a shoulder: four inflection points instead of the single
    Gaussian's two. For two equal Gaussians this happens beyond a separation
    of 2 sigma (where the sum's curvature at the midpoint changes sign).
    """
    for i in range(m.size):
        if i == j:
            continue
        lo = min(m[i] - 3 * s[i], m[j] - 3 * s[j])
        hi = max(m[i] + 3 * s[i], m[j] + 3 * s[j])
        x = np.linspace(lo, hi, 400)
        curv = 0.0
        for k in (i, j):
            z = (x - m[k]) / s[k]
            curv = curv + a[k] * (z * z - 1.0) * np.exp(-0.5 * z * z) / s[k] ** 2
        if np.count_nonzero(np.diff(np.sign(curv)) != 0) < 4:
            return False
    return True


def _order_and_fit(amp, loc, sig, base, *, y, valid, rule, k_max, censored,
                   add_components, max_nfev, fit_baseline):
    """Fit, prune insignificant echoes, add resolved echoes at residual peaks (BIC).

    ``valid`` (mask or None) selects the samples fitted; ``y`` has its gaps filled.
    ``rule`` (an ``_AmplitudeRule``) says which echoes are too weak
    and filters the residual for the search of further echoes.
    Returns (params, free, cov, rss) or None when no echo survives.
    """
    t = np.arange(y.size, dtype=float)
    if valid is None:
        y_fit, t_fit, cens_fit = y, t, censored
    else:
        y_fit, t_fit = y[valid], t[valid]
        cens_fit = None if censored is None else censored[valid]
    n = y_fit.size

    def fit(a, m, s, b):
        return _fit(y_fit, t_fit, a, m, s, b, fit_baseline, max_nfev, cens_fit)

    def prune(p, free, cov, rss):
        while True:
            a, m, s, b = _split(p)
            se = _standard_errors(p, free, cov, rss, n)
            se_a = se[0:-1:3]
            # significant: fitted height at least the detection threshold and two
            # standard errors; resolvable: sigma >= 0.3 sample; peak inside the record
            # or at most one sigma beyond its ends (an echo cut by the record)
            bad = (rule.weak(a, s) | (s < _MIN_SIGMA_SAMPLES) | (s > t.size) | (m < -s)
                   | (m > t.size - 1 + s) | ~np.isfinite(a)
                   | (np.isfinite(se_a) & (a < 2.0 * se_a)))
            if not bad.any():
                return p, free, cov, rss
            keep = ~bad
            if not keep.any():
                # a detected echo exists: keep the strongest well-formed one rather than none
                usable = (np.isfinite(a) & (a > 0) & (s >= _MIN_SIGMA_SAMPLES) & (s <= t.size)
                          & (m >= -s) & (m <= t.size - 1 + s))
                if not usable.any():
                    return None
                keep[int(np.argmax(np.where(usable, a, -np.inf)))] = True
                return fit(a[keep], m[keep], s[keep], b)
            p, free, cov, rss = fit(a[keep], m[keep], s[keep], b)

    state = prune(*fit(amp, loc, sig, base))
    if state is None or not add_components:
        return state
    p, free, cov, rss = state
    n_eff = n - (0 if cens_fit is None else int(cens_fit.sum()))
    bic = _bic(rss, n_eff, int(free.sum()))
    # residual peaks are tried from the highest down. One that is not resolved from the
    # echoes already there is passed over (it is the pulse's departure from a Gaussian,
    # e.g. the tail of the system response, not a target); the search stops at the first
    # resolved one that does not lower the BIC (a lower residual peak is even less likely
    # to)
    skipped = np.zeros(y.size, bool)
    while (p.size - 1) // 3 < k_max:
        a, m, s, b = _split(p)
        r = y - b - gaussian_sum(t, a, m, s)
        if censored is not None:
            r[censored] = 0.0
        if valid is not None:
            r[~valid] = 0.0
        rs, level = rule.residual(r, skipped)
        j = int(np.argmax(rs))
        if rs[j] < level:
            break
        # one Gaussian fitted to the residual, the other echoes held
        hw = [w for w in (_half_width(rs, j, j, rs[j], 0.0, -1),
                          _half_width(rs, j, j, rs[j], 0.0, +1)) if w is not None]
        s0 = max(float(np.mean(hw)) / np.sqrt(2.0 * np.log(2.0)), 0.5) if hw else float(
            np.median(s))
        if rule.width is None:
            lone = _fit(r if valid is None else r[valid], t_fit, [max(r[j], rs[j])],
                        [float(j)], [s0], 0.0, False, max_nfev, cens_fit)[0]
        else:
            # the residual feature's start values stand in for the lone fit: its width
            # with the filter's removed (a Gaussian through a Gaussian filter adds in
            # quadrature)
            se = np.sqrt(max(s0 * s0 - rule.width(rs is rule.last_mf),
                             0.25))
            lone = np.array([max(r[j], rs[j]), float(j), se])
        if not _resolved(np.append(m, lone[1]), np.append(s, lone[2]),
                         np.append(a, lone[0]), a.size):
            # pass over this residual feature: mask it to its half-maximum width
            lo = j - (hw[0] if hw else 2.0)
            hi = j + (hw[-1] if hw else 2.0)
            skipped[max(0, int(np.floor(lo))):int(np.ceil(hi)) + 1] = True
            continue
        trial = prune(*fit(np.append(a, lone[0]), np.append(m, lone[1]),
                           np.append(s, lone[2]), b))
        if trial is None or (trial[0].size - 1) // 3 <= (p.size - 1) // 3:
            break
        bic_new = _bic(trial[3], n_eff, int(trial[1].sum()))
        if bic_new >= bic:
            break
        p, free, cov, rss = trial
        bic = bic_new
        skipped[:] = False
    return p, free, cov, rss

