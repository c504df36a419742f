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
3. **The measurement, simulated and inverted** (``method="deconvolve"``, the
   default).  At leaf scale the range noise (5 mm on the VZ-400, along the
   beam) is comparable with the spread of a leaf's echoes (about 7 mm); a
   wide beam's partial hits put the echo on the pulse's central direction;
   sub-rays on a leaf and on what lies behind it merge into one echo between
   the two (within the range resolution); and leaves are seen in part.  So
   single normals scatter by tens of degrees and the weighted histogram is
   biased.  The default models the measurement: for every true inclination
   bin, leaves of that inclination are scanned in simulation around sampled
   echoes (their range, beam and outward direction) on the scan's angular
   grid by the instrument's beam (its sub-rays stop on the first leaf they
   meet; each pulse gives one echo on its central direction at the
   power-weighted mean range of its sub-rays' hits, with the range noise),
   and fitted, weighted and dropped as the measured ones are.  Each simulated
   leaf draws an occlusion level: whole, cut by one or two straight edges
   (others hide part of it), or with a second leaf behind it in one of four
   distance bands (0-2.5, 2.5-5, 5-10, 10-25 cm; ``second_leaf``); and it
   faces a random azimuth or away from the crown centre (the trunk's axis,
   :func:`trunk_center` of the wood echoes at its base; ``azimuth``).  An
   echo's observation is its measured inclination bin, the azimuth of its
   normal from the outward direction (4 classes) and its neighbour count
   (7 classes), or the count alone when it has no fit.  The expected
   histogram of the observations is linear in the leaf-area distribution for
   given shares of the occlusion levels and azimuth models, and all are
   fitted by maximum likelihood (EM): the azimuth models' shares first, per
   layer, together with the rest; then each layer keeps the model with the
   larger share (a mixture of the two read the four planophile crowns
   0.7-1.9 deg steeper than the right model alone), and its distribution and occlusion mix (per
   scan and layer) are fitted with that model.  The sampled echoes stand for
   the leaf area around them, so each weighs r^2 in the simulation.  Everything
   is simulated per scan and crown layer (the upper layers are farther from
   ground scanners, seen more steeply and more hidden); the crown's
   distribution is the one that explains every layer's rows together.
   ``method="weighted"`` is step 2 alone.

Accuracy (``benchmarks/bench_leaf_angles.py``, docs/bench/leaf_angles*.md):
on the oak's two VZ-400 scans (7-sub-ray beam, 5 mm range noise) with
uniform, planophile and erectophile leaves, facing outwards (the paper's oak)
or random azimuths, on two oaks (seeds 0 and 1), every crown's mean
inclination is within 3.1 deg and its G within 3.9 % over the scanned
zenith angles, and 46 of the 48 layers are within 5 deg and 5 %; the two
others are erectophile layers that miss on G alone (6.2 and 5.2 %, means
within 3.5 deg).  Uniform and erectophile crowns read 1.2-3.1 deg flat,
planophile ones -0.6 to +1.4 deg (docs/bench/leaf_angle_kernel.md: the
kernel measures 30-75 deg leaves 1-4 deg steeper than the scans do).  Each
layer's azimuth model is the right one on all four oaks.  Two scans take
44-58 s (2 cores) and 1.3-1.4 GiB.

**Limits.**  One trunk: the outward model faces leaves away from one vertical
axis.  The simulated leaves are flat ellipses of ``leaf_size``, and a second
leaf behind the first has the first's inclination bin.

The crown is cut into ``layers`` equal-height layers between the 1st and 99th
height percentiles of the leaf echoes with a plane fit; every layer gets its
histogram, mean inclination and a beta distribution (Goel & Strebel 1984)
fitted by moments, a :class:`~voxlidar.leafangle.LeafAngle` usable as
``voxelize(leaf_angle=...)`` and stored in the scene file like any other.

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
Kasa, I. (1976). A circle fitting procedure and its error analysis. IEEE
    Transactions on Instrumentation and Measurement 25(1), 8-14.
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
           "histogram_G", "trunk_center"]

