"""The leaf angle distribution measured from the scans, per crown layer.

The paper's first preprocessing step needs the leaf inclination distribution
for G(theta); the paper took it from photographs.  Here it comes from the leaf
echoes' local geometry:

1. **Plane fits.**  Each leaf echo's neighbours within a leaf-scale radius
   (default 2.5 cm, half a leaf length), in the world frame, one scan at a
   time, give a covariance matrix; its smallest eigenvector is the leaf
   normal, folded to the upper hemisphere; its zenith angle is the leaf
   inclination ``t``.
2. **Visibility.**  A leaf whose normal makes the angle ``a`` with the beam is
   hit in proportion to ``|cos a|``, and the echo density falls as 1/r^2, so
   an echo stands for a leaf area proportional to ``r^2 / |cos a|``.  Fits
   nearer edge-on than ``|cos a| = cap`` (0.2) are dropped: there the normal
   is set by the errors along the beam (range noise, and echoes whose
   sub-rays met a leaf and whatever lies just behind or in front of it),
   which pile up normals perpendicular to the beam with the largest weights.
3. **Plane-fit noise.**  At leaf scale the range noise (5 mm on the VZ-400,
   along the beam) is comparable with the spread of a leaf's echoes (about
   7 mm), so single normals scatter by tens of degrees and the weighted
   histogram is biased towards the middle.  The default
   (``method="deconvolve"``) models the measurement: for every true
   inclination bin, leaves of that inclination (random azimuth and spin, of
   ``leaf_size``) are scanned by the angular grid around sampled echoes (their
   range and beam), with the instrument's range noise, and fitted, weighted
   and dropped as the measured ones are.  Leaves in a crown are often seen
   only in part (others hide the rest): each simulated leaf is cut by one or
   two straight edges at one of seven occlusion levels (none, one edge at
   four depths beyond its echo, two edges at two depths); a neighbourhood
   can also span two leaves (28 % of the fits on the seed-0 oak's near
   scan, counted by hand from the leaf each echo hit; their normals tens of
   degrees off), so three more levels put a second leaf of the same
   inclination bin just behind the first, seen where the first is cut or
   ends (``second_leaf``).  The mix of
   levels is the one whose neighbour counts match the data's own
   (non-negative least squares, given the weighted histogram), a calibration
   on the data, not on any truth.  All of this is done per scan and crown
   layer: the echoes sampled, the groups of beam zenith angles and the
   occlusion mix are the layer's own, since the upper layers are farther from
   ground scanners, seen more steeply and more hidden.  That gives, per group,
   the expected weighted histogram of unit leaf area of each true bin, and a
   layer's leaf-area distribution is the EM (Richardson-Lucy) solution of
   that linear model; the crown's is the one distribution that explains every
   layer's groups together.  ``method="weighted"`` is step 2 alone.

Accuracy (``benchmarks/bench_leaf_angles.py``, docs/bench/leaf_angles.md):
on the oak's two VZ-400 scans (7-sub-ray beam, 5 mm range noise) the whole
crown is measured at 44.3 deg for 45.0 (uniform), 28.7 for 26.7
(planophile) and 64.1 for 63.2 (erectophile), G within 3.2 % over the
scanned zenith angles; on a held-out oak (seed 1) 41.1, 27.1 and 61.4 deg
(G 4.6, 1.6, 4.8 %).  Ten of the twelve layers on seed 0 and nine on
seed 1 are within 5 deg and 5 %; the others miss by 5.0-11.5 deg or a G
error of 6.1-9.2 % (layer 3 of the uniform and erectophile oaks on seed 0,
read flat: leaves facing outwards are seen edge-on where inclination plus
beam zenith is near 90 deg, which the random-azimuth kernel does not model;
on seed 1 the sparse lowest layer and a layer 2).  Without the second-leaf
levels: nine layers on each oak.  Without range noise (pencil beams) the
deconvolution gives 25.7 deg for 26.7.

**Limit: leaves facing random azimuths.**  The kernel's pencil beams miss
the scanner's 7-sub-ray beam, whose partial hits and echoes merged across a
leaf and what lies behind it read flat leaves about 9 deg steep, and its
random azimuths miss the oak's outward-facing leaves, which read them about
5 deg flat; on the paper's oak the two offset.  On an oak whose leaves face
random azimuths the planophile crown reads 37.0 and 35.4 deg for 26.7
(docs/bench/leaf_angles-uniform-azimuth.md, docs/voxelize.md).

The crown is cut into ``layers`` equal-height layers between the 1st and 99th
height percentiles of the leaf echoes; every layer gets its histogram, mean
inclination and a beta distribution (Goel & Strebel 1984) fitted by moments,
a :class:`~voxlidar.leafangle.LeafAngle` usable as ``voxelize(leaf_angle=...)``
and stored in the scene file like any other.

Examples
--------
>>> from tlsvox.leafangles import fit_beta
>>> la = fit_beta(np.full(18, 1 / 18))  # a flat histogram: the uniform distribution
>>> round(la.mu, 2), round(la.nu, 2)
(1.0, 1.0)

References
----------
Goel, N. S. & Strebel, D. E. (1984). Simple beta distribution representation
    of leaf orientation in vegetation canopies. Agronomy Journal 76(5), 800-802.
    doi:10.2134/agronj1984.00021962007600050021x
Richardson, W. H. (1972). Bayesian-based iterative method of image
    restoration. JOSA 62(1), 55-59. doi:10.1364/JOSA.62.000055
Bailey, B. N. & Mahaffee, W. F. (2017). Rapid measurement of the
    three-dimensional distribution of leaf orientation and the leaf angle
    probability density function using terrestrial LiDAR scanning. Remote
    Sensing of Environment 194, 63-76. doi:10.1016/j.rse.2017.03.011
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from tlsvox.errors import InputError
from voxlidar.choices import Choice
from voxlidar.leafangle import LeafAngle, ross_kernel

__all__ = ["LeafAngleMethod", "LayerLeafAngles", "LeafAngleMeasurement", "measure_leaf_angles", "fit_beta",
           "histogram_G"]

HALF_PI = 0.5 * np.pi
#: occlusion levels of the simulated leaves: each of two straight cuts (random directions) hiding part of
#: the leaf lies between the two distances of its pair beyond the centre echo (in leaf half-axes); 1e9 is
#: no cut, so the first level is a whole leaf and the last two are cut on two sides
_CUTS = np.array([[1e9, 1e9, 1e9, 1e9], [0.5, 1.0, 1e9, 1e9], [0.25, 0.5, 1e9, 1e9], [0.1, 0.25, 1e9, 1e9],
                  [0.0, 0.1, 1e9, 1e9], [0.1, 0.25, 0.1, 0.25], [0.0, 0.1, 0.0, 0.1]])
#: levels with a second leaf (``second_leaf=True``): the first leaf whole or cut once as in ``_CUTS``, and
#: another leaf of the same inclination bin (random azimuth) just behind it, seen in the gaps the first
#: leaf's outline and cut leave, so that some neighbourhoods hold echoes of two leaves
_SECOND_CUTS = np.array([[1e9, 1e9, 1e9, 1e9], [0.25, 0.5, 1e9, 1e9], [0.0, 0.1, 1e9, 1e9]])
_MAX_COUNT = 40


class LeafAngleMethod(str, Choice):
    """How the leaf normals' histogram is corrected."""

    DECONVOLVE = "deconvolve"
    WEIGHTED = "weighted"


