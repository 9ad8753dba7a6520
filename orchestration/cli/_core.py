"""The machinery of the ``mdft`` command line: command registry, parser, error handling.

Each command is one function decorated with :func:`subcommand`, which declares
its name, help text and arguments; :func:`build_parser` turns the registry
into argparse sub-parsers. Adding a command is adding one such function in
one of the command modules (:mod:`orchestration.cli.engine`,
:mod:`orchestration.cli.reproduce`).

Errors: every user error (bad options, unreadable files, invalid models,
arguments the library rejects) is one line on stderr and exit code 2, without
a traceback. An unexpected exception (a bug) is also reported on one line,
with exit code 1. Ctrl-C exits with code 130. The command modules are the
only code of the project that prints.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

__all__ = ["UsageError", "arg", "build_parser", "main", "subcommand", "version"]

#: Largest --samples accepted: beyond it a run takes minutes and gigabytes.
MAX_SAMPLES = 10_000_000
#: Largest number of deliberation steps (--steps, --max-steps) accepted.
MAX_STEPS = 1_000_000


class UsageError(Exception):
    """Bad input from the user: one line on stderr, exit code 2.

    Examples
    --------
    >>> main(["simulate"])
    Traceback (most recent call last):
    ...
    SystemExit: 2
    """


# ----------------------------------------------------------------------------- registry
@dataclass(frozen=True)
class Arg:
    """One ``add_argument`` call: flags and keyword arguments."""

    flags: tuple
    kwargs: dict


def arg(*flags, **kwargs) -> Arg:
    """Declare an argument of a subcommand (same signature as ``add_argument``).

    Examples
    --------
    >>> arg("--samples", type=int, default=10).flags
    ('--samples',)
    """
    return Arg(flags, kwargs)


@dataclass(frozen=True)
class _Command:
    name: str
    help: str
    description: str
    arguments: tuple
    run: Callable


_COMMANDS: list = []


class _HelpFormatter(argparse.HelpFormatter):
    """Show an argument's default in its help, unless there is none to show."""

    def _get_help_string(self, action):
        text = action.help or ""
        if action.default not in (None, False, argparse.SUPPRESS) and "%(default)" not in text:
            text += " (default: %(default)s)"
        return text


class _Parser(argparse.ArgumentParser):
    """An argument parser whose errors are one line: ``prog: error: message``."""

    def error(self, message):
        text = " ".join(str(message).split())
        self.exit(2, f"{self.prog}: error: {text} (see '{self.prog} --help')\n")


def subcommand(name: str, *, help: str, arguments=(), description: str | None = None):
    """Register the decorated function ``run(args) -> int`` as ``mdft <name>``.

    Parameters
    ----------
    name : str
        The command word.
    help : str
        One line for ``mdft --help``.
    arguments : sequence of Arg
        The command's arguments, made with :func:`arg`.
    description : str, optional
        Longer text for ``mdft <name> --help``; ``help`` by default.

    Examples
    --------
    >>> @subcommand("hello", help="say hello", arguments=[arg("--name", default="world")])
    ... def _hello(args):
    ...     print(f"hello {args.name}")
    ...     return 0
    >>> main(["hello", "--name", "MDFT"])
    hello MDFT
    0
    >>> _COMMANDS.pop().name  # tidy up the registry
    'hello'
    """

    def register(run):
        _COMMANDS.append(_Command(name, help, description or help, tuple(arguments), run))
        return run

    return register


def version() -> str:
    """The installed version of the ``pymdft`` distribution.

    Read from the package metadata; in a source checkout that is not
    installed, from the ``pyproject.toml`` beside the packages.

    Examples
    --------
    >>> version().split(".")[0].isdigit()
    True
    """
    from importlib.metadata import PackageNotFoundError
    from importlib.metadata import version as _dist_version

    try:
        return _dist_version("pymdft")
    except PackageNotFoundError:
        import tomllib

        pyproject = Path(__file__).resolve().parents[2] / "pyproject.toml"
        try:
            return str(tomllib.loads(pyproject.read_text())["project"]["version"]) + " (not installed)"
        except (OSError, KeyError, ValueError):
            return "unknown (not installed)"


