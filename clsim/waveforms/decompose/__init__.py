"""Gaussian decomposition of full waveforms.

A received waveform is modelled as a constant baseline plus a sum of Gaussian
echoes (Hofton et al. 2000; Wagner et al. 2006)

.. math::  y(t) = b + \\sum_k A_k \\exp\\left(-\\frac{(t-\\mu_k)^2}{2\\sigma_k^2}\\right)

One algorithm, two entry points. :func:`decompose_batch` decomposes many
waveforms at once (module :mod:`._batch`: robust baseline and noise, no-data
gaps, clipped samples censored, a matched filter with the system pulse and its
false-alarm threshold, Levenberg-Marquardt fits of all waveforms with the same
number of echoes together, pruning, and rounds of adding a resolved echo at the
highest residual feature while the Bayesian information criterion falls); on an
OpenCL device the detection (:mod:`._detect_cl`) and the fits
(:mod:`._batch_cl`) run there, one waveform per work-item, else each step is
one NumPy call over all of them (:mod:`._batch_detect`, :mod:`._batch_select`,
:mod:`._batch_fit`). :func:`decompose` of one waveform, with its default
detection (``"matched"``), is ``decompose_batch([samples])[0]``: the same
steps, the same defaults, the same answer. A waveform's echoes depend only on
itself and on what the call shares (the pulse, the cap on echoes): never on
``chunk`` or on the order of the input.

The earlier amplitude rule (``decompose(detection="amplitude")``, chosen too
by ``min_amplitude`` or ``impulse``) is :func:`decompose`'s own. Its steps:

1. Baseline ``b`` and noise standard deviation are estimated robustly (lowest
   fifth of the samples; median absolute first difference). Exact zeros more
   than 4 noise sigma below the baseline are no-data fill (the gap between
   two digitised segments of a NEON record) and are left out of the fit.
2. Optional deconvolution with a measured system impulse response
   (Richardson-Lucy; Zhou et al. 2017 used it on the same NEON waveforms).
3. Detection: local maxima of the (optionally Gaussian-smoothed, ``smooth_ns``)
   waveform plus "terraces" (runs of equal samples on a rising or falling
   flank, the trace of a weak echo riding on a strong one in 8-bit data) plus
   echoes cut by the ends of the record, kept when they rise
   ``min_amplitude`` (default 4 noise sigma) above the baseline. Initial
   width: the full width at half maximum between the linearly interpolated
   half-maximum crossings of the two flanks (Hofton et al. 2000); a flank that
   a neighbouring echo stops before half height gives the Gaussian through
   its valley sample instead.
4. Levenberg-Marquardt least squares (MINPACK ``lmder`` through
   :func:`scipy.optimize.leastsq`) with the analytic Jacobian; location,
   width, amplitude of every echo and the baseline are free. Start values:
   the detected locations and widths, with amplitudes and baseline from the
   linear least-squares fit at those locations and widths. Clipped
   (saturated) samples are censored: they count only where the model falls
   below them (Tobin 1958), so the unclipped flanks set height and width.
5. Component count: echoes under ``min_amplitude`` or two standard errors,
   or not resolvable (sigma under 0.3 sample), are dropped and the fit
   repeated; then an echo is added at the largest smoothed residual above the
   threshold when, fitted alone to the residual, it is resolved from every
   echo already there by Sparrow's criterion (the pair's sum shows two
   features: four inflection points), and kept after the refit of all echoes
   only if the Bayesian information criterion decreases (Schwarz 1978). The
   search stops at the first rejected residual peak.
6. Standard errors from the covariance ``s^2 (J^T J)^{-1}`` with
   ``s^2 = RSS / (n - p)``.

Modules: ``_model`` (the Gaussian sum, :class:`Components`), ``_results``
(:class:`EchoTable`, records, CSV), ``_checks``, ``_noise`` (baseline, noise,
gaps, clipping), ``_detection`` (local maxima and terraces), ``_matched``
(matched filter, false-alarm threshold), ``_deconvolve``, ``_fitting`` (one
waveform's Levenberg-Marquardt), ``_selection`` (pruning, BIC additions),
``_single`` (:func:`decompose`: a batch of one, or the amplitude rule), ``_batch_detect`` (NumPy detection of the
batch), ``_batch_select`` (its grouped fits, pruning and additions),
``_batch_fit`` (NumPy fits), ``_batch_cl`` (OpenCL fits), ``_detect_cl`` (OpenCL
detection) and ``_batch`` (:func:`decompose_batch`: input, chunks, the table).

References
----------
Hofton, M. A., Minster, J. B. & Blair, J. B. (2000). Decomposition of laser
    altimeter waveforms. IEEE TGRS 38(4), 1989-1996. doi:10.1109/36.851780
Wagner, W., Ullrich, A., Ducic, V., Melzer, T. & Studnicka, N. (2006).
    Gaussian decomposition and calibration of a novel small-footprint
    full-waveform digitising airborne laser scanner. ISPRS J. 60(2), 100-112.
    doi:10.1016/j.isprsjprs.2005.12.001
Zhou, T., Popescu, S. C., Krause, K., Sheridan, R. D. & Putman, E. (2017).
    Gold - a novel deconvolution algorithm with optimization for waveform
    LiDAR processing. ISPRS J. 129, 131-150. doi:10.1016/j.isprsjprs.2017.04.021
Schwarz, G. (1978). Estimating the dimension of a model. Ann. Stat. 6(2),
    461-464. doi:10.1214/aos/1176344136
Lucy, L. B. (1974). An iterative technique for the rectification of observed
    distributions. AJ 79, 745. doi:10.1086/111605
Rice, S. O. (1944). Mathematical analysis of random noise. Bell Syst. Tech. J.
    23(3), 282-332. doi:10.1002/j.1538-7305.1944.tb00874.x
Turin, G. L. (1960). An introduction to matched filters. IRE Trans. Inf.
    Theory 6(3), 311-329. doi:10.1109/TIT.1960.1057571
Sparrow, C. M. (1916). On spectroscopic resolving power. ApJ 44, 76.
    doi:10.1086/142271
Tobin, J. (1958). Estimation of relationships for limited dependent
    variables. Econometrica 26(1), 24-36. doi:10.2307/1907382
"""

from __future__ import annotations

from clsim.waveforms.decompose._batch import decompose_batch
from clsim.waveforms.decompose._deconvolve import deconvolve
from clsim.waveforms.decompose._detection import detect_peaks
from clsim.waveforms.decompose._matched import Detection, Pulse, detect_echoes, threshold
from clsim.waveforms.decompose._model import Components, echo_positions, gaussian_sum
from clsim.waveforms.decompose._noise import noise_level
from clsim.waveforms.decompose._results import EchoTable
from clsim.waveforms.decompose._single import decompose

__all__ = [
    "Components",
    "Detection",
    "EchoTable",
    "Pulse",
    "decompose",
    "decompose_batch",
    "deconvolve",
    "detect_echoes",
    "detect_peaks",
    "echo_positions",
    "gaussian_sum",
    "noise_level",
    "threshold",
]