HALF_PI = 0.5 * np.pi
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
#: neighbour-count classes of the observations (counts from each edge up to the next)
_COUNT_EDGES = (0, 5, 8, 11, 15, 20, 27)
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
        The settings used (radius, range noise, ...); the scans measured
        (``scans_used``: a scan with too few leaf echoes is left out, and the
        per-scan lists follow this one); per scan and layer the fitted mix of
        occlusion levels (``occlusion_mix``); the azimuth models tried
        (``azimuth_models``), their shares fitted together per layer
        (``azimuth_share``) and the one each layer uses (``azimuth_model``);
        the crown centre and where it came from (``crown_center_m``,
        ``crown_center_from``); the beam per scan.  The deconvolution's
        entries are None for ``weighted``.
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


def _azimuth_class(nrm, outward, n_classes):
    """Class of the angle between a normal's horizontal part and the outward direction: 0 facing out."""
    if n_classes == 1:
        return np.zeros(len(nrm), np.int64)
    h = np.maximum(np.linalg.norm(nrm[:, :2], axis=1), 1e-12)
    c = (nrm[:, 0] * outward[:, 0] + nrm[:, 1] * outward[:, 1]) / h
    return np.minimum((np.arccos(np.clip(c, -1.0, 1.0)) / np.pi * n_classes).astype(np.int64), n_classes - 1)


def _columns(fitted, meas_bin, az_class, count, *, n_bins, n_azimuth, count_edges):
    """Observation column of each echo: (measured bin, azimuth class, count class) for a plane fit, else the
    count class alone in the last ``len(count_edges)`` columns."""
    n_count = len(count_edges)
    cc = np.searchsorted(np.asarray(count_edges), count, side="right") - 1
    return np.where(fitted, (meas_bin * n_azimuth + az_class) * n_count + cc, n_bins * n_azimuth * n_count + cc)


def _n_columns(n_bins, n_azimuth, count_edges):
    return (n_bins * n_azimuth + 1) * len(count_edges)


def _measured_bins(kernel, n_bins, n_azimuth=1, count_edges=_COUNT_EDGES):
    """Sum a kernel's observation columns over azimuth and count classes: (..., n_bins) per measured bin
    (echoes without a plane fit left out)."""
    n_count = len(count_edges)
    fit = kernel[..., :n_bins * n_azimuth * n_count]
    return fit.reshape(fit.shape[:-1] + (n_bins, n_azimuth * n_count)).sum(axis=-1)


@dataclass
class _ScanFits:
    """Plane fits of one scan's leaf echoes (every echo; ``ok`` marks those with a fit)."""

    z: np.ndarray  # (n,) echo heights
    r: np.ndarray  # (n,) range, metres
    d: np.ndarray  # (n, 3) unit beam direction
    ok: np.ndarray  # (n,) bool, a plane fit
    theta: np.ndarray  # (n,) beam zenith angle, folded to [0, pi/2]
    weight: np.ndarray  # (n,) r^2 / max(|n . d|, cap) with a fit (|n . d| >= cap), r^2 without
    meas_bin: np.ndarray  # (n,) measured inclination bin
    outward: np.ndarray  # (n, 2) unit horizontal direction from the crown centre (zeros without a centre)
    column: np.ndarray  # (n,) observation column (see _columns)


def _fit_scan(xyz, origin, *, radius, min_points, min_spread, n_bins, cap, centre=None, n_azimuth=1,
              count_edges=_COUNT_EDGES):
    d = xyz - origin
    r = np.linalg.norm(d, axis=1)
    d = d / r[:, None]
    pi, J = _pairs(xyz, radius)
    nrm, cnt, _, spread = _normals(xyz[J], pi, len(xyz))
    cos_a = np.abs(np.einsum("ij,ij->i", nrm, d))
    ok = (cnt >= min_points) & (spread >= min_spread) & (cos_a >= cap)
    outward = np.zeros((len(xyz), 2))
    if centre is not None:
        outward = xyz[:, :2] - np.asarray(centre, float)[None, :2]
        outward /= np.maximum(np.linalg.norm(outward, axis=1, keepdims=True), 1e-9)
    meas_bin = _inclination_bin(nrm, n_bins)
    column = _columns(ok, meas_bin, _azimuth_class(nrm, outward, n_azimuth), cnt.astype(np.int64), n_bins=n_bins,
                      n_azimuth=n_azimuth, count_edges=count_edges)
    return _ScanFits(z=xyz[:, 2], r=r, d=d, ok=ok, theta=np.arccos(np.abs(d[:, 2])),
                     weight=np.where(ok, r * r / np.maximum(cos_a, cap), r * r), meas_bin=meas_bin, outward=outward,
                     column=column)


