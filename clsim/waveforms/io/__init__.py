"""Readers and writers of airborne full-waveform files.

- :mod:`clsim.waveforms.io.las`: LAS 1.3/1.4 waveform packets (point formats 4, 5,
  9, 10; internal or external ``.wdp``), reader and LAS 1.4 writer.
- :mod:`clsim.waveforms.io.pulsewaves`: PulseWaves ``.pls`` + ``.wvs`` reader and writer.
- :mod:`clsim.waveforms.io.helios`: HELIOS++ full-waveform text (``*_fullwave.txt``), reader and writer.
"""

from clsim.waveforms.io.helios import HeliosFullwave, read_helios_fullwave, write_helios_fullwave
from clsim.waveforms.io.las import LasWaveforms, WavePacketDescriptor, read_las_waveforms, write_las_waveforms
from clsim.waveforms.io.pulsewaves import PulseWaves, read_pulsewaves, write_pulsewaves

__all__ = [
    "HeliosFullwave",
    "LasWaveforms",
    "PulseWaves",
    "WavePacketDescriptor",
    "read_helios_fullwave",
    "read_las_waveforms",
    "read_pulsewaves",
    "write_helios_fullwave",
    "write_las_waveforms",
    "write_pulsewaves",
]
