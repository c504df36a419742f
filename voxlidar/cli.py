"""One way to run a command-line tool, shared by ``tlsvox`` and ``clsim``.

The convention both tools follow:

- plain ``argparse`` sub-commands, each module adding its own with
  ``register(subparsers)``, listed explicitly by the tool's ``main`` (no
  plugin list that could skip a module silently);
- exit code 0 on success, 2 for usage and input errors (argparse's own code),
  1 for runtime failures (no working device, a registration that failed),
  130 after Ctrl-C;
- one line on stderr for every error raised on purpose
  (:class:`voxlidar.errors.VoxlidarError`) and for every usage error that
  argparse finds, never a traceback (``--debug`` before the sub-command shows
  one: ``tlsvox --debug voxelize ...``);
- the same flag for the same thing in every command: ``-o/--output``,
  ``--plot PATH`` (a picture; the suffix picks the format), ``--voxel-size``,
  ``--seed``, ``--device``, ``-q/--quiet``.
"""

from __future__ import annotations

import argparse
import math
import re
import sys

from voxlidar.errors import VoxlidarError, exit_code

__all__ = ["Parser", "join_negative_values", "number", "numbers", "run", "with_debug"]

#: A value that starts like a negative number: ``-5``, ``-0.5,1``, ``-.5e3``.
_NEGATIVE = re.compile(r"^-(\d|\.\d)[\d.,eE+-]*$")


def join_negative_values(argv) -> list[str]:
    """``--opt -5,0,0.5`` as ``--opt=-5,0,0.5``: argparse reads a value starting with '-' as an option.

    Only a token that starts like a negative number, right after a long
    option written without ``=``, is joined to it.

    >>> join_negative_values(["voxelize", "--scan-origin", "-5,0,0.5", "-q", "--seed", "-1"])
    ['voxelize', '--scan-origin=-5,0,0.5', '-q', '--seed=-1']
    """
    out: list[str] = []
    for tok in argv:
        if out and _NEGATIVE.match(tok) and out[-1].startswith("--") and "=" not in out[-1] and out[-1] != "--":
            out[-1] = f"{out[-1]}={tok}"
        else:
            out.append(tok)
    return out


class Parser(argparse.ArgumentParser):
    """``argparse`` with a one-line usage error (the sub-parsers it makes are Parsers too).

    >>> p = Parser(prog="demo")
    >>> _ = p.add_argument("--n", type=int)
    >>> try:
    ...     p.parse_args(["--n", "x"])
    ... except SystemExit as stop:
    ...     stop.code
    2
    """

    def __init__(self, *args, **kwargs):
        kwargs.setdefault("allow_abbrev", False)  # a typo such as --photon must not pass for --photons
        super().__init__(*args, **kwargs)

    def error(self, message):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def number(kind=float, *, lo=None, hi=None, lo_open=False, hi_open=False, unit: str = ""):
    """An argparse ``type`` for a finite number within bounds, with the bounds in its error.

    >>> fraction = number(float, lo=0.0, hi=1.0, lo_open=True, hi_open=True)
    >>> fraction("0.01")
    0.01
    >>> try:
    ...     fraction("2")
    ... except argparse.ArgumentTypeError as err:
    ...     print(err)
    must be a finite number > 0 and < 1, got '2'
    """
    what = "an integer" if kind is int else "a finite number"
    limits = []
    if lo is not None:
        limits.append(f"{'>' if lo_open else '>='} {lo:g}")
    if hi is not None:
        limits.append(f"{'<' if hi_open else '<='} {hi:g}")
    wanted = f"{what} {' and '.join(limits)}{' ' + unit if unit else ''}".strip()

    def parse(text):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"must be {wanted}, got {text!r}") from None
        bad = not math.isfinite(value)
        bad |= lo is not None and (value <= lo if lo_open else value < lo)
        bad |= hi is not None and (value >= hi if hi_open else value > hi)
        if bad:
            raise argparse.ArgumentTypeError(f"must be {wanted}, got {text!r}")
        return value

    parse.__name__ = wanted
    return parse


def numbers(*counts: int, what: str = "", example: str = ""):
    """An argparse ``type`` for comma-separated finite numbers, as many as one of ``counts``.

    Returns a tuple of floats.  ``what`` names them in the error (e.g.
    ``"X,Y in metres"``) and ``example`` shows a value that works.

    >>> xy = numbers(2, what="X,Y in metres", example="1.5,-2")
    >>> xy("3,4")
    (3.0, 4.0)
    >>> try:
    ...     xy("3")
    ... except argparse.ArgumentTypeError as err:
    ...     print(err)
    must be X,Y in metres (2 comma-separated finite numbers), e.g. 1.5,-2; got '3'
    """
    how_many = " or ".join(str(n) for n in counts)
    wanted = f"{what + ' (' if what else ''}{how_many} comma-separated finite numbers{')' if what else ''}"
    if example:
        wanted += f", e.g. {example}"

    def parse(text):
        try:
            values = tuple(float(v) for v in str(text).split(","))
        except ValueError:
            values = ()
        if len(values) not in counts or not all(math.isfinite(v) for v in values):
            raise argparse.ArgumentTypeError(f"must be {wanted}; got {text!r}")
        return values

    parse.__name__ = wanted
    return parse


def with_debug(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Add the ``--debug`` flag (show the traceback of an error) to a tool's parser."""
    parser.add_argument("--debug", action="store_true", help="show the full traceback of an error")
    return parser


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
    args = parser.parse_args(join_negative_values(sys.argv[1:] if argv is None else [str(a) for a in argv]))
    fn = getattr(args, "func", None)
    if fn is None:
        parser.print_help()
        return 2
    try:
        return int(fn(args) or 0)
    except VoxlidarError as err:
        if getattr(args, "debug", False):
            raise
        print(f"{prog} {args.command}: error: {err}", file=sys.stderr)
        return exit_code(err)
    except KeyboardInterrupt:
        print(f"{prog} {args.command}: interrupted (outputs are written whole or not at all)", file=sys.stderr)
        return 130
