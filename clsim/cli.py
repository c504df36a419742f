"""clsim: simulate airborne full-waveform LiDAR over a voxel scene, and read real waveforms.

Run ``clsim COMMAND --help`` for each command.

Examples:
  clsim simulate out/scene.npz --sensor ahab-chiroptera-i --photons 1000000 --seed 1 -o out/wf.npz --plot out/wf.png
  clsim devices
  clsim waveforms info fwf.las
  clsim decompose fwf.las -o echoes.csv --plot echoes.png
"""

from __future__ import annotations

import argparse
import importlib
import sys

from voxlidar.errors import VoxlidarError, exit_code

# sub-command modules that add themselves with register(subparsers)
_PLUGINS = ("clsim.cli_sim", "clsim.cli_waveforms", "clsim.cli_reference")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="clsim", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    p = sub.add_parser("versions", help="print package versions and OpenCL devices (for bug reports)")
    p.set_defaults(func=_versions)
    for name in _PLUGINS:
        try:
            module = importlib.import_module(name)
        except ModuleNotFoundError as err:
            if err.name != name:
                raise
            continue
        module.register(sub)
    return parser


def _versions(args) -> int:
    from tlsvox.versions import show_versions

    show_versions(kernels=("clsim", "tlsvox"))
    return 0


def main(argv=None) -> int:
    """Entry point of the ``clsim`` command."""
    parser = build_parser()
    args = parser.parse_args(argv)
    fn = getattr(args, "func", None) or getattr(args, "handler", None)
    if fn is None:
        parser.print_help()
        return 2
    try:
        return int(fn(args) or 0)
    except VoxlidarError as err:
        print(f"clsim {args.command}: error: {err}", file=sys.stderr)
        return exit_code(err)
    except KeyboardInterrupt:
        print(f"clsim {args.command}: interrupted (outputs are written whole or not at all)", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
