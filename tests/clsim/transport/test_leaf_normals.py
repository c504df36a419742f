"""Spherical leaves: the leaf normal at a collision drawn directly (the cosine law about -d,
folded onto the upper hemisphere; kernels/transport.cl ``leaf_normal_seen``, the oracle's
``rejection_normals``) has the rejection sampler's distribution p(n) |n . d| / G(d), with
p uniform on the upper hemisphere and G = 1/2 (docs/method.md, section 3)."""

from __future__ import annotations

import numpy as np
import pytest

from clsim.transport.reference_geometry import cosine_dir, row_dot

N = 200_000


def by_rejection(d, n, rng):
    """Propose n uniform on the upper hemisphere, accept with probability |n . d|."""
    out = np.empty((0, 3))
    while len(out) < n:
        z = rng.random(4 * n)  # cos(zenith) of a uniform hemisphere
        ph = 2.0 * np.pi * rng.random(4 * n)
        s = np.sqrt(1.0 - z * z)
        nn = np.column_stack([s * np.cos(ph), s * np.sin(ph), z])
        out = np.vstack([out, nn[rng.random(4 * n) < np.abs(nn @ d)]])
    return out[:n]


def directly(d, n, rng):
    """The cosine law about -d, folded onto the upper hemisphere."""
    v = cosine_dir(np.tile(-d, (n, 1)), rng.random(n), rng.random(n))
    return np.where(v[:, 2:3] < 0.0, -v, v), v


def z_scores(a, b, bins):
    """Per bin, the difference of two samples' counts over its standard error."""
    ca, _ = np.histogram(a, bins)
    cb, _ = np.histogram(b, bins)
    return (ca - cb) / np.sqrt(np.maximum(ca + cb, 1))


@pytest.mark.parametrize("zenith_deg", [0.0, 35.0, 80.0])
def test_direct_draw_has_the_rejection_distribution(zenith_deg):
    rng = np.random.default_rng(int(zenith_deg) + 5)
    t = np.radians(zenith_deg)
    d = np.array([np.sin(t) * 0.6, np.sin(t) * 0.8, -np.cos(t)])  # downwards, some azimuth
    a = by_rejection(d, N, rng)
    b, unfolded = directly(d, N, rng)
    assert np.all(b[:, 2] >= 0.0)
    # the marginals of n.z, of n . d and of the azimuth agree bin by bin within 4.5 standard
    # errors (30 bins; a false alarm about 1e-4 per test)
    bins = np.linspace(-1.0, 1.0, 11)
    assert np.abs(z_scores(a[:, 2], b[:, 2], np.linspace(0.0, 1.0, 11))).max() < 4.5
    assert np.abs(z_scores(a @ d, b @ d, bins)).max() < 4.5
    assert np.abs(z_scores(np.arctan2(a[:, 1], a[:, 0]), np.arctan2(b[:, 1], b[:, 0]),
                           np.linspace(-np.pi, np.pi, 11))).max() < 4.5
    # known answer: |n . d| has density 2c on [0, 1], mean 2/3 (standard deviation 1/sqrt(18))
    m = np.abs(b @ d).mean()
    assert abs(m - 2.0 / 3.0) < 4.5 / np.sqrt(18.0 * N), m
    # the side facing -d (incident_side) is the unfolded draw itself
    side = np.where(row_dot(b, np.tile(d, (N, 1)))[:, None] > 0.0, -b, b)
    assert np.allclose(side, unfolded)
