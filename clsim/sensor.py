"""Airborne full-waveform LiDAR sensors: geometry, beam and receiver.

A :class:`Sensor` is a monostatic laser/receiver pair: a Gaussian beam with
divergence half angle ``divergence_mrad`` (1/e^2 intensity) leaves the sensor
towards a target point on the ground; the receiver (aperture diameter
``aperture_m``, field of view half angle ``fov_mrad``) sits at the same point
and looks along the beam.  Presets are TOML files in ``clsim/presets``.

Examples
--------
>>> s = Sensor.preset("ahab-chiroptera-i")
>>> s.wavelength_nm, s.altitude_m, s.sampling_ghz
(1064.0, 360.0, 1.8)
>>> s2 = s.replace(off_nadir_deg=20.0)
>>> round(s2.range_m, 1)
383.1
>>> Sensor.preset("nope")
Traceback (most recent call last):
...
voxlidar.errors.InputError: sensor preset 'nope' is unknown; choose one of: ahab-chiroptera-i, riegl-lms-q680i, or pass a path to a .toml file
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np

from clsim.errors import InputError
from voxlidar.errors import finite_number

__all__ = ["Sensor", "list_presets", "read_preset", "C_M_PER_NS"]

#: Speed of light in vacuum, metres per nanosecond (air: 0.03 % slower, ignored).
C_M_PER_NS = 0.299792458


def list_presets() -> list[str]:
    """Names of the built-in sensor presets."""
    folder = resources.files("clsim") / "presets"
    return sorted(p.name[:-5] for p in folder.iterdir() if p.name.endswith(".toml"))


#: The table of a preset that holds the survey geometry (read by :mod:`clsim.survey`).
SURVEY_TABLE = "survey"


def read_preset(name) -> tuple[dict, str]:
    """The parsed TOML of a built-in preset (by name) or of a ``.toml`` file
    (by path), and a label for error messages."""
    path = Path(str(name))
    if path.suffix == ".toml":
        try:
            return tomllib.loads(path.read_text()), str(path)
        except (OSError, tomllib.TOMLDecodeError) as err:
            raise InputError(f"cannot read sensor file {str(path)!r}: {err}") from err
    if name not in list_presets():
        raise InputError(
            f"sensor preset {name!r} is unknown; choose one of: "
            f"{', '.join(list_presets())}, or pass a path to a .toml file"
        )
    text = (resources.files("clsim") / "presets" / f"{name}.toml").read_text()
    return tomllib.loads(text), f"preset {name!r}"


@dataclass(frozen=True)
class Sensor:
    """A monostatic airborne full-waveform LiDAR.

    Parameters
    ----------
    name : str
    wavelength_nm : float, nm
        Selects the optical properties of the scene's materials.
    altitude_m : float, metres
        Height of the sensor above the target point (ground plane, or the
        scene's lower corner when the scene has no ground).
    off_nadir_deg : float, degrees
        Beam zenith angle, in [0, 75].
    azimuth_deg : float, degrees
        Azimuth (from +x towards +y) of the sensor as seen from the target.
    divergence_mrad : float, mrad
        Beam divergence half angle at 1/e^2 intensity; per-axis angular
        standard deviation is half of it.
    sampling_ghz : float, GHz
        Digitiser sampling rate.
    pulse_fwhm_ns : float, ns
        Full width at half maximum of the Gaussian outgoing pulse.
    aperture_m : float, metres
        Receiver aperture diameter (area ``pi aperture_m**2 / 4``).
    fov_mrad : float, mrad
        Receiver field-of-view half angle.
    virtual_aperture_m : float, metres
        Diameter of the enlarged aperture used by ``detect="analog"`` (the real
        5 cm aperture at 360 m would catch almost no photon); counted energy
        is scaled by the area ratio.
    description : str
    """

    name: str = "custom"
    wavelength_nm: float = 1064.0
    altitude_m: float = 360.0
    off_nadir_deg: float = 0.0
    azimuth_deg: float = 0.0
    divergence_mrad: float = 0.5
    sampling_ghz: float = 1.8
    pulse_fwhm_ns: float = 4.0
    aperture_m: float = 0.05
    fov_mrad: float = 1.0
    virtual_aperture_m: float = 20.0
    description: str = ""

    def __post_init__(self):
        positive = ("wavelength_nm", "altitude_m", "sampling_ghz", "pulse_fwhm_ns",
                    "aperture_m", "fov_mrad", "virtual_aperture_m")
        for f in dataclasses.fields(self):
            if f.name in ("name", "description"):
                continue
            v = finite_number(getattr(self, f.name), f"sensor {f.name}")
            object.__setattr__(self, f.name, v)
            if f.name in positive and v <= 0:
                hint = " (the sensor must be above the ground)" if f.name == "altitude_m" else ""
                raise InputError(f"sensor {f.name} must be > 0, got {v!r}{hint}")
        if self.divergence_mrad < 0:
            raise InputError(f"sensor divergence_mrad must be >= 0, got {self.divergence_mrad!r}")
        if not 0.0 <= self.off_nadir_deg <= 75.0:
            raise InputError(
                f"sensor off_nadir_deg must lie in [0, 75] degrees, got {self.off_nadir_deg!r}"
            )
        if self.virtual_aperture_m < self.aperture_m:
            raise InputError(
                f"virtual_aperture_m={self.virtual_aperture_m!r} must be >= aperture_m="
                f"{self.aperture_m!r}"
            )

    # -- construction ---------------------------------------------------------
    @classmethod
    def preset(cls, name: str, **overrides) -> Sensor:
        """A built-in preset by name, or a TOML file by path, with overrides.

        The preset's ``[survey]`` table (scan pattern, typical flight) is read
        by :class:`clsim.survey.ScanPattern`, not here."""
        data, where = read_preset(name)
        return cls._from_mapping(data, where, overrides)

    @classmethod
    def from_toml(cls, path, **overrides) -> Sensor:
        """Read a sensor from a TOML file (keys are the field names)."""
        data, where = read_preset(Path(path))
        return cls._from_mapping(data, where, overrides)

    @classmethod
    def _from_mapping(cls, data: dict, where: str, overrides: dict) -> Sensor:
        data = {k: v for k, v in data.items() if k != SURVEY_TABLE}
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted((set(data) | set(overrides)) - names)
        if unknown:
            raise InputError(f"{where}: unknown sensor keys {unknown}; valid keys: {sorted(names)}")
        return cls(**{**data, **overrides})

    def replace(self, **changes) -> Sensor:
        """A copy with some fields changed."""
        return self._from_mapping(dataclasses.asdict(self), "replace()", changes)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    # -- derived geometry -------------------------------------------------------
    @property
    def range_m(self) -> float:
        """Slant range from the sensor to the target point, metres."""
        return self.altitude_m / math.cos(math.radians(self.off_nadir_deg))

    @property
    def aperture_area_m2(self) -> float:
        return math.pi * self.aperture_m**2 / 4.0

    @property
    def virtual_aperture_area_m2(self) -> float:
        return math.pi * self.virtual_aperture_m**2 / 4.0

    @property
    def pulse_sigma_ns(self) -> float:
        """Standard deviation of the Gaussian pulse, ns."""
        return self.pulse_fwhm_ns / (2.0 * math.sqrt(2.0 * math.log(2.0)))

    def beam_axis(self) -> np.ndarray:
        """(3,) unit vector from the sensor towards the target."""
        th, ph = math.radians(self.off_nadir_deg), math.radians(self.azimuth_deg)
        return -np.array([math.sin(th) * math.cos(ph), math.sin(th) * math.sin(ph), math.cos(th)])

    def position(self, target) -> np.ndarray:
        """(3,) sensor position, metres, for a target point (3,)."""
        return np.asarray(target, dtype=np.float64) - self.range_m * self.beam_axis()
