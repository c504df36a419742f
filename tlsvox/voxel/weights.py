"""Echo weights: how much of its pulse's beam each echo stops.

A pulse is a beam of weight 1.  Each echo removes its weight from the beam;
what no echo removed carries on as the *tail* (:mod:`tlsvox.voxel.trace`).
The rules (:class:`EchoWeights`):

``uniform``
    Every echo of an ``n``-echo pulse weighs ``1/n`` (the usual rule; Béland
    et al. 2014).  A wide beam that grazes a leaf edge and goes on is then
    counted as half (or fully) intercepted, so LAD comes out high: on the
    leaf box of ``docs/voxelize.md`` +43 % with the RIEGL VZ-400's 7-sub-ray
    beam.
``fraction``
    Every echo weighs the share of the beam it intercepted; the rest of the
    pulse is the tail.  The share comes from the scan's ``beam_fraction``
    column (a simulated scan's sub-ray count; any exporter's column), else
    from apparent reflectance over the reflectance a full hit would read:
    ``f = rho_app / (R * k)``, clipped to [0, 1], with ``R`` the material's
    nominal reflectance (:mod:`voxlidar.materials` at the scanner's
    wavelength, or given) and ``k`` the mean incidence cosine of a full hit
    (leaves: ``E[(n.d)^2] / G(theta)`` for the leaf angle model, 2/3 for
    spherical leaves; wood: pi/4, a cylinder).  Echoes that stop the beam
    without being leaf or wood (ground, targets) take what the pulse has
    left.  When the shares of a pulse add up to more than 1 they are scaled
    to 1.
``threshold``
    The paper's rule: leaf and wood echoes reading under half the nominal
    leaf reflectance are dropped as noise (they neither stop the beam nor
    count in ``n``), the others weigh ``1/n``.
``geometric``
    Every echo weighs the share of the beam a return of its rank in a pulse
    of ``n`` returns stops in expectation, from the beam's footprint, the
    leaves' size and the scan's own statistics of returns per pulse
    (:mod:`tlsvox.voxel.footprint`): for multi-return scans with neither a
    ``beam_fraction`` column nor calibrated reflectance.  Ground and targets
    take what the pulse has left.
``auto`` (default)
    ``fraction`` for a scan with a ``beam_fraction`` column, else ``uniform``.
    The rule used is stated per scan in ``Scene.meta["scans"][i]["echo_weights"]``.

References
----------
Béland, M., Widlowski, J.-L., Fournier, R. A. (2014). A model for deriving
    voxel-level tree leaf area density estimates from ground-based LiDAR.
    Environmental Modelling & Software 51, 184-189. doi:10.1016/j.envsoft.2013.09.034
Kim, A. M., Olsen, R. C., Béland, M. (2015). Simulation of small-footprint
    full-waveform LiDAR propagation through a tree canopy in 3D. Proc. SPIE
    9465, 94650N. doi:10.1117/12.2177456
Ross, J. (1981). The radiation regime and architecture of plant stands. Junk,
    The Hague.

Examples
--------
>>> EchoWeights.parse("Fraction", "echo_weights").value
'fraction'
>>> round(float(full_hit_cosine("spherical", [0.3])[0]), 4)
0.6667
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tlsvox.errors import InputError
from voxlidar.choices import Choice

__all__ = ["EchoWeights", "NominalReflectance", "below_threshold", "echo_fractions", "full_hit_cosine", "resolve_rule"]

#: wavelength assumed for a scan that does not say (the RIEGL VZ-400's)
DEFAULT_WAVELENGTH_NM = 1550.0
#: the paper's noise threshold: half the nominal leaf reflectance
THRESHOLD_SHARE = 0.5


class EchoWeights(Choice):
    """How echoes share their pulse's beam (see the module docstring)."""

    AUTO = "auto"  #: fraction with a beam_fraction column, else uniform
    UNIFORM = "uniform"  #: 1/n
    FRACTION = "fraction"  #: the intercepted share of the beam
    THRESHOLD = "threshold"  #: drop returns under 50 % of the nominal leaf reflectance, then 1/n
    GEOMETRIC = "geometric"  #: the expected share from the beam's footprint (tlsvox.voxel.footprint)


@dataclass(frozen=True)
class NominalReflectance:
    """Apparent reflectance of a surface that intercepts the whole beam at normal incidence.

    Parameters
    ----------
    leaf, wood : float
        Linear reflectance (1 = white Lambertian target).
    source : str
        Where the numbers came from (stated in the output).
    """

    leaf: float
    wood: float
    source: str = "given"

    def __post_init__(self):
        for name in ("leaf", "wood"):
            v = getattr(self, name)
            if not (np.isfinite(v) and 0 < v <= 10):
                raise InputError(f"nominal {name} reflectance={v!r} must be a linear reflectance > 0 "
                                 "(e.g. 0.267 for a leaf at 1550 nm)")

    @classmethod
    def for_scan(cls, scan, leaf: float | None = None, wood: float | None = None) -> NominalReflectance:
        """The given values, else the leaf and bark optics at the scan's wavelength."""
        from voxlidar.materials import Material, optics_for

        wl = (scan.meta.get("preset") or {}).get("wavelength_nm") or scan.meta.get("wavelength_nm")
        src = f"voxlidar.materials at {float(wl):g} nm" if wl else \
            f"voxlidar.materials at {DEFAULT_WAVELENGTH_NM:g} nm (assumed: the scan does not say)"
        optics = optics_for(wl or DEFAULT_WAVELENGTH_NM)
        if leaf is not None and wood is not None:
            src = "given"
        elif leaf is not None or wood is not None:
            src = f"{'leaf' if leaf is not None else 'wood'} given, the other from {src}"
        return cls(optics[Material.LEAF].reflectance if leaf is None else float(leaf),
                   optics[Material.BARK].reflectance if wood is None else float(wood), src)


