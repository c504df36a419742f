"""clsim: simulate airborne full-waveform LiDAR over a voxel scene, and read real waveforms.

Run ``clsim COMMAND --help`` for each command.

Examples:
  clsim simulate out/scene.npz --sensor ahab-chiroptera-i --photons 1000000 --seed 1 -o out/wf.npz --plot out/wf.png
  clsim survey out/scene.npz -o out/survey --pulses 100000 --photons 1000 --workers 2
  clsim devices
  clsim waveforms info fwf.las
  clsim decompose fwf.las -o echoes.csv --plot echoes.png
  clsim replay neon-harvard-waveforms/ -o out/replay
"""

from __future__ import annotations

import argparse
import sys

from clsim.cli import pick, replay, simulate, survey, waveforms
from voxlidar.cli import Parser, run, with_debug


def build_parser() -> argparse.ArgumentParser:
    parser = with_debug(Parser(prog="clsim", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter))
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    p = sub.add_parser("versions", help="print package versions and OpenCL devices (for bug reports)")
    p.set_defaults(func=_versions)
    simulate.register(sub)
    waveforms.register(sub)
    pick.register(sub)
    survey.register(sub)
    replay.register(sub)
    return parser


def _versions(args) -> int:
    from voxlidar.versions import show_versions

    show_versions(kernels=("clsim", "tlsvox"))
    return 0


def main(argv=None) -> int:
    """Entry point of the ``clsim`` command (exit codes: :mod:`voxlidar.cli`)."""
    return run("clsim", build_parser(), argv)


if __name__ == "__main__":
    sys.exit(main())
