"""Survey geometry: a platform flying straight legs, a scan pattern, and the
pulses they fire (time, position, beam direction, ground target, seed).

The geometry is NumPy only (no OpenCL): each pulse's angles and target are
what :meth:`clsim.Simulator.run` takes for one pulse (:meth:`Pulses.sensor`);
:meth:`clsim.Simulator.run_pulses` runs many over one scene, and
:func:`run_survey` runs a whole survey in batches, in a loop or on Dask
(:mod:`clsim.survey.distributed`).  :func:`write_survey_las` writes the
pulses' waveforms and their returns as LAS 1.4 with waveform packets;
:func:`read_survey_las` reads them back.
See docs/survey.md.
"""

from clsim.survey._line import CentreLine, centre_line
from clsim.survey._pattern import Flight, ScanKind, ScanPattern, typical_flight
from clsim.survey._pulses import Pulses, pulse_count, survey_pulses
from clsim.survey._trajectory import Leg, Trajectory
from clsim.survey.distributed import SurveyJob, SurveyRun, load_survey, run_survey
from clsim.survey.las import SurveyLas, read_survey_las, write_survey_las, write_survey_pulsewaves
from clsim.survey.plots import plot_footprints, plot_point_cloud, plot_radargram

__all__ = ["CentreLine", "Flight", "Leg", "Pulses", "ScanKind", "ScanPattern", "SurveyJob", "SurveyLas", "SurveyRun",
           "Trajectory", "centre_line", "load_survey", "plot_footprints", "plot_point_cloud", "plot_radargram",
           "pulse_count", "read_survey_las", "run_survey", "survey_pulses", "typical_flight", "write_survey_las",
           "write_survey_pulsewaves"]
