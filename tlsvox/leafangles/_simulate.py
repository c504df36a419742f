"""The simulated measurement (step 3 of the package docstring): leaves of every inclination
scanned by the instrument's beam around sampled echoes, fitted as the measured ones are."""

from __future__ import annotations

import numpy as np

from tlsvox.leafangles._histogram import HALF_PI
from tlsvox.leafangles._planes import _COUNT_EDGES, _azimuth_class, _columns, _inclination_bin, _n_columns

#: occlusion levels of the simulated leaves: each of two straight cuts (random directions) hiding part of
#: the leaf lies between the two distances of its pair beyond the centre echo (in leaf half-axes); 1e9 is
#: no cut, so the first level is a whole leaf and the last two are cut on two sides
_CUTS = np.array([[1e9, 1e9, 1e9, 1e9], [0.5, 1.0, 1e9, 1e9], [0.25, 0.5, 1e9, 1e9], [0.1, 0.25, 1e9, 1e9],
                  [0.0, 0.1, 1e9, 1e9], [0.1, 0.25, 0.1, 0.25], [0.0, 0.1, 0.0, 0.1]])


#: levels with a second leaf (``second_leaf=True``), one set per distance band ``_BANDS``: the first leaf whole
#: or cut once as in ``_CUTS``, and another leaf of the same inclination bin and azimuth model behind it, seen in
#: the gaps the first leaf's outline and cut leave, so that some neighbourhoods hold echoes of two leaves
_SECOND_CUTS = np.array([[1e9, 1e9, 1e9, 1e9], [0.25, 0.5, 1e9, 1e9], [0.0, 0.1, 1e9, 1e9]])


#: distance bands (metres behind the first leaf, along the beam) of the second leaf's plane
_BANDS = np.array([[0.0, 0.025], [0.025, 0.05], [0.05, 0.1], [0.1, 0.25]])


_MAX_COUNT = 40


def _layer_rows(f, sel, *, n_bins, n_groups, max_sim, rng, **sim):
    """The observation rows of one scan's echoes ``sel`` (one crown layer): (histogram, kernel) per group.

    The kernel is simulated for echoes sampled from ``sel`` (their ranges,
    beams and outward directions) and the groups are quantiles of the beam
    zenith angles of the fitted ones.  Each row holds the weighted histogram
    of the group's echoes over the observation columns and the kernel
    ``(azimuth models, levels, true bins, columns)``.
    """
    fit = sel & f.ok
    if not fit.any():
        return []
    q = np.quantile(f.theta[fit], np.linspace(0, 1, n_groups + 1))
    group = np.clip(np.searchsorted(q[1:-1], f.theta, side="right"), 0, n_groups - 1)
    every = np.flatnonzero(sel)
    sub = every if len(every) <= max_sim else np.sort(rng.choice(every, max_sim, replace=False))
    # the sampled echoes stand for the leaf area around them: echoes fall off as 1/r^2, so weigh them by r^2
    kernels, _ = _simulate_kernel(f.r[sub], f.d[sub], group[sub], f.outward[sub], n_bins=n_bins, n_groups=n_groups,
                                  rng=rng, area=f.r[sub] ** 2, **sim)
    rows = []
    for g in range(n_groups):
        m = sel & (group == g)
        h = np.bincount(f.column[m], weights=f.weight[m], minlength=kernels.shape[-1])
        if h.sum() > 0 and kernels[:, :, g].sum() > 0:  # a group none of whose echoes was sampled: no row
            rows.append((h, kernels[:, :, g]))
    return rows


def _leaf_axes(normal, spin):
    """The major and minor axes of leaves with unit normals ``normal`` (N, 3), turned by ``spin`` (N,) radians
    in their plane from a reference axis (horizontal unless the leaf is nearly flat)."""
    u = np.cross(normal, np.where(np.abs(normal[:, 2:3]) < 0.9, [[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]]))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    major = np.cos(spin)[:, None] * u + np.sin(spin)[:, None] * np.cross(normal, u)
    return major, np.cross(normal, major)


