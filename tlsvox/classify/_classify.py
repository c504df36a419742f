"""Classifying a scan: leaf, wood, ground, noise (the three methods of :class:`ClassifyMethod`).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from tlsvox.classify._classes import PointClass
from tlsvox.classify._geometry import (
    ground_band_mask,
    incidence_cosine,
    isolated,
    neighbourhood_mean,
    refine_geometric,
    wood_score,
)
from tlsvox.classify._mixture import (
    GaussianMixture,
    ThresholdRule,
    fit_gaussians,
    leaf_wood_threshold,
    parse_components,
)
from tlsvox.classify.settings import ClassifySettings
from tlsvox.errors import InputError
from tlsvox.readers import check_scan
from tlsvox.reflectance import apparent_reflectance
from tlsvox.scan import Scan
from voxlidar.choices import Choice
from voxlidar.materials import DEFAULT_OPTICS, Material


class ClassifyMethod(Choice):
    """How echoes are split into leaf, wood and noise (see the module docstring)."""

    NEIGHBOURHOOD = "neighbourhood"  #: neighbourhood-mean dB reflectance, geometric noise
    ECHO = "echo"  #: per-echo reflectance, geometric noise
    PAPER = "paper"  #: per-echo reflectance, noise below a fraction of the leaf reflectance
    GEOMETRIC = "geometric"  #: no reflectance: the neighbourhood's shape (wood_score), geometric noise


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
    mixture : GaussianMixture
        Gaussians fitted to ``feature`` of the vegetation echoes (two or
        three, see ``components`` of :func:`classify_scan`); the brightest is
        the wood, the others the leaves.
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
    on_cylinders : int
        Leaf-classed echoes relabelled wood because they lie on the bark of a
        cylinder fitted to the wood echoes (:func:`tlsvox.voxel.wood.qsm.bark_echoes`;
        :func:`tlsvox.pipeline.scene_from_scans` does it; 0 otherwise).
    settings : dict
        The run's :class:`~tlsvox.classify.settings.ClassifySettings`, as
        ``to_dict`` gives them (``ClassifySettings.from_dict`` repeats it).
    """

    scan_name: str
    labels: np.ndarray
    reflectance: np.ndarray
    mixture: GaussianMixture
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
    on_cylinders: int = 0
    settings: dict = field(default_factory=dict)

    def with_bark(self, bark) -> Classification:
        """A copy with the echoes of ``bark`` ((N,) bool: leaf echoes on a fitted cylinder's bark,
        :func:`tlsvox.voxel.wood.qsm.bark_echoes`) labelled wood, its counts and ``on_cylinders`` updated."""
        bark = np.asarray(bark, bool)
        labels = np.where(bark, np.uint8(PointClass.WOOD), self.labels).astype(self.labels.dtype)
        return dataclasses.replace(self, labels=labels, counts=class_counts(labels),
                                   on_cylinders=self.on_cylinders + int(bark.sum()))

    def summary(self) -> dict:
        m = self.mixture
        nt = self.noise_threshold
        return {"scan": self.scan_name, "method": self.method, "rule": self.rule,
                "incidence_correction": self.incidence_correction,
                "fit_single_returns": self.fit_single_returns, "feature": self.feature_label,
                "leaf_wood_threshold": self.leaf_wood_threshold,
                "noise_threshold": float(nt) if np.isfinite(nt) else None,
                "target_threshold": self.target_threshold,
                "components": m.n_components, "means": m.means.tolist(), "sigmas": m.sigmas.tolist(),
                "weights": m.weights.tolist(),
                "refined": self.refined, "moved_to_wood": self.moved_to_wood, "on_cylinders": self.on_cylinders,
                "counts": self.counts, "settings": self.settings}


def class_counts(labels) -> dict:
    """Echoes per :class:`PointClass`, by lower-case name."""
    return {c.name.lower(): int(np.count_nonzero(labels == c)) for c in PointClass}


def _scan_step_deg(scan: Scan) -> float | None:
    grid = getattr(getattr(scan, "pulses", None), "grid", None)
    if grid is None:
        return None
    return float(min(grid.zenith_step_deg, grid.azimuth_step_deg))


