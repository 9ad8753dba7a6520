"""The ``mdft`` command line.

Commands::

    mdft simulate   simulate an MDFT model given inline or in a JSON file
    mdft effects    the similarity, attraction and compromise effects: table and figure

Each command is one function decorated with :func:`subcommand`, which declares
its name, help text and arguments; :func:`build_parser` turns the registry
into argparse sub-parsers. Adding a command is adding one such function.

User errors (bad options, unreadable files, invalid models) are reported by
argparse on stderr with exit code 2, without a traceback. This is the only
module of the project that prints.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

__all__ = ["UsageError", "build_parser", "main", "subcommand"]

#: Defaults of ``mdft simulate`` for parameters not given: the canonical set
#: of Hotaling, Busemeyer & Li (2010) (docs/concepts.md, section 7).
DEFAULT_PARAMETERS = {"phi1": 0.022, "phi2": 0.05, "beta": 12.0, "sigma2": 1.0}
DEFAULT_STEPS = 100
DEFAULT_MAX_STEPS = 10_000
_MODEL_KEYS = {"M", "w", "phi1", "phi2", "beta", "sigma2", "P0", "labels"}


class UsageError(Exception):
    """Bad input from the user; reported through argparse (exit code 2).

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


def build_parser() -> argparse.ArgumentParser:
    """The ``mdft`` parser with one sub-parser per registered command.

    Examples
    --------
    >>> args = build_parser().parse_args(["effects", "--samples", "100"])
    >>> args.command, args.samples, args.out
    ('effects', 100, 'effects.png')
    """
    parser = argparse.ArgumentParser(
        prog="mdft",
        description="Multi-alternative Decision Field Theory: simulation and context effects.",
    )
    commands = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
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
    """Run the command line; return the exit code (argparse exits with 2 on bad input).

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
    except BrokenPipeError:  # e.g. `mdft simulate ... --json | head`
        sys.stdout = open(os.devnull, "w")
        return 0


# ----------------------------------------------------------------------------- argument types
def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {value}")
    return value


def _non_negative_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer >= 0, got {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"expected an integer >= 0, got {value}")
    return value


def _positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}") from None
    if not math.isfinite(value) or value <= 0:
        raise argparse.ArgumentTypeError(f"expected a finite positive number, got {text!r}")
    return value


def _real(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
    return value


_STOPPING_ARGS = (
    arg("--steps", type=_positive_int, metavar="N",
        help="fixed deliberation time: choose the best option after N steps"),
    arg("--threshold", type=_positive_float, metavar="THETA",
        help="threshold stopping: choose the first option whose preference reaches THETA"),
    arg("--max-steps", type=_positive_int, metavar="K", default=None,
        help=f"with --threshold: trials undecided after K steps are reported as undecided "
             f"(default: {DEFAULT_MAX_STEPS})"),
)
_SEED_ARG = arg(
    "--seed", type=_non_negative_int, default=None,
    help="random seed (an integer >= 0); a fresh seed is drawn and printed if omitted",
)


def _stopping(args, *, default):
    """The stopping rule from --steps / --threshold / --max-steps."""
    import mdft

    if args.steps is not None and args.threshold is not None:
        raise UsageError("give either --steps (fixed time) or --threshold, not both")
    if args.max_steps is not None and args.threshold is None:
        raise UsageError("--max-steps applies to threshold stopping only; add --threshold THETA")
    if args.steps is not None:
        return mdft.FixedTime(args.steps)
    if args.threshold is not None:
        max_steps = DEFAULT_MAX_STEPS if args.max_steps is None else args.max_steps
        return mdft.Threshold(args.threshold, max_steps=max_steps)
    return default()


def _describe_stopping(stopping) -> str:
    if hasattr(stopping, "n_steps"):
        return f"fixed time, {stopping.n_steps} steps"
    return f"threshold {stopping.theta:g} (at most {stopping.max_steps} steps)"


def _stopping_json(stopping) -> dict:
    if hasattr(stopping, "n_steps"):
        return {"rule": "fixed_time", "n_steps": int(stopping.n_steps)}
    return {"rule": "threshold", "theta": float(stopping.theta),
            "max_steps": int(stopping.max_steps)}


def _seed(args) -> int:
    if args.seed is not None:
        return args.seed
    return int(np.random.SeedSequence().entropy % (2**63))


# ----------------------------------------------------------------------------- simulate
def _parse_options(text: str) -> list:
    rows = [r for r in text.replace(" ", "").split(";") if r != ""]
    if len(rows) < 2:
        raise UsageError(
            f"--options needs at least two options separated by ';' (got {text!r}); "
            "e.g. --options '1,3;3,1;2,2'"
        )
    M = []
    for k, row in enumerate(rows):
        try:
            values = [float(v) for v in row.split(",")]
        except ValueError:
            raise UsageError(
                f"--options: option {k + 1} ({row!r}) must be numbers separated by ','"
            ) from None
        M.append(values)
    if len({len(r) for r in M}) != 1:
        raise UsageError(
            f"--options: every option needs the same number of attributes "
            f"(got {[len(r) for r in M]} in {text!r})"
        )
    if not all(math.isfinite(v) for r in M for v in r):
        raise UsageError(f"--options must contain finite numbers only (got {text!r})")
    return M


def _parse_list(name: str, text: str, cast=float) -> list:
    try:
        return [cast(v) for v in text.replace(" ", "").split(",") if v != ""]
    except ValueError:
        raise UsageError(f"{name} must be values separated by ',' (got {text!r})") from None


def _read_model_file(path: str) -> dict:
    p = Path(path)
    try:
        text = p.read_text()
    except OSError as exc:
        raise UsageError(f"--model: cannot read {path!r} ({exc.strerror or exc})") from None
    try:
        spec = json.loads(text)
    except json.JSONDecodeError as exc:
        raise UsageError(f"--model: {path!r} is not valid JSON ({exc})") from None
    if not isinstance(spec, dict):
        raise UsageError(f"--model: {path!r} must hold a JSON object with at least 'M'")
    unknown = set(spec) - _MODEL_KEYS
    if unknown:
        raise UsageError(
            f"--model: unknown key(s) {sorted(unknown)} in {path!r}; allowed: {sorted(_MODEL_KEYS)}"
        )
    if "M" not in spec:
        raise UsageError(f"--model: {path!r} has no 'M' (the options x attributes matrix)")
    return spec


def _default_labels(n: int) -> list:
    if n <= 26:
        return [chr(ord("A") + i) for i in range(n)]
    return [f"option {i}" for i in range(n)]


def _model_from_args(args):
    """(model, labels, notes) from --options/--model and the parameter flags."""
    import mdft

    if (args.options is None) == (args.model is None):
        raise UsageError("give the options either inline with --options or in a file with --model")
    spec = {} if args.model is None else _read_model_file(args.model)
    M = _parse_options(args.options) if args.options is not None else spec["M"]
    try:
        n_options, n_attributes = np.shape(M)
    except ValueError:
        raise UsageError(f"M must be a rectangular options x attributes matrix (got {M!r})") from None
    if args.weights is not None:
        w = _parse_list("--weights", args.weights)
    else:
        w = spec.get("w", [1.0 / n_attributes] * n_attributes if n_attributes else [])
    params = {}
    for name, default in DEFAULT_PARAMETERS.items():
        flag = getattr(args, name)
        params[name] = flag if flag is not None else spec.get(name, default)
    if args.labels is not None:
        labels = _parse_list("--labels", args.labels, cast=str)
    else:
        labels = spec.get("labels", _default_labels(n_options))
    labels = [str(s) for s in labels]
    if len(labels) != n_options:
        raise UsageError(f"labels: need one per option, {n_options} (got {len(labels)}: {labels})")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", mdft.UnstableFeedbackWarning)
        try:
            model = mdft.MDFTModel(M, w, P0=spec.get("P0"), **params)
        except (ValueError, TypeError) as exc:
            raise UsageError(f"invalid model: {exc}") from None
    notes = [str(c.message) for c in caught if issubclass(c.category, mdft.UnstableFeedbackWarning)]
    return model, labels, notes


@subcommand(
    "simulate",
    help="simulate choices of an MDFT model",
    description=(
        "Monte Carlo choice probabilities of an MDFT model. Give the options inline "
        "(--options '1,3;3,1;2,2': rows are options, columns attributes) or in a JSON file "
        "(--model file.json with keys M, and optionally w, phi1, phi2, beta, sigma2, P0, "
        "labels). Parameters not given take the canonical values phi1=0.022, phi2=0.05, "
        "beta=12, sigma2=1 and equal attention. Fixed time of 100 steps unless --steps or "
        "--threshold says otherwise."
    ),
    arguments=(
        arg("--options", metavar="ROWS",
            help="options inline, e.g. '1,3;3,1;2,2' (write --options=-1,3;... when the first "
                 "value is negative)"),
        arg("--model", metavar="FILE", help="JSON file with M (and w, parameters, labels)"),
        arg("--weights", metavar="W",
            help="attention weights, e.g. '0.5,0.5' (sum to 1; default: equal attention)"),
        arg("--labels", metavar="NAMES", help="option labels, e.g. 'A,B,C'"),
        arg("--phi1", type=_real, help="distance sensitivity of lateral inhibition (default: 0.022)"),
        arg("--phi2", type=_real, help="strength of lateral inhibition and decay (default: 0.05)"),
        arg("--beta", type=_real,
            help="weight of the dominance dimension in the distance (default: 12)"),
        arg("--sigma2", type=_real, help="variance of the valence noise (default: 1)"),
        *_STOPPING_ARGS,
        arg("--samples", type=_positive_int, default=10_000, metavar="N",
            help="number of simulated trials"),
        _SEED_ARG,
        arg("--json", action="store_true", help="print the result as JSON"),
    ),
)
def _simulate_command(args) -> int:
    import mdft

    model, labels, notes = _model_from_args(args)
    try:
        stopping = _stopping(args, default=lambda: mdft.FixedTime(DEFAULT_STEPS))
    except (ValueError, TypeError) as exc:
        raise UsageError(str(exc)) from None
    seed = _seed(args)
    res = mdft.simulate(model, args.samples, stopping=stopping, rng=seed)
    rts = getattr(res, "mean_response_times", None) if hasattr(stopping, "theta") else None
    if args.json:
        out = {
            "options": [
                {
                    "label": labels[i],
                    "M": [float(v) for v in model.M[i]],
                    "probability": float(res.probabilities[i]),
                    "standard_error": float(res.standard_errors[i]),
                    "count": int(res.counts[i]),
                    **({"mean_response_time": _finite_or_none(rts[i])} if rts is not None else {}),
                }
                for i in range(model.n_options)
            ],
            "w": [float(v) for v in model.w],
            "parameters": {k: float(getattr(model, k)) for k in DEFAULT_PARAMETERS},
            "spectral_radius": float(model.spectral_radius),
            "stopping": _stopping_json(stopping),
            "n_samples": int(res.n_samples),
            "n_undecided": int(res.n_undecided),
            "p_undecided": float(res.p_undecided),
            "seed": seed,
            "notes": notes,
        }
        print(json.dumps(out, indent=2))
        return 0
    print(
        f"MDFT simulation: {model.n_options} options, {model.n_attributes} attributes, "
        f"{_describe_stopping(stopping)}, {res.n_samples} trials, seed {seed}"
    )
    print(
        f"w = ({', '.join(f'{v:g}' for v in model.w)}), phi1 = {model.phi1:g}, "
        f"phi2 = {model.phi2:g}, beta = {model.beta:g}, sigma2 = {model.sigma2:g}, "
        f"spectral radius of S = {model.spectral_radius:.4f}"
    )
    header = ["option", "M", "P(choose)", "s.e.", "count"] + (["mean RT"] if rts is not None else [])
    rows = []
    for i in range(model.n_options):
        row = [
            labels[i], ", ".join(f"{v:g}" for v in model.M[i]),
            f"{res.probabilities[i]:.4f}", f"{res.standard_errors[i]:.4f}", str(int(res.counts[i])),
        ]
        if rts is not None:
            row.append("-" if not np.isfinite(rts[i]) else f"{rts[i]:.1f}")
        rows.append(row)
    rows.append(["undecided", "", f"{res.p_undecided:.4f}", "", str(int(res.n_undecided))]
                + ([""] if rts is not None else []))
    print(_table(header, rows))
    for note in notes:
        print(f"note: {note}", file=sys.stderr)
    return 0


# ----------------------------------------------------------------------------- effects
@subcommand(
    "effects",
    help="the similarity, attraction and compromise effects: table and figure",
    description=(
        "Run the three canonical context effects (Hotaling, Busemeyer & Li 2010 parameters) "
        "against the binary baseline {A, B}: print a table and write a figure of choice "
        "shares and preference trajectories. Threshold stopping at 17.5 unless --steps or "
        "--threshold says otherwise."
    ),
    arguments=(
        *_STOPPING_ARGS,
        arg("--samples", type=_positive_int, default=20_000, metavar="N",
            help="trials per option set"),
        _SEED_ARG,
        arg("--out", default="effects.png", metavar="PNG", help="where to write the figure"),
        arg("--trajectories", type=_non_negative_int, default=5, metavar="K",
            help="preference trajectories drawn per scenario"),
        arg("--criterion", type=_positive_float, default=3.0, metavar="Z",
            help="standard errors an effect must exceed to count as shown"),
        arg("--json", action="store_true", help="print the table as JSON"),
    ),
)
def _effects_command(args) -> int:
    import mdft

    out = Path(args.out)
    if out.suffix.lower() != ".png":
        raise UsageError(f"--out must name a .png file (got {args.out!r})")
    if not out.parent.is_dir():
        raise UsageError(f"--out: directory {str(out.parent)!r} does not exist")
    try:
        stopping = _stopping(args, default=mdft.default_stopping)
    except (ValueError, TypeError) as exc:
        raise UsageError(str(exc)) from None
    seed = _seed(args)
    results = mdft.context_effects(
        stopping=stopping, n_samples=args.samples, n_trajectories=args.trajectories,
        criterion=args.criterion, rng=seed,
    )
    _write_figure(results, out)
    if args.json:
        payload = {
            "stopping": _stopping_json(stopping),
            "n_samples": args.samples,
            "seed": seed,
            "criterion": args.criterion,
            "figure": str(out),
            "effects": [_effect_json(r) for r in results],
        }
        print(json.dumps(payload, indent=2))
        return 0
    print(
        f"Context effects: {_describe_stopping(stopping)}, {args.samples} trials per option "
        f"set, seed {seed}; shown = effect > {args.criterion:g} s.e. in the expected direction"
    )
    header = ["effect", "options", "with third", "binary", "measure", "effect", "s.e.", "z",
              "shown"]
    rows = []
    for r in results:
        s = r.scenario
        rows.append([
            s.name,
            " ".join(s.labels),
            " ".join(f"{p:.3f}" for p in r.ternary),
            " ".join(f"{p:.3f}" for p in r.binary),
            _measure_text(s),
            f"{r.effect_size:+.3f}",
            f"{r.standard_error:.3f}",
            f"{r.z:.1f}",
            "yes" if r.shown else "no",
        ])
    print(_table(header, rows))
    print(f"figure written to {out}")
    return 0


def _measure_text(s) -> str:
    t = s.labels[s.target]
    if s.measure == "relative_share":
        r = s.labels[s.rivals[0]]
        return f"P({t}) / (P({t}) + P({r}))"
    return f"P({t}) - max P({','.join(s.labels[r] for r in s.rivals)})"


def _effect_json(r) -> dict:
    s = r.scenario
    return {
        "name": s.name,
        "labels": list(s.labels),
        "M": [list(row) for row in s.M],
        "target": s.labels[s.target],
        "measure": s.measure,
        "expected": s.expected,
        "ternary": [float(p) for p in r.ternary],
        "ternary_se": [float(p) for p in r.ternary_se],
        "binary_options": [s.labels[i] for i in s.baseline],
        "binary": [float(p) for p in r.binary],
        "binary_se": [float(p) for p in r.binary_se],
        "p_undecided": [float(r.p_undecided_ternary), float(r.p_undecided_binary)],
        "effect_size": float(r.effect_size),
        "standard_error": float(r.standard_error),
        "z": _finite_or_none(r.z),
        "shown": bool(r.shown),
    }


def _write_figure(results, path: Path) -> None:
    from matplotlib.figure import Figure

    from mdft.plot import plot_context_effects

    fig = plot_context_effects(results, fig=Figure())
    try:
        fig.savefig(path, dpi=110)
    except OSError as exc:
        raise UsageError(f"--out: cannot write {str(path)!r} ({exc.strerror or exc})") from None


# ----------------------------------------------------------------------------- output helpers
def _finite_or_none(x):
    x = float(x)
    return x if math.isfinite(x) else None


def _table(header, rows) -> str:
    widths = [max(len(str(c)) for c in col) for col in zip(header, *rows)]
    lines = ["  ".join(str(c).ljust(w) for c, w in zip(header, widths)).rstrip()]
    lines.append("  ".join("-" * w for w in widths))
    lines += ["  ".join(str(c).ljust(w) for c, w in zip(row, widths)).rstrip() for row in rows]
    return "\n".join(lines)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
