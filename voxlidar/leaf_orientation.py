"""Leaf inclination distributions and the projection function G(theta).

A leaf angle distribution (LAD in the ecology sense; here ``LeafAngle`` to keep
"LAD" for leaf area density) is a probability density ``f(t)`` of the leaf
*normal* zenith angle ``t`` on ``[0, pi/2]``.  The mean projection of unit leaf
area on a plane perpendicular to a beam of zenith angle ``theta`` is

.. math::  G(\\theta) = \\int_0^{\\pi/2} f(t)\\, A(\\theta, t)\\, dt

with Ross's kernel (azimuths uniform)

.. math::
   A = \\cos\\theta\\cos t  \\quad (\\theta + t \\le \\pi/2),\\qquad
   A = \\cos\\theta\\cos t\\,[1 + \\tfrac{2}{\\pi}(\\tan\\psi - \\psi)],\\;
   \\psi = \\arccos(\\cot\\theta\\cot t) \\quad\\text{otherwise}.

Checks (tested): spherical leaves give G = 1/2 at every theta; horizontal
leaves give cos(theta); vertical leaves (2/pi) sin(theta); planophile
G(0) = 8/(3 pi).

References
----------
Ross, J. (1981). The radiation regime and architecture of plant stands.
    Dr W. Junk, The Hague. doi:10.1007/978-94-009-8647-3
de Wit, C. T. (1965). Photosynthesis of leaf canopies. Agricultural Research
    Reports 663, Pudoc, Wageningen.
Goel, N. S. & Strebel, D. E. (1984). Simple beta distribution representation
    of leaf orientation in vegetation canopies. Agronomy Journal 76(5), 800-802.
    doi:10.2134/agronj1984.00021962007600050021x
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from voxlidar.choices import Choice
from voxlidar.errors import InputError

__all__ = ["LeafAngle", "LeafAngleKind", "LeafAzimuth", "ross_kernel", "sample_leaf_normals"]

HALF_PI = 0.5 * np.pi
_GL_X, _GL_W = np.polynomial.legendre.leggauss(96)
#: zenith angles per block of G's quadrature (its arrays: about 10 of 8 x 96 x _G_BLOCK bytes)
_G_BLOCK = 256


def _beta(a: float, b: float):
    """scipy's frozen beta distribution (scipy.stats is imported on first use: it
    takes ~0.4 s, and most runs never need a beta leaf angle distribution)."""
    from scipy import stats

    return stats.beta(a, b)


class LeafAzimuth(str, Choice):
    """Azimuths of the leaf normals."""

    UNIFORM = "uniform"  #: any azimuth, equally likely: G depends on the beam's zenith only
    OUTWARD = "outward"  #: facing away from the crown axis (the paper's oak)


class LeafAngleKind(str, Choice):
    """Named leaf inclination distributions (de Wit 1965, plus extras)."""

    PLANOPHILE = "planophile"
    ERECTOPHILE = "erectophile"
    PLAGIOPHILE = "plagiophile"
    EXTREMOPHILE = "extremophile"
    UNIFORM = "uniform"
    SPHERICAL = "spherical"
    BETA = "beta"
    HORIZONTAL = "horizontal"
    VERTICAL = "vertical"



def ross_kernel(theta, t):
    """Ross's projection kernel A(theta, t) for azimuthally uniform leaves.

    Parameters
    ----------
    theta : array_like, radians
        Beam zenith angle(s) in [0, pi] (pi - theta is used above pi/2).
    t : array_like, radians
        Leaf normal zenith angle(s) in [0, pi/2].

    Returns
    -------
    ndarray
        Mean ``|cos|`` between beam and leaf normal over leaf azimuths.

    Examples
    --------
    >>> round(float(ross_kernel(0.3, 0.0)), 6) == round(float(np.cos(0.3)), 6)
    True
    """
    theta = np.asarray(theta, dtype=float)
    theta = np.where(theta > HALF_PI, np.pi - theta, theta)
    t = np.asarray(t, dtype=float)
    ct, st = np.cos(theta), np.sin(theta)
    cl, sl = np.cos(t), np.sin(t)
    den = st * sl
    with np.errstate(divide="ignore", invalid="ignore"):
        c = np.where(den > 0, ct * cl / np.where(den > 0, den, 1.0), np.inf)
    inside = c < 1.0
    cc = np.clip(c, -1.0, 1.0)
    psi = np.arccos(cc)
    # cos th cos t [1 + (2/pi)(tan psi - psi)] written without tan psi (stable at t = pi/2)
    crossing = ct * cl * (1.0 - 2.0 * psi / np.pi) + (2.0 / np.pi) * st * sl * np.sqrt(
        np.clip(1.0 - cc * cc, 0.0, None)
    )
    return np.where(inside, crossing, ct * cl)


@dataclass(frozen=True)
class LeafAngle:
    """A leaf inclination distribution.

    Parameters
    ----------
    kind : str or LeafAngleKind
        One of planophile, erectophile, plagiophile, extremophile, uniform
        (the paper's choice), spherical, beta, horizontal, vertical.
    mu, nu : float
        Parameters of the two-parameter beta distribution (Goel & Strebel 1984)
        of x = 2t/pi: ``f(t) = (2/pi) (1-x)^(mu-1) x^(nu-1) / B(mu, nu)``.
        Only used with ``kind="beta"``.

    Examples
    --------
    >>> round(LeafAngle("spherical").G(0.7), 6)
    0.5
    >>> abs(LeafAngle("planophile").G(0.0) - 8 / (3 * np.pi)) < 1e-9
    True
    """

    kind: LeafAngleKind = LeafAngleKind.UNIFORM
    mu: float = 1.0
    nu: float = 1.0
    _table: tuple = field(default=(), init=False, repr=False, compare=False)

    def __post_init__(self):
        object.__setattr__(self, "kind", LeafAngleKind.parse(self.kind, "leaf_angle"))
        if self.kind is LeafAngleKind.BETA:
            for name in ("mu", "nu"):
                value = getattr(self, name)
                if not np.isfinite(value) or value <= 0:
                    raise InputError(
                        f"beta leaf angle parameter {name}={value!r} must be a finite "
                        "number > 0 (e.g. mu=2.8, nu=1.2 for a planophile-like canopy)"
                    )

    # -- densities ---------------------------------------------------------
    @property
    def is_delta(self) -> bool:
        """True for the single-angle distributions (horizontal, vertical)."""
        return self.kind in (LeafAngleKind.HORIZONTAL, LeafAngleKind.VERTICAL)

    def pdf(self, t):
        """Density f(t) of the leaf normal zenith angle, 1/rad, on [0, pi/2]."""
        t = np.asarray(t, dtype=float)
        k = self.kind
        two_pi = 2.0 / np.pi
        if k is LeafAngleKind.PLANOPHILE:
            f = two_pi * (1 + np.cos(2 * t))
        elif k is LeafAngleKind.ERECTOPHILE:
            f = two_pi * (1 - np.cos(2 * t))
        elif k is LeafAngleKind.PLAGIOPHILE:
            f = two_pi * (1 - np.cos(4 * t))
        elif k is LeafAngleKind.EXTREMOPHILE:
            f = two_pi * (1 + np.cos(4 * t))
        elif k is LeafAngleKind.UNIFORM:
            f = np.full_like(t, two_pi)
        elif k is LeafAngleKind.SPHERICAL:
            f = np.sin(t)
        elif k is LeafAngleKind.BETA:
            f = two_pi * _beta(self.nu, self.mu).pdf(t / HALF_PI)
        else:
            raise InputError(f"{k.value} leaves have no density (a single angle)")
        return np.where((t >= 0) & (t <= HALF_PI), f, 0.0)

    def cdf(self, t):
        """Cumulative distribution of the leaf normal zenith angle."""
        t = np.clip(np.asarray(t, dtype=float), 0.0, HALF_PI)
        k = self.kind
        two_pi = 2.0 / np.pi
        if k is LeafAngleKind.PLANOPHILE:
            return two_pi * (t + 0.5 * np.sin(2 * t))
        if k is LeafAngleKind.ERECTOPHILE:
            return two_pi * (t - 0.5 * np.sin(2 * t))
        if k is LeafAngleKind.PLAGIOPHILE:
            return two_pi * (t - 0.25 * np.sin(4 * t))
        if k is LeafAngleKind.EXTREMOPHILE:
            return two_pi * (t + 0.25 * np.sin(4 * t))
        if k is LeafAngleKind.UNIFORM:
            return two_pi * t
        if k is LeafAngleKind.SPHERICAL:
            return 1.0 - np.cos(t)
        if k is LeafAngleKind.BETA:
            return _beta(self.nu, self.mu).cdf(t / HALF_PI)
        if k is LeafAngleKind.HORIZONTAL:
            return np.ones_like(t)
        return np.where(t >= HALF_PI, 1.0, 0.0)

    def mean_angle(self) -> float:
        """Mean leaf inclination (radians)."""
        if self.is_delta:
            return 0.0 if self.kind is LeafAngleKind.HORIZONTAL else HALF_PI
        x = 0.5 * (_GL_X + 1.0) * HALF_PI
        return float(np.sum(0.5 * HALF_PI * _GL_W * x * self.pdf(x)))

    # -- sampling ------------------------------------------------------------
    def sample(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """Draw ``n`` leaf normal zenith angles (radians) by inverse CDF.

        Parameters
        ----------
        n : int
            Number of angles.
        rng : numpy.random.Generator
            Source of randomness (``np.random.default_rng(seed)``).
        """
        u = rng.random(int(n))
        return self.ppf(u)

    def ppf(self, u) -> np.ndarray:
        """Inverse CDF: leaf zenith angle (radians) at probability ``u``."""
        u = np.asarray(u, dtype=float)
        k = self.kind
        if k is LeafAngleKind.HORIZONTAL:
            return np.zeros_like(u)
        if k is LeafAngleKind.VERTICAL:
            return np.full_like(u, HALF_PI)
        if k is LeafAngleKind.UNIFORM:
            return u * HALF_PI
        if k is LeafAngleKind.SPHERICAL:
            return np.arccos(1.0 - u)
        if k is LeafAngleKind.BETA:
            return _beta(self.nu, self.mu).ppf(u) * HALF_PI
        if not self._table:
            grid = np.linspace(0.0, HALF_PI, 20001)
            object.__setattr__(self, "_table", (self.cdf(grid), grid))
        cdf_tab, grid = self._table
        return np.interp(u, cdf_tab, grid)

    # -- projection -----------------------------------------------------------
    def G(self, theta):
        """Projection function G(theta) for beam zenith angle(s) theta (radians).

        Exact for the single-angle kinds; otherwise Gauss-Legendre quadrature
        (96 nodes) split at the kernel's kink t = pi/2 - theta, accurate to
        better than 1e-10 for the smooth densities, and to under 1 % where a
        beta density is infinite at an end (mu or nu < 1; 0.75 % at 0.5).
        """
        theta = np.asarray(theta, dtype=float)
        scalar = theta.ndim == 0
        th = np.atleast_1d(theta).ravel()
        th = np.where(th > HALF_PI, np.pi - th, th)
        if self.kind is LeafAngleKind.HORIZONTAL:
            out = ross_kernel(th, 0.0)
        elif self.kind is LeafAngleKind.VERTICAL:
            out = ross_kernel(th, HALF_PI)
        else:  # in blocks of angles: the quadrature's (m, q) arrays stay a few MiB whatever m is
            out = np.concatenate([self._G_quadrature(th[i:i + _G_BLOCK]) for i in range(0, len(th), _G_BLOCK)]
                                 or [np.zeros(0)])
        out = out.reshape(np.shape(theta))
        return float(out) if scalar else out

    def _G_quadrature(self, th):
        """G at zenith angles ``th`` in [0, pi/2] by Gauss-Legendre quadrature split at the kink."""
        kink = HALF_PI - th  # (m,)
        x01 = 0.5 * (_GL_X + 1.0)  # (q,)
        lo = kink[:, None] * x01[None, :]
        hi = kink[:, None] + (HALF_PI - kink)[:, None] * x01[None, :]
        w_lo = 0.5 * kink[:, None] * _GL_W[None, :]
        w_hi = 0.5 * (HALF_PI - kink)[:, None] * _GL_W[None, :]
        thc = th[:, None]
        # a part of zero width adds nothing, also where the density is infinite at its one point (a beta
        # distribution with mu or nu < 1 at 0 or pi/2, for a beam at zenith pi/2 or 0)
        with np.errstate(invalid="ignore"):
            part_lo = np.where(w_lo != 0, w_lo * self.pdf(lo) * ross_kernel(thc, lo), 0.0)  # NaN stays NaN
            part_hi = np.where(w_hi != 0, w_hi * self.pdf(hi) * ross_kernel(thc, hi), 0.0)
        return part_lo.sum(axis=1) + part_hi.sum(axis=1)

    def to_dict(self) -> dict:
        """Plain-data form for files (``name`` plus parameters)."""
        d = {"name": self.kind.value}
        if self.kind is LeafAngleKind.BETA:
            d.update(mu=float(self.mu), nu=float(self.nu))
        return d

    @classmethod
    def from_dict(cls, d: dict | str | LeafAngle) -> LeafAngle:
        """Inverse of :meth:`to_dict`; also accepts a name or a LeafAngle."""
        if isinstance(d, LeafAngle):
            return d
        if isinstance(d, str):
            return cls(d)
        return cls(d["name"], mu=float(d.get("mu", 1.0)), nu=float(d.get("nu", 1.0)))


def sample_leaf_normals(
    n: int,
    leaf_angle: LeafAngle,
    rng: np.random.Generator,
    *,
    azimuth: str = "uniform",
    positions=None,
    crown_center=None,
) -> np.ndarray:
    """Draw unit leaf normals (upper hemisphere) from a leaf angle model.

    Parameters
    ----------
    n : int
        Number of normals.
    leaf_angle : LeafAngle
        Zenith angle distribution of the normals.
    rng : numpy.random.Generator
        Random source.
    azimuth : {"uniform", "outward"}
        ``"outward"``: the normal's azimuth points from ``crown_center`` (x, y)
        to each leaf's ``positions`` (n, 3), as in the paper's oak.
    positions : (n, 3) float, metres, optional
        Leaf centres, required for ``azimuth="outward"``.
    crown_center : (2,) float, metres, optional
        Crown centre (x, y), required for ``azimuth="outward"``.

    Returns
    -------
    (n, 3) float64
        Unit normals with non-negative z.
    """
    t = leaf_angle.sample(n, rng)
    if azimuth == "uniform":
        phi = rng.uniform(0.0, 2.0 * np.pi, int(n))
    elif azimuth == "outward":
        if positions is None or crown_center is None:
            raise InputError(
                "azimuth='outward' needs positions (n, 3) and crown_center (x, y); "
                "pass both or use azimuth='uniform'"
            )
        p = np.asarray(positions, dtype=float)
        dx = p[:, 0] - crown_center[0]
        dy = p[:, 1] - crown_center[1]
        phi = np.arctan2(dy, dx)
    else:
        raise InputError(f"azimuth={azimuth!r} must be 'uniform' or 'outward'")
    st = np.sin(t)
    return np.column_stack([st * np.cos(phi), st * np.sin(phi), np.cos(t)])