def trunk_center(wood_xyz, *, low: float = 0.3, high: float = 1.3):
    """The trunk's axis (x, y) and radius from wood echoes near its base.

    A circle fitted by least squares (Kasa 1976) to the wood echoes between
    ``low`` and ``high`` metres above their 1st height percentile, refitted
    without the echoes more than three median deviations off the circle
    (branches, mislabelled ground) until the kept ones stay the same.

    Returns
    -------
    centre : (2,) float, metres, or None
        None when fewer than 30 echoes lie in the slice or the fit is not a
        trunk (radius outside 1 cm - 3 m).
    radius : float, metres (nan with no centre)
    """
    wood_xyz = np.asarray(wood_xyz, float).reshape(-1, 3)
    if len(wood_xyz) < 30:
        return None, float("nan")
    z0 = np.percentile(wood_xyz[:, 2], 1)
    sel = wood_xyz[(wood_xyz[:, 2] > z0 + low) & (wood_xyz[:, 2] < z0 + high)][:, :2]
    from tlsvox.qsm import _circle

    keep = np.ones(len(sel), bool)
    for _ in range(20):
        if keep.sum() < 30:
            return None, float("nan")
        centre, rad = _circle(sel[keep])
        off = np.abs(np.linalg.norm(sel - centre, axis=1) - rad)
        new = off <= 3.0 * max(np.median(off[keep]), 1e-3)
        if np.array_equal(new, keep):
            break
        keep = new
    if not 0.01 <= rad <= 3.0:
        return None, float("nan")
    return centre, rad


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


def _in_layer(z, cuts, k):
    """Heights ``z`` in layer k of the layer boundaries ``cuts`` (the bottom and top layers take those below
    and above the cuts)."""
    n_layers = len(cuts) - 1
    low = (z >= cuts[k]) | (k == 0)
    return low if k == n_layers - 1 else low & (z < cuts[k + 1])


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


def _class_mask(scan, material, point_class):
    """Echoes of a truth material, else of a class; None when the scan says neither."""
    if scan.truth_material is not None:
        return np.asarray(scan.truth_material) == material
    if scan.classification is not None:
        return np.asarray(scan.classification) == point_class
    return None


def _leaf_mask(scan):
    from tlsvox.classify import PointClass
    from voxlidar.materials import Material

    mask = _class_mask(scan, Material.LEAF, PointClass.LEAF)
    if mask is None:
        raise InputError(f"scan {scan.name!r} says neither which echoes are leaves (no truth_material, no "
                         "classification): classify it first (tlsvox.classify_scan) or pass leaf=[mask, ...]")
    return mask


def _scan_beam(scan):
    """(exit radius m, half divergence rad, sub-rays) of a scan's preset, else the RIEGL VZ-400's."""
    p = scan.meta.get("preset", {})
    return (0.5 * float(p.get("beam_exit_diameter_m", 0.007)), 0.5e-3 * float(p.get("divergence_mrad", 0.35)),
            int(p.get("n_subrays", 7)))


