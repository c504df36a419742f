"""The echo model: a sum of Gaussians, and the table of fitted echoes (:class:`Components`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

FWHM_PER_SIGMA = 2.0 * np.sqrt(2.0 * np.log(2.0))
#: the default upper bound on echoes per waveform, of decompose and decompose_batch alike
MAX_COMPONENTS = 8


@dataclass
class EchoColumns:
    """The per-echo columns of :class:`Components` (one waveform) and of
    :class:`._results.EchoTable` (many): equal-length arrays, in ``COLUMNS`` order."""

    amplitude: np.ndarray
    location_ns: np.ndarray
    sigma_ns: np.ndarray
    amplitude_se: np.ndarray
    location_se_ns: np.ndarray
    sigma_se_ns: np.ndarray

    COLUMNS = ("amplitude", "location_ns", "sigma_ns", "amplitude_se", "location_se_ns",
               "sigma_se_ns")


@dataclass
class Components(EchoColumns):
    """Gaussian echoes of one waveform: a table of equal-length columns.

    Attributes
    ----------
    amplitude : (K,) float64
        Peak height above the baseline, in the units of the samples.
    location_ns : (K,) float64
        Peak time, ns from the first sample (plus ``t0_ns``).
    sigma_ns : (K,) float64
        Gaussian standard deviation, ns (FWHM = 2.3548 sigma).
    amplitude_se, location_se_ns, sigma_se_ns : (K,) float64
        Standard errors (NaN for initial guesses that were not fitted).
    baseline, baseline_se : float
        Fitted constant background and its standard error.
    noise_sigma : float
        Robust noise standard deviation of the samples.
    rss : float
        Residual sum of squares of the fit.
    """

    baseline: float = 0.0
    baseline_se: float = float("nan")
    noise_sigma: float = float("nan")
    rss: float = float("nan")

    def __len__(self) -> int:
        return int(np.size(self.amplitude))

    @property
    def fwhm_ns(self) -> np.ndarray:
        """(K,) full width at half maximum, ns."""
        return FWHM_PER_SIGMA * self.sigma_ns

    @property
    def energy(self) -> np.ndarray:
        """(K,) area of each Gaussian, sample units x ns."""
        return self.amplitude * self.sigma_ns * np.sqrt(2.0 * np.pi)

    def model(self, time_ns) -> np.ndarray:
        """Evaluate baseline + sum of the Gaussians at ``time_ns`` (any shape, ns)."""
        return self.baseline + gaussian_sum(time_ns, self.amplitude, self.location_ns,
                                            self.sigma_ns)

    def to_records(self) -> np.ndarray:
        """The table as a NumPy structured array (one row per echo)."""
        dtype = [(name, "f8") for name in self.COLUMNS]
        out = np.empty(len(self), dtype=dtype)
        for name in self.COLUMNS:
            out[name] = getattr(self, name)
        return out

    @classmethod
    def empty(cls, **scalars) -> Components:
        z = np.zeros(0)
        return cls(z, z.copy(), z.copy(), z.copy(), z.copy(), z.copy(), **scalars)


def gaussian_sum(t, amplitude, location, sigma) -> np.ndarray:
    """Sum of Gaussians ``sum_k A_k exp(-(t - mu_k)^2 / (2 sigma_k^2))``.

    Parameters
    ----------
    t : array_like, any shape
    amplitude, location, sigma : (K,) array_like

    Returns
    -------
    ndarray, shape of ``t``

    Examples
    --------
    >>> float(gaussian_sum(2.0, [3.0], [2.0], [1.0]))
    3.0
    """
    t = np.asarray(t, dtype=float)
    a = np.asarray(amplitude, dtype=float).reshape(-1)
    m = np.asarray(location, dtype=float).reshape(-1)
    s = np.asarray(sigma, dtype=float).reshape(-1)
    z = (t[..., None] - m) / s
    return np.sum(a * np.exp(-0.5 * z * z), axis=-1)



def echo_positions(location_ns, *, origin, direction) -> np.ndarray:
    """3-D positions of echoes along a straight pulse.

    Parameters
    ----------
    location_ns : (K,) array_like
        Echo times, ns on the waveform clock.
    origin : (3,) array_like
        Position (m) that corresponds to time 0 of the waveform clock.
    direction : (3,) array_like
        Displacement per ns along the waveform (m/ns; for a two-way return
        waveform its length is c/2 = 0.1499 m/ns).

    Returns
    -------
    (K, 3) float64, metres

    Examples
    --------
    >>> echo_positions([0.0, 10.0], origin=[0, 0, 100], direction=[0, 0, -0.15]).tolist()
    [[0.0, 0.0, 100.0], [0.0, 0.0, 98.5]]
    """
    t = np.asarray(location_ns, dtype=float).reshape(-1, 1)
    o = np.asarray(origin, dtype=float).reshape(3)
    d = np.asarray(direction, dtype=float).reshape(3)
    return o + t * d

