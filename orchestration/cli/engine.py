"""Commands of the MDFT engine: ``mdft simulate`` and ``mdft effects``.

Thin layers over :func:`mdft.simulate` and :func:`mdft.context_effects`: parse
and check the arguments, call the library, print a table or JSON, write figures.
"""

from __future__ import annotations

import json
import math
import sys
import warnings
from pathlib import Path

import numpy as np

from ._core import (
    MAX_SAMPLES,
    MAX_STEPS,
    SEED_ARG,
    UsageError,
    arg,
    bounded_int,
    finite_or_none,
    non_negative_int,
    positive_float,
    real,
    seed_of,
    subcommand,
    table,
)

#: Defaults of ``mdft simulate`` for parameters not given: the canonical set
#: of Hotaling, Busemeyer & Li (2010) (docs/concepts.md, section 7).
DEFAULT_PARAMETERS = {"phi1": 0.022, "phi2": 0.05, "beta": 12.0, "sigma2": 1.0}
DEFAULT_STEPS = 100
DEFAULT_MAX_STEPS = 10_000
#: Most preference trajectories ``mdft effects`` draws per scenario.
MAX_TRAJECTORIES = 1000
_MODEL_KEYS = {"M", "w", "phi1", "phi2", "beta", "sigma2", "P0", "labels"}


# ----------------------------------------------------------------------------- stopping
_STOPPING_ARGS = (
    arg("--steps", type=bounded_int(MAX_STEPS), metavar="N",
        help="fixed deliberation time: choose the best option after N steps"),
    arg("--threshold", type=positive_float, metavar="THETA",
        help="threshold stopping: choose the first option whose preference reaches THETA"),
    arg("--max-steps", type=bounded_int(MAX_STEPS), metavar="K", default=None,
        help=f"with --threshold: trials undecided after K steps are reported as undecided "
             f"(default: {DEFAULT_MAX_STEPS})"),
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
        text = p.read_text(encoding="utf-8")
    except OSError as exc:
        raise UsageError(f"--model: cannot read {path!r} ({exc.strerror or exc})") from None
    except UnicodeDecodeError as exc:
        raise UsageError(
            f"--model: {path!r} is not UTF-8 text (byte {exc.start}: {exc.reason})"
        ) from None
    try:
        spec = json.loads(text)
    except json.JSONDecodeError as exc:
        raise UsageError(f"--model: {path!r} is not valid JSON ({exc})") from None
    except (ValueError, RecursionError) as exc:  # e.g. integers of more than 4300 digits
        raise UsageError(f"--model: {path!r} is not usable JSON ({exc})") from None
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
        if not isinstance(labels, list) or not all(isinstance(x, (str, int, float))
                                                   for x in labels):
            raise UsageError(f"labels must be a list of names, one per option (got {labels!r})")
    labels = [str(s) for s in labels]
    if len(labels) != n_options:
        raise UsageError(f"labels: need one per option, {n_options} (got {len(labels)}: {labels})")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", mdft.UnstableFeedbackWarning)
        try:
            model = mdft.MDFTModel(M, w, P0=spec.get("P0"), **params)
        except (ValueError, TypeError, OverflowError) as exc:
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
        arg("--phi1", type=real, help="distance sensitivity of lateral inhibition (default: 0.022)"),
        arg("--phi2", type=real, help="strength of lateral inhibition and decay (default: 0.05)"),
        arg("--beta", type=real,
            help="weight of the dominance dimension in the distance (default: 12)"),
        arg("--sigma2", type=real, help="variance of the valence noise (default: 1)"),
        *_STOPPING_ARGS,
        arg("--samples", type=bounded_int(MAX_SAMPLES), default=10_000, metavar="N",
            help="number of simulated trials"),
        SEED_ARG,
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
    seed = seed_of(args)
    with warnings.catch_warnings(record=True) as caught:  # notes, not stray warning lines
        warnings.simplefilter("always", mdft.UnstableFeedbackWarning)
        res = mdft.simulate(model, args.samples, stopping=stopping, rng=seed)
    notes = list(notes) + [str(c.message) for c in caught
                           if issubclass(c.category, mdft.UnstableFeedbackWarning)]
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
                    **({"mean_response_time": finite_or_none(rts[i])} if rts is not None else {}),
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
    print(table(header, rows))
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
        arg("--samples", type=bounded_int(MAX_SAMPLES), default=20_000, metavar="N",
            help="trials per option set"),
        SEED_ARG,
        arg("--out", default="effects.png", metavar="PNG", help="where to write the figure"),
        arg("--trajectories", type=non_negative_int, default=5, metavar="K",
            help="preference trajectories drawn per scenario"),
        arg("--criterion", type=positive_float, default=3.0, metavar="Z",
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
    if args.trajectories > min(args.samples, MAX_TRAJECTORIES):
        raise UsageError(
            f"--trajectories ({args.trajectories}) must not exceed --samples ({args.samples}) "
            f"nor {MAX_TRAJECTORIES}; they are a few trials drawn for the figure"
        )
    seed = seed_of(args)
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
    print(table(header, rows))
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
        "z": finite_or_none(r.z),
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
