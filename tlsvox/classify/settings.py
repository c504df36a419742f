"""The settings of :func:`~tlsvox.classify.classify_scan`, in five groups, and their TOML file.

===============  =================================================================  ==========================
group            fields                                                             the step that reads it
===============  =================================================================  ==========================
``mixture``      method, rule, components, fit_single_returns, smooth_k             the Gaussian fit and the
                                                                                    leaf/wood threshold
``reflectance``  source, reference_range_m, allow_relative, wavelength_nm,          each echo's reflectance
                 incidence_correction, normal_k, min_cos, target_threshold,
                 relative_target_factor
``noise``        noise_radius_cells, noise_min_neighbours,                          the noise echoes
                 nominal_leaf_reflectance, noise_fraction
``ground``       ground, ground_band_m, ground_tolerance_m                          the ground plane
``refine``       refine, refine_k, min_linearity, min_wood_fraction                 the geometric refinement
===============  =================================================================  ==========================

A calibration table (``calibration=``) is not a setting but data: it is
passed beside them. ``Classification.settings`` records them in full.

Examples
--------
>>> s = ClassifySettings.from_kwargs(method="echo", refine=True)
>>> s.mixture.method, s.refine.refine, s.ground.ground_band_m
('echo', True, 0.5)
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar

from tlsvox.grouped import GroupedSettings

__all__ = ["ClassifySettings", "GroundBandSettings", "MixtureSettings", "NoiseSettings", "ReflectanceSettings",
           "RefineSettings"]


@dataclass(frozen=True)
class MixtureSettings:
    """The Gaussian mixture of the reflectances and the leaf/wood threshold between its modes."""

    method: str = "neighbourhood"  #: "neighbourhood", "echo", "paper" or "geometric"
    rule: str = "midway"  #: "midway" or "equal_posterior"
    components: int | str = "bic"  #: Gaussians fitted, or "bic"
    fit_single_returns: bool = True  #: fit to single-echo pulses' echoes
    smooth_k: int = 10  #: neighbours averaged by "neighbourhood"
    geometry_radius_m: float = 0.3  #: "geometric": the neighbourhood of the wood score, metres
    geometry_max_nn: int = 300  #: "geometric": at most this many neighbours


@dataclass(frozen=True)
class ReflectanceSettings:
    """Each echo's apparent reflectance (:func:`tlsvox.reflectance.apparent_reflectance`)."""

    source: str = "auto"  #: "auto", "db" or "intensity"
    reference_range_m: float | None = None  #: range of the intensity's reference
    allow_relative: bool = False  #: raw intensity without a calibration, relative
    wavelength_nm: float = 1550.0  #: for the default leaf reflectance
    incidence_correction: bool = False  #: divide by the estimated incidence cosine
    normal_k: int = 20  #: neighbours of the normal estimate
    min_cos: float = 0.2  #: the incidence cosine's floor
    target_threshold: float = 1.0  #: linear reflectance above which an echo is a target
    relative_target_factor: float = 10.0  #: relative intensity: targets this many times the scan's median


@dataclass(frozen=True)
class NoiseSettings:
    """Which echoes are noise."""

    noise_radius_cells: float = 10.0  #: geometric rule: neighbourhood radius, angular cells
    noise_min_neighbours: int = 1  #: geometric rule: neighbours a kept echo needs
    nominal_leaf_reflectance: float | None = None  #: "paper": default the optics at the wavelength
    noise_fraction: float = 0.5  #: "paper": noise below this share of the leaf reflectance


@dataclass(frozen=True)
class GroundBandSettings:
    """The ground plane set apart before the fit."""

    ground: bool = True  #: set the ground apart (scanner z up)
    ground_band_m: float = 0.5  #: the plane is fitted to echoes this near the lowest
    ground_tolerance_m: float = 0.05  #: and takes echoes this near it


@dataclass(frozen=True)
class RefineSettings:
    """The geometric refinement (:func:`tlsvox.classify.refine_geometric`)."""

    refine: bool = False
    refine_k: int = 20
    min_linearity: float = 0.6
    min_wood_fraction: float = 0.5


@dataclass(frozen=True)
class ClassifySettings(GroupedSettings):
    """Every setting of a :func:`~tlsvox.classify.classify_scan` run, in five groups (module docstring)."""

    GROUPS: ClassVar[dict[str, type]] = {"mixture": MixtureSettings, "reflectance": ReflectanceSettings,
                                         "noise": NoiseSettings, "ground": GroundBandSettings,
                                         "refine": RefineSettings}
    NULLABLE: ClassVar[tuple[str, ...]] = ()
    LABEL: ClassVar[str] = "classify"

    mixture: MixtureSettings = field(default_factory=MixtureSettings)
    reflectance: ReflectanceSettings = field(default_factory=ReflectanceSettings)
    noise: NoiseSettings = field(default_factory=NoiseSettings)
    ground: GroundBandSettings = field(default_factory=GroundBandSettings)
    refine: RefineSettings = field(default_factory=RefineSettings)