def build_parser() -> argparse.ArgumentParser:
    """The ``mdft`` parser with one sub-parser per registered command.

    Examples
    --------
    >>> args = build_parser().parse_args(["effects", "--samples", "100"])
    >>> args.command, args.samples, args.out
    ('effects', 100, 'effects.png')
    """
    parser = _Parser(
        prog="mdft",
        description="Multi-alternative Decision Field Theory: simulation, context effects and "
                    "the experiments of Glazier et al. (2022).",
    )
    parser.add_argument("--version", action="version", version=f"mdft (pymdft) {version()}")
    commands = parser.add_subparsers(dest="command", metavar="COMMAND", required=True,
                                     parser_class=_Parser)
    for cmd in _COMMANDS:
        sub = commands.add_parser(
            cmd.name, help=cmd.help, description=cmd.description,
            formatter_class=_HelpFormatter,
        )
        for a in cmd.arguments:
            sub.add_argument(*a.flags, **a.kwargs)
        sub.set_defaults(_run=cmd.run, _parser=sub)
    return parser


def main(argv=None) -> int:
    """Run the command line; return the exit code (exits with 2 on bad input).

    Examples
    --------
    >>> main(["simulate", "--options", "1,3;3,1", "--samples", "1000", "--seed", "0",
    ...       "--json"])  # doctest: +ELLIPSIS
    {...}
    0
    """
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args._run(args) or 0)
    except UsageError as exc:
        args._parser.error(str(exc))  # exits with code 2
    except ValueError as exc:  # input the library rejected, with its message
        args._parser.error(str(exc))
    except MemoryError:
        args._parser.error("not enough memory for this run; ask for fewer samples or steps")
    except BrokenPipeError:  # e.g. `mdft simulate ... --json | head`
        sys.stdout = open(os.devnull, "w")
        return 0
    except KeyboardInterrupt:
        print(f"{args._parser.prog}: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:  # a bug: one line, no traceback, exit code 1
        text = " ".join(str(exc).split())
        print(f"{args._parser.prog}: internal error: {type(exc).__name__}: {text}",
              file=sys.stderr)
        return 1


# ----------------------------------------------------------------------------- argument types
def _number(text, cast, noun, valid, range_noun, show_text=False):
    """``cast(text)``, or an ArgumentTypeError naming what was expected."""
    try:
        value = cast(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected {noun}, got {text!r}") from None
    if not valid(value):
        shown = repr(text) if show_text else value
        raise argparse.ArgumentTypeError(f"expected {range_noun}, got {shown}")
    return value


def positive_int(text: str, *, high: int | None = None) -> int:
    """argparse type: an integer >= 1 (and <= ``high``)."""
    value = _number(text, int, "a positive integer", lambda v: v >= 1, "a positive integer")
    if high is not None and value > high:
        raise argparse.ArgumentTypeError(f"expected an integer <= {high:,}, got {value:,}")
    return value


def bounded_int(high: int) -> Callable:
    """argparse type: an integer in [1, high]."""

    def parse(text):
        return positive_int(text, high=high)

    parse.__name__ = "positive integer"
    return parse


def non_negative_int(text: str) -> int:
    """argparse type: an integer >= 0."""
    return _number(text, int, "an integer >= 0", lambda v: v >= 0, "an integer >= 0")


def positive_float(text: str) -> float:
    """argparse type: a finite number > 0."""
    return _number(text, float, "a positive number", lambda v: math.isfinite(v) and v > 0,
                   "a finite positive number", show_text=True)


def real(text: str) -> float:
    """argparse type: a finite number."""
    return _number(text, float, "a number", math.isfinite, "a finite number", show_text=True)


SEED_ARG = arg(
    "--seed", type=non_negative_int, default=None,
    help="random seed (an integer >= 0); a fresh seed is drawn and printed if omitted",
)


def seed_of(args) -> int:
    """``--seed``, or a fresh seed drawn from the operating system."""
    if args.seed is not None:
        return args.seed
    return int(np.random.SeedSequence().entropy % (2**63))


# ----------------------------------------------------------------------------- output helpers
def finite_or_none(x):
    """``float(x)``, or None where it is not finite (JSON has no NaN)."""
    x = float(x)
    return x if math.isfinite(x) else None


def table(header, rows) -> str:
    """A plain-text table with left-aligned columns.

    Examples
    --------
    >>> print(table(["a", "bb"], [["1", "2"]]))
    a  bb
    -  --
    1  2
    """
    widths = [max(len(str(c)) for c in col) for col in zip(header, *rows)]
    lines = ["  ".join(str(c).ljust(w) for c, w in zip(header, widths)).rstrip()]
    lines.append("  ".join("-" * w for w in widths))
    lines += ["  ".join(str(c).ljust(w) for c, w in zip(row, widths)).rstrip() for row in rows]
    return "\n".join(lines)
