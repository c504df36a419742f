"""Levenberg-Marquardt fits of many waveforms at once, vectorised across waveforms.

Every waveform of a group has the same number of echoes ``K``; the model,
the Jacobian ``J`` (P x n, ``P = 3K + 1``), the normal matrix ``J J^T`` and
the damped step ``(J J^T + lambda diag(J J^T)) delta = -J r`` (Marquardt 1963)
are stacked arrays, so one NumPy call serves the whole group. Each waveform
keeps its own damping ``lambda`` (Nielsen 1999: after an accepted step
multiplied by ``max(1/3, 1 - (2 rho - 1)^3)``, ``rho`` the ratio of actual to
predicted decrease; after a rejected one by ``nu``, which doubles while steps
keep failing) and leaves the active set when an
accepted step lowers its RSS by less than ``tol`` relative (or ``0.01 noise^2``),
or when, at the start or after an accepted step, the next step (whole, inside the
trust region) is predicted to lower it by less than that: the step is then not
taken, which saves the evaluation that would only confirm convergence. Censored
(clipped) samples count only where the model falls below them (Tobin 1958),
as in the single-waveform fit.

References
----------
Marquardt, D. W. (1963). An algorithm for least-squares estimation of
    nonlinear parameters. J. SIAM 11(2), 431-441. doi:10.1137/0111030
Nielsen, H. B. (1999). Damping parameter in Marquardt's method. Technical
    report IMM-REP-1999-05, Technical University of Denmark.
Tobin, J. (1958). Estimation of relationships for limited dependent
    variables. Econometrica 26(1), 24-36. doi:10.2307/1907382
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

_TOL = 1e-6


@dataclass
class GroupFit:
    """Result of :func:`fit_group` for G waveforms of K echoes (one line on each
    attribute below)."""

    a: np.ndarray
    """(G, K) amplitudes, in the units of the samples."""
    m: np.ndarray
    """(G, K) locations, samples."""
    s: np.ndarray
    """(G, K) Gaussian widths, samples."""
    b: np.ndarray
    """(G,) baselines."""
    rss: np.ndarray
    """(G,) residual sums of squares."""
    se: np.ndarray
    """(G, 3K + 1) standard errors in the order [a_1..a_K, m_1..m_K, s_1..s_K, b]
    (b's NaN when the baseline was held)."""
    n_eff: np.ndarray
    """(G,) samples that count."""
    n_iter: np.ndarray
    """(G,) Levenberg-Marquardt iterations (one model and Jacobian each)."""
    resid: np.ndarray | None = None
    """(G, n) float32 samples minus model at the fit, zero where a sample does not
    count or is censored; None on the NumPy path, which does not keep it."""
    filtered: np.ndarray | None = None
    """(G, 2, n) float32 that residual through the matched filter and the Gaussian
    of sigma 1 sample (the device fits), or None."""


def _evaluate(y, w, cens, t, a, m, s, b, fit_baseline, want_jac):
    """Residuals (G, n) and, if asked, the weighted Jacobian (G, P, n)."""
    z = (t - m[:, :, None]) / s[:, :, None]
    # the exponential in float32 (5x faster than float64 here; relative error 1e-7 near
    # the peak, far below any noise), everything else in float64
    arg = np.multiply(z, z, dtype=np.float32)
    arg *= np.float32(-0.5)
    e = np.exp(arg, out=arg)
    r = np.matmul(a[:, None, :], e.astype(float))[:, 0, :] + (b[:, None] - y)
    use = w
    if cens is not None:
        hit = cens & (r >= 0.0)
        r[hit] = 0.0
        use = w & ~hit
    r *= w
    if not want_jac:
        return r, None
    g, k, n = e.shape
    p = 3 * k + (1 if fit_baseline else 0)
    # the Jacobian in float32 too: it sets the step's direction and the normal matrix
    # (relative error ~1e-6 after the sums), not the residuals the steps are judged by
    jac = np.empty((g, p, n), dtype=np.float32)
    jac[:, :k] = e
    dm = jac[:, k:2 * k]
    z32 = z.astype(np.float32)
    np.multiply(e, (a / s).astype(np.float32)[:, :, None], out=dm)
    dm *= z32
    np.multiply(dm, z32, out=jac[:, 2 * k:3 * k])
    if fit_baseline:
        jac[:, -1] = 1.0
    jac *= use[:, None, :]
    return r, jac


def fit_group(y, w, a, m, s, b, *, cens=None, fit_baseline=True, max_iter=40, tol=_TOL,
              noise=None):
    """Fit G waveforms of K Gaussian echoes each (see the module docstring).

    Parameters
    ----------
    y : (G, n) float64
        Samples (padding anywhere ``w`` is False).
    w : (G, n) bool
        Samples that count.
    a, m, s : (G, K) float64
        Start amplitudes, locations and widths, samples.
    b : (G,) float64
        Start (or held) baseline.
    cens : (G, n) bool, optional
        Censored samples.
    fit_baseline : bool
        Fit ``b`` (else hold it).
    noise : (G,) float64, optional
        Noise standard deviation of each waveform: the fit also stops when an
        accepted step lowers the RSS by less than ``0.01 noise^2`` (a change of
        chi-square under 0.01: the parameters are within about 0.1 standard
        error of the minimum).

    Returns
    -------
    GroupFit
    """
    g, k = a.shape
    n = y.shape[1]
    t = np.arange(n, dtype=float)
    a, m, s, b = a.astype(float).copy(), m.astype(float).copy(), s.astype(float).copy(), \
        b.astype(float).copy()
    p = 3 * k + (1 if fit_baseline else 0)
    with np.errstate(over="ignore", invalid="ignore", divide="ignore", under="ignore"):
        r, jac = _evaluate(y, w, cens, t, a, m, s, b, fit_baseline, True)
        cost = np.einsum("gn,gn->g", r, r)
        hess = np.matmul(jac, jac.transpose(0, 2, 1)).astype(float)
        grad = np.matmul(jac, r.astype(np.float32)[:, :, None])[:, :, 0].astype(float)
        lam = np.full(g, 1e-3)
        nu = np.full(g, 2.0)
        act = np.arange(g)
        first = np.argmax(w, axis=1)
        last = n - 1 - np.argmax(w[:, ::-1], axis=1)
        n_iter = np.zeros(g, int)
        eye = np.eye(p)
        for _it in range(max_iter):
            if act.size == 0:
                break
            n_iter[act] += 1
            h = hess[act]
            d = np.diagonal(h, axis1=1, axis2=2)
            damp = h + (lam[act, None] * d + 1e-12 * (d.max(axis=1, keepdims=True) + 1e-300)
                        )[:, :, None] * eye
            try:
                step = np.linalg.solve(damp, -grad[act][:, :, None])[:, :, 0]
            except np.linalg.LinAlgError:
                step = np.stack([np.linalg.lstsq(dm, -gr, rcond=None)[0]
                                 for dm, gr in zip(damp, grad[act])])
            # a trust region in the natural scales: a step moves no location by more
            # than 2 sigma + 1 sample and no width by more than half of itself + 0.5
            # sample (else the whole step is shortened); widths stay in [0.2, n]
            sa = s[act]
            ratio = np.maximum(np.abs(step[:, k:2 * k]) / (2.0 * sa + 1.0),
                               np.abs(step[:, 2 * k:3 * k]) / (0.5 * sa + 0.5)).max(axis=1)
            step *= (1.0 / np.maximum(ratio, 1.0))[:, None]
            # predicted decrease of the RSS, -2 g.d - d.H.d
            pred = -2.0 * np.einsum("gp,gp->g", grad[act], step) - np.einsum(
                "gp,gpq,gq->g", step, h, step)
            # converged: at the start or after an accepted step (nu back at 2), a step
            # the trust region leaves whole would lower the RSS by less than the gain
            # that stops the fit (below); it is not taken, nor counted
            enough = tol * np.maximum(cost[act], 1e-300)
            if noise is not None:
                enough = np.maximum(enough, 0.01 * noise[act] ** 2)
            conv = (nu[act] == 2.0) & (ratio <= 1.0) & (pred <= enough)
            if conv.any():
                n_iter[act[conv]] -= 1
                keep = ~conv
                act, step, h, pred, sa = act[keep], step[keep], h[keep], pred[keep], sa[keep]
                if act.size == 0:
                    break
            na = a[act] + step[:, :k]
            nm = m[act] + step[:, k:2 * k]
            ns = np.clip(np.abs(s[act] + step[:, 2 * k:3 * k]), 0.2, n)
            nb = b[act] + step[:, -1] if fit_baseline else b[act]
            rt, jt = _evaluate(y[act], w[act], None if cens is None else cens[act], t,
                               na, nm, ns, nb, fit_baseline, True)
            ct = np.einsum("gn,gn->g", rt, rt)
            ok = np.isfinite(ct) & (ct <= cost[act])
            # gain ratio: actual over predicted decrease of the RSS
            rho = np.where(pred > 0, (cost[act] - ct) / np.where(pred > 0, pred, 1.0), 0.0)
            acc = act[ok]
            gain = cost[acc] - ct[ok]
            a[acc], m[acc], s[acc] = na[ok], nm[ok], ns[ok]
            if fit_baseline:
                b[acc] = nb[ok]
            cost[acc] = ct[ok]
            jo = jt[ok]
            hess[acc] = np.matmul(jo, jo.transpose(0, 2, 1))
            grad[acc] = np.matmul(jo, rt[ok].astype(np.float32)[:, :, None])[:, :, 0]
            # Nielsen's damping: after a good step lambda falls by up to 3, after a
            # rejected one it rises by nu, which doubles while steps keep failing
            lam[acc] *= np.maximum(1.0 / 3.0, 1.0 - (2.0 * np.clip(rho[ok], 0.0, 1.0) - 1.0) ** 3)
            nu[acc] = 2.0
            rej = act[~ok]
            lam[rej] *= nu[rej]
            nu[rej] *= 2.0
            # done: an accepted step that gains under tol (relative), a step that moves
            # the parameters by less than tol of their size, or damping so high that the
            # steps are negligible
            done = np.zeros(act.size, bool)
            enough = tol * np.maximum(cost[acc], 1e-300)
            if noise is not None:
                enough = np.maximum(enough, 0.01 * noise[acc] ** 2)
            done[ok] = gain <= enough
            # (MINPACK's xtol: the step's norm under tol of the parameters' norm)
            size = np.linalg.norm(np.concatenate([a[act], m[act], s[act]], axis=1), axis=1)
            done |= np.linalg.norm(step[:, :3 * k], axis=1) <= tol * size
            done |= lam[act] > 1e8
            # an echo collapsed (width under 0.25 sample, amplitude <= 0) or left the
            # record (peak more than one sigma beyond its first or last sample): the fit
            # stops here; model selection drops that echo and refits the rest
            sa, ma = s[act], m[act]
            done |= np.any((sa <= 0.25) | (a[act] <= 0.0) | (ma < first[act, None] - sa)
                           | (ma > last[act, None] + sa), axis=1)
            act = act[~done]
        n_eff = w.sum(axis=1)
        if cens is not None:
            n_eff = n_eff - (cens & w).sum(axis=1)
        se = standard_errors(hess, cost, n_eff, k)
    return GroupFit(a, m, s, b, cost, se, n_eff, n_iter)


def linear_start(y, w, a, m, s, b):
    """Start amplitudes and baseline by linear least squares at the start locations and
    widths ``m, s`` (G, K) over the samples ``w`` (G, n) that count (clipped ones left
    out): sample heights include the tails of overlapping echoes, the linear solution
    does not. Kept for a waveform only where every amplitude comes out positive;
    returns (a, b)."""
    g, k = a.shape
    n = y.shape[1]
    z = (np.arange(n, dtype=float) - m[:, :, None]) / s[:, :, None]
    arg = np.multiply(z, z, dtype=np.float32)
    arg *= np.float32(-0.5)
    design = np.ones((g, k + 1, n))
    design[:, :k] = np.exp(arg, out=arg)
    design *= w[:, None, :]
    h = np.matmul(design, design.transpose(0, 2, 1))
    rhs = np.matmul(design, (y * w)[:, :, None])
    try:
        coef = np.linalg.solve(h + 1e-9 * np.eye(k + 1), rhs)[:, :, 0]
    except np.linalg.LinAlgError:
        return a, b
    ok = np.all(coef[:, :k] > 0, axis=1) & np.all(np.isfinite(coef), axis=1)
    return np.where(ok[:, None], coef[:, :k], a), np.where(ok, coef[:, k], b)


def standard_errors(hess, rss, n_eff, k):
    """(G, 3K + 1) standard errors from ``s^2 (J^T J)^-1``, ``s^2 = RSS / (n - P)``.

    ``hess`` (G, P, P) is ``J^T J`` at the solution (P = 3K + 1, or 3K with the
    baseline held: its error is then NaN); NaN where a diagonal is not positive
    or no degree of freedom is left.
    """
    g, p = hess.shape[0], hess.shape[1]
    dof = np.maximum(n_eff - p, 0)
    se = np.full((g, 3 * k + 1), np.nan)
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        d = np.diagonal(hess, axis1=1, axis2=2)
        okh = np.all(d > 0, axis=1) & (dof > 0)
        if okh.any():
            hh = hess[okh] + 1e-12 * d[okh].max(axis=1)[:, None, None] * np.eye(p)
            try:
                cov = np.linalg.inv(hh)
            except np.linalg.LinAlgError:
                cov = np.linalg.pinv(hh)
            var = np.diagonal(cov, axis1=1, axis2=2) * (rss[okh] / dof[okh])[:, None]
            se[np.ix_(okh, np.arange(p))] = np.sqrt(np.clip(var, 0.0, None))
    return se