def measure_leaf_angles(scans, *, layers: int = 4, method="deconvolve", radius: float = 0.025,
                        min_points: int = 5, min_spread: float = 0.0, bins: int = 18, range_noise: float | None = None,
                        leaf_size: float = 0.05, angular_step=None, beam=None, azimuth="auto", crown_center=None,
                        zenith_groups: int = 6, samples: int = 3, max_simulated: int = 3000, iterations: int = 300,
                        cap: float = 0.2, second_leaf: bool = True, leaf=None, seed: int = 0) -> LeafAngleMeasurement:
    """Measure the leaf inclination distribution per crown layer from leaf echoes.

    Parameters
    ----------
    scans : list of Scan
        Registered scans (a pose each; a simulated scan's true pose is used
        when it has no other).
    layers : int
        Equal-height crown layers between the 1st and 99th height percentiles
        of the leaf echoes with a plane fit (>= 1).
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
    beam : (3,) tuple, optional
        The instrument's beam in the deconvolution: (exit beam diameter m,
        full divergence mrad, sub-rays 1/7/19/37); default each scan's preset,
        else the RIEGL VZ-400's (7 mm, 0.35 mrad, 7).  ``(0, 0, 1)`` is a
        pencil beam.
    azimuth : {"auto", "uniform", "outward"}
        Leaf azimuth model of the deconvolution: leaves facing any azimuth,
        facing away from the crown centre, or (``"auto"``) per layer the one
        of the two with the larger share when both are fitted together
        (``params["azimuth_share"]``, ``params["azimuth_model"]``).  Without
        a crown centre (none given and no trunk found) only ``"uniform"`` is
        used and ``params["azimuth_models"]`` says so.
    crown_center : (2,) float, metres, optional
        The crown's axis (x, y) in the world frame for the outward model;
        default the trunk's (:func:`trunk_center` of the wood echoes: truth
        bark or the classification's wood class).
    zenith_groups, samples, max_simulated, iterations
        Deconvolution: groups of beam zenith angles per scan and crown
        layer, simulated leaves per bin, sampled echo and azimuth model
        (spread over the occlusion levels), echoes sampled per scan and crown
        layer, EM iterations (of each fit: with ``"auto"`` the shares' fit
        comes first).
    cap : float
        Smallest ``|cos a|`` between a fitted normal and its beam: fits nearer
        edge-on are dropped (their normals are set by the errors along the
        beam), in the simulation too; the others are weighted by ``1 / |cos a|``.
    second_leaf : bool
        Deconvolution: add occlusion levels where a second leaf behind the
        first lies in the neighbourhood (see :func:`_simulate_kernel`); their
        share, like the other levels', is fitted.  False gives the
        single-leaf levels alone.
    leaf : list of (N_i,) bool, optional
        Leaf echoes per scan; default ``truth_material == LEAF`` or the
        classification's leaf class.
    seed : int
        Seeds the simulated leaves.

    Returns
    -------
    LeafAngleMeasurement
    """
    from tlsvox.classify import PointClass
    from voxlidar.leafangle import LeafAzimuth
    from voxlidar.materials import Material

    method = LeafAngleMethod.parse(method, "method")
    scans = list(scans)
    if not scans:
        raise InputError("measure_leaf_angles needs at least one scan")
    if not (np.isfinite(radius) and radius > 0):
        raise InputError(f"radius={radius!r} must be a positive number of metres (leaf scale, e.g. 0.025)")
    if int(min_points) < 3:
        raise InputError(f"min_points={min_points!r} must be >= 3 (a plane needs three points)")
    if not (np.isfinite(cap) and 0 < cap < 1):
        raise InputError(f"cap={cap!r} must lie in (0, 1): the smallest |cos| between a leaf normal and its beam "
                         "(e.g. 0.2)")
    if leaf is not None and len(leaf) != len(scans):
        raise InputError(f"leaf= holds {len(leaf)} masks for {len(scans)} scans; give one per scan")
    azimuth = str(azimuth).lower()
    if azimuth not in ("auto", LeafAzimuth.UNIFORM.value, LeafAzimuth.OUTWARD.value):
        raise InputError(f"azimuth={azimuth!r} is not known; choose one of: auto, uniform, outward")
    for name, value, least in (("layers", layers, 1), ("zenith_groups", zenith_groups, 1), ("samples", samples, 1),
                               ("max_simulated", max_simulated, 1), ("iterations", iterations, 1), ("bins", bins, 2)):
        if not isinstance(value, (int, np.integer)) or value < least:
            raise InputError(f"{name}={value!r} must be an integer >= {least}")
    if beam is not None:
        try:
            raw = tuple(beam)
            beam = (float(raw[0]), float(raw[1]), float(raw[2]))
            ok = len(raw) == 3 and 0 <= beam[0] < 0.1 and 0 <= beam[1] < 10 and beam[2] in (1, 7, 19, 37)
        except (TypeError, ValueError, IndexError):
            ok = False
        if not ok:
            raise InputError(f"beam={beam!r} must be (exit diameter m < 0.1, full divergence mrad < 10, sub-rays 1, "
                             "7, 19 or 37), e.g. (0.007, 0.35, 7) for the RIEGL VZ-400")
        beam = (beam[0], beam[1], int(beam[2]))
    if crown_center is not None:
        try:
            crown_center = np.asarray(crown_center, float).reshape(-1)
        except (TypeError, ValueError):
            crown_center = np.array([np.nan])
        if crown_center.shape != (2,) or not np.isfinite(crown_center).all():
            raise InputError(f"crown_center={crown_center!r} must be (x, y) in metres, world frame, e.g. (0.4, -0.2)")
    if angular_step is not None:
        st = np.asarray(angular_step, float).reshape(-1)
        if st.size not in (1, 2) or not (np.isfinite(st).all() and (st > 0).all()):
            raise InputError(f"angular_step={angular_step!r} must be one or two positive angles in degrees "
                             "(zenith, azimuth), e.g. 0.06")
    rng = np.random.default_rng(seed)
    poses = []
    for s in scans:
        pose = s.pose if s.pose is not None else s.pose_true
        if pose is None:
            raise InputError(f"scan {s.name!r} has no pose: register it (tlsvox register) first")
        poses.append(np.asarray(pose, float))

    # the crown centre of the outward model
    centre, centre_from = None, "none"
    if crown_center is not None:
        centre = crown_center
        centre_from = "given"
    elif method is LeafAngleMethod.DECONVOLVE and azimuth != "uniform":
        wood = [s.world_xyz(p)[m] for s, p in zip(scans, poses)
                if (m := _class_mask(s, Material.BARK, PointClass.WOOD)) is not None]
        centre, _ = trunk_center(np.concatenate(wood) if wood else np.zeros((0, 3)))
        centre_from = "trunk" if centre is not None else "no trunk found in the wood echoes"
    if azimuth == "outward" and centre is None and method is LeafAngleMethod.DECONVOLVE:
        raise InputError("azimuth='outward' needs the crown centre: pass crown_center=(x, y) or scans with wood "
                         "echoes at the trunk's base (classify them first)")
    models = {"auto": ("uniform", "outward"), "uniform": ("uniform",), "outward": ("outward",)}[azimuth]
    if centre is None:
        models = ("uniform",)
    n_azimuth = 4 if "outward" in models else 1

    fits, noise_used, steps, beams, used = [], [], [], [], []
    for i, (s, pose) in enumerate(zip(scans, poses)):
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
        fits.append(_fit_scan(xyz, pose[:3, 3], radius=radius, min_points=int(min_points),
                              min_spread=float(min_spread), n_bins=int(bins), cap=cap, centre=centre,
                              n_azimuth=n_azimuth))
        noise_used.append(sigma)
        used.append(s.name)
        steps.append(tuple(step))
        beams.append(_scan_beam(s) if beam is None else (0.5 * beam[0], 0.5e-3 * beam[1], int(beam[2])))
    z_all = np.concatenate([f.z[f.ok] for f in fits]) if fits else np.zeros(0)
    if len(z_all) < 10 * bins:
        raise InputError(f"only {len(z_all)} leaf echoes have {min_points} neighbours within {radius} m: too few "
                         "for a leaf angle histogram; scan closer or denser, or raise radius")
    lo, hi = np.percentile(z_all, [1, 99])
    cuts = np.linspace(lo, hi, int(layers) + 1)
    edges = np.linspace(0.0, HALF_PI, int(bins) + 1)
    n_layers = int(layers)

    def in_layer(f, k):
        return _in_layer(f.z, cuts, k)

    # per scan and layer: its kernel (its echoes' ranges, beams and outward directions) and rows
    rows = []  # (layer, scan, histogram, kernel)
    if method is LeafAngleMethod.DECONVOLVE:
        for i, f in enumerate(fits):
            for k in range(n_layers):
                rows += [(k, i, h, K) for h, K in _layer_rows(
                    f, in_layer(f, k), n_bins=int(bins), n_groups=int(zenith_groups), max_sim=int(max_simulated),
                    rng=rng, step=steps[i], beam=beams[i], leaf_size=float(leaf_size), radius=radius,
                    min_points=int(min_points), min_spread=float(min_spread), range_noise=noise_used[i],
                    samples=int(samples), cap=cap, second_leaf=bool(second_leaf), azimuths=models,
                    n_azimuth=n_azimuth)]
    mixes = [[None] * n_layers for _ in fits]
    # the azimuth model of each layer: with both, the one with the larger share when both are fitted together
    shares, chosen = [None] * n_layers, [0 if len(models) == 1 else None for _ in range(n_layers)]
    if len(models) > 1:
        for k in range(n_layers):
            sel = [(i, h, K) for k_, i, h, K in rows if k_ == k]
            if sel:
                shares[k] = _em([(0, i, 0, h, K) for i, h, K in sel], (1, len(fits), 1), int(iterations))[2][0]
                chosen[k] = int(np.argmax(shares[k]))
        rows = [(k, i, h, K[chosen[k]:chosen[k] + 1]) for k, i, h, K in rows]  # a layer with rows has a choice

    def result(ks, z_range):
        masks = [np.logical_or.reduce([in_layer(f, k) for k in ks]) for f in fits]
        if method is LeafAngleMethod.WEIGHTED:
            p = _weighted(fits, masks, int(bins))
        else:
            # one distribution; an occlusion mix per scan and layer; each layer's azimuth model
            sel = [(k, i, h, K) for k, i, h, K in rows if k in ks]
            p = np.zeros(int(bins))
            if sel:
                p, mix, _ = _em([(0, i * len(ks) + list(ks).index(k), 0, h, K) for k, i, h, K in sel],
                                (1, len(fits) * len(ks), 1), int(iterations))
                p = p[0]
                if len(ks) == 1:
                    for i in range(len(fits)):
                        if any(i_ == i for _, i_, _, _ in sel):
                            mixes[i][ks[0]] = mix[i]
        n = int(sum((m & f.ok).sum() for f, m in zip(fits, masks)))
        th = np.concatenate([f.theta[m & f.ok] for f, m in zip(fits, masks)])
        zr = np.percentile(th, [5, 95]) if len(th) else np.array([np.nan, np.nan])
        la = fit_beta(p, edges) if n and p.sum() > 0 else LeafAngle("uniform")
        return LayerLeafAngles(z_range=np.asarray(z_range, float), edges=edges, density=p / np.diff(edges),
                               n_echoes=n, zenith_range=zr, leaf_angle=la)

    per_layer = [result([k], cuts[k:k + 2]) for k in range(n_layers)]
    crown = result(list(range(n_layers)), [z_all.min(), z_all.max()])
    deconvolve = method is LeafAngleMethod.DECONVOLVE
    params = {"occlusion_mix": [[None if m is None else [round(float(v), 3) for v in m] for m in scan_mixes]
                                for scan_mixes in mixes],
              "azimuth_models": list(models) if deconvolve else None,
              "azimuth_share": [None if a is None else {mod: round(float(v), 3) for mod, v in zip(models, a)}
                                for a in shares] if deconvolve else None,
              "azimuth_model": [None if c is None else models[c] for c in chosen] if deconvolve else None,
              "scans_used": used,
              "crown_center_m": None if centre is None else [round(float(v), 3) for v in centre],
              "crown_center_from": centre_from,
              "beam": [{"exit_radius_m": b[0], "half_divergence_rad": b[1], "subrays": b[2]} for b in beams],
              "layers": n_layers, "radius_m": float(radius), "min_points": int(min_points),
              "min_spread_m": float(min_spread), "bins": int(bins), "range_noise_m": [float(v) for v in noise_used],
              "zenith_groups": int(zenith_groups), "leaf_size_m": float(leaf_size), "samples": int(samples),
              "max_simulated": int(max_simulated), "iterations": int(iterations), "cap": float(cap),
              "second_leaf": bool(second_leaf), "seed": int(seed)}
    return LeafAngleMeasurement(layers=per_layer, crown=crown, method=method, params=params)
