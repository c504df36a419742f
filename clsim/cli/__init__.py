"""The ``clsim`` command: :mod:`clsim.cli.app` (versions),
:mod:`clsim.cli.simulate` (simulate, devices, bench),
:mod:`clsim.cli.waveforms` (waveforms info, decompose, georegister).
Conventions: :mod:`voxlidar.cli`."""

from clsim.cli.app import build_parser, main

__all__ = ["build_parser", "main"]
