"""Leaf angle distributions and G(theta) against closed forms (docs/method.md §2)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import integrate, stats

from tlsvox.errors import InputError
from voxlidar.leaf_orientation import LeafAngle, LeafAngleKind, ross_kernel

THETA = np.linspace(0.0, np.pi / 2, 37)
SMOOTH = ["planophile", "erectophile", "plagiophile", "extremophile", "uniform", "spherical"]


def test_spherical_is_half_at_every_angle():
    g = LeafAngle("spherical").G(np.concatenate([THETA, np.pi - THETA]))
    np.testing.assert_allclose(g, 0.5, atol=1e-4)


def test_planophile_at_nadir():
    assert LeafAngle("planophile").G(0.0) == pytest.approx(8 / (3 * np.pi), abs=1e-9)


def test_horizontal_and_vertical_leaves():
    np.testing.assert_allclose(LeafAngle("horizontal").G(THETA), np.cos(THETA), atol=1e-12)
    np.testing.assert_allclose(LeafAngle("vertical").G(THETA), 2 / np.pi * np.sin(THETA), atol=1e-12)


@pytest.mark.parametrize("kind", SMOOTH)
def test_g_matches_independent_quadrature(kind):
    """The split Gauss-Legendre G against scipy.quad of f(t) A(theta, t)."""
    la = LeafAngle(kind)
    for theta in (0.1, 0.6, 1.0, 1.4):
        kink = np.pi / 2 - theta
        want = sum(integrate.quad(lambda t: la.pdf(t) * ross_kernel(theta, t), a, b, epsabs=1e-13)[0]
                   for a, b in ((0, kink), (kink, np.pi / 2)))
        assert la.G(theta) == pytest.approx(want, abs=1e-9)


@pytest.mark.parametrize("kind", SMOOTH)
def test_mean_g_over_the_hemisphere_is_half(kind):
    """Any leaf angle distribution averages G = 1/2 over beam directions (Ross 1981)."""
    la = LeafAngle(kind)
    mean = integrate.quad(lambda th: la.G(th) * np.sin(th), 0, np.pi / 2)[0]
    assert mean == pytest.approx(0.5, abs=1e-6)


@pytest.mark.parametrize("kind", SMOOTH + ["beta"])
def test_pdf_normalised_and_cdf_consistent(kind):
    la = LeafAngle(kind, mu=2.8, nu=1.2) if kind == "beta" else LeafAngle(kind)
    total = integrate.quad(la.pdf, 0, np.pi / 2)[0]
    assert total == pytest.approx(1.0, abs=1e-9)
    for t in (0.2, 0.7, 1.3):
        assert la.cdf(t) == pytest.approx(integrate.quad(la.pdf, 0, t)[0], abs=1e-8)


@pytest.mark.parametrize("kind", SMOOTH + ["beta"])
def test_sampling_follows_the_cdf(kind):
    """KS test of 20,000 samples; p > 0.001 (a fixed seed keeps it deterministic)."""
    la = LeafAngle(kind, mu=2.8, nu=1.2) if kind == "beta" else LeafAngle(kind)
    x = la.sample(20000, np.random.default_rng(7))
    assert np.all((x >= 0) & (x <= np.pi / 2))
    assert stats.kstest(x, la.cdf).pvalue > 1e-3


def test_unknown_kind_lists_choices():
    with pytest.raises(InputError, match="planophile, erectophile"):
        LeafAngle("flat")
    assert LeafAngleKind.parse("Spherical", "leaf_angle") is LeafAngleKind.SPHERICAL


@pytest.mark.parametrize("mu,nu", [(0.7, 0.6), (0.5, 2.0), (2.0, 0.5)])
def test_beta_with_a_density_infinite_at_an_end_has_finite_g(mu, nu):
    """A beta distribution with mu or nu < 1 (as fitted to measured leaf angles) has an infinite density at
    0 or pi/2; G at the zenith angles 0, pi/2 and pi, where one quadrature part has zero width there, is
    finite and equals the mean projection of sampled leaves (|cos t| at 0, 2/pi sin t at pi/2) within 3
    standard errors of 400,000 samples and the quadrature's error, which the singular end raises from
    1e-10 to under 1 % (measured 0.75 % at mu or nu = 0.5)."""
    la = LeafAngle("beta", mu=mu, nu=nu)
    g = la.G(np.array([0.0, np.pi / 2, np.pi]))
    assert np.all(np.isfinite(g))
    assert np.isnan(la.G(np.array([np.nan]))[0])  # a bad angle stays visible
    t = la.ppf(np.random.default_rng(0).random(400_000))
    for got, proj in ((g[0], np.cos(t)), (g[1], 2 / np.pi * np.sin(t)), (g[2], np.cos(t))):
        assert abs(got - proj.mean()) < 3 * proj.std() / np.sqrt(len(t)) + 0.01 * got, (got, proj.mean())
