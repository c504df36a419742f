"""From photon arrival times to a digitised waveform: plain functions.

A transport (the voxel Monte Carlo here, a mesh reference elsewhere) produces
energy per fine time bin; these functions turn it into what the sensor
records: convolution with the outgoing pulse (and, optionally, a measured
system impulse response), then sampling at the digitiser's rate.

Units: fine histograms hold energy per bin as a fraction of the emitted pulse
energy; digitised waveforms are received power as a fraction of the emitted
energy per nanosecond, so ``waveform.sum() / sampling_ghz`` is the received
energy fraction.

Examples
--------
>>> import numpy as np
>>> edges = fine_edges(100.0, 200.0, 0.05)
>>> e = np.zeros(len(edges) - 1); e[1000] = 1e-6          # one return at 150 ns
>>> t, wf = digitize(edges, e, sampling_ghz=1.8, pulse_fwhm_ns=4.0)
>>> round(float(wf.sum() / 1.8) * 1e6, 4)                  # energy is kept
1.0
>>> round(float(t[np.argmax(wf)]), 1)
150.0
"""

from __future__ import annotations

import math

import numpy as np

from clsim.errors import InputError

__all__ = ["fine_edges", "pulse_kernel", "convolve_fine", "digitize"]


def fine_edges(t_start_ns: float, t_end_ns: float, dt_ns: float) -> np.ndarray:
    """Edges (F+1,) of a fine time grid covering [t_start, t_end], ns."""
    if not (dt_ns > 0 and t_end_ns > t_start_ns):
        raise InputError(
            f"time grid needs dt_ns > 0 and t_end > t_start; got dt_ns={dt_ns!r}, "
            f"[{t_start_ns!r}, {t_end_ns!r}]"
        )
    n = int(math.ceil((t_end_ns - t_start_ns) / dt_ns))
    return t_start_ns + dt_ns * np.arange(n + 1)


def pulse_kernel(dt_ns: float, fwhm_ns: float, *, impulse=None, impulse_dt_ns=None):
    """Outgoing pulse (optionally convolved with a system impulse) on the fine grid.

    Parameters
    ----------
    dt_ns : float
        Fine bin width, ns.
    fwhm_ns : float
        Gaussian pulse FWHM, ns.
    impulse : (n,) array_like, optional
        Measured system impulse response sampled every ``impulse_dt_ns``,
        starting at lag 0 (any units; normalised to unit area).
    impulse_dt_ns : float, optional

    Returns
    -------
    kernel : (K,) float64
        Weights summing to 1.
    lag0 : int
        Index of zero lag in ``kernel``.
    """
    if not fwhm_ns > 0:
        raise InputError(f"pulse_fwhm_ns must be > 0, got {fwhm_ns!r}")
    sigma = fwhm_ns / (2.0 * math.sqrt(2.0 * math.log(2.0)))
    half = int(math.ceil(5.0 * sigma / dt_ns))
    edges = (np.arange(-half, half + 2) - 0.5) * dt_ns
    from scipy.special import erf  # ~0.3 s to import; only here

    cdf = 0.5 * (1.0 + erf(edges / (sigma * math.sqrt(2.0))))
    kernel = np.diff(cdf)  # bin-integrated Gaussian, centred on index `half`
    lag0 = half
    if impulse is not None:
        imp = np.asarray(impulse, dtype=np.float64).ravel()
        if impulse_dt_ns is None or not impulse_dt_ns > 0 or imp.size < 1 or not np.all(np.isfinite(imp)):
            raise InputError(
                "impulse must be a finite 1-D array with impulse_dt_ns > 0 (its sample spacing, ns)"
            )
        t_imp = np.arange(imp.size) * impulse_dt_ns
        t_fine = np.arange(0.0, t_imp[-1] + dt_ns, dt_ns)
        fine = np.interp(t_fine, t_imp, imp)
        if not fine.sum() > 0:
            raise InputError("impulse response must have a positive area")
        kernel = np.convolve(kernel, fine / fine.sum())
    return kernel / kernel.sum(), lag0


def convolve_fine(energy, kernel, lag0: int) -> np.ndarray:
    """Convolve fine-bin energies (..., F) with a kernel; same length, energy kept
    except what is pushed beyond the grid's ends."""
    e = np.asarray(energy, dtype=np.float64)
    flat = e.reshape(-1, e.shape[-1])
    out = np.zeros_like(flat)
    n, m = e.shape[-1], len(kernel)
    for i, row in enumerate(flat):
        # Only the span around the nonzero bins is convolved (a pulse's returns fill
        # a few per cent of its window).  Each output sample is the same dot product
        # over the same numbers as the full convolution's, since the span keeps a
        # kernel's length of zeros each side: the same bits (tested).
        nz = np.flatnonzero(row)
        if nz.size == 0:
            continue
        a, b = max(0, int(nz[0]) - m), min(n, int(nz[-1]) + 1 + m)
        full = np.convolve(row[a:b], kernel)              # full[k] is output sample a + k - lag0
        lo, hi = max(0, a - lag0 + 0), min(n, a + len(full) - lag0)
        out[i, lo:hi] = full[lo - a + lag0 : hi - a + lag0]
    return out.reshape(e.shape)


def digitize(edges_ns, energy, *, sampling_ghz: float, pulse_fwhm_ns: float, impulse=None,
             impulse_dt_ns=None, t0_ns: float | None = None):
    """Pulse-convolved waveform sampled at the digitiser rate.

    Parameters
    ----------
    edges_ns : (F+1,) float
        Fine bin edges, ns (uniform).
    energy : (..., F) float
        Energy per fine bin (fraction of emitted energy).
    sampling_ghz : float
    pulse_fwhm_ns : float
    impulse, impulse_dt_ns : optional
        Measured system impulse response (see :func:`pulse_kernel`).
    t0_ns : float, optional
        Time of the first sample (default: the grid start rounded down to a
        sample of a clock that ticks at t = 0).

    Returns
    -------
    time_ns : (S,) float64
    waveform : (..., S) float64
        Received power, fraction of emitted energy per ns.
    """
    edges = np.asarray(edges_ns, dtype=np.float64)
    dt = float(edges[1] - edges[0])
    if not sampling_ghz > 0:
        raise InputError(f"sampling_ghz must be > 0, got {sampling_ghz!r}")
    kernel, lag0 = pulse_kernel(dt, pulse_fwhm_ns, impulse=impulse, impulse_dt_ns=impulse_dt_ns)
    power = convolve_fine(energy, kernel, lag0) / dt
    centres = 0.5 * (edges[:-1] + edges[1:])
    period = 1.0 / sampling_ghz
    if t0_ns is None:
        t0_ns = math.floor(edges[0] / period) * period
    n = int(math.floor((edges[-1] - t0_ns) / period)) + 1
    time = t0_ns + period * np.arange(n)
    flat = power.reshape(-1, power.shape[-1])
    out = np.stack([np.interp(time, centres, row, left=0.0, right=0.0) for row in flat])
    return time, out.reshape(power.shape[:-1] + (n,))