def classify_scan(scan: Scan, settings: ClassifySettings | None = None, *, calibration=None,
                  **kwargs) -> Classification:
    """Classify every echo of one scan as leaf, wood, noise, ground or target.

    Its settings come from ``settings``
    (:class:`~tlsvox.classify.settings.ClassifySettings`, in five groups),
    any of whose fields a keyword argument replaces (``classify_scan(scan,
    refine=True)``); ``Classification.settings`` records them in full.

    Parameters
    ----------
    scan : Scan
        Needs reflectance (dB) or intensity (then pass ``calibration=``, see
        :func:`tlsvox.reflectance.apparent_reflectance`).  Points in the
        scanner frame (scanner at the origin, z up).
    settings : ClassifySettings, optional
        Every setting below, grouped (default: the defaults).
    calibration : CalibrationTable, optional
        Raw intensity to reflectance (:func:`tlsvox.reflectance.apparent_reflectance`).
    method : {'neighbourhood', 'echo', 'paper'}
        See :class:`ClassifyMethod` and the module docstring.
    rule : {'midway', 'equal_posterior'}
        Leaf/wood threshold rule, between the wood Gaussian (the brightest)
        and the leaf Gaussians (the others, pooled).
    components : int >= 2 or 'bic', default 'bic'
        Gaussians fitted (:func:`fit_gaussians`).  ``'bic'`` fits two and
        three and keeps the one the Bayesian information criterion prefers:
        on a scan, three, so that the leaves' skewed mode cannot take the
        wood's place (docs/classify_register.md, *Two or three Gaussians*).
        ``2`` is the paper's fit.
    incidence_correction : bool, default False
        Divide each echo's reflectance by its estimated incidence cosine
        (:func:`incidence_cosine`, ``normal_k`` neighbours, clamped at
        ``min_cos``) before the fit.  Off by default: with normals estimated
        from the cloud it lowers the scores on the synthetic truth
        (docs/classify_register.md).
    fit_single_returns : bool, default True
        ``neighbourhood`` and ``echo``: fit the Gaussians to the echoes of
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
        :data:`voxlidar.materials.DEFAULT_OPTICS` at ``wavelength_nm`` (0.267 at 1550 nm).
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
    source, reference_range_m, allow_relative
        See :func:`tlsvox.reflectance.apparent_reflectance`. Raw intensity
        without a calibration table (``allow_relative=True``; CLI
        ``--intensity relative``) is range-normalised and divided by the
        scan's median: the leaf/wood split does not depend on the scale, the
        paper's absolute noise threshold is refused, and targets are the
        echoes ``relative_target_factor`` (10) times the median or brighter.

    Returns
    -------
    Classification

    References
    ----------
    Béland et al. (2014), doi:10.1016/j.agrformet.2013.09.005
    Kaasalainen et al. (2011), doi:10.3390/rs3102207
    """
    st = ClassifySettings.from_kwargs(settings, **kwargs)
    mx, rf, nz, gr, rn = st.mixture, st.reflectance, st.noise, st.ground, st.refine
    method = ClassifyMethod.parse(mx.method, "method")
    rule = ThresholdRule.parse(mx.rule, "rule")
    components = parse_components(mx.components)
    nominal_leaf_reflectance, noise_fraction, wavelength_nm = (nz.nominal_leaf_reflectance, nz.noise_fraction,
                                                               rf.wavelength_nm)
    smooth_k, normal_k, target_threshold = mx.smooth_k, rf.normal_k, rf.target_threshold
    geometric = method is ClassifyMethod.GEOMETRIC
    check_scan(scan, min_points=30, require_reflectance=not geometric)
    if method is ClassifyMethod.PAPER:
        nominal_leaf_reflectance = _leaf_reflectance(nominal_leaf_reflectance, wavelength_nm)
        if not (0 < noise_fraction < 1):
            raise InputError(f"noise_fraction={noise_fraction!r} must lie in (0, 1)")
    for name, v in (("smooth_k", smooth_k), ("normal_k", normal_k)):
        if int(v) < 1:
            raise InputError(f"{name}={v!r} must be an integer >= 1")
    calibrated = calibration is not None or (scan.reflectance_db is not None
                                             and bool(np.any(np.isfinite(scan.reflectance_db))))
    if geometric and not calibrated:
        rho = np.full(len(scan), np.nan)  # no absolute reflectance: no target told apart by its brightness
    else:
        rho = apparent_reflectance(scan, source=rf.source, calibration=calibration,
                                   reference_range_m=rf.reference_range_m, allow_relative=rf.allow_relative)
    rho = np.where(np.isfinite(rho), rho, 0.0)
    relative = _is_relative(scan, rf.source, calibration) and not geometric
    if relative:  # raw intensity, range-normalised: no absolute scale, so no paper rule; targets by their ratio
        if method is ClassifyMethod.PAPER:
            raise InputError(f"scan {scan.name!r}: the paper's noise threshold needs absolute reflectance, and "
                             "this scan has raw intensity only; use method 'neighbourhood' or 'echo' (the leaf/wood "
                             "split does not depend on the scale), or a calibration table")
        rho, scale_note = _scale_relative(rho, rf.relative_target_factor)
        target_threshold = float(rf.relative_target_factor)
    labels = np.full(len(scan), PointClass.NOISE, np.uint8)
    is_ground = (ground_band_mask(scan.xyz, band_m=gr.ground_band_m, tolerance_m=gr.ground_tolerance_m,
                              max_tilt_deg=15.0) if gr.ground else np.zeros(len(scan), bool))
    is_target = rho > target_threshold
    candidate = (~is_ground) & (~is_target)
    if method is ClassifyMethod.PAPER:
        noise_t = noise_fraction * nominal_leaf_reflectance
        veg = candidate & (rho >= noise_t)
        why = f"between the noise threshold {noise_t:.3f} and {target_threshold}"
    else:
        noise_t = float("nan")
        veg = candidate & ((rho > 0) | geometric)
        if np.count_nonzero(veg):
            idx = np.flatnonzero(veg)
            lone = isolated(scan.xyz[idx], angular_step_deg=_scan_step_deg(scan),
                            radius_cells=nz.noise_radius_cells, min_neighbours=nz.noise_min_neighbours)
            veg[idx[lone]] = False
        why = f"above 0 and below {target_threshold} with neighbours (not isolated)"
    if np.count_nonzero(veg) < 10:
        raise InputError(
            f"scan {scan.name!r}: only {int(np.count_nonzero(veg))} echoes lie {why}; check the "
            "reflectance units (linear 0-1 expected; pass calibration= for raw intensity)")
    idx = np.flatnonzero(veg)
    value = rho[idx]
    if rf.incidence_correction and not geometric:
        value = value / incidence_cosine(scan.xyz[idx], k=normal_k, min_cos=rf.min_cos)
    if geometric:
        value = wood_score(scan.xyz[idx], radius_m=mx.geometry_radius_m, max_nn=mx.geometry_max_nn)
        label = (f"geometric wood score: linearity + planarity x verticality within {mx.geometry_radius_m:g} m "
                 "(no reflectance)")
    elif method is ClassifyMethod.NEIGHBOURHOOD:
        value = neighbourhood_mean(scan.xyz[idx], 10.0 * np.log10(value), k=smooth_k)
        label = f"mean reflectance of {smooth_k + 1} neighbours, dB"
    else:
        label = "apparent reflectance"
    if rf.incidence_correction and not geometric:
        label += " / cos(incidence)"
    if relative:
        label += f" ({scale_note})"
    fit = np.ones(len(idx), bool)
    if (mx.fit_single_returns and method not in (ClassifyMethod.PAPER, ClassifyMethod.GEOMETRIC)
            and getattr(scan, "number_of_returns", None) is not None):
        single = np.asarray(scan.number_of_returns)[idx] == 1
        if np.count_nonzero(single) >= 10:
            fit = single
    mix = fit_gaussians(value[fit], components=components)
    t = leaf_wood_threshold(mix, rule=rule)
    feature = np.full(len(scan), np.nan)
    feature[idx] = value
    labels[idx] = np.where(value < t, PointClass.LEAF, PointClass.WOOD)
    labels[is_target & ~is_ground] = PointClass.TARGET
    labels[is_ground] = PointClass.GROUND
    moved = 0
    if rn.refine:
        labels, moved = refine_geometric(scan.xyz, labels, k=rn.refine_k, min_linearity=rn.min_linearity,
                                         min_wood_fraction=rn.min_wood_fraction)
    return Classification(scan.name, labels, rho, mix, t, noise_t, target_threshold, rule.value,
                          rn.refine, moved, class_counts(labels), method=method.value, feature=feature,
                          feature_label=label,
                          incidence_correction=bool(rf.incidence_correction),
                          fit_single_returns=bool(fit.sum() < len(fit)), settings=st.to_dict())


