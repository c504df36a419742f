"""One way to run a command-line tool, shared by ``tlsvox`` and ``clsim``.

The convention both tools follow:

- plain ``argparse`` sub-commands, each module adding its own with
  ``register(subparsers)``, listed explicitly by the tool's ``main`` (no
  plugin list that could skip a module silently);
- exit code 0 on success, 2 for usage and input errors (argparse's own code),
  1 for runtime failures (no working device, a registration that failed),
  130 after Ctrl-C;
- one line on stderr for every error raised on purpose
  (:class:`voxlidar.errors.VoxlidarError`), never a traceback;
- the same flag for the same thing in every command: ``-o/--output``,
  ``--plot PATH`` (a picture; the suffix picks the format), ``--voxel-size``,
  ``--seed``, ``--device``, ``-q/--quiet``.
"""

from __future__ import annotations

import argparse
import sys

from voxlidar.errors import VoxlidarError, exit_code

__all__ = ["run"]


def run(prog: str, parser: argparse.ArgumentParser, argv=None) -> int:
    """Parse ``argv`` with ``parser`` and run the chosen sub-command's ``func``.

    Returns the exit code (see the module docstring).

    Examples
    --------
    >>> p = argparse.ArgumentParser(prog="demo")
    >>> sub = p.add_subparsers(dest="command", required=True)
    >>> _ = sub.add_parser("hello").set_defaults(func=lambda args: 0)
    >>> run("demo", p, ["hello"])
    0
    """
    args = parser.parse_args(argv)
    fn = getattr(args, "func", None)
    if fn is None:
        parser.print_help()
        return 2
    try:
        return int(fn(args) or 0)
    except VoxlidarError as err:
        print(f"{prog} {args.command}: error: {err}", file=sys.stderr)
        return exit_code(err)
    except KeyboardInterrupt:
        print(f"{prog} {args.command}: interrupted (outputs are written whole or not at all)", file=sys.stderr)
        return 130