def _levels(second_leaf):
    """Occlusion levels: (cuts (L, 4), second-leaf band (L, 2) in metres behind the first, nan for none)."""
    if not second_leaf:
        return _CUTS, np.full((len(_CUTS), 2), np.nan)
    cuts = np.concatenate([_CUTS] + [_SECOND_CUTS] * len(_BANDS))
    band = np.concatenate([np.full((len(_CUTS), 2), np.nan)] + [np.repeat(b[None], len(_SECOND_CUTS), 0)
                                                                for b in _BANDS])
    return cuts, band


def _reach(r, *, radius, margin):
    """tan of the largest angle off the beam of an echo at range ``r`` (taken ``margin`` nearer) at which a ray
    passes within ``radius`` of it (a ray at angle a passes r sin(a) from the echo)."""
    rho = radius / np.maximum(np.asarray(r, float) - margin, 0.1)
    return rho / np.sqrt(np.maximum(1.0 - rho * rho, 1e-12))


def _grid_half_widths(r, sin_z, *, step, radius, margin, max_offsets=10):
    """Pulses each side of an echo's own whose rays can pass within ``radius`` of it.

    Parameters
    ----------
    r, sin_z : (S,) float
        The echoes' ranges (m) and the sines of their beams' zenith angles.
    step : (2,) float, radians
        Zenith and azimuth steps of the scan (the azimuth step across the beam
        is ``step[1] * sin_z``).
    radius : float, m
        Neighbourhood radius.
    margin : float, m
        How much nearer than ``r`` the centre pulse's echo can lie (range
        noise, and sub-rays meeting the leaf's plane short of its centre ray).
    max_offsets : int
        Cap on each half-width (echoes within about 2.4 m / sin(zenith) of
        the scanner at 0.06 deg steps get fewer pulses than they could).

    Returns
    -------
    m_z, m_a : (S,) int64
        Half-widths in zenith and azimuth steps.
    """
    tan_max = _reach(r, radius=radius, margin=margin)
    m_z = np.minimum(max_offsets, np.ceil(tan_max / step[0])).astype(np.int64)
    m_a = np.minimum(max_offsets, np.ceil(tan_max / (step[1] * np.maximum(sin_z, 1e-3)))).astype(np.int64)
    return m_z, m_a


def _pulse_grid(r, sin_z, *, step, radius, margin, max_offsets=10):
    """Step offsets of the pulses around a centre echo whose rays can pass within ``radius`` of any of the
    echoes (ranges ``r``, beams' sin(zenith) ``sin_z``; see :func:`_grid_half_widths`): the rectangle of the
    largest half-widths cut to the ellipse of the nearest echo (a ray farther than the radius from the echo
    gives no neighbour).

    Returns
    -------
    i, k : (P,) float
        Zenith and azimuth step offsets; (0, 0), the centre pulse, among them.
    """
    m_z, m_a = (int(v.max()) for v in _grid_half_widths(r, sin_z, step=step, radius=radius, margin=margin,
                                                         max_offsets=max_offsets))
    i, k = (g.ravel().astype(float) for g in np.meshgrid(np.arange(-m_z, m_z + 1), np.arange(-m_a, m_a + 1),
                                                           indexing="ij"))
    tan_max = float(_reach(np.min(r), radius=radius, margin=margin))
    inside = (i * step[0]) ** 2 + (k * step[1] * max(float(np.min(sin_z)), 1e-3)) ** 2 <= tan_max ** 2
    return i[inside], k[inside]