@dataclass
class LayerLeafAngles:
    """The measured leaf inclination distribution of one crown layer.

    Attributes
    ----------
    z_range : (2,) float, metres
    edges : (B + 1,) float, radians
        Inclination bin edges on [0, pi/2].
    density : (B,) float, 1/rad
        Leaf-area-weighted inclination density (integrates to 1).
    n_echoes : int
        Leaf echoes with a plane fit in the layer.
    zenith_range : (2,) float, radians
        5th and 95th percentiles of the zenith angles of the beams that hit
        the layer's leaves (the scanned directions).
    leaf_angle : LeafAngle
        Beta distribution fitted by moments to ``density``.  A layer without
        a single fitted echo (``n_echoes == 0``) has a zero density and the
        uniform model.
    """

    z_range: np.ndarray
    edges: np.ndarray
    density: np.ndarray
    n_echoes: int
    zenith_range: np.ndarray
    leaf_angle: LeafAngle

    @property
    def mean_inclination(self) -> float:
        """Mean leaf inclination of the histogram, radians."""
        c = 0.5 * (self.edges[1:] + self.edges[:-1])
        return float(np.sum(c * self.density * np.diff(self.edges)))

    def G(self, theta) -> np.ndarray:
        """G(theta) of the histogram itself (theta in radians)."""
        return histogram_G(self.edges, self.density, theta)

    def to_dict(self) -> dict:
        return {"z_range_m": [float(v) for v in self.z_range], "n_echoes": int(self.n_echoes),
                "mean_inclination_deg": float(np.degrees(self.mean_inclination)),
                "zenith_range_deg": [float(v) for v in np.degrees(self.zenith_range)],
                "edges_deg": [float(v) for v in np.degrees(self.edges)],
                "density_per_rad": [float(v) for v in self.density], "leaf_angle": self.leaf_angle.to_dict()}


