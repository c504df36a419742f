"""The settings of :func:`~tlsvox.leafangles.measure_leaf_angles`, in four groups, and their TOML file.

==================  ===========================================================  =============================
group               fields                                                       the stage that reads it
==================  ===========================================================  =============================
``histogram``       layers, bins, method                                         the layers and the result
``planes``          radius, min_points, min_spread, cap                          the plane fits
``instrument``      range_noise, angular_step, beam                              the simulated measurement
``deconvolution``   leaf_size, azimuth, crown_center, zenith_groups, samples,    the simulated measurement and
                    max_simulated, iterations, second_leaf, seed                 its inversion
==================  ===========================================================  =============================

``measurement.params["settings"]`` records them in full (:meth:`LeafAngleSettings.to_dict`).

Examples
--------
>>> s = LeafAngleSettings.from_kwargs(layers=2, beam=(0.007, 0.35, 7))
>>> s.histogram.layers, s.instrument.beam, s.planes.radius
(2, (0.007, 0.35, 7), 0.025)
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar

from tlsvox.grouped import GroupedSettings

__all__ = ["DeconvolutionSettings", "HistogramSettings", "InstrumentSettings", "LeafAngleSettings",
           "PlaneFitSettings"]


@dataclass(frozen=True)
class HistogramSettings:
    """The layers and the histogram each one gets."""

    layers: int = 4  #: equal-height crown layers (>= 1)
    bins: int = 18  #: inclination bins on [0, 90] degrees
    method: str = "deconvolve"  #: "deconvolve" or "weighted"


@dataclass(frozen=True)
class PlaneFitSettings:
    """The plane fitted to each leaf echo's neighbourhood."""

    radius: float = 0.025  #: neighbourhood radius, metres
    min_points: int = 5  #: echoes a neighbourhood needs (>= 3)
    min_spread: float = 0.0  #: smallest in-plane minor spread kept, metres
    cap: float = 0.2  #: smallest absolute cosine between a normal and its beam kept


@dataclass(frozen=True)
class InstrumentSettings:
    """The instrument the deconvolution simulates (default: each scan's preset)."""

    range_noise: float | None = None  #: range noise (1 sigma), metres
    angular_step: float | tuple | None = None  #: zenith and azimuth steps, degrees
    beam: tuple | None = None  #: (exit diameter m, full divergence mrad, sub-rays)


@dataclass(frozen=True)
class DeconvolutionSettings:
    """The simulated leaves and the EM inversion."""

    leaf_size: float = 0.05  #: leaf length of the simulated leaves, metres
    azimuth: str = "auto"  #: "auto", "uniform" or "outward"
    crown_center: tuple | None = None  #: (x, y) of the crown axis, metres
    zenith_groups: int = 6  #: groups of beam zenith angles per scan and layer
    samples: int = 3  #: simulated leaves per bin, sampled echo and azimuth model
    max_simulated: int = 3000  #: echoes sampled per scan and layer
    iterations: int = 300  #: EM iterations
    second_leaf: bool = True  #: occlusion levels with a second leaf behind the first
    seed: int = 0  #: seeds the simulated leaves


@dataclass(frozen=True)
class LeafAngleSettings(GroupedSettings):
    """Every setting of a :func:`~tlsvox.leafangles.measure_leaf_angles` run, in four groups."""

    GROUPS: ClassVar[dict[str, type]] = {"histogram": HistogramSettings, "planes": PlaneFitSettings,
                                         "instrument": InstrumentSettings, "deconvolution": DeconvolutionSettings}
    LABEL: ClassVar[str] = "leaf-angle"

    histogram: HistogramSettings = field(default_factory=HistogramSettings)
    planes: PlaneFitSettings = field(default_factory=PlaneFitSettings)
    instrument: InstrumentSettings = field(default_factory=InstrumentSettings)
    deconvolution: DeconvolutionSettings = field(default_factory=DeconvolutionSettings)