def _simulate_kernel(r, d, group, outward, *, step, beam, leaf_size, radius, min_points, min_spread, n_bins,
                     n_groups, range_noise, samples, cap, rng, area=None, second_leaf: bool = True,
                     azimuths=("uniform",), n_azimuth: int = 1, count_edges=_COUNT_EDGES, max_offsets: int = 10):
    """The expected observation histogram of unit leaf area of each true inclination bin.

    For each sampled echo (range ``r``, unit beam ``d``, outward direction
    ``outward``) and true bin: a leaf (an ellipse ``leaf_size`` x
    ``leaf_size/2``, random spin, the echo at a random point of it) of that
    inclination, facing a random azimuth (``"uniform"``) or away from the
    crown centre (``"outward"``), is scanned by the pulses of the angular grid
    around the echo (``step`` = zenith and azimuth steps, radians) whose rays
    pass within ``radius`` of it (:func:`_pulse_grid`; the others give no
    neighbour; echoes needing the same grid are simulated together).  Each pulse
    is the instrument's beam ``beam = (exit radius m, half divergence rad,
    sub-rays)``: its sub-rays (:func:`tlsvox.truth.scanner.subray_pattern`,
    the pattern turned at random per pulse) stop on the first leaf they meet
    and the pulse gives one echo on its central ray at the power-weighted
    (|cos|) mean range of its sub-rays' hits, with Gaussian range noise.  The
    echoes within ``radius`` of the centre echo are fitted as the measured ones
    are; the leaf is hit in proportion to its true ``|cos a|``; a fit weighs
    ``1 / measured |cos a|`` (dropped below ``cap``), an echo without a fit 1,
    as the measured ones do; ``area`` (S,) weighs each sampled echo by the
    leaf area it stands for (default equal).  Each simulated leaf draws one occlusion level
    (:func:`_levels`): straight cuts hide part of it (``_CUTS``) and, with
    ``second_leaf``, another leaf of the same inclination bin and azimuth
    model crosses the centre beam in one of the distance bands ``_BANDS``
    behind the first, seen where the first is cut or ends or is partly hit.

    Returns
    -------
    kernel : (models, levels, n_groups, B, columns) float
        Per azimuth model, level, group and true bin, the expected weight per
        simulated leaf in each observation column (:func:`_columns`).
    counts : (levels, B, _MAX_COUNT) float
        Hit-weighted distribution of the neighbour counts per level and bin.
    """
    area = np.ones(len(r)) if area is None else np.asarray(area, float) / np.mean(area)
    # each echo's pulse grid (:func:`_pulse_grid`): echoes needing the same one are simulated together
    sin_z = np.sqrt(np.clip(1.0 - d[:, 2] ** 2, 0.0, 1.0))
    # the centre echo lies at most a leaf length (sub-rays meeting a grazing leaf short of the centre ray) and
    # five noise sigmas nearer than the sampled range
    margin = leaf_size + 5.0 * range_noise
    m_z, m_a = _grid_half_widths(r, sin_z, step=step, radius=radius, margin=margin, max_offsets=max_offsets)
    n_col = _n_columns(n_bins, n_azimuth, count_edges)
    n_lev = len(_levels(second_leaf)[0])
    kernel = np.zeros((len(azimuths), n_lev, n_groups, n_bins, n_col))
    n_sim = np.zeros((len(azimuths), n_lev, n_groups, n_bins))
    counts = np.zeros((n_lev, n_bins, _MAX_COUNT))
    n_cnt = np.zeros((n_lev, n_bins))
    for mz, ma in sorted(set(zip(m_z.tolist(), m_a.tolist()))):
        sel = np.flatnonzero((m_z == mz) & (m_a == ma))
        _simulate_pulses(r[sel], d[sel], group[sel], outward[sel], area[sel], (kernel, n_sim, counts, n_cnt),
                         offsets=_pulse_grid(r[sel], sin_z[sel], step=step, radius=radius, margin=margin,
                                             max_offsets=max_offsets),
                         step=step, beam=beam, leaf_size=leaf_size, radius=radius,
                         min_points=min_points, min_spread=min_spread, n_bins=n_bins, range_noise=range_noise,
                         samples=samples, cap=cap, rng=rng, second_leaf=second_leaf, azimuths=azimuths,
                         n_azimuth=n_azimuth, count_edges=count_edges)
    return kernel / np.maximum(n_sim, 1e-300)[..., None], counts / np.maximum(n_cnt, 1)[..., None]