@dataclass
class LeafAngleMeasurement:
    """Per-layer results of :func:`measure_leaf_angles` and the whole crown's.

    Attributes
    ----------
    layers : list of LayerLeafAngles
        Bottom to top.
    crown : LayerLeafAngles
        All layers together (the ``leaf_angle`` to give ``voxelize``).
    method : LeafAngleMethod
    params : dict
        The settings used (radius, range noise, ...) and, per scan, the fitted
        mix of occlusion levels (``occlusion_mix``; None for ``weighted``).
    """

    layers: list
    crown: LayerLeafAngles
    method: LeafAngleMethod
    params: dict = field(default_factory=dict)

    @property
    def leaf_angle(self) -> LeafAngle:
        """The whole crown's fitted beta distribution."""
        return self.crown.leaf_angle

    def to_dict(self) -> dict:
        return {"method": self.method.value, "params": self.params, "crown": self.crown.to_dict(),
                "layers": [lay.to_dict() for lay in self.layers]}


# --------------------------------------------------------------------------------------
# histogram helpers


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


# --------------------------------------------------------------------------------------
# plane fits


def _pairs(xyz, radius):
    """Neighbour pairs within ``radius``, both ways and each point with itself: (I, J)."""
    from scipy.spatial import cKDTree

    pairs = cKDTree(xyz).query_pairs(radius, output_type="ndarray")
    n = len(xyz)
    idx = np.arange(n)
    return np.concatenate([pairs[:, 0], pairs[:, 1], idx]), np.concatenate([pairs[:, 1], pairs[:, 0], idx])


def _normals(pts, centre, n, weights=None):
    """Per-centre plane normals (smallest covariance eigenvector), upper hemisphere.

    ``pts`` (P, 3) belong to ``centre`` (P,) in 0..n-1; returns normals (n, 3),
    counts (n,), centroids (n, 3) and in-plane minor spreads (n,) (the square
    root of the middle eigenvalue, metres).
    """
    w = np.ones(len(pts)) if weights is None else weights
    cnt = np.bincount(centre, weights=w, minlength=n)
    safe = np.where(cnt > 0, cnt, 1.0)
    mean = np.stack([np.bincount(centre, weights=w * pts[:, k], minlength=n) for k in range(3)], 1) / safe[:, None]
    dev = pts - mean[centre]
    cov = np.empty((n, 3, 3))
    for a in range(3):
        for b in range(a, 3):
            cov[:, a, b] = cov[:, b, a] = np.bincount(centre, weights=w * dev[:, a] * dev[:, b], minlength=n) / safe
    val, vec = np.linalg.eigh(cov)
    nrm = vec[:, :, 0]
    nrm = nrm * np.where(nrm[:, 2:3] < 0, -1.0, 1.0)
    return nrm, cnt, mean, np.sqrt(np.clip(val[:, 1], 0.0, None))


def _inclination_bin(nrm, n_bins):
    t = np.arccos(np.clip(np.abs(nrm[:, 2]), 0.0, 1.0))
    return np.minimum((t / HALF_PI * n_bins).astype(np.int64), n_bins - 1)


@dataclass
class _ScanFits:
    """Plane fits of one scan's leaf echoes (every echo; ``ok`` marks those with a fit)."""

    z: np.ndarray  # (n,) echo heights
    r: np.ndarray  # (n,) range, metres
    d: np.ndarray  # (n, 3) unit beam direction
    count: np.ndarray  # (n,) echoes within the radius, itself included
    ok: np.ndarray  # (n,) bool, a plane fit
    theta: np.ndarray  # (n,) beam zenith angle, folded to [0, pi/2]
    weight: np.ndarray  # (n,) r^2 / max(|n . d|, cap), the visibility weight (|n . d| >= cap where ok)
    meas_bin: np.ndarray  # (n,) measured inclination bin


def _fit_scan(xyz, origin, *, radius, min_points, min_spread, n_bins, cap):
    d = xyz - origin
    r = np.linalg.norm(d, axis=1)
    d = d / r[:, None]
    I, J = _pairs(xyz, radius)
    nrm, cnt, _, spread = _normals(xyz[J], I, len(xyz))
    cos_a = np.abs(np.einsum("ij,ij->i", nrm, d))
    ok = (cnt >= min_points) & (spread >= min_spread) & (cos_a >= cap)
    return _ScanFits(z=xyz[:, 2], r=r, d=d, count=cnt.astype(np.int64), ok=ok, theta=np.arccos(np.abs(d[:, 2])),
                     weight=r * r / np.maximum(cos_a, cap), meas_bin=_inclination_bin(nrm, n_bins))