def full_hit_cosine(leaf_angle, theta) -> np.ndarray:
    """Mean incidence cosine of beams of zenith ``theta`` on the leaves they hit.

    A leaf is hit with probability proportional to its projection ``|n.d|``,
    so the mean cosine over hits is ``E[(n.d)^2] / E[|n.d|]`` with
    ``E[|n.d|] = G(theta)`` and, for leaf inclination ``t`` and uniform
    azimuth, ``E[(n.d)^2] = cos^2(theta) E[cos^2 t] + sin^2(theta) E[sin^2 t] / 2``.

    Parameters
    ----------
    leaf_angle : LeafAngle, str or dict
    theta : (B,) float, radians

    Returns
    -------
    (B,) float in (0, 1]
    """
    from voxlidar.leaf_orientation import LeafAngle, LeafAngleKind

    la = LeafAngle.from_dict(leaf_angle)
    theta = np.asarray(theta, dtype=np.float64)
    if la.kind is LeafAngleKind.HORIZONTAL:
        c2 = 1.0
    elif la.kind is LeafAngleKind.VERTICAL:
        c2 = 0.0
    else:
        t = np.linspace(0.0, np.pi / 2, 2049)
        f = la.pdf(t)
        c2 = float(np.trapezoid(f * np.cos(t) ** 2, t) / np.trapezoid(f, t))
    ct2 = np.cos(theta) ** 2
    second = ct2 * c2 + 0.5 * (1.0 - ct2) * (1.0 - c2)
    g = np.maximum(la.G(theta), 1e-6)
    return np.clip(second / g, 1e-3, 1.0)


def resolve_rule(rule, scan) -> EchoWeights:
    """The rule used for ``scan``: ``auto`` resolved, and the inputs the rule needs checked."""
    rule = EchoWeights.parse(rule, "echo_weights")
    has_fraction = scan.beam_fraction is not None and bool(np.any(np.isfinite(scan.beam_fraction)))
    if rule is EchoWeights.AUTO:
        return EchoWeights.FRACTION if has_fraction else EchoWeights.UNIFORM
    has_refl = scan.reflectance_db is not None and bool(np.any(np.isfinite(scan.reflectance_db)))
    if rule is EchoWeights.FRACTION and not (has_fraction or has_refl):
        raise InputError(f"echo_weights='fraction': scan {scan.name!r} has neither a beam_fraction column nor "
                         "reflectance (dB) to derive it from; use echo_weights='uniform' (1/n)")
    if rule is EchoWeights.THRESHOLD and not has_refl:
        raise InputError(f"echo_weights='threshold': scan {scan.name!r} has no reflectance (dB) to threshold; "
                         "use echo_weights='uniform' (1/n)")
    return rule


def echo_fractions(scan, kinds, world_theta, *, leaf_angle=None, nominal: NominalReflectance) -> tuple[np.ndarray, str]:
    """Intercepted share of the beam per echo (NaN where unknown) and where it came from.

    Parameters
    ----------
    scan : Scan
    kinds : (N,) uint8, :class:`~tlsvox.voxel.trace.EchoKind`
    world_theta : (N,) float, radians
        Zenith angle of each echo's pulse in the world frame.
    leaf_angle : LeafAngle, optional
        For the incidence cosine of full leaf hits (default uniform, the paper).
    nominal : NominalReflectance

    Returns
    -------
    fraction : (N,) float64
        In [0, 1]; NaN for echoes that stop the beam without being leaf or
        wood when the share comes from reflectance (they take what is left).
    source : str
    """
    from tlsvox.voxel.trace import EchoKind

    n = len(scan)
    if scan.beam_fraction is not None and np.any(np.isfinite(scan.beam_fraction)):
        return scan.beam_fraction.astype(np.float64), "beam_fraction column"
    rho = scan.reflectance
    if rho is None:
        raise InputError(f"scan {scan.name!r} has no reflectance to derive beam fractions from")
    kinds = np.asarray(kinds)
    full = np.full(n, np.nan)
    leaf = kinds == EchoKind.LEAF
    wood = kinds == EchoKind.WOOD
    full[leaf] = nominal.leaf * full_hit_cosine(leaf_angle or "uniform", np.asarray(world_theta)[leaf])
    full[wood] = nominal.wood * np.pi / 4
    with np.errstate(invalid="ignore"):
        frac = np.clip(rho / full, 0.0, 1.0)
    frac[~(leaf | wood)] = np.nan
    frac[(leaf | wood) & ~np.isfinite(rho)] = np.nan
    return frac, f"reflectance over nominal ({nominal.source}: leaf {nominal.leaf:g}, wood {nominal.wood:g})"


def below_threshold(scan, kinds, nominal: NominalReflectance) -> np.ndarray:
    """(N,) bool: leaf or wood echoes reading under half the nominal leaf reflectance (the paper's noise)."""
    from tlsvox.voxel.trace import EchoKind

    rho = scan.reflectance
    kinds = np.asarray(kinds)
    with np.errstate(invalid="ignore"):
        low = rho < THRESHOLD_SHARE * nominal.leaf
    return low & ((kinds == EchoKind.LEAF) | (kinds == EchoKind.WOOD))
