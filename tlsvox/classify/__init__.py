"""Leaf / wood / noise classification of a scan from its apparent reflectance.

Three methods (:class:`ClassifyMethod`); docs/classify_register.md compares
them against the truth labels of simulated scans.

``neighbourhood`` (default)
    The echo's feature is the mean reflectance in dB over itself and its
    ``smooth_k`` nearest vegetation echoes.  The apparent reflectance of one
    echo is ``R_material * cos(incidence) * hit_fraction``: two nuisance
    factors that multiply, so they add in dB, and averaging over a
    neighbourhood of one surface (a leaf cluster, a branch) shrinks their
    spread while the material term stays.  Gaussians are fitted to the
    averaged dB values and split by the threshold rule.  Noise is geometric
    (:func:`isolated`): an echo with too few neighbours within a few scan
    grid spacings; dark echoes are partial hits, not noise.  The Gaussians
    are fitted to the echoes of single-echo pulses (full hits).
``echo``
    The same per-echo: Gaussians on the echo's own reflectance, geometric
    noise; optionally divided by an estimated ``cos(incidence)``
    (``incidence_correction=True``, :func:`incidence_cosine`).
``paper``
    The paper's method (Kim et al. 2015, §3.3), made automatic:

1. Per scan (beam footprint, and so partial-hit statistics, differ between
   scan positions), fit two Gaussians to the reflectance distribution of the
   vegetation echoes (EM, maximum likelihood on the samples themselves):
   leaves are darker than bark at 1550 nm.  By default (``components='bic'``,
   every method) three are fitted too and the Bayesian information criterion
   keeps the better: the brightest Gaussian is the wood, the others together
   the leaves, whose mode is skewed (``_mixture``).
2. Leaf/wood threshold midway between the leaf and wood means (the paper's
   rule) or where the weighted leaf and wood densities are equal (the Bayes
   rule for the fitted mixture).
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

Modules: ``_classes`` (the labels), ``_mixture`` (the Gaussians and the
threshold), ``_geometry`` (geometric features), ``_classify`` (the methods),
``_score`` (against truth), ``plots`` (the pictures).
"""

from tlsvox.classify._classes import TRUTH_CLASS, PointClass
from tlsvox.classify._classify import Classification, ClassifyMethod, classify_scan
from tlsvox.classify._geometry import (
                                      incidence_cosine,
                                      isolated,
                                      linearity,
                                      neighbourhood_mean,
                                      refine_geometric,
                                      wood_score,
)
from tlsvox.classify._mixture import (
                                      GaussianMixture,
                                      GaussianMixture2,
                                      ThresholdRule,
                                      fit_gaussians,
                                      fit_two_gaussians,
                                      leaf_wood_threshold,
)
from tlsvox.classify._score import Score, score
from tlsvox.classify.settings import ClassifySettings

__all__ = [
    "Classification",
    "ClassifyMethod",
    "ClassifySettings",
    "GaussianMixture",
    "GaussianMixture2",
    "PointClass",
    "Score",
    "TRUTH_CLASS",
    "ThresholdRule",
    "classify_scan",
    "fit_gaussians",
    "fit_two_gaussians",
    "incidence_cosine",
    "isolated",
    "leaf_wood_threshold",
    "linearity",
    "neighbourhood_mean",
    "refine_geometric",
    "wood_score",
    "score",
]