def _layer_rows(f, sel, *, n_bins, n_groups, max_sim, rng, **sim):
    """The deconvolution rows of one scan's echoes ``sel`` (one crown layer): (histogram, kernel) per group.

    The kernel is simulated for echoes sampled from ``sel`` (their ranges and
    beams), the groups are quantiles of their beam zenith angles, and the mix
    of occlusion levels is the one whose neighbour counts match those of
    ``sel`` (non-negative least squares, given the weighted histogram).
    Returns the rows and the mix (None when ``sel`` has no fit).
    """
    fit = sel & f.ok
    if not fit.any():
        return [], None
    q = np.quantile(f.theta[fit], np.linspace(0, 1, n_groups + 1))
    group = np.clip(np.searchsorted(q[1:-1], f.theta, side="right"), 0, n_groups - 1)
    every = np.flatnonzero(sel)
    sub = every if len(every) <= max_sim else np.sort(rng.choice(every, max_sim, replace=False))
    kernels, counts = _simulate_kernel(f.r[sub], f.d[sub], group[sub], n_bins=n_bins, n_groups=n_groups, rng=rng,
                                       **sim)
    prior = np.bincount(f.meas_bin[fit], weights=f.weight[fit], minlength=n_bins)
    prior /= prior.sum()
    pred = np.einsum("b,lbc->lc", prior, counts)
    pred /= np.maximum(pred.sum(axis=1, keepdims=True), 1e-300)
    seen = np.bincount(np.minimum(f.count[sel], _MAX_COUNT - 1), minlength=_MAX_COUNT).astype(float)
    seen /= seen.sum()
    from scipy.optimize import nnls

    mix = nnls(pred.T, seen)[0]
    mix = mix / mix.sum() if mix.sum() > 0 else np.eye(len(mix))[0]
    kernel = np.einsum("l,lgbm->gbm", mix, kernels)
    rows = []
    for g in range(n_groups):
        m = fit & (group == g)
        if m.any() and kernel[g].sum() > 0:  # far echoes whose simulated leaves never get a fit: no row
            rows.append((np.bincount(f.meas_bin[m], weights=f.weight[m], minlength=n_bins), kernel[g]))
    return rows, mix


def _leaf_axes(normal, spin):
    """The major and minor axes of leaves with unit normals ``normal`` (N, 3), turned by ``spin`` (N,) radians
    in their plane from a reference axis (horizontal unless the leaf is nearly flat)."""
    u = np.cross(normal, np.where(np.abs(normal[:, 2:3]) < 0.9, [[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]]))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    major = np.cos(spin)[:, None] * u + np.sin(spin)[:, None] * np.cross(normal, u)
    return major, np.cross(normal, major)


