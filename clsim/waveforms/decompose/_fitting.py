"""Levenberg-Marquardt fit of a Gaussian sum to one waveform (censored samples allowed)."""

from __future__ import annotations

import numpy as np
from scipy import optimize

_MIN_SIGMA_SAMPLES = 0.3
# LM stops when the relative change of the RSS or of the parameters is under 1e-6:
# a millionth of a parameter, far below any standard error of 8-16 bit waveforms
_LM_TOL = 1e-6


def _fit(y: np.ndarray, t: np.ndarray, amp, loc, sig, base, fit_baseline: bool,
         max_nfev: int, censored=None):
    """Levenberg-Marquardt fit; returns (params, free mask, cov or None, rss).

    ``censored`` (boolean mask or None) marks saturated samples: their true
    value is at least the recorded one, so they contribute a residual only
    where the model falls below them (one-sided, Tobit-like least squares).
    The Jacobian is built in column-major layout (``col_deriv``) so MINPACK
    uses it without a copy.
    """
    k = len(amp)
    # internal layout [a_1..a_k, mu_1..mu_k, sigma_1..sigma_k, b]: contiguous slices
    q0 = np.concatenate([np.asarray(amp, float), np.asarray(loc, float),
                         np.asarray(sig, float), [float(base)]])
    nf = q0.size if fit_baseline else q0.size - 1
    y_b = y if fit_baseline else y - float(base)
    jac = np.empty((nf, t.size))
    if fit_baseline:
        jac[-1] = 1.0
    last = {"key": None}

    def f(q):
        a, m, s = q[:k], q[k:2 * k], q[2 * k:3 * k]
        z = t - m[:, None]  # (k, n), scaled in place
        z /= s[:, None]
        e = np.square(z)
        e *= -0.5
        np.exp(e, out=e)
        r = a @ e
        r -= y_b
        if fit_baseline:
            r += q[3 * k]
        if censored is not None:
            r[censored] = np.minimum(r[censored], 0.0)
        last.update(key=q.tobytes(), z=z, e=e, a_s=a / s, r=r)
        return r

    def df(q):
        # MINPACK asks for the Jacobian at the last point where it evaluated f
        if q.tobytes() != last["key"]:
            f(q)
        z, e = last["z"], last["e"]
        jac[:k] = e
        dm = jac[k:2 * k]
        np.multiply(e, last["a_s"][:, None], out=dm)
        dm *= z
        np.multiply(dm, z, out=jac[2 * k:3 * k])
        if censored is not None:
            jac[:, censored & (last["r"] >= 0.0)] = 0.0
        return jac

    with np.errstate(over="ignore", invalid="ignore", divide="ignore", under="ignore"):
        q, cov, info, _msg, _ier = optimize.leastsq(
            f, q0[:nf], Dfun=df, col_deriv=True, full_output=True, maxfev=max_nfev,
            ftol=_LM_TOL, xtol=_LM_TOL)
    # back to the public layout [a_1, mu_1, sigma_1, ..., b]
    order = np.append(np.arange(3 * k).reshape(3, k).T.reshape(-1), 3 * k)
    qf = q0.copy()
    qf[:nf] = q
    full = qf[order]
    full[2:-1:3] = np.abs(full[2:-1:3])
    free = np.zeros(full.size, bool)
    free[:full.size if fit_baseline else full.size - 1] = True
    if cov is not None:
        sel = order[:nf] if fit_baseline else order[:-1]
        cov = cov[np.ix_(sel, sel)]
    r = info["fvec"]
    rss = float(r @ r)
    return full, free, cov, rss


def _split(p: np.ndarray):
    return p[0:-1:3].copy(), p[1:-1:3].copy(), p[2:-1:3].copy(), float(p[-1])



def _linear_start(y, amp, loc, sig, base, fit_baseline, valid, censored):
    """Start amplitudes (and baseline) by linear least squares at the guessed locations
    and widths: sample heights include the tails of overlapping echoes, the linear
    solution does not. Falls back to the heights when an amplitude comes out <= 0."""
    use = np.ones(y.size, bool)
    if valid is not None:
        use &= valid
    if censored is not None:
        use &= ~censored
    t = np.flatnonzero(use).astype(float)
    z = (t[:, None] - loc) / sig
    design = np.exp(-0.5 * z * z)
    target = y[use]
    if fit_baseline:
        design = np.column_stack([design, np.ones(t.size)])
    else:
        target = target - base
    if t.size <= design.shape[1]:
        return amp, base
    coef = np.linalg.lstsq(design, target, rcond=None)[0]
    a = coef[:amp.size]
    if not np.all(a > 0):
        return amp, base
    return a, (float(coef[-1]) if fit_baseline else base)



def _standard_errors(p, free, cov, rss, n) -> np.ndarray:
    se = np.full(p.size, np.nan)
    dof = n - int(free.sum())
    if cov is None or dof <= 0:
        return se
    with np.errstate(over="ignore"):  # a singular covariance: an infinite error
        var = np.diag(cov) * rss / dof
    se[free] = np.sqrt(np.clip(var, 0.0, None))
    return se

