"""The ``clsim`` command: :mod:`clsim.cli.main` (versions),
:mod:`clsim.cli.simulate` (simulate, devices, bench),
:mod:`clsim.cli.waveforms` (waveforms info, decompose, georegister).
Conventions: :mod:`voxlidar.cli`."""