def _simulate_kernel(r, d, group, *, step, leaf_size, radius, min_points, min_spread, n_bins, n_groups, range_noise,
                     samples, cap, rng, second_leaf: bool = False, max_offsets: int = 10):
    """The weighted estimator's histogram for unit leaf area of each true inclination bin.

    For each sampled echo (range ``r``, unit beam ``d``) and true bin: a leaf
    (an ellipse ``leaf_size`` x ``leaf_size/2``, random azimuth and spin, the
    echo at a random point of it) of that inclination is scanned by the beams
    of the angular grid around the echo (``step`` = zenith and azimuth steps,
    radians), with Gaussian range noise; the echoes within ``radius`` of the
    centre echo are fitted as the measured ones are.  The leaf is hit in
    proportion to its true ``|cos a|`` and the fit is weighted by
    ``1 / measured |cos a|`` and dropped below ``cap``, as the measured fits are.
    Each simulated leaf draws one of the occlusion levels ``_CUTS`` and, with
    ``second_leaf``, also those of ``_SECOND_CUTS``, where a second leaf of the
    same inclination bin (random azimuth, spin and position, its plane
    crossing the centre beam up to half a leaf length behind the echo) gives
    the echoes of the beams that miss the first leaf or meet it behind the
    second: neighbourhoods that span two leaves.

    Returns
    -------
    kernel : (levels, n_groups, B, B) float
        ``kernel[l, g, true, measured]``, per unit area of the true bin.
    counts : (levels, B, _MAX_COUNT) float
        Hit-weighted distribution of the neighbour counts per level and bin.
    """
    dz, da = step
    zen = np.arccos(np.clip(d[:, 2], -1.0, 1.0))
    e_a = np.column_stack([-d[:, 1], d[:, 0], np.zeros(len(d))])
    norm = np.linalg.norm(e_a, axis=1, keepdims=True)
    e_a = np.where(norm > 1e-9, e_a / np.maximum(norm, 1e-12), [[1.0, 0.0, 0.0]])
    e_z = np.cross(e_a, d)
    m = int(min(max_offsets, np.ceil(radius / (max(r.min(), 0.1) * min(dz, da)))))
    i, k = np.meshgrid(np.arange(-m, m + 1), np.arange(-m, m + 1), indexing="ij")
    i, k = i.ravel().astype(float), k.ravel().astype(float)
    centre = int(np.flatnonzero((i == 0) & (k == 0))[0])
    rays = (d[:, None, :] + i[None, :, None] * dz * e_z[:, None, :]
            + (k[None, :] * da * np.maximum(np.sin(zen), 1e-3)[:, None])[:, :, None] * e_a[:, None, :])
    rays /= np.linalg.norm(rays, axis=2, keepdims=True)  # (S, P, 3)
    n = len(r)
    cuts = np.concatenate([_CUTS, _SECOND_CUTS]) if second_leaf else _CUTS
    with_second = np.arange(len(cuts)) >= len(_CUTS)
    n_lev = len(cuts)
    kernel = np.zeros((n_lev, n_groups, n_bins, n_bins))
    n_sim = np.zeros((n_lev, n_groups, n_bins))
    counts = np.zeros((n_lev, n_bins, _MAX_COUNT))
    n_lev = np.zeros((n_lev, n_bins))
    half_len, half_wid = 0.5 * leaf_size, 0.25 * leaf_size
    for b in range(n_bins):
        for _ in range(samples):
            t = (b + rng.random(n)) * HALF_PI / n_bins
            phi = rng.uniform(0.0, 2 * np.pi, n)
            nt = np.column_stack([np.sin(t) * np.cos(phi), np.sin(t) * np.sin(phi), np.cos(t)])
            cos_true = np.einsum("ij,ij->i", nt, d)
            # the leaf: axes in its plane, the centre echo at a random point of the ellipse
            major, minor = _leaf_axes(nt, rng.uniform(0.0, 2 * np.pi, n))
            rho, beta = np.sqrt(rng.random(n)), rng.uniform(0.0, 2 * np.pi, n)
            off_a, off_b = rho * np.cos(beta) * half_len, rho * np.sin(beta) * half_wid
            den = np.einsum("spc,sc->sp", rays, nt)
            ok = np.sign(den) == np.sign(cos_true)[:, None]
            s = (r * cos_true)[:, None] / np.where(ok & (np.abs(den) > 1e-9), den, 1.0)
            rel = rays * s[:, :, None] - (d * r[:, None])[:, None, :]  # from the centre echo, in the plane
            ea = np.einsum("spc,sc->sp", rel, major) + off_a[:, None]
            eb = np.einsum("spc,sc->sp", rel, minor) + off_b[:, None]
            hit = ok & ((ea / half_len) ** 2 + (eb / half_wid) ** 2 <= 1.0)
            # the part of the leaf hidden by others: a straight cut at a distance beyond the centre echo
            # set by the occlusion level (level 0: the whole leaf is seen)
            level = rng.integers(0, len(cuts), n)
            for c0 in range(0, cuts.shape[1], 2):
                gam = rng.uniform(0.0, 2 * np.pi, n)
                proj = np.cos(gam)[:, None] * ea / half_len + np.sin(gam)[:, None] * eb / half_wid
                beyond = proj[:, centre] + rng.uniform(cuts[level, c0], cuts[level, c0 + 1])
                hit &= proj <= beyond[:, None]
            if second_leaf:
                # the second leaf: its plane crosses the centre beam up to half a leaf length behind the echo
                t2 = (b + rng.random(n)) * HALF_PI / n_bins
                phi2 = rng.uniform(0.0, 2 * np.pi, n)
                n2 = np.column_stack([np.sin(t2) * np.cos(phi2), np.sin(t2) * np.sin(phi2), np.cos(t2)])
                q = d * (r + rng.uniform(0.0, half_len, n))[:, None]
                major2, minor2 = _leaf_axes(n2, rng.uniform(0.0, 2 * np.pi, n))
                rho2, beta2 = np.sqrt(rng.random(n)), rng.uniform(0.0, 2 * np.pi, n)
                # drawn for every sample (the same random stream whatever the levels), traced for those
                # whose level has a second leaf
                two = np.flatnonzero(with_second[level])
                if len(two):
                    ray2, n2, q = rays[two], n2[two], q[two]
                    den2 = np.einsum("spc,sc->sp", ray2, n2)
                    s2 = np.einsum("sc,sc->s", q, n2)[:, None] / np.where(np.abs(den2) > 1e-9, den2, 1.0)
                    rel2 = ray2 * s2[:, :, None] - q[:, None, :]
                    ea2 = (np.einsum("spc,sc->sp", rel2, major2[two])
                           + (rho2[two] * np.cos(beta2[two]) * half_len)[:, None])
                    eb2 = (np.einsum("spc,sc->sp", rel2, minor2[two])
                           + (rho2[two] * np.sin(beta2[two]) * half_wid)[:, None])
                    hit2 = (np.abs(den2) > 1e-9) & (s2 > 0) & ((ea2 / half_len) ** 2 + (eb2 / half_wid) ** 2 <= 1.0)
                    use2 = hit2 & ~(hit[two] & (s[two] <= s2))  # the nearer leaf gives the echo
                    s[two] = np.where(use2, s2, s[two])
                    hit[two] |= hit2
            s_noisy = s + rng.normal(0.0, range_noise, s.shape)
            pts = rays * s_noisy[:, :, None]  # relative to the scanner
            near = hit & (np.linalg.norm(pts - pts[:, centre:centre + 1, :], axis=2) <= radius)
            cnt = near.sum(axis=1)
            wgt = near / np.maximum(cnt, 1)[:, None]
            mean = np.einsum("sp,spc->sc", wgt, pts)
            dev = pts - mean[:, None, :]
            cov = np.einsum("sp,spa,spb->sab", wgt, dev, dev)
            val, vec = np.linalg.eigh(cov)
            nrm = vec[:, :, 0]
            nrm = nrm * np.where(nrm[:, 2:3] < 0, -1.0, 1.0)
            cos_m = np.abs(np.einsum("ij,ij->i", nrm, d))
            fitted = (cnt >= min_points) & (np.sqrt(np.clip(val[:, 1], 0.0, None)) >= min_spread) & (cos_m >= cap)
            mb = _inclination_bin(nrm, n_bins)
            w_est = np.abs(cos_true) / np.maximum(cos_m, cap)
            np.add.at(kernel, (level[fitted], group[fitted], b, mb[fitted]), w_est[fitted])
            np.add.at(n_sim, (level, group, b), 1.0)
            np.add.at(counts, (level, b, np.minimum(cnt, _MAX_COUNT - 1)), np.abs(cos_true))
            np.add.at(n_lev, (level, b), 1.0)
    return kernel / np.maximum(n_sim, 1)[..., None], counts / np.maximum(n_lev, 1)[..., None]


