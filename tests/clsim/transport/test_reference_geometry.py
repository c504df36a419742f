"""The NumPy oracle's geometry against closed forms."""

from __future__ import annotations

import numpy as np
import pytest

from clsim.errors import InputError
from clsim.transport.reference_geometry import beam_directions
from clsim.transport.rng import check_seed, split_seed


def test_beam_directions_spread_by_sigma_about_the_axis():
    """Per-axis angular standard deviation sigma (Box-Muller), unit length, centred on the axis."""
    n, sigma = 200_000, 2.5e-3
    u = np.random.default_rng(7).random((n, 2))
    axis, e1, e2 = np.array([0.0, 0.0, -1.0]), np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])
    d = beam_directions(axis, e1, e2, sigma, 1.0 - u[:, 0], u[:, 1])
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, rtol=0, atol=1e-12)
    along = -d[:, 2]
    for e in (e1, e2):
        angle = np.arctan2(d @ e, along)
        # standard error of a standard deviation: sigma / sqrt(2 n) (0.16 % here); 5 of them
        assert abs(angle.std() / sigma - 1) < 5 / np.sqrt(2 * n)
        assert abs(angle.mean()) < 5 * sigma / np.sqrt(n)


def test_seed_check_is_the_one_of_split_seed():
    assert check_seed("12") == 12 and split_seed(2**32 + 5) == (5, 1)
    for bad in (-1, 2**64, "one", None, 1.5j):
        with pytest.raises(InputError, match=r"seed must be an integer in \[0, 2\*\*64\)"):
            check_seed(bad)
