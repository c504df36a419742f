"""Leaf / wood / noise classification of a scan from its apparent reflectance.

Three methods (:class:`ClassifyMethod`); docs/classify_register.md compares
them against the truth labels of simulated scans.

``neighbourhood`` (default)
    The echo's feature is the mean reflectance in dB over itself and its
    ``smooth_k`` nearest vegetation echoes.  The apparent reflectance of one
    echo is ``R_material * cos(incidence) * hit_fraction``: two nuisance
    factors that multiply, so they add in dB, and averaging over a
    neighbourhood of one surface (a leaf cluster, a branch) shrinks their
    spread while the material term stays.  Two Gaussians are fitted to the
    averaged dB values and split by the threshold rule.  Noise is geometric
    (:func:`isolated`): an echo with too few neighbours within a few scan
    grid spacings; dark echoes are partial hits, not noise.  The Gaussians
    are fitted to the echoes of single-echo pulses (full hits).
``echo``
    The same per-echo: two Gaussians on the echo's own reflectance, geometric
    noise; optionally divided by an estimated ``cos(incidence)``
    (``incidence_correction=True``, :func:`incidence_cosine`).
``paper``
    The paper's method (Kim et al. 2015, §3.3), made automatic:

1. Per scan (beam footprint, and so partial-hit statistics, differ between
   scan positions), fit two Gaussians to the reflectance distribution of the
   vegetation echoes (EM, maximum likelihood on the samples themselves):
   leaves are darker than bark at 1550 nm.
2. Leaf/wood threshold midway between the two means (the paper's rule) or
   where the two weighted components have equal posterior probability
   (the Bayes rule for the fitted mixture).
3. Noise: echoes below ``noise_fraction`` (50 %) of the nominal leaf
   reflectance: mostly partial hits on leaf and branch edges (paper: 12.5 %
   for a 25 % leaf).
4. Echoes above 1 (0 dB) cannot come from a Lambertian surface: targets.
   The ground (a RANSAC plane through the lowest echoes) is set apart first,
   so that its reflectance does not enter the fit.
5. Optional geometric refinement: a leaf (or noise) echo whose k nearest
   neighbours are mostly wood and whose neighbourhood is linear (local PCA:
   ``(l1 - l2) / l1`` of the covariance eigenvalues, Demantké et al. 2011)
   becomes wood: the dark partial hits on branch edges that the paper fixed
   by hand.

:func:`score` compares labels with the truth materials of simulated scans:
confusion matrix, per-class precision and recall.

References
----------
Dempster, A. P., Laird, N. M., Rubin, D. B. (1977). Maximum likelihood from
    incomplete data via the EM algorithm. J. R. Stat. Soc. B 39(1), 1-38.
    doi:10.1111/j.2517-6161.1977.tb01600.x
Demantké, J., Mallet, C., David, N., Vallet, B. (2011). Dimensionality based
    scale selection in 3D lidar point clouds. ISPRS Arch. XXXVIII-5/W12,
    97-102. doi:10.5194/isprsarchives-XXXVIII-5-W12-97-2011
Kaasalainen, S., Jaakkola, A., Kaasalainen, M., Krooks, A., Kukko, A. (2011).
    Analysis of incidence angle and distance effects on terrestrial laser
    scanner intensity. Remote Sens. 3(10), 2207-2221. doi:10.3390/rs3102207
Rusu, R. B., Marton, Z. C., Blodow, N., Dolha, M., Beetz, M. (2008). Towards
    3D point cloud based object maps for household environments. Robot. Auton.
    Syst. 56(11), 927-941. doi:10.1016/j.robot.2008.08.005 (outlier removal)
Béland, M., Baldocchi, D. D., Widlowski, J.-L., Fournier, R. A., Verstraete,
    M. M. (2014). On seeing the wood from the leaves and the role of voxel
    size in determining leaf area distribution of forests with terrestrial
    LiDAR. Agric. For. Meteorol. 184, 82-97. doi:10.1016/j.agrformet.2013.09.005

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

import enum
from dataclasses import dataclass, field

import numpy as np

from .errors import InputError, parse_choice
from .io import check_scan
from .materials import DEFAULT_OPTICS, Material
from .reflectance import apparent_reflectance
from .scan import Scan

__all__ = [
    "Classification",
    "ClassifyMethod",
    "GaussianMixture2",
    "PointClass",
    "Score",
    "ThresholdRule",
    "classify_scan",
    "fit_two_gaussians",
    "incidence_cosine",
    "isolated",
    "leaf_wood_threshold",
    "linearity",
    "neighbourhood_mean",
    "refine_geometric",
    "score",
]


class PointClass(enum.IntEnum):
    """Class of an echo; values are the LAS ``classification`` codes written.

    Ground 2 and low noise 7 are ASPRS codes, leaf uses 5 (high vegetation),
    wood and target take user-definable codes (64, 65).
    """

    GROUND = 2
    LEAF = 5
    NOISE = 7
    WOOD = 64
    TARGET = 65


#: truth material -> the class a perfect classifier would give
TRUTH_CLASS = {
    Material.NONE: PointClass.NOISE,
    Material.LEAF: PointClass.LEAF,
    Material.BARK: PointClass.WOOD,
    Material.GROUND: PointClass.GROUND,
    Material.TARGET: PointClass.TARGET,
}


class ThresholdRule(enum.Enum):
    """Where the leaf/wood threshold goes between the two fitted Gaussians."""

    MIDWAY = "midway"  #: halfway between the two means (the paper)
    EQUAL_POSTERIOR = "equal_posterior"  #: where w1 N1 = w2 N2 (Bayes rule)

    @classmethod
    def parse(cls, value):
        return parse_choice(cls, value, "rule", "threshold rule")


class ClassifyMethod(enum.Enum):
    """How echoes are split into leaf, wood and noise (see the module docstring)."""

    NEIGHBOURHOOD = "neighbourhood"  #: neighbourhood-mean dB reflectance, geometric noise
    ECHO = "echo"  #: per-echo reflectance, geometric noise
    PAPER = "paper"  #: per-echo reflectance, noise below a fraction of the leaf reflectance

    @classmethod
    def parse(cls, value):
        return parse_choice(cls, value, "method", "classification method")


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
    rule = ThresholdRule.parse(rule)
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


def _covariances(xyz: np.ndarray, k: int) -> np.ndarray:
    import open3d as o3d

    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.ascontiguousarray(xyz, dtype=np.float64)))
    pc.estimate_covariances(o3d.geometry.KDTreeSearchParamKNN(knn=int(k)))
    return np.asarray(pc.covariances)


def linearity(xyz, *, k: int = 20) -> np.ndarray:
    """Local linearity ``(l1 - l2) / l1`` of every point's k-neighbourhood.

    Eigenvalues ``l1 >= l2 >= l3`` of the covariance of the ``k`` nearest
    neighbours (Open3D KD-tree).  1 on a line, ~0 on a plane or a blob.

    Parameters
    ----------
    xyz : (N, 3) float, metres
    k : int, default 20

    Returns
    -------
    (N,) float64 in [0, 1]

    References
    ----------
    Demantké et al. (2011), doi:10.5194/isprsarchives-XXXVIII-5-W12-97-2011
    """
    xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
    if len(xyz) < 3:
        raise InputError(f"linearity needs >= 3 points, got {len(xyz)}")
    ev = np.linalg.eigvalsh(_covariances(xyz, min(k, len(xyz))))  # ascending
    l1, l2 = ev[:, 2], ev[:, 1]
    return np.where(l1 > 0, (l1 - l2) / np.where(l1 > 0, l1, 1.0), 0.0)


def refine_geometric(xyz, labels, *, k: int = 20, min_linearity: float = 0.6,
                     min_wood_fraction: float = 0.5) -> tuple[np.ndarray, int]:
    """Move branch-edge echoes from leaf (or noise) to wood.

    An echo labelled leaf or noise becomes wood when, among its ``k``
    nearest neighbours, at least ``min_wood_fraction`` are wood and the
    neighbourhood's linearity is at least ``min_linearity`` (a branch).

    Parameters
    ----------
    xyz : (N, 3) float, metres
    labels : (N,) PointClass values
    k : int, default 20
    min_linearity : float, default 0.6
    min_wood_fraction : float, default 0.5
        A majority of wood neighbours.

    Returns
    -------
    labels : (N,) uint8, a new array
    moved : int
        How many echoes became wood.
    """
    from scipy.spatial import cKDTree

    xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
    labels = np.asarray(labels, dtype=np.uint8).copy()
    if len(labels) != len(xyz):
        raise InputError(f"labels has {len(labels)} values for {len(xyz)} points")
    veg = np.flatnonzero(np.isin(labels, [PointClass.LEAF, PointClass.WOOD, PointClass.NOISE]))
    if len(veg) <= k:
        return labels, 0
    pts = xyz[veg]
    lin = linearity(pts, k=k)
    _, nn = cKDTree(pts).query(pts, k=k + 1, workers=-1)
    wood = labels[veg] == PointClass.WOOD
    frac = wood[nn[:, 1:]].mean(axis=1)
    cand = (~wood) & (frac >= min_wood_fraction) & (lin >= min_linearity)
    labels[veg[cand]] = PointClass.WOOD
    return labels, int(cand.sum())


def incidence_cosine(xyz, *, k: int = 20, min_cos: float = 0.2) -> np.ndarray:
    """Estimated ``|cos|`` of the incidence angle of every echo, clamped below.

    The local surface normal is the smallest-eigenvalue direction of the
    covariance of the ``k`` nearest echoes (Open3D KD-tree normals); the beam
    direction is the echo's direction from the scanner (points in the scanner
    frame, scanner at the origin).

    Parameters
    ----------
    xyz : (N, 3) float, metres, scanner frame
    k : int, default 20
    min_cos : float, default 0.2
        Lower clamp (incidence 78 deg), so that a grazing estimate cannot
        multiply a reflectance by more than 5.

    Returns
    -------
    (N,) float64 in [min_cos, 1]

    References
    ----------
    Kaasalainen et al. (2011), doi:10.3390/rs3102207
    """
    import open3d as o3d

    xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
    if len(xyz) < 3:
        raise InputError(f"incidence_cosine needs >= 3 points, got {len(xyz)}")
    if not (0 < min_cos <= 1):
        raise InputError(f"min_cos={min_cos!r} must lie in (0, 1]")
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.ascontiguousarray(xyz)))
    pc.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(knn=int(min(k, len(xyz)))))
    n = np.asarray(pc.normals)
    r = np.linalg.norm(xyz, axis=1)
    d = xyz / np.where(r > 0, r, 1.0)[:, None]
    return np.clip(np.abs(np.einsum("ij,ij->i", n, d)), min_cos, 1.0)


def neighbourhood_mean(xyz, values, *, k: int = 10) -> np.ndarray:
    """Mean of ``values`` over every point and its ``k`` nearest neighbours.

    Parameters
    ----------
    xyz : (N, 3) float, metres
    values : (N,) float
    k : int, default 10

    Returns
    -------
    (N,) float64
    """
    from scipy.spatial import cKDTree

    xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
    values = np.asarray(values, dtype=np.float64).reshape(-1)
    if len(values) != len(xyz):
        raise InputError(f"values has {len(values)} entries for {len(xyz)} points")
    k = int(min(k, len(xyz) - 1))
    if k < 1:
        return values.copy()
    _, nn = cKDTree(xyz).query(xyz, k=k + 1, workers=-1)
    return values[nn].mean(axis=1)


def isolated(xyz, *, angular_step_deg: float | None = None, radius_cells: float = 10.0,
             min_neighbours: int = 1, min_radius_m: float = 0.01) -> np.ndarray:
    """Echoes with fewer than ``min_neighbours`` others within a range-scaled radius.

    A surface seen by a scanner with angular step ``a`` is sampled about every
    ``a * range`` metres, so the search radius of an echo at range ``r`` is
    ``radius_cells * a * r`` (at least ``min_radius_m``): the same number of
    grid cells at every range.  A real surface echo has neighbours in the
    cells around it; a lone echo in the air (a bird, dust, a ghost, a range
    outlier) has none.  This is radius outlier removal (Rusu et al. 2008)
    with the radius tied to the scan's own sampling.

    Parameters
    ----------
    xyz : (N, 3) float, metres, scanner frame (scanner at the origin)
    angular_step_deg : float, optional
        The scan's angular step; default: estimated as the median of
        nearest-neighbour distance / range.
    radius_cells : float, default 10
        Inside a crown most pulses are intercepted before they reach the
        deep leaves, so true echoes there are sparse: on the synthetic scans
        (0.06-0.12 deg steps) 5 cells with 2 neighbours calls 3-8 % of the
        true vegetation echoes isolated, 10 cells with 1 neighbour 0.05-0.1 %.
    min_neighbours : int, default 1
    min_radius_m : float, default 0.01

    Returns
    -------
    (N,) bool
        True where the echo is isolated (noise).

    References
    ----------
    Rusu et al. (2008), doi:10.1016/j.robot.2008.08.005
    """
    from scipy.spatial import cKDTree

    xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
    n = len(xyz)
    if n == 0:
        return np.zeros(0, bool)
    if n <= min_neighbours:
        return np.ones(n, bool)
    tree = cKDTree(xyz)
    r = np.linalg.norm(xyz, axis=1)
    if angular_step_deg is None:
        dist, _ = tree.query(xyz, k=2, workers=-1)
        step = float(np.median(dist[:, 1] / np.maximum(r, 1e-9)))
    else:
        if not (np.isfinite(angular_step_deg) and angular_step_deg > 0):
            raise InputError(f"angular_step_deg={angular_step_deg!r} must be a positive angle in degrees")
        step = np.deg2rad(angular_step_deg)
    radius = np.maximum(radius_cells * step * r, min_radius_m)
    count = tree.query_ball_point(xyz, radius, return_length=True, workers=-1) - 1
    return count < min_neighbours


def _ground_mask(xyz: np.ndarray, *, band_m: float, tolerance_m: float, max_tilt_deg: float) -> np.ndarray:
    """Echoes within ``tolerance_m`` of a RANSAC plane fitted to the lowest band."""
    import open3d as o3d

    z0 = np.percentile(xyz[:, 2], 1.0)
    low = np.flatnonzero(xyz[:, 2] < z0 + band_m)
    mask = np.zeros(len(xyz), bool)
    if len(low) < 50:
        return mask
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(xyz[low]))
    o3d.utility.random.seed(0)
    plane, _ = pc.segment_plane(distance_threshold=tolerance_m, ransac_n=3, num_iterations=1000)
    n = np.asarray(plane[:3]) / np.linalg.norm(plane[:3])
    if np.degrees(np.arccos(min(1.0, abs(n[2])))) > max_tilt_deg:
        return mask
    d = np.abs(xyz @ np.asarray(plane[:3]) + plane[3]) / np.linalg.norm(plane[:3])
    return d < tolerance_m


@dataclass
class Classification:
    """Labels of one scan and how they were decided.

    Attributes
    ----------
    labels : (N,) uint8
        :class:`PointClass` of every echo.
    reflectance : (N,) float64
        Apparent reflectance of every echo (linear, before any correction).
    feature : (N,) float64
        The value the leaf/wood threshold splits (NaN where not fitted:
        ground, target, noise): linear reflectance (``paper``, ``echo``,
        divided by the incidence cosine with ``incidence_correction``) or
        neighbourhood-mean reflectance in dB (``neighbourhood``).
    feature_label : str
        What ``feature`` is, with its unit.
    mixture : GaussianMixture2
        Two-Gaussian fit to ``feature`` of the vegetation echoes.
    leaf_wood_threshold : float
        In the unit of ``feature``.
    noise_threshold : float
        Linear reflectance below which an echo is noise (``paper``); NaN for
        the geometric noise rule.
    target_threshold : float
        Linear reflectance above which an echo is a target.
    method, rule : str
    moved_to_wood : int
        Echoes the geometric refinement moved (0 without it).
    """

    scan_name: str
    labels: np.ndarray
    reflectance: np.ndarray
    mixture: GaussianMixture2
    leaf_wood_threshold: float
    noise_threshold: float
    target_threshold: float
    rule: str
    refined: bool = False
    moved_to_wood: int = 0
    counts: dict = field(default_factory=dict)
    method: str = ClassifyMethod.PAPER.value
    feature: np.ndarray | None = None
    feature_label: str = "apparent reflectance"
    incidence_correction: bool = False
    fit_single_returns: bool = False

    def summary(self) -> dict:
        m = self.mixture
        nt = self.noise_threshold
        return {"scan": self.scan_name, "method": self.method, "rule": self.rule,
                "incidence_correction": self.incidence_correction,
                "fit_single_returns": self.fit_single_returns, "feature": self.feature_label,
                "leaf_wood_threshold": self.leaf_wood_threshold,
                "noise_threshold": float(nt) if np.isfinite(nt) else None,
                "target_threshold": self.target_threshold,
                "means": m.means.tolist(), "sigmas": m.sigmas.tolist(), "weights": m.weights.tolist(),
                "refined": self.refined, "moved_to_wood": self.moved_to_wood, "counts": self.counts}


def _scan_step_deg(scan: Scan) -> float | None:
    grid = getattr(getattr(scan, "pulses", None), "grid", None)
    if grid is None:
        return None
    return float(min(grid.zenith_step_deg, grid.azimuth_step_deg))


def classify_scan(scan: Scan, *, method: "str | ClassifyMethod" = ClassifyMethod.NEIGHBOURHOOD,
                  rule: "str | ThresholdRule" = ThresholdRule.MIDWAY,
                  incidence_correction: bool = False, fit_single_returns: bool = True,
                  smooth_k: int = 10, normal_k: int = 20,
                  min_cos: float = 0.2, noise_radius_cells: float = 10.0, noise_min_neighbours: int = 1,
                  nominal_leaf_reflectance: float | None = None, noise_fraction: float = 0.5,
                  target_threshold: float = 1.0, ground: bool = True, ground_band_m: float = 0.5,
                  ground_tolerance_m: float = 0.05, refine: bool = False, refine_k: int = 20,
                  min_linearity: float = 0.6, min_wood_fraction: float = 0.5,
                  wavelength_nm: float = 1550.0, **reflectance_kwargs) -> Classification:
    """Classify every echo of one scan as leaf, wood, noise, ground or target.

    Parameters
    ----------
    scan : Scan
        Needs reflectance (dB) or intensity (then pass ``calibration=``, see
        :func:`tlsvox.reflectance.apparent_reflectance`).  Points in the
        scanner frame (scanner at the origin, z up).
    method : {'neighbourhood', 'echo', 'paper'}
        See :class:`ClassifyMethod` and the module docstring.
    rule : {'midway', 'equal_posterior'}
        Leaf/wood threshold rule.
    incidence_correction : bool, default False
        Divide each echo's reflectance by its estimated incidence cosine
        (:func:`incidence_cosine`, ``normal_k`` neighbours, clamped at
        ``min_cos``) before the fit.  Off by default: with normals estimated
        from the cloud it lowers the scores on the synthetic truth
        (docs/classify_register.md).
    fit_single_returns : bool, default True
        ``neighbourhood`` and ``echo``: fit the two Gaussians to the echoes of
        single-echo pulses only (when there are at least 10), then threshold
        every echo.  An echo of a multi-echo pulse carries only part of the
        beam, so its reflectance is lowered by an unknown fraction; full hits
        show the material.  Ignored without return counts.
    smooth_k : int, default 10
        Neighbours averaged by the ``neighbourhood`` method.
    noise_radius_cells, noise_min_neighbours
        Geometric noise rule (``neighbourhood`` and ``echo``), see :func:`isolated`.
    nominal_leaf_reflectance : float, optional
        ``paper`` only.  Defaults to the leaf reflectance of
        :data:`tlsvox.materials.DEFAULT_OPTICS` at ``wavelength_nm`` (0.267 at 1550 nm).
    noise_fraction : float, default 0.5
        ``paper`` only: noise below ``noise_fraction * nominal_leaf_reflectance``.
    target_threshold : float, default 1.0
        Above this (0 dB) an echo is a retro-reflective target.
    ground : bool, default True
        Set apart the ground plane (scanner z taken as up).
    ground_band_m, ground_tolerance_m : float, metres
        The plane is fitted to echoes within ``ground_band_m`` of the lowest
        and takes echoes within ``ground_tolerance_m`` of it.
    refine : bool, default False
        Apply :func:`refine_geometric`.
    refine_k, min_linearity, min_wood_fraction
        See :func:`refine_geometric`.

    Returns
    -------
    Classification

    References
    ----------
    Béland et al. (2014), doi:10.1016/j.agrformet.2013.09.005
    Kaasalainen et al. (2011), doi:10.3390/rs3102207
    """
    method = ClassifyMethod.parse(method)
    rule = ThresholdRule.parse(rule)
    check_scan(scan, min_points=30, require_reflectance=True)
    if method is ClassifyMethod.PAPER:
        if nominal_leaf_reflectance is None:
            key = int(round(wavelength_nm))
            if key not in DEFAULT_OPTICS:
                raise InputError(f"wavelength_nm={wavelength_nm!r}: no default leaf reflectance; "
                                 f"pass nominal_leaf_reflectance= (tabulated: {sorted(DEFAULT_OPTICS)} nm)")
            nominal_leaf_reflectance = DEFAULT_OPTICS[key][Material.LEAF].reflectance
        if not (0 < noise_fraction < 1):
            raise InputError(f"noise_fraction={noise_fraction!r} must lie in (0, 1)")
    for name, v in (("smooth_k", smooth_k), ("normal_k", normal_k)):
        if int(v) < 1:
            raise InputError(f"{name}={v!r} must be an integer >= 1")
    rho = apparent_reflectance(scan, **reflectance_kwargs)
    rho = np.where(np.isfinite(rho), rho, 0.0)
    labels = np.full(len(scan), PointClass.NOISE, np.uint8)
    is_ground = (_ground_mask(scan.xyz, band_m=ground_band_m, tolerance_m=ground_tolerance_m,
                              max_tilt_deg=15.0) if ground else np.zeros(len(scan), bool))
    is_target = rho > target_threshold
    candidate = (~is_ground) & (~is_target)
    if method is ClassifyMethod.PAPER:
        noise_t = noise_fraction * nominal_leaf_reflectance
        veg = candidate & (rho >= noise_t)
        why = f"between the noise threshold {noise_t:.3f} and {target_threshold}"
    else:
        noise_t = float("nan")
        veg = candidate & (rho > 0)
        if np.count_nonzero(veg):
            idx = np.flatnonzero(veg)
            lone = isolated(scan.xyz[idx], angular_step_deg=_scan_step_deg(scan),
                            radius_cells=noise_radius_cells, min_neighbours=noise_min_neighbours)
            veg[idx[lone]] = False
        why = f"above 0 and below {target_threshold} with neighbours (not isolated)"
    if np.count_nonzero(veg) < 10:
        raise InputError(
            f"scan {scan.name!r}: only {int(np.count_nonzero(veg))} echoes lie {why}; check the "
            "reflectance units (linear 0-1 expected; pass calibration= for raw intensity)")
    idx = np.flatnonzero(veg)
    value = rho[idx]
    if incidence_correction:
        value = value / incidence_cosine(scan.xyz[idx], k=normal_k, min_cos=min_cos)
    if method is ClassifyMethod.NEIGHBOURHOOD:
        value = neighbourhood_mean(scan.xyz[idx], 10.0 * np.log10(value), k=smooth_k)
        label = f"mean reflectance of {smooth_k + 1} neighbours, dB"
    else:
        label = "apparent reflectance"
    if incidence_correction:
        label += " / cos(incidence)"
    fit = np.ones(len(idx), bool)
    if (fit_single_returns and method is not ClassifyMethod.PAPER
            and getattr(scan, "number_of_returns", None) is not None):
        single = np.asarray(scan.number_of_returns)[idx] == 1
        if np.count_nonzero(single) >= 10:
            fit = single
    mix = fit_two_gaussians(value[fit])
    t = leaf_wood_threshold(mix, rule=rule)
    feature = np.full(len(scan), np.nan)
    feature[idx] = value
    labels[idx] = np.where(value < t, PointClass.LEAF, PointClass.WOOD)
    labels[is_target & ~is_ground] = PointClass.TARGET
    labels[is_ground] = PointClass.GROUND
    moved = 0
    if refine:
        labels, moved = refine_geometric(scan.xyz, labels, k=refine_k, min_linearity=min_linearity,
                                         min_wood_fraction=min_wood_fraction)
    counts = {c.name.lower(): int(np.count_nonzero(labels == c)) for c in PointClass}
    return Classification(scan.name, labels, rho, mix, t, noise_t, target_threshold, rule.value,
                          refine, moved, counts, method=method.value, feature=feature, feature_label=label,
                          incidence_correction=bool(incidence_correction),
                          fit_single_returns=bool(fit.sum() < len(fit)))


@dataclass
class Score:
    """Labels against truth.

    Attributes
    ----------
    classes : list of PointClass
        Row/column order of the matrix.
    confusion : (C, C) int
        ``confusion[i, j]``: echoes of true class ``classes[i]`` labelled ``classes[j]``.
    precision, recall : dict name -> float (NaN where undefined)
    """

    classes: list
    confusion: np.ndarray
    precision: dict
    recall: dict

    def table(self) -> str:
        """Markdown table of the confusion matrix with precision and recall."""
        names = [c.name.lower() for c in self.classes]
        head = "| truth \\ label | " + " | ".join(names) + " | recall |"
        lines = [head, "|" + "---|" * (len(names) + 2)]
        for i, n in enumerate(names):
            row = " | ".join(str(int(v)) for v in self.confusion[i])
            lines.append(f"| {n} | {row} | {self.recall[n]:.3f} |")
        lines.append("| precision | " + " | ".join(f"{self.precision[n]:.3f}" for n in names) + " | |")
        return "\n".join(lines)

    def to_dict(self) -> dict:
        return {"classes": [c.name.lower() for c in self.classes], "confusion": self.confusion.tolist(),
                "precision": self.precision, "recall": self.recall}


def score(labels, truth_material) -> Score:
    """Confusion matrix, precision and recall of labels against truth materials.

    Parameters
    ----------
    labels : (N,) PointClass values
    truth_material : (N,) :class:`tlsvox.materials.Material` ids

    Returns
    -------
    Score
    """
    labels = np.asarray(labels).reshape(-1)
    truth = np.asarray(truth_material).reshape(-1)
    if labels.shape != truth.shape:
        raise InputError(f"labels {labels.shape} and truth_material {truth.shape} must have the same length")
    classes = list(PointClass)
    index = {int(c): i for i, c in enumerate(classes)}
    lut = np.full(256, index[PointClass.NOISE], np.int64)
    for mat, cls in TRUTH_CLASS.items():
        lut[int(mat)] = index[int(cls)]
    t_idx = lut[truth.astype(np.int64)]
    l_idx = np.array([index.get(int(v), -1) for v in np.unique(labels)])
    if np.any(l_idx < 0):
        raise InputError(f"labels hold values that are not PointClass codes: {np.unique(labels).tolist()}")
    llut = np.zeros(256, np.int64)
    for c in classes:
        llut[int(c)] = index[int(c)]
    p_idx = llut[labels.astype(np.int64)]
    C = len(classes)
    conf = np.bincount(t_idx * C + p_idx, minlength=C * C).reshape(C, C)
    prec, rec = {}, {}
    for i, c in enumerate(classes):
        col, row = conf[:, i].sum(), conf[i].sum()
        prec[c.name.lower()] = float(conf[i, i] / col) if col else float("nan")
        rec[c.name.lower()] = float(conf[i, i] / row) if row else float("nan")
    return Score(classes, conf, prec, rec)
