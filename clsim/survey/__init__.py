"""Survey geometry: a platform flying straight legs, a scan pattern, and the
pulses they fire (time, position, beam direction, ground target, seed).

NumPy only (no OpenCL): each pulse's angles and target are what
:meth:`clsim.Simulator.run` takes for one pulse (:meth:`Pulses.sensor`).
See docs/survey.md.
"""

from clsim.survey._pattern import Flight, ScanKind, ScanPattern, typical_flight
from clsim.survey._pulses import Pulses, survey_pulses
from clsim.survey._trajectory import Leg, Trajectory
from clsim.survey.plots import plot_footprints

__all__ = ["Flight", "Leg", "Pulses", "ScanKind", "ScanPattern", "Trajectory", "plot_footprints",
           "survey_pulses", "typical_flight"]