def _simulate_pulses(r, d, group, outward, area, sums, *, offsets, step, beam, leaf_size, radius, min_points,
                     min_spread, n_bins, range_noise, samples, cap, rng, second_leaf, azimuths, n_azimuth,
                     count_edges):
    """:func:`_simulate_kernel` for echoes scanned by the same pulse grid ``offsets`` = (zenith, azimuth step
    offsets) from :func:`_pulse_grid`; adds to ``sums`` = (kernel, n_sim, counts, n_cnt), not normalised."""
    from tlsvox.truth.scanner import subray_pattern

    kernel, n_sim, counts, n_cnt = sums
    exit_r, half_div, n_sub = beam
    sub_r, sub_a = subray_pattern(int(n_sub))
    cuts, band = _levels(second_leaf)
    n_lev = len(cuts)
    dz, da = step
    zen = np.arccos(np.clip(d[:, 2], -1.0, 1.0))
    e_a = np.column_stack([-d[:, 1], d[:, 0], np.zeros(len(d))])
    norm = np.linalg.norm(e_a, axis=1, keepdims=True)
    e_a = np.where(norm > 1e-9, e_a / np.maximum(norm, 1e-12), [[1.0, 0.0, 0.0]])
    e_z = np.cross(e_a, d)
    i, k = offsets
    centre = int(np.flatnonzero((i == 0) & (k == 0))[0])
    rays = (d[:, None, :] + i[None, :, None] * dz * e_z[:, None, :]
            + (k[None, :] * da * np.maximum(np.sin(zen), 1e-3)[:, None])[:, :, None] * e_a[:, None, :])
    rays /= np.linalg.norm(rays, axis=2, keepdims=True)  # (S, P, 3)
    n, n_pulse = len(r), len(i)
    width = exit_r + half_div * r  # beam radius at the echo, (S,)
    half_len, half_wid = 0.5 * leaf_size, 0.25 * leaf_size
    out_phi = np.arctan2(outward[:, 1], outward[:, 0])

    def dot(a, b):
        return np.einsum("ij,ij->i", a, b)

    def leaf(b, model):
        """Normals, axes and the echo's offset in the leaf (units of half-axes) of n leaves of bin b."""
        t = (b + rng.random(n)) * HALF_PI / n_bins
        phi = out_phi if model == "outward" else rng.uniform(0.0, 2 * np.pi, n)
        nt = np.column_stack([np.sin(t) * np.cos(phi), np.sin(t) * np.sin(phi), np.cos(t)])
        major, minor = _leaf_axes(nt, rng.uniform(0.0, 2 * np.pi, n))
        rho, beta = np.sqrt(rng.random(n)), rng.uniform(0.0, 2 * np.pi, n)
        return nt, major, minor, rho * np.cos(beta), rho * np.sin(beta)

    def trace(idx, nt, major, minor, off_a, off_b, point, c1, c2):
        """Sub-ray hits of the pulses ``idx`` on the leaves (nt, ...) whose plane holds ``point`` (S, 3):
        (range along each sub-ray (S, P, K), inside the ellipse (S, P, K), |cos| (S, P), leaf coordinates of
        the pulses' central rays in half-axes (S, P) x 2)."""
        den = np.einsum("spc,sc->sp", rays[idx], nt)
        sden = np.where(np.abs(den) > 1e-9, den, 1.0)
        s = dot(point, nt)[:, None] / sden
        rel = rays[idx] * s[:, :, None] - point[:, None, :]
        ea = np.einsum("spc,sc->sp", rel, major) / half_len + off_a[:, None]
        eb = np.einsum("spc,sc->sp", rel, minor) / half_wid + off_b[:, None]
        # a sub-ray offset (c1, c2) across the beam meets the plane tau further along the beam
        tau = -(c1 * dot(e_a[idx], nt)[:, None, None] + c2 * dot(e_z[idx], nt)[:, None, None]) / sden[:, :, None]

        def coord(axis, at, half):
            return at[:, :, None] + (c1 * dot(e_a[idx], axis)[:, None, None] + c2 * dot(e_z[idx], axis)[:, None, None]
                                     + tau * dot(d[idx], axis)[:, None, None]) / half

        sa, sb = coord(major, ea, half_len), coord(minor, eb, half_wid)
        t_sub = s[:, :, None] + tau
        inside = (np.abs(den) > 1e-9)[:, :, None] & (t_sub > 0) & (sa * sa + sb * sb <= 1.0)
        return t_sub, inside, np.abs(den), ea, eb, sa, sb

    everyone = np.arange(n)
    for a, model in enumerate(azimuths):
        for b in range(n_bins):
            for _ in range(samples):
                nt, major, minor, off_a, off_b = leaf(b, model)
                cos_true = dot(nt, d)
                turn = sub_a[None, None, :] + rng.uniform(0.0, 2 * np.pi, (n, n_pulse, 1))
                c1 = width[:, None, None] * sub_r[None, None, :] * np.cos(turn)
                c2 = width[:, None, None] * sub_r[None, None, :] * np.sin(turn)
                t_sub, hit, cos1, ea, eb, sa, sb = trace(everyone, nt, major, minor, off_a, off_b, d * r[:, None],
                                                         c1, c2)
                # the part of the leaf hidden by others: straight cuts at distances beyond the centre echo set
                # by the occlusion level (level 0: the whole leaf is seen)
                level = rng.integers(0, n_lev, n)
                for c0 in range(0, cuts.shape[1], 2):
                    gam = rng.uniform(0.0, 2 * np.pi, n)
                    cg, sg = np.cos(gam)[:, None, None], np.sin(gam)[:, None, None]
                    beyond = (cg[:, 0, 0] * ea[:, centre] + sg[:, 0, 0] * eb[:, centre]
                              + rng.uniform(cuts[level, c0], cuts[level, c0 + 1]))
                    hit &= cg * sa + sg * sb <= beyond[:, None, None]
                hit[:, centre, 0] = True  # the sampled echo: the centre pulse's central sub-ray on the leaf
                power = np.where(hit, cos1[:, :, None], 0.0)
                # the second leaf, drawn for every sample (the same random stream whatever the levels)
                n2, major2, minor2, off_a2, off_b2 = leaf(b, model)
                lo, hi = np.nan_to_num(band[level, 0]), np.nan_to_num(band[level, 1])
                behind = d * (r + rng.uniform(lo, hi))[:, None]
                two = np.flatnonzero(np.isfinite(band[level, 0]))
                if len(two):
                    t2, hit2, cos2, *_ = trace(two, n2[two], major2[two], minor2[two], off_a2[two], off_b2[two],
                                               behind[two], c1[two], c2[two])
                    use2 = hit2 & ~(hit[two] & (t_sub[two] <= t2))  # each sub-ray stops on the nearer leaf
                    t_sub[two] = np.where(use2, t2, t_sub[two])
                    power[two] = np.where(use2, cos2[:, :, None], power[two])
                    hit[two] |= hit2
                any_hit = hit.any(axis=2)
                s_m = (power * np.where(hit, t_sub, 0.0)).sum(axis=2) / np.maximum(power.sum(axis=2), 1e-30)
                s_noisy = s_m + rng.normal(0.0, range_noise, s_m.shape)
                pts = rays * s_noisy[:, :, None]  # relative to the scanner
                near = any_hit & (np.linalg.norm(pts - pts[:, centre:centre + 1, :], axis=2) <= radius)
                cnt = near.sum(axis=1)
                wgt = near / np.maximum(cnt, 1)[:, None]
                mean = np.einsum("sp,spc->sc", wgt, pts)
                dev = pts - mean[:, None, :]
                cov = np.einsum("sp,spa,spb->sab", wgt, dev, dev)
                val, vec = np.linalg.eigh(cov)
                nrm = vec[:, :, 0]
                nrm = nrm * np.where(nrm[:, 2:3] < 0, -1.0, 1.0)
                cos_m = np.abs(dot(nrm, d))
                fitted = (cnt >= min_points) & (np.sqrt(np.clip(val[:, 1], 0.0, None)) >= min_spread) & (cos_m >= cap)
                col = _columns(fitted, _inclination_bin(nrm, n_bins), _azimuth_class(nrm, outward, n_azimuth), cnt,
                               n_bins=n_bins, n_azimuth=n_azimuth, count_edges=count_edges)
                w = np.abs(cos_true) * np.where(fitted, 1.0 / np.maximum(cos_m, cap), 1.0)
                np.add.at(kernel, (a, level, group, b, col), w * area)
                np.add.at(n_sim, (a, level, group, b), area)
                np.add.at(counts, (level, b, np.minimum(cnt, _MAX_COUNT - 1)), np.abs(cos_true))
                np.add.at(n_cnt, (level, b), 1.0)
