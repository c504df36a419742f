"""Survey geometry: a platform flying straight legs, a scan pattern, and the
pulses they fire (time, position, beam direction, ground target, seed).

The geometry is NumPy only (no OpenCL): each pulse's angles and target are
what :meth:`clsim.Simulator.run` takes for one pulse (:meth:`Pulses.sensor`);
:meth:`clsim.Simulator.run_pulses` runs many over one scene, and
:func:`run_survey` runs a whole survey in batches, in a loop or on Dask
(:mod:`clsim.survey.distributed`).
See docs/survey.md.
"""

from clsim.survey._pattern import Flight, ScanKind, ScanPattern, typical_flight
from clsim.survey._pulses import Pulses, survey_pulses
from clsim.survey._trajectory import Leg, Trajectory
from clsim.survey.distributed import SurveyJob, SurveyRun, load_survey, run_survey
from clsim.survey.plots import plot_footprints

__all__ = ["Flight", "Leg", "Pulses", "ScanKind", "ScanPattern", "SurveyJob", "SurveyRun", "Trajectory",
           "load_survey", "plot_footprints", "run_survey", "survey_pulses", "typical_flight"]
