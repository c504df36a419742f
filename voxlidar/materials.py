"""Materials and their optical properties.

Material ids label every triangle of a synthetic scene, every echo of a
simulated scan (``truth_material``) and every voxel class.  The default optical
properties come from ``shared/data/spectra/optical_properties.csv`` (PROSPECT-D
leaves, Helios/LOPEX93 bark libraries); the seed paper's own material table
was lost from its text.  Values are hemispherical reflectance R and
transmittance T, Lambertian.

References
----------
Feret, J.-B. et al. (2017). PROSPECT-D: towards modeling leaf optical
    properties through a complete lifecycle. Remote Sensing of Environment
    193, 204-215. doi:10.1016/j.rse.2017.03.004
Hosgood, B. et al. (1993). Leaf Optical Properties EXperiment 93 (LOPEX93).
    JRC report EUR 16095 EN.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

from voxlidar.errors import InputError

__all__ = ["Material", "Optics", "DEFAULT_OPTICS", "optics_for"]


class Material(enum.IntEnum):
    """Material id stored per triangle and per echo."""

    NONE = 0
    LEAF = 1
    BARK = 2
    GROUND = 3
    TARGET = 4


@dataclass(frozen=True)
class Optics:
    """Lambertian reflectance and transmittance of a material at one wavelength.

    ``retro_gain`` > 1 marks a retro-reflector: its apparent reflectance is
    ``reflectance * retro_gain`` regardless of incidence angle (RIEGL
    reflectors read above 0 dB).
    """

    reflectance: float
    transmittance: float = 0.0
    retro_gain: float = 1.0

    def __post_init__(self):
        for name in ("reflectance", "transmittance"):
            v = getattr(self, name)
            if not (0.0 <= v <= 1.0):
                raise InputError(
                    f"{name}={v!r} must lie in [0, 1] (a Lambertian surface cannot "
                    "return more than it receives; use retro_gain for retro-reflectors)"
                )
        if self.reflectance + self.transmittance > 1.0 + 1e-12:
            raise InputError(
                f"reflectance + transmittance = {self.reflectance + self.transmittance:.3f} "
                "exceeds 1; lower one of them"
            )
        if self.retro_gain < 1.0:
            raise InputError(f"retro_gain={self.retro_gain!r} must be >= 1")

    @property
    def absorptance(self) -> float:
        return 1.0 - self.reflectance - self.transmittance


# wavelength (nm) -> material -> optics.  Leaf: PROSPECT-D N=1.5 Cab=40;
# bark: mean of cherry, elm and almond trunk (Helios library); ground: a dry
# loam soil (assumed, editable); target: white retro-reflective foil.
DEFAULT_OPTICS: dict[int, dict[Material, Optics]] = {
    1064: {
        Material.LEAF: Optics(0.437, 0.478),
        Material.BARK: Optics(0.443, 0.0),
        Material.GROUND: Optics(0.30, 0.0),
        Material.TARGET: Optics(0.90, 0.0, retro_gain=10.0),
    },
    1550: {
        Material.LEAF: Optics(0.267, 0.339),
        Material.BARK: Optics(0.425, 0.0),
        Material.GROUND: Optics(0.35, 0.0),
        Material.TARGET: Optics(0.90, 0.0, retro_gain=10.0),
    },
}


def optics_for(wavelength_nm: float) -> dict[Material, Optics]:
    """Default optics at a wavelength the package has numbers for.

    Raises
    ------
    InputError
        If ``wavelength_nm`` is not one of the tabulated wavelengths.
    """
    key = int(round(float(wavelength_nm)))
    if key not in DEFAULT_OPTICS:
        raise InputError(
            f"wavelength_nm={wavelength_nm!r}: no default optical properties; "
            f"tabulated are {sorted(DEFAULT_OPTICS)} nm, or pass optics explicitly"
        )
    return dict(DEFAULT_OPTICS[key])
