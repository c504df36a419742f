"""Model selection of :func:`._batch.decompose_batch`, over every waveform of a
chunk at once: the state of each waveform's echoes (:class:`_State`), the fits of
rows grouped by their number of echoes (:func:`_fit_rows`, one round of the
device's fits or of :func:`._batch_fit.fit_group`), pruning of weak, collapsed or
misplaced echoes (:func:`_prune`, :func:`_rescue`) and the rounds that add a
resolved echo at the highest residual feature while the BIC falls
(:func:`_add`, Sparrow's criterion in :func:`_resolved_rows`).

References
----------
Schwarz, G. (1978). Estimating the dimension of a model. Ann. Stat. 6(2),
    461-464. doi:10.1214/aos/1176344136
Sparrow, C. M. (1916). On spectroscopic resolving power. ApJ 44, 76.
    doi:10.1086/142271
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import gaussian_filter1d

from clsim.waveforms.decompose._batch_detect import _SQRT_PI, _log_parabola
from clsim.waveforms.decompose._fitting import _MIN_SIGMA_SAMPLES
from clsim.waveforms.decompose._matched import filter_output


class _State:
    """Echo parameters of every waveform, (N, K_max) with an ``on`` mask."""

    def __init__(self, n_rows, k_max, n):
        shape = (n_rows, k_max)
        self.a, self.m, self.s = np.zeros(shape), np.zeros(shape), np.ones(shape)
        self.se = np.full((n_rows, 3, k_max), np.nan)
        self.on = np.zeros(shape, bool)
        self.b = np.zeros(n_rows)
        self.b_se = np.full(n_rows, np.nan)
        self.rss = np.full(n_rows, np.nan)
        self.n_eff = np.zeros(n_rows, int)
        # samples minus model of the last fit, its matched filter and smoothing (float32,
        # from the device), kept where ok
        self.resid = np.zeros((n_rows, 3, n), dtype=np.float32)
        self.resid_ok = np.zeros(n_rows, bool)

    def k(self):
        return self.on.sum(axis=1)


def _fit_rows(fit, rows, a, m, s, b, fit_baseline=True, linear=False):
    """Fit rows (R,) with start (R, K) arrays, grouped by the number of active echoes
    (``a`` NaN = inactive), all groups one call of ``fit`` (:func:`_group_fitter`;
    ``linear``: start amplitudes and baseline by linear least squares first).
    Returns per-row results padded back to (R, K), the residuals as a :class:`_Resid`."""
    rk = np.isfinite(a).sum(axis=1)
    R, K = a.shape
    out_a, out_m, out_s = np.full((R, K), np.nan), np.full((R, K), np.nan), np.full((R, K), np.nan)
    out_se = np.full((R, 3, K), np.nan)
    out_b, out_bse, out_rss = b.astype(float).copy(), np.full(R, np.nan), np.full(R, np.nan)
    out_neff = np.zeros(R, int)
    out_resid = None
    groups, placed = [], []
    for k in np.unique(rk):
        if k == 0:
            continue
        sel = np.flatnonzero(rk == k)
        on = np.isfinite(a[sel])
        if on[:, :k].all():
            # the active echoes are the first k columns already (as after detection)
            order = None
            groups.append((rows[sel], a[sel, :k], m[sel, :k], s[sel, :k], b[sel]))
        else:
            # compact the active echoes to the first k columns
            order = np.argsort(~on, axis=1, kind="stable")[:, :k]
            a_k, m_k, s_k = (np.take_along_axis(v[sel], order, axis=1) for v in (a, m, s))
            groups.append((rows[sel], a_k, m_k, s_k, b[sel]))
        placed.append((k, sel, order))
    for (k, sel, order), res in zip(placed, fit(groups, fit_baseline, linear)):
        ii = sel[:, None]
        if order is None:
            out_a[sel, :k], out_m[sel, :k], out_s[sel, :k] = res.a, res.m, res.s
            out_se[sel, :, :k] = res.se[:, :3 * k].reshape(-1, 3, k)
        else:
            out_a[ii, order], out_m[ii, order], out_s[ii, order] = res.a, res.m, res.s
            for q in range(3):
                out_se[ii, q, order] = res.se[:, q * k:(q + 1) * k]
        out_b[sel], out_rss[sel], out_neff[sel] = res.b, res.rss, res.n_eff
        if fit_baseline:
            out_bse[sel] = res.se[:, 3 * k]
        if res.resid is not None and res.filtered is not None:
            if out_resid is None:
                out_resid = _Resid(R)
            out_resid.add(sel, res.resid, res.filtered)
    return out_a, out_m, out_s, out_se, out_b, out_bse, out_rss, out_neff, out_resid


def _refit(st, rows, y, use, cens, linear=False):
    if rows.size == 0:
        return
    a = np.where(st.on[rows], st.a[rows], np.nan)
    res = _fit_rows(st.fit, rows, a, st.m[rows], st.s[rows], st.b[rows], linear=linear)
    _store(st, rows, *res)


def _store(st, rows, a, m, s, se, b, bse, rss, neff, resid):
    on = np.isfinite(a)
    st.on[rows] = on
    st.a[rows] = np.where(on, a, 0.0)
    st.m[rows] = np.where(on, m, 0.0)
    st.s[rows] = np.where(on, s, 1.0)
    st.se[rows] = se
    st.b[rows], st.b_se[rows], st.rss[rows], st.n_eff[rows] = b, bse, rss, neff
    _keep_resid(st, rows, resid)


class _Resid:
    """The residuals and their filtered twins of a round's rows (R,), left where the
    device's results hold them: parts ``(sel, src, resid, filtered)``, rows ``sel`` of
    the round being rows ``src`` (None: all, in order) of ``resid`` (G, n) and
    ``filtered`` (G, 2, n); rows in no part have none."""

    def __init__(self, n_rows):
        self.n_rows, self.parts = n_rows, []

    def add(self, sel, resid, filtered, src=None):
        self.parts.append((np.asarray(sel), src, resid, filtered))

    def take(self, idx):
        """The rows ``idx`` (positions or a mask) of this round, in that order."""
        idx = np.flatnonzero(idx) if idx.dtype == bool else idx
        part = np.full(self.n_rows, -1)
        loc = np.zeros(self.n_rows, int)
        for p, (sel, src, _, _) in enumerate(self.parts):
            part[sel] = p
            loc[sel] = np.arange(sel.size) if src is None else src
        out = _Resid(idx.size)
        for p, (_, _, resid, filtered) in enumerate(self.parts):
            hit = np.flatnonzero(part[idx] == p)
            if hit.size:
                out.add(hit, resid, filtered, loc[idx[hit]])
        return out


def _keep_resid(st, rows, resid):
    """Keep the fits' residuals and their filtered twins (a :class:`_Resid` of ``rows``;
    None, or rows without one or with a NaN first sample: not kept)."""
    st.resid_ok[rows] = False
    if resid is None:
        return
    for sel, src, r, f in resid.parts:
        if src is not None:
            r, f = r[src], f[src]
        ok = ~np.isnan(r[:, 0]) & ~np.isnan(f[:, 0, 0])
        dest = rows[sel]
        if not ok.all():
            dest, r, f = dest[ok], r[ok], f[ok]
        st.resid[dest, 0] = r
        st.resid[dest, 1:] = f
        st.resid_ok[dest] = True


def _bad(a, m, s, se_a, u, sigma, n):
    with np.errstate(invalid="ignore"):
        weak = a * np.sqrt(np.abs(s) * _SQRT_PI) < (u * sigma)[:, None]
        return (weak | (s < _MIN_SIGMA_SAMPLES) | (s > n[:, None]) | (m < -s)
                | (m > n[:, None] - 1 + s) | ~np.isfinite(a)
                | (np.isfinite(se_a) & (a < 2.0 * se_a)))


def _broken(a, m, s, n):
    """Echoes that collapsed (height not positive, sigma under the resolvable limit) or
    left the record (peak more than one sigma beyond its ends)."""
    with np.errstate(invalid="ignore"):
        return (~np.isfinite(a) | (a <= 0) | (s < _MIN_SIGMA_SAMPLES) | (s > n[:, None])
                | (m < -s) | (m > n[:, None] - 1 + s))


def _well_formed(a, m, s, n):
    """Echoes (R, K) a waveform can keep alone: positive and finite height, sigma
    between the resolvable limit and the record's length ``n`` (R,), peak within one
    sigma of the record (NaN anywhere: not well formed)."""
    n = n[:, None]
    with np.errstate(invalid="ignore"):
        return (np.isfinite(a) & (a > 0) & (s >= _MIN_SIGMA_SAMPLES) & (s <= n) & (m >= -s)
                & (m <= n - 1 + s))


def _prune(st, y, use, cens, u, sigma, lengths, rounds=5):
    """Drop weak, unresolvable or misplaced echoes and refit, until none is left to drop.
    A fit that stopped because an echo collapsed or left the record (the fits stop
    there) has only those echoes dropped first: its residual sum, and so the standard
    errors and significance of the others, are not yet those of a converged fit. A
    waveform whose echoes all fail keeps its strongest well-formed one (a detected
    echo exists), refitted alone and not pruned again."""
    locked = np.zeros(st.on.shape[0], bool)
    for _ in range(rounds):
        bad = _bad(st.a, st.m, st.s, st.se[:, 0], u, sigma, lengths) & st.on
        broken = _broken(st.a, st.m, st.s, lengths) & st.on
        bad = np.where(broken.any(axis=1)[:, None], broken, bad)
        bad[locked] = False
        rows = np.flatnonzero(bad.any(axis=1))
        if rows.size == 0:
            return
        keep = st.on[rows] & ~bad[rows]
        none = ~keep.any(axis=1)
        if none.any():
            usable = st.on[rows] & _well_formed(st.a[rows], st.m[rows], st.s[rows], lengths[rows])
            best = np.argmax(np.where(usable, st.a[rows], -np.inf), axis=1)
            fix = np.flatnonzero(none & usable.any(axis=1))
            keep[fix, best[fix]] = True
            locked[rows[fix]] = True
        st.on[rows] = keep
        st.resid_ok[rows] = False
        gone = rows[~keep.any(axis=1)]
        st.se[gone] = np.nan
        _refit(st, rows[keep.any(axis=1)], y, use, cens)


def _rescue(st, start, y, use, cens, lengths):
    """Waveforms with candidates whose fits all failed (every echo collapsed or left
    the record) get the strongest candidate fitted alone, kept when well formed."""
    a0, m0, s0, on0, b0 = start
    rows = np.flatnonzero((st.k() == 0) & on0.any(axis=1))
    if rows.size == 0:
        return
    best = np.argmax(np.where(on0[rows], a0[rows], -np.inf), axis=1)
    ii = np.arange(rows.size)
    res = _fit_rows(st.fit, rows, a0[rows, best][:, None], m0[rows, best][:, None],
                    s0[rows, best][:, None], b0[rows], linear=True)
    a, m, s = res[0][:, 0], res[1][:, 0], res[2][:, 0]
    ok = _well_formed(a[:, None], m[:, None], s[:, None], lengths[rows])[:, 0]
    rows, best, ii = rows[ok], best[ok], ii[ok]
    st.on[rows] = False
    st.on[rows, best] = True
    st.a[rows, best], st.m[rows, best], st.s[rows, best] = a[ok], m[ok], s[ok]
    st.se[rows] = np.nan
    st.se[rows, :, best] = res[3][ii, :, 0]
    st.b[rows], st.b_se[rows], st.rss[rows], st.n_eff[rows] = (res[4][ii], res[5][ii],
                                                             res[6][ii], res[7][ii])
    _keep_resid(st, rows, None if res[8] is None else res[8].take(ii))


def _bic(rss, n, p):
    return n * np.log(np.maximum(rss, 1e-300) / n) + p * np.log(n)


def _model(st, rows, n):
    """(R, n) baseline plus the active echoes of ``rows`` at samples 0..n-1 (only the
    columns some row uses; the exponential in float32, as in the fits)."""
    on = st.on[rows]
    k = int(on.sum(axis=1).max())
    order = np.argsort(~on, axis=1, kind="stable")[:, :k]
    take = lambda v: np.take_along_axis(v[rows], order, axis=1)  # noqa: E731
    a = np.where(np.take_along_axis(on, order, axis=1), take(st.a), 0.0)
    m, s = take(st.m).astype(np.float32), take(st.s).astype(np.float32)
    z = np.arange(n, dtype=np.float32) - m[:, :, None]
    z /= s[:, :, None]
    z *= z
    z *= np.float32(-0.5)
    e = np.exp(z, out=z)
    return st.b[rows][:, None] + np.matmul(a[:, None, :].astype(np.float32), e)[:, 0, :]


def _add(st, y, use, cens, u, sigma, lengths, pl, level, k_cap):
    n_rows, n = y.shape
    search = (st.k() > 0) & (st.k() < k_cap)
    skipped = np.zeros((n_rows, n), bool)
    passes = np.zeros(n_rows, int)
    for _ in range(3 * k_cap):
        rows = np.flatnonzero(search)
        if rows.size == 0:
            return
        on = st.on[rows]
        # the residual of the last fit and its matched filter and smoothing, kept from
        # the device (float32; else computed here), each filter over its threshold
        ii = np.arange(rows.size)
        fm_at, fs_at, r_at = _search_view(st, rows, y, use, cens, pl, level[rows],
                                          4.0 * sigma[rows], ~use[rows] | skipped[rows])
        # the search follows whichever filter stands higher above its threshold
        jm, js = fm_at.argmax(), fs_at.argmax()
        vm, vs = fm_at(ii, jm[:, None])[:, 0], fs_at(ii, js[:, None])[:, 0]
        use_m = vm >= vs
        j = np.where(use_m, jm, js)
        go = np.where(use_m, vm, vs) >= 1.0
        search[rows[~go]] = False
        rows, j, use_m, on, ii = rows[go], j[go], use_m[go], on[go], ii[go]
        if rows.size == 0:
            return
        # the new echo's start: a log-parabola through the filtered residual's maximum
        # and its two neighbours (the filter's own width removed); amplitude from the
        # residual
        near3 = np.clip(j[:, None] + np.arange(-1, 2), 0, n - 1)
        filt = np.where(use_m[:, None], fm_at(ii, near3) * level[rows][:, None],
                        fs_at(ii, near3) * (4.0 * sigma[rows])[:, None])
        m1, var = _log_parabola(filt, np.arange(rows.size), np.ones_like(j), 3)
        # (a maximum on the first or last sample has no neighbour on that side)
        inner = (j > 0) & (j < n - 1)
        m1 = np.where(inner, m1 + j - 1, j)
        var = np.where(inner, var, np.nan)
        var = np.where(use_m, var - pl.sigma ** 2, var - 1.0)
        s0 = np.clip(np.where(np.isfinite(var) & (var > 0.25), np.sqrt(np.abs(var)),
                              pl.sigma), 0.5, n / 2.0)
        s1 = s0
        a1 = np.maximum(r_at(ii, j[:, None])[:, 0], filt[:, 1])
        res = _resolved_rows(st.a[rows], st.m[rows], st.s[rows], on, a1, m1, s1)
        res &= np.isfinite(a1) & (a1 > 0)
        # unresolved: pass over this feature (mask it) and try the next, up to 3 times
        un = rows[~res]
        if un.size:
            half = np.ceil(2.0 * s0[~res]).astype(int)[:, None]
            dist = np.abs(np.arange(n) - j[~res][:, None])
            skipped[un] |= dist <= half
        passes[un] += 1
        search[un[passes[un] >= 3]] = False
        if not res.any():
            continue
        rows, a1, m1, s1 = rows[res], a1[res], m1[res], s1[res]
        # the trial: every echo refitted with the new one in the first free column
        free = np.argmin(st.on[rows], axis=1)
        ta = np.where(st.on[rows], st.a[rows], np.nan)
        tm, ts = st.m[rows].copy(), st.s[rows].copy()
        ii = np.arange(rows.size)
        ta[ii, free], tm[ii, free], ts[ii, free] = a1, m1, s1
        fa, fm_, fs_, fse, fb, fbse, frss, fneff, fres = _fit_rows(st.fit, rows, ta, tm, ts,
                                                                   st.b[rows])
        k_old = st.k()[rows]
        bic_old = _bic(st.rss[rows], st.n_eff[rows], 3 * k_old + 1)
        bic_new = _bic(frss, fneff, 3 * (k_old + 1) + 1)
        bad = _bad(np.nan_to_num(fa, nan=0.0), fm_, fs_, fse[:, 0], u[rows], sigma[rows],
                   lengths[rows]) & np.isfinite(fa)
        ok = (bic_new < bic_old) & ~bad.any(axis=1) & np.isfinite(frss)
        acc = rows[ok]
        _store(st, acc, fa[ok], fm_[ok], fs_[ok], fse[ok], fb[ok], fbse[ok], frss[ok],
               fneff[ok], None if fres is None else fres.take(ok))
        skipped[acc] = False
        passes[acc] = 0
        search[rows[~ok]] = False
        search[acc] &= st.k()[acc] < k_cap


class _Channel:
    """One channel (residual, matched filter or smoothing) of the search's rows, each
    row divided by its ``scale`` (None: 1) and -inf where ``out``: rows ``fast`` read
    from the device's float32 values, the others from float64 rows ``slow`` (S, n).
    Only the samples asked for are divided (:meth:`__call__`); :meth:`argmax` is
    taken on the float32 rows as they stand: the float64 quotient of two float32
    values by one positive scale (between 1e-200 and 1e200) keeps their order strictly
    (their relative gap, 2^-24 or more, exceeds the quotient's rounding), so the
    maximum is the one of the whole divided row, and so are the values."""

    def __init__(self, raw, scale, out, fast, slow, at=None):
        self.raw, self.scale, self.fast, self.slow = raw, scale, fast, slow
        # the rows of ``raw`` (``at``: row i is raw[at[i]], read in place)
        self.at = np.arange(fast.size) if at is None else at
        if out is not None:
            np.copyto(raw, -np.inf, where=out)
        self.inv = np.cumsum(~fast) - 1  # row -> its row of ``slow``

    def argmax(self):
        j = np.argmax(self.raw, axis=1)
        if self.slow is not None:
            j[~self.fast] = np.argmax(self.slow, axis=1)
        return j

    def __call__(self, pos, idx):
        """Values at rows ``pos`` (P,) and their samples ``idx`` (P, w), float64."""
        v = self.raw[self.at[pos][:, None], idx].astype(float)
        if self.scale is not None:
            v /= self.scale[pos][:, None]
        sl = ~self.fast[pos]
        if sl.any():
            v[sl] = self.slow[self.inv[pos[sl]][:, None], idx[sl]]
        return v


def _search_view(st, rows, y, use, cens, pl, level, spread, out):
    """The residual search's channels (:class:`_Channel`) of ``rows``: the kept residual
    and its matched filter over ``level`` and smoothing over ``spread`` (each -inf where
    ``out``); rows without a kept residual (or an extreme scale) in float64, the
    residual computed here."""
    fast = st.resid_ok[rows] & (level > 1e-200) & (level < 1e200) & (spread > 1e-200) & (
        spread < 1e200)
    slow = [None, None, None]
    if not fast.all():
        sr = rows[~fast]
        r, fm, fs = (st.resid[sr, c].astype(float) for c in range(3))
        redo = np.flatnonzero(~st.resid_ok[sr])
        if redo.size:
            n = y.shape[1]
            rr = np.where(use[sr[redo]], y[sr[redo]] - _model(st, sr[redo], n), 0.0)
            if cens is not None:
                rr = np.where(cens[sr[redo]], 0.0, rr)
            r[redo] = rr
            fm[redo] = filter_output(rr, pl)
            fs[redo] = gaussian_filter1d(rr, 1.0, axis=1, mode="constant")
        fm /= level[~fast][:, None]
        fm[out[~fast]] = -np.inf
        fs /= spread[~fast][:, None]
        fs[out[~fast]] = -np.inf
        slow = [r, fm, fs]
    # the filters copied (masked here), the residual read in place at the samples used
    return (_Channel(st.resid[rows, 1], level, out, fast, slow[1]),
            _Channel(st.resid[rows, 2], spread, out, fast, slow[2]),
            _Channel(st.resid[:, 0], None, None, fast, slow[0], at=rows))


#: Separation, in sums of the pair's sigmas, beyond which two echoes count as resolved
#: without a look at their curvature: each echo's inflection points then lie 6 or more
#: of the other's sigmas from that one's peak, where its curvature is under 1e-6 of its
#: peak value; it could remove them only if its peak curvature ``a / s^2`` exceeded
#: the other's about a million times.
_FAR = 6.0


def _resolved_rows(a, m, s, on, a1, m1, s1):
    """Sparrow's criterion between the new echo (a1, m1, s1) (R,) and each active
    echo (R, K): the pair's sum has four inflection points (looked for on a grid of
    160 points, for the pairs closer than :data:`_FAR` sigmas)."""
    with np.errstate(invalid="ignore"):
        near = on & ~(np.abs(m - m1[:, None]) >= _FAR * (s + s1[:, None]))
    r, c = np.nonzero(near)
    ok = np.ones(on.shape[0], bool)
    if r.size == 0:
        return ok
    a, m, s = a[r, c], m[r, c], s[r, c]
    a1, m1, s1 = a1[r], m1[r], s1[r]
    lo = np.minimum(m - 3 * s, m1 - 3 * s1)
    hi = np.maximum(m + 3 * s, m1 + 3 * s1)
    # in float32 (the exponentials are most of the search's time on many-echo
    # waveforms; a sign of the curvature is not changed by the rounding except within
    # 1e-6 of an inflection point)
    grid = np.linspace(0.0, 1.0, 160, dtype=np.float32)
    f32 = np.float32
    with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
        # z^2 of each echo of the pair on the grid x = lo + (hi - lo) * grid
        z0 = ((lo - m) / s).astype(f32)[:, None] + ((hi - lo) / s).astype(f32)[:, None] * grid
        z1 = ((lo - m1) / s1).astype(f32)[:, None] + ((hi - lo) / s1).astype(f32)[:, None] * grid
        z0 *= z0
        z1 *= z1
        e0 = np.exp(np.multiply(z0, f32(-0.5)))
        e1 = np.exp(np.multiply(z1, f32(-0.5)))
        z0 -= f32(1.0)
        z1 -= f32(1.0)
        curv = z0 * e0 * (a / s ** 2).astype(f32)[:, None]
        curv += z1 * e1 * (a1 / s1 ** 2).astype(f32)[:, None]
    sign = np.sign(curv)
    changes = np.count_nonzero(sign[:, 1:] != sign[:, :-1], axis=-1)
    ok[r[changes < 4]] = False
    return ok
