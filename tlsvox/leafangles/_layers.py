"""Crown layers and the results of a measurement."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from tlsvox.leafangles._histogram import histogram_G
from voxlidar.choices import Choice
from voxlidar.leaf_orientation import LeafAngle


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


def _in_layer(z, cuts, k):
    """Heights ``z`` in layer k of the layer boundaries ``cuts`` (the bottom and top layers take those below
    and above the cuts)."""
    n_layers = len(cuts) - 1
    low = (z >= cuts[k]) | (k == 0)
    return low if k == n_layers - 1 else low & (z < cuts[k + 1])
