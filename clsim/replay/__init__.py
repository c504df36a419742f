"""Replay measured airborne pulses over a voxel scene, scored against the measurement.

The measured file gives each pulse as the sensor fired it: its position, its
direction, the instrument's pulse (:mod:`._measured`, :mod:`._echoes`).  For
held-out pulses (:func:`cross_validate`: interleaved folds, or one scan line
at a time) a scene is made from the other pulses' echoes (airborne beams
through the voxel grid, :mod:`tlsvox.voxel.airborne`), each held-out pulse is
simulated as fired (:mod:`._forward`), brought into the file's counts by a
gain and a time offset fitted on training pulses only, and scored beside two
baselines (:mod:`._baselines`: the Blair-Hofton method from the training
echoes, the nearest training pulse) on the same pulses (:mod:`._scores`).
``clsim replay`` runs it from the shell and writes the tables and pictures
(:func:`write_replay`).

Examples
--------
>>> from clsim.replay import Scheme
>>> Scheme.parse("Lines", "scheme").value
'lines'
"""

from clsim.replay._baselines import blair_hofton, nearest_pulse
from clsim.replay._echoes import Prepared, prepare, pulse_shape
from clsim.replay._forward import (
                                   Calibration,
                                   SimulatedPulses,
                                   calibrate,
                                   scene_echoes,
                                   scene_from_pulses,
                                   simulate_pulses,
)
from clsim.replay._measured import (
                                   GeometryFit,
                                   MeasuredPulses,
                                   common_point,
                                   read_helios_pulses,
                                   read_las_pulses,
                                   read_measured,
                                   read_neon,
                                   rebuild_positions,
                                   scan_lines,
                                   straight_trajectory,
)
from clsim.replay._replay import METHODS, ReplayResult, Scheme, cross_validate, folds, peak_counts, pool_sigma
from clsim.replay._scores import score_pulse, summarize
from clsim.replay._write import write_replay

__all__ = [
    "METHODS",
    "Calibration",
    "GeometryFit",
    "MeasuredPulses",
    "Prepared",
    "ReplayResult",
    "Scheme",
    "SimulatedPulses",
    "blair_hofton",
    "calibrate",
    "common_point",
    "cross_validate",
    "folds",
    "nearest_pulse",
    "peak_counts",
    "pool_sigma",
    "prepare",
    "pulse_shape",
    "read_helios_pulses",
    "read_las_pulses",
    "read_measured",
    "read_neon",
    "rebuild_positions",
    "scan_lines",
    "scene_echoes",
    "scene_from_pulses",
    "straight_trajectory",
    "score_pulse",
    "simulate_pulses",
    "summarize",
    "write_replay",
]