def _leaf_reflectance(nominal, wavelength_nm) -> float:
    """The given nominal leaf reflectance, else the default optics' at ``wavelength_nm``."""
    if nominal is not None:
        return float(nominal)
    key = int(round(wavelength_nm))
    if key not in DEFAULT_OPTICS:
        raise InputError(f"wavelength_nm={wavelength_nm!r}: no default leaf reflectance; "
                         f"pass nominal_leaf_reflectance= (tabulated: {sorted(DEFAULT_OPTICS)} nm)")
    return float(DEFAULT_OPTICS[key][Material.LEAF].reflectance)


def _is_relative(scan: Scan, source, calibration) -> bool:
    """True when the reflectance is range-normalised raw intensity (no dB, no calibration table)."""
    if calibration is not None:
        return False
    has_db = scan.reflectance_db is not None and bool(np.any(np.isfinite(scan.reflectance_db)))
    return str(source).lower() == "intensity" or not has_db


def _scale_relative(rho, factor) -> tuple[np.ndarray, str]:
    """Relative values divided by the scan's median (of the echoes above 0). The leaf/wood split (a Gaussian
    mixture in dB, its threshold between the modes) does not depend on the scale. A target is an echo
    ``factor`` times the median or brighter: no Lambertian surface is brighter than reflectance 1, and the
    median vegetation echo's apparent reflectance is about 0.1 (measured: -9.9 dB on the synthetic oak's
    scan, leaves 0.27 seen in part and obliquely), so 10 times it is where Lambertian echoes end. The
    paper's noise threshold, absolute, is refused."""
    pos = rho[rho > 0]
    med = float(np.median(pos)) if pos.size else 1.0
    return rho / med, (f"relative intensity: range-normalised, divided by the scan's median; targets {factor:g} "
                       "times the median or brighter")