def _deconvolve(rows, n_bins, iterations):
    """EM (Richardson-Lucy) estimate of the area-weighted bin probabilities.

    ``rows`` are (histogram, kernel) pairs, one per scan, crown layer and beam
    zenith group g: the weighted histogram of the fits is modelled as
    ``h_g = s_g f @ K_g`` (``s_g`` the leaf area the group sees).
    """
    if not rows:
        return np.zeros(n_bins)
    h = np.array([row[0] for row in rows])  # (G, B)
    K = np.array([row[1] for row in rows])  # (G, B, B)
    p = np.full(n_bins, 1.0 / n_bins)
    for _ in range(iterations):
        pred = np.einsum("b,gbm->gm", p, K)
        scale = h.sum(axis=1) / np.maximum(pred.sum(axis=1), 1e-300)
        pred *= scale[:, None]
        ratio = np.where(pred > 0, h / np.maximum(pred, 1e-300), 0.0)
        num = np.einsum("g,gbm,gm->b", scale, K, ratio)
        den = np.einsum("g,gbm->b", scale, K)
        p = p * np.where(den > 0, num / np.maximum(den, 1e-300), 0.0)
        p /= p.sum()
    return p


def _weighted(fits, masks, n_bins):
    h = np.zeros(n_bins)
    for f, m in zip(fits, masks):
        m = m & f.ok
        h += np.bincount(f.meas_bin[m], weights=f.weight[m], minlength=n_bins)
    return h / h.sum() if h.sum() > 0 else h


def _leaf_mask(scan):
    from voxlidar.materials import Material

    if scan.truth_material is not None:
        return np.asarray(scan.truth_material) == Material.LEAF
    if scan.classification is not None:
        from tlsvox.classify import PointClass

        return np.asarray(scan.classification) == PointClass.LEAF
    raise InputError(f"scan {scan.name!r} says neither which echoes are leaves (no truth_material, no "
                     "classification): classify it first (tlsvox.classify_scan) or pass leaf=[mask, ...]")


