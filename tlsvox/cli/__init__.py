"""The ``tlsvox`` command: :mod:`tlsvox.cli.app` (tree, scan, view, versions),
:mod:`tlsvox.cli.register` (register, classify), :mod:`tlsvox.cli.georegister`,
:mod:`tlsvox.cli.voxelize` (voxelize).  Conventions: :mod:`voxlidar.cli`."""

from tlsvox.cli.app import build_parser, main

__all__ = ["build_parser", "main"]
