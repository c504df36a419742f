"""The measured records prepared once: baselines removed, echoes decomposed and placed.

:func:`prepare` takes a :class:`~clsim.replay._measured.MeasuredPulses` and
returns :class:`Prepared`: each record above its own baseline (padding and
no-data fill set to 0 and masked), the instrument's pulse shape, and the
echoes of every record, each the instrument's pulse shifted and scaled
(:func:`clsim.waveforms.decompose._template.decompose_template`: a system's
ringing and trailing tail are part of every echo, not new echoes; each
record's echoes depend on its own samples alone), placed in 3-D.  Which pulses
train and which are tested is decided later: nothing here mixes records.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from clsim.errors import InputError
from clsim.waveforms.decompose._noise import noise_level
from clsim.waveforms.decompose._template import subsample_peak

__all__ = ["Prepared", "prepare", "pulse_shape"]


@dataclass
class Prepared:
    """Measured records ready for the replay.

    Attributes
    ----------
    pulses : MeasuredPulses
    signal : (N, S) float64, counts above each record's baseline (0 where not recorded)
    mask : (N, S) bool, the recorded samples inside each record
    noise : (N,) float64, counts; each record's noise standard deviation
    shape : (K,) float64
        The system pulse (a hard target's return) on the record's sample
        clock, unit sum, its peak at index ``shape_peak`` (sub-sample).
    shape_peak : float
    echo_pulse : (E,) int64; echo_sample, echo_energy, echo_sigma : (E,) float64
        The records' echoes, each the system pulse shifted and scaled
        (:func:`clsim.waveforms.decompose._template.decompose_template`):
        pulse, location of the pulse peak (samples), energy (counts x
        samples), spread in range (samples).
    echo_xyz : (E, 3) float64, metres
    shape_source : str, where the pulse shape came from
    part_echo : (P,) int64, optional; part_sample, part_energy : (P,) float64
        The template shifts each echo is the sum of (its deconvolved
        profile in range): echo, location (samples), energy; None where
        the echoes are points (a file's discrete returns).
    """

    pulses: object
    signal: np.ndarray
    mask: np.ndarray
    noise: np.ndarray
    shape: np.ndarray
    shape_peak: float
    echo_pulse: np.ndarray
    echo_sample: np.ndarray
    echo_energy: np.ndarray
    echo_sigma: np.ndarray
    echo_xyz: np.ndarray
    shape_source: str = ""
    part_echo: np.ndarray | None = None
    part_sample: np.ndarray | None = None
    part_energy: np.ndarray | None = None

    @property
    def energy(self) -> np.ndarray:
        """(N,) each record's energy above the baseline, counts x samples."""
        return self.signal.sum(axis=1)

    def echo_counts(self) -> np.ndarray:
        """(N,) Gaussian echoes per record."""
        return np.bincount(self.echo_pulse, minlength=len(self.signal))


def pulse_shape(pulses, signal=None, mask=None) -> tuple[np.ndarray, float, str]:
    """The instrument's pulse on the record clock: unit sum, its sub-sample peak, where it came from.

    The measured system impulse response when the file has one; else the
    median of the strongest single-peaked records, each shifted to a common
    peak (a hard target's return, estimated from the file itself:
    :func:`clsim.waveforms.decompose._template.template_from_returns`).
    """
    if pulses.impulse is not None:
        h = np.clip(np.asarray(pulses.impulse, dtype=np.float64), 0.0, None)
        if h.sum() > 0:
            return h / h.sum(), subsample_peak(h), "measured system impulse response"
    if signal is None:
        raise InputError("no system impulse response and no records to estimate one from")
    from clsim.waveforms.decompose._template import template_from_returns

    h = template_from_returns([y[m] for y, m in zip(signal, mask)])
    return h / h.sum(), subsample_peak(h), "the median of the file's 20 strongest single returns (no impulse response recorded)"


def prepare(pulses, *, false_alarm: float = 0.01) -> Prepared:
    """Baselines, pulse shape and Gaussian echoes of every record (see the module docstring)."""
    from clsim.waveforms.decompose._template import decompose_template

    n, width = pulses.samples.shape
    signal = np.zeros((n, width))
    mask = np.zeros((n, width), dtype=bool)
    noise = np.zeros(n)
    lengths = pulses.n_samples
    rows = []
    for i in range(n):
        m = pulses.valid[i, : lengths[i]]
        y = pulses.samples[i, : lengths[i]]
        if m.sum() < 4:
            raise InputError(f"record {i} of {pulses.name} has {int(m.sum())} recorded samples; at least 4 are needed")
        b, s = noise_level(y[m])
        signal[i, : lengths[i]] = np.where(m, y - b, 0.0)
        mask[i, : lengths[i]] = m
        noise[i] = s
        rows.append(y)
    h, peak, source = pulse_shape(pulses, signal, mask)
    table = decompose_template(rows, h, dt_ns=pulses.dt_ns, false_alarm=false_alarm)
    loc = table.location_ns / pulses.dt_ns
    e_pulse = table.waveform.astype(np.int64)
    xyz = pulses.bin0[e_pulse] + loc[:, None] * pulses.step[e_pulse]
    energy = table.energy / pulses.dt_ns
    return Prepared(pulses=pulses, signal=signal, mask=mask, noise=noise, shape=h, shape_peak=peak,
                    echo_pulse=e_pulse, echo_sample=loc, echo_energy=energy,
                    echo_sigma=table.extent_ns / pulses.dt_ns, echo_xyz=xyz, shape_source=source,
                    part_echo=table.part_echo, part_sample=table.part_location_ns / pulses.dt_ns,
                    part_energy=table.part_energy / pulses.dt_ns)