def measure_leaf_angles(scans, *, layers: int = 4, method="deconvolve", radius: float = 0.025,
                        min_points: int = 5, min_spread: float = 0.0, bins: int = 18, range_noise: float | None = None,
                        leaf_size: float = 0.05, angular_step=None, zenith_groups: int = 6, samples: int = 5,
                        max_simulated: int = 3000, iterations: int = 30, cap: float = 0.2, second_leaf: bool = True,
                        leaf=None, seed: int = 0) -> LeafAngleMeasurement:
    """Measure the leaf inclination distribution per crown layer from leaf echoes.

    Parameters
    ----------
    scans : list of Scan
        Registered scans (a pose each; a simulated scan's true pose is used
        when it has no other).
    layers : int
        Equal-height crown layers between the 1st and 99th height percentiles
        of the leaf echoes (>= 1).
    method : {"deconvolve", "weighted"}
        See the module docstring.
    radius : float, metres
        Neighbourhood radius of the plane fits (leaf scale).
    min_points : int
        Echoes a neighbourhood needs for a plane fit (>= 3).
    min_spread : float, metres
        Smallest in-plane minor spread (square root of the middle covariance
        eigenvalue) of a neighbourhood kept for a plane fit; nearly collinear
        neighbourhoods (oblique leaves) fix no plane.  The deconvolution
        applies the same test to its simulated leaves.
    bins : int
        Inclination bins on [0, 90] degrees.
    range_noise : float, metres, optional
        Range noise (1 sigma) of the instrument; default the scan's preset
        (``meta["preset"]["range_noise_m"]``) else 5 mm (RIEGL VZ-400).
    leaf_size : float, metres
        Leaf length of the simulated leaves (ellipses, width half the
        length) in the deconvolution.
    angular_step : float or (2,) float, degrees, optional
        Zenith and azimuth steps of the scans; default each scan's angular
        grid (pulse table) or simulator preset.
    zenith_groups, samples, max_simulated, iterations
        Deconvolution: groups of beam zenith angles per scan and crown
        layer, simulated leaves per bin and sampled echo (spread over the
        occlusion levels), echoes sampled per scan and crown layer, EM
        iterations (few: Richardson-Lucy amplifies noise as it goes on; on
        the oak, seed 0, the crown's mean inclination moves by under 1 deg
        and a layer's by up to 2.5 deg between 10 and 100 iterations).
    cap : float
        Smallest |cos a| between a fitted normal and its beam: fits nearer
        edge-on are dropped (their normals are set by the errors along the
        beam), in the simulation too; the others are weighted by 1/|cos a|.
    second_leaf : bool
        Deconvolution: add occlusion levels where a second leaf just behind
        the first lies in the neighbourhood (see :func:`_simulate_kernel`);
        their share, like the other levels', comes from the neighbour counts.
        False gives the single-leaf levels alone.
    leaf : list of (N_i,) bool, optional
        Leaf echoes per scan; default ``truth_material == LEAF`` or the
        classification's leaf class.
    seed : int
        Seeds the simulated normals.

    Returns
    -------
    LeafAngleMeasurement
    """
    method = LeafAngleMethod.parse(method, "method")
    scans = list(scans)
    if not scans:
        raise InputError("measure_leaf_angles needs at least one scan")
    if int(layers) < 1:
        raise InputError(f"layers={layers!r} must be an integer >= 1 (e.g. 4 crown layers)")
    if not (np.isfinite(radius) and radius > 0):
        raise InputError(f"radius={radius!r} must be a positive number of metres (leaf scale, e.g. 0.025)")
    if int(min_points) < 3:
        raise InputError(f"min_points={min_points!r} must be >= 3 (a plane needs three points)")
    if not (np.isfinite(cap) and 0 < cap < 1):
        raise InputError(f"cap={cap!r} must lie in (0, 1): the smallest |cos| between a leaf normal and its beam "
                         "(e.g. 0.2)")
    if leaf is not None and len(leaf) != len(scans):
        raise InputError(f"leaf= holds {len(leaf)} masks for {len(scans)} scans; give one per scan")
    rng = np.random.default_rng(seed)
    fits, noise_used, steps = [], [], []
    for i, s in enumerate(scans):
        pose = s.pose if s.pose is not None else s.pose_true
        if pose is None:
            raise InputError(f"scan {s.name!r} has no pose: register it (tlsvox register) first")
        mask = _leaf_mask(s) if leaf is None else np.asarray(leaf[i], bool)
        if mask.shape != (len(s),):
            raise InputError(f"leaf[{i}] has shape {mask.shape}; scan {s.name!r} has {len(s)} echoes")
        sigma = range_noise
        if sigma is None:
            sigma = float(s.meta.get("preset", {}).get("range_noise_m", 0.005))
        step = angular_step
        if step is None and s.pulses is not None and s.pulses.grid is not None:
            step = (s.pulses.grid.zenith_step_deg, s.pulses.grid.azimuth_step_deg)
        if step is None and "zenith_step_deg" in s.meta.get("preset", {}):
            step = (s.meta["preset"]["zenith_step_deg"], s.meta["preset"]["azimuth_step_deg"])
        if step is None and method is LeafAngleMethod.DECONVOLVE:
            raise InputError(f"scan {s.name!r} has no angular grid: pass angular_step= (degrees, e.g. 0.06 for the "
                             "RIEGL VZ-400) or use method='weighted'")
        step = np.radians(np.broadcast_to(np.asarray(step if step is not None else 0.06, float), (2,)))
        xyz = s.world_xyz(pose)[mask]
        if len(xyz) < min_points:
            continue
        fits.append(_fit_scan(xyz, np.asarray(pose, float)[:3, 3], radius=radius, min_points=int(min_points),
                              min_spread=float(min_spread), n_bins=int(bins), cap=cap))
        noise_used.append(sigma)
        steps.append(tuple(step))
    z_all = np.concatenate([f.z[f.ok] for f in fits]) if fits else np.zeros(0)
    if len(z_all) < 10 * bins:
        raise InputError(f"only {len(z_all)} leaf echoes have {min_points} neighbours within {radius} m: too few "
                         "for a leaf angle histogram; scan closer or denser, or raise radius")
    lo, hi = np.percentile(z_all, [1, 99])
    cuts = np.linspace(lo, hi, int(layers) + 1)
    edges = np.linspace(0.0, HALF_PI, int(bins) + 1)

    def in_layer(f, k):
        """Echoes of layer k (the bottom and top layers take the echoes below and above the cuts)."""
        return (f.z >= cuts[k]) | (k == 0) if k == layers - 1 else ((f.z >= cuts[k]) | (k == 0)) & (f.z < cuts[k + 1])

    # per scan and layer: its kernel (its echoes' ranges and beams, its occlusion) and rows
    rows = [[[] for _ in fits] for _ in range(int(layers))]
    mixes = [[None] * int(layers) for _ in fits]
    if method is LeafAngleMethod.DECONVOLVE:
        for i, f in enumerate(fits):
            for k in range(int(layers)):
                rows[k][i], mixes[i][k] = _layer_rows(
                    f, in_layer(f, k), n_bins=int(bins), n_groups=int(zenith_groups), max_sim=int(max_simulated),
                    rng=rng, step=steps[i], leaf_size=float(leaf_size), radius=radius, min_points=int(min_points),
                    min_spread=float(min_spread), range_noise=noise_used[i], samples=int(samples), cap=cap,
                    second_leaf=bool(second_leaf))

    def result(ks, z_range):
        masks = [np.logical_or.reduce([in_layer(f, k) for k in ks]) for f in fits]
        if method is LeafAngleMethod.DECONVOLVE:
            p = _deconvolve([row for k in ks for scan_rows in rows[k] for row in scan_rows], int(bins),
                            int(iterations))
        else:
            p = _weighted(fits, masks, int(bins))
        n = int(sum((m & f.ok).sum() for f, m in zip(fits, masks)))
        th = np.concatenate([f.theta[m & f.ok] for f, m in zip(fits, masks)])
        zr = np.percentile(th, [5, 95]) if len(th) else np.array([np.nan, np.nan])
        return LayerLeafAngles(z_range=np.asarray(z_range, float), edges=edges, density=p / np.diff(edges),
                               n_echoes=n, zenith_range=zr, leaf_angle=fit_beta(p, edges) if n else LeafAngle("uniform"))

    per_layer = [result([k], cuts[k:k + 2]) for k in range(int(layers))]
    crown = result(range(int(layers)), [z_all.min(), z_all.max()])
    params = {"occlusion_mix": [[None if m is None else [round(float(v), 3) for v in m] for m in scan_mixes]
                                for scan_mixes in mixes],
              "layers": int(layers), "radius_m": float(radius), "min_points": int(min_points),
              "min_spread_m": float(min_spread), "bins": int(bins), "range_noise_m": [float(v) for v in noise_used],
              "zenith_groups": int(zenith_groups), "leaf_size_m": float(leaf_size), "samples": int(samples),
              "max_simulated": int(max_simulated), "iterations": int(iterations), "cap": float(cap),
              "second_leaf": bool(second_leaf), "seed": int(seed)}
    return LeafAngleMeasurement(layers=per_layer, crown=crown, method=method, params=params)
