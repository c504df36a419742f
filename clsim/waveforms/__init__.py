"""Measured airborne waveforms: file I/O, decomposition, pointing, metrics.

Nothing here needs OpenCL: these tools serve real survey files as well as the
simulator's output.

- :mod:`clsim.waveforms.io`: LAS 1.3/1.4 waveform packets and PulseWaves;
- :mod:`clsim.waveforms.decompose`: Gaussian decomposition into echoes;
- :mod:`clsim.waveforms.pointing`: laser pointing vectors per pulse;
- :mod:`clsim.waveforms.metrics`: waveform metrics and comparisons.
"""
