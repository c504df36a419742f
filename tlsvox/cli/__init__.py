"""The ``tlsvox`` command: :mod:`tlsvox.cli.main` (tree, scan, view, versions),
:mod:`tlsvox.cli.register` (register, classify, georegister),
:mod:`tlsvox.cli.voxelize` (voxelize).  Conventions: :mod:`voxlidar.cli`."""
