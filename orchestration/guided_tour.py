"""``mdft tour``: the whole story of the package in about a minute, as tables, figures and a report.

:func:`tour` runs, on built-in defaults:

1. the compiled kernels, compiled on a first run (numba caches them on disk)
   or loaded from the cache afterwards;
2. the three context effects of MDFT (:func:`mdft.context_effects`):
   similarity, attraction and compromise against their binary baselines;
3. constraints learned from demonstrations in the world of the paper's
   Figure 1 (:func:`irl.load_paper_worlds`, :func:`irl.generate_demonstrations`,
   :func:`irl.mesc_irl`), scored against the true constraints;
4. the Greedy, weighted-average and MDFT orchestrators trading the nominal
   goal off against the learned constraints at a few weights
   (:func:`orchestration.rollout`);

and writes PNG figures, ``results.json`` and a one-page HTML report
(``report.html``, figures embedded) into an output folder. It prints nothing:
progress goes through a callback, the tables are in the returned
:class:`TourResult`.
"""

from __future__ import annotations

import json
import math
import sys
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

__all__ = ["TourResult", "TourTable", "tour"]

#: Paper's threshold on zeta for calling a feature a constraint (its Section 5).
MIN_ZETA = 0.6
#: Constraint weights w_c of the orchestrator comparison (w_n = 1 - w_c).
WEIGHTS_W_C = (0.2, 0.5, 0.8)
#: Colours of WA and MDFT in every figure (those of the trade-off figure's curves).
_COLOURS = ("tab:blue", "tab:orange")
#: Figures written by :func:`tour`, in the order of the story.
FIGURES = ("effects.png", "constraints.png", "trajectories.png", "tradeoff.png")


def settings(quick: bool = False) -> dict:
    """The sizes of a tour: the default ones (about a minute) or small ones for tests.

    Examples
    --------
    >>> settings()["n_demonstrations"], settings(quick=True)["n_demonstrations"]
    (100, 30)
    """
    if quick:
        return dict(n_samples=3000, n_trajectories_effects=3, n_demonstrations=30,
                    n_rollouts=30, p_slip=0.1, max_length=200, dpi=60)
    return dict(n_samples=20_000, n_trajectories_effects=5, n_demonstrations=100,
                n_rollouts=200, p_slip=0.1, max_length=500, dpi=100)


@dataclass(frozen=True)
class TourTable:
    """One table of the tour: a title, a header, rows of text cells and notes.

    The same cells are printed by ``mdft tour`` and written into the HTML report.

    Examples
    --------
    >>> t = TourTable("t", ("a", "b"), (("1", "2"),), ("a note",))
    >>> print(t.text())
    a  b
    -  -
    1  2
    """

    title: str
    header: tuple
    rows: tuple
    notes: tuple = ()

    def text(self) -> str:
        """The table as aligned plain text (no title, no notes)."""
        cells = [self.header, *self.rows]
        widths = [max(len(str(c)) for c in col) for col in zip(*cells)]
        lines = ["  ".join(str(c).ljust(w) for c, w in zip(self.header, widths)).rstrip(),
                 "  ".join("-" * w for w in widths)]
        lines += ["  ".join(str(c).ljust(w) for c, w in zip(row, widths)).rstrip()
                  for row in self.rows]
        return "\n".join(lines)

    def to_dict(self) -> dict:
        """The table as JSON-ready builtins."""
        return {"title": self.title, "header": list(self.header),
                "rows": [list(r) for r in self.rows], "notes": list(self.notes)}


@dataclass(frozen=True)
class TourResult:
    """What :func:`tour` computed and wrote.

    Attributes
    ----------
    out_dir : Path
        The output folder.
    files : dict of str to Path
        Every file written (figures, ``results.json``, ``report.html``).
    seed : int or None
        The integer seed when ``rng`` was one (None for a Generator).
    quick : bool
        Whether the small test sizes were used.
    settings : dict
        The sizes of the run (:func:`settings`).
    effects : list of dict
        One entry per context effect: name, options, shares with and without
        the third option, effect size, standard error, z and whether it is shown.
    constraints : dict
        The learned constraints: one entry per feature that is truly
        constrained or learned with zeta >= 0.6 (name, truth, penalty, zeta),
        precision, recall, counts, MESC-IRL convergence.
    orchestrators : list of dict
        One entry per method and weight: mean path length (steps), mean
        learned penalty and mean true violations per trajectory with their
        standard errors, share of trajectories that reached the goal.
    compiled : bool or None
        True if the kernels were compiled during this run, False if they were
        loaded from the cache, None if it could not be told in advance.
    seconds : dict of str to float
        Wall time of each step and in total.
    tables : tuple of TourTable
        The three tables, as printed and as in the report.
    highlights : tuple of str
        One sentence per step that sums up its numbers.

    Examples
    --------
    >>> import dataclasses
    >>> [f.name for f in dataclasses.fields(TourResult)][:4]
    ['out_dir', 'files', 'seed', 'quick']

    See :func:`tour` for a run.
    """

    out_dir: Path
    files: dict
    seed: object
    quick: bool
    settings: dict
    effects: list
    constraints: dict
    orchestrators: list
    compiled: object
    seconds: dict
    tables: tuple = field(default=())
    highlights: tuple = field(default=())

    def __repr__(self) -> str:
        shown = sum(e["shown"] for e in self.effects)
        c = self.constraints
        return (f"TourResult(out_dir={str(self.out_dir)!r}, effects shown {shown}/"
                f"{len(self.effects)}, precision {c['precision']:.2f}, recall "
                f"{c['recall']:.2f}, {len(self.orchestrators)} orchestrator runs, "
                f"{self.seconds.get('total', float('nan')):.1f} s)")

    def to_dict(self) -> dict:
        """Everything but the figures, as JSON-ready builtins (what ``results.json`` holds)."""
        return {
            "seed": self.seed, "quick": self.quick, "settings": dict(self.settings),
            "effects": self.effects, "constraints": self.constraints,
            "orchestrators": self.orchestrators, "compiled": self.compiled,
            "seconds": dict(self.seconds),
            "tables": [t.to_dict() for t in self.tables],
            "highlights": list(self.highlights),
            "files": {name: path.name for name, path in self.files.items()},
        }


# ----------------------------------------------------------------------------- compilation
def kernels_compiled():
    """Whether the compiled kernels of :mod:`mdft` and :mod:`irl` are ready without compiling.

    True when each package has compiled code in memory or in numba's on-disk
    cache (``cache=True``), False when one of them has none (a first run will
    compile), None when it cannot be told (numba's cache is not inspectable).

    Examples
    --------
    >>> kernels_compiled() in (True, False, None)
    True
    """
    try:
        from numba.core.dispatcher import Dispatcher
    except ImportError:  # pragma: no cover - numba is a dependency
        return None
    import irl  # noqa: F401  (load the kernel modules)
    import mdft  # noqa: F401

    ready = {"mdft": False, "irl": False}
    seen = {"mdft": False, "irl": False}
    for name, module in list(sys.modules.items()):
        package = name.split(".")[0]
        if package not in ready or module is None:
            continue
        for obj in list(vars(module).values()):
            if not isinstance(obj, Dispatcher):
                continue
            seen[package] = True
            if obj.signatures:
                ready[package] = True
                continue
            load_index = getattr(getattr(getattr(obj, "_cache", None), "_cache_file", None),
                                 "_load_index", None)
            if load_index is None:
                return None
            try:
                if load_index():
                    ready[package] = True
            except Exception:  # an unreadable cache index: numba recompiles, so do we
                pass
    if not all(seen.values()):
        return None
    return all(ready.values())


def _warm_up() -> None:
    """Call every compiled engine the tour uses once on a tiny problem."""
    import irl
    import mdft

    import orchestration as orch

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # tiny problems: their warnings mean nothing
        _tiny_calls(mdft, irl, orch)


def _tiny_calls(mdft, irl, orch) -> None:
    mdft.context_effects("compromise", n_samples=200, n_trajectories=1, rng=0)
    world = irl.GridWorld(4, 0, 15, constrained_states=(5,), p_slip=0.1)
    demos = irl.generate_demonstrations(world.constrained_mdp, 5, rng=0)
    learned = irl.mesc_irl(world.nominal_mdp, demos, max_iter=3)
    prefs = orch.action_preferences(world.nominal_mdp, learned.constrained)
    orch.rollout(orch.MDFTOrchestrator.from_preferences(prefs, (0.5, 0.5)), 2, rng=0,
                 max_length=20)


# ----------------------------------------------------------------------------- the tour
def _check_progress(progress):
    if progress is not None and not callable(progress):
        raise TypeError(
            f"progress must be None or a callable progress(done, total, step) (got {progress!r})"
        )


def _check_rng(rng) -> np.random.Generator:
    if isinstance(rng, bool) or (isinstance(rng, (int, np.integer)) and rng < 0):
        raise ValueError(f"rng must be None, an integer >= 0 or a numpy.random.Generator "
                         f"(got {rng!r})")
    try:
        return np.random.default_rng(rng)
    except (TypeError, ValueError):
        raise TypeError(f"rng must be None, an integer >= 0 or a numpy.random.Generator "
                        f"(got {rng!r})") from None


def _check_out_dir(out_dir) -> Path:
    if not isinstance(out_dir, (str, Path)) or str(out_dir) == "":
        raise TypeError(f"out_dir must be a folder path (str or Path) (got {out_dir!r})")
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise ValueError(f"out_dir {str(out)!r} exists and is not a folder; pass a folder path")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ValueError(f"out_dir {str(out)!r} cannot be created ({exc.strerror or exc})") from None
    return out


def tour(out_dir, *, rng=0, quick=False, progress=None) -> TourResult:
    """Run the tour of the package and write its figures, results and report into ``out_dir``.

    Parameters
    ----------
    out_dir : str or Path
        Output folder, created if needed. Files of the same names are replaced.
    rng : None, int or numpy.random.Generator, default 0
        Randomness, resolved with :func:`numpy.random.default_rng`; one child
        generator is spawned per step, so the same seed gives the same numbers.
    quick : bool, default False
        Small sizes (a few seconds once compiled), for tests; the defaults
        (:func:`settings`) take about a minute with compilation.
    progress : callable, optional
        Called as ``progress(done, total, step)`` before each step (``step``
        says what runs, and announces compilation on a first run) and once more
        with ``done == total`` and ``step = "done"``.

    Returns
    -------
    TourResult

    Raises
    ------
    ValueError
        If ``out_dir`` is a file or cannot be created.

    Notes
    -----
    Step 2 uses the canonical parameters of Hotaling, Busemeyer & Li (2010)
    with threshold stopping at 17.5 (``docs/concepts.md``). Step 3 follows the
    paper's Section 3: demonstrations from the soft policy of the true
    constrained world (slip 0.1), MESC-IRL with its defaults, and a feature
    called a constraint when its zeta is at least 0.6. Step 4 follows its
    Section 4, with MDFT's settings phi1 = phi2 = 0.01, beta = 2, sigma2 = 1 and
    100 deliberation steps; a violation counts each truly constrained feature
    of a transition once (``docs/orchestration.md``).

    Examples
    --------
    >>> import tempfile
    >>> steps = []
    >>> with tempfile.TemporaryDirectory() as out:
    ...     result = tour(out, rng=0, quick=True,
    ...                   progress=lambda done, total, step: steps.append(done))
    >>> steps
    [0, 1, 2, 3, 4, 5]
    >>> [e["name"] for e in result.effects]
    ['similarity', 'attraction', 'compromise']
    >>> list(result.files)  # doctest: +NORMALIZE_WHITESPACE
    ['effects.png', 'constraints.png', 'trajectories.png', 'tradeoff.png', 'results.json',
     'report.html']
    >>> [t.title for t in result.tables]
    ['Context effects', 'Constraints learned from demonstrations', 'Orchestrators']
    """
    _check_progress(progress)
    if not isinstance(quick, bool):
        raise TypeError(f"quick must be True or False (got {quick!r})")
    gen = _check_rng(rng)
    out = _check_out_dir(out_dir)
    seed = int(rng) if isinstance(rng, (int, np.integer)) else None
    g_effects, g_demos, g_rollouts, g_figures = gen.spawn(4)
    s = settings(quick)

    compiled = kernels_compiled()
    if compiled is True:
        first = "loading the compiled MDFT and IRL kernels from the cache"
    elif compiled is False:
        first = "compiling the MDFT and IRL kernels (first run only, cached afterwards)"
    else:
        first = "compiling the MDFT and IRL kernels, unless they are cached"
    steps = [
        first,
        f"the three context effects of MDFT ({s['n_samples']:,} trials per option set)",
        f"learning constraints from {s['n_demonstrations']} demonstrations in the paper's world",
        f"Greedy, WA and MDFT orchestrators ({s['n_rollouts']} trajectories per method and weight)",
        f"writing figures and the report into {str(out)!r}",
    ]
    seconds = {}
    names = ("kernels", "effects", "constraints", "orchestrators", "report")
    start_all = time.perf_counter()

    def run(k, fn):
        if progress is not None:
            progress(k, len(steps), steps[k])
        t0 = time.perf_counter()
        value = fn()
        seconds[names[k]] = time.perf_counter() - t0
        return value

    run(0, _warm_up)
    effects = run(1, lambda: _effects(s, g_effects))
    world, demos, learned, constraints = run(2, lambda: _constraints(s, g_demos))
    runs, orchestrators = run(3, lambda: _orchestrators(s, world, learned, g_rollouts))
    figures = run(4, lambda: _write_figures(out, s["dpi"], effects[0], world, demos, learned,
                                            runs, orchestrators, g_figures))
    seconds["total"] = time.perf_counter() - start_all
    files = {**figures, "results.json": out / "results.json", "report.html": out / "report.html"}
    result = TourResult(
        out, files, seed, quick, s, effects[1], constraints, orchestrators, compiled,
        dict(seconds), _tables(effects[1], constraints, orchestrators, s),
        _highlights(effects[1], constraints, orchestrators),
    )
    _write_report(result)
    if progress is not None:
        progress(len(steps), len(steps), "done")
    return result


# ----------------------------------------------------------------------------- steps
def _finite(x):
    x = float(x)
    return x if math.isfinite(x) else None


def _effects(s, gen):
    import mdft

    results = mdft.context_effects(n_samples=s["n_samples"],
                                   n_trajectories=s["n_trajectories_effects"], rng=gen)
    rows = []
    for r in results:
        sc = r.scenario
        rows.append({
            "name": sc.name, "labels": list(sc.labels),
            "M": [[float(v) for v in row] for row in sc.M],
            "target": sc.labels[sc.target], "measure": sc.measure,
            "ternary": [float(p) for p in r.ternary],
            "binary_options": [sc.labels[i] for i in sc.baseline],
            "binary": [float(p) for p in r.binary],
            "effect_size": float(r.effect_size), "standard_error": float(r.standard_error),
            "z": _finite(r.z), "shown": bool(r.shown),
        })
    return results, rows


def _constraints(s, gen):
    import irl

    world = irl.load_paper_worlds("scobee_example", p_slip=s["p_slip"])[0]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # a cut demonstration is still kept
        demos = irl.generate_demonstrations(world.constrained_mdp, s["n_demonstrations"], rng=gen)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", RuntimeWarning)
        learned = irl.mesc_irl(world.nominal_mdp, demos)
    truth = np.asarray(world.constraint_mask)
    predicted = learned.zeta >= MIN_ZETA
    scores = irl.hard_constraint_scores(truth, predicted)
    shown = np.flatnonzero(truth | predicted)
    order = sorted(shown, key=lambda i: (not truth[i], -learned.zeta[i], i))
    features = [{
        "feature": int(i), "name": learned.feature_names[i], "true": bool(truth[i]),
        "true_penalty": float(world.true_penalties[i]), "penalty": float(learned.penalties[i]),
        "zeta": float(learned.zeta[i]), "learned": bool(predicted[i]),
    } for i in order]
    data = {
        "world": "scobee_example", "p_slip": s["p_slip"],
        "n_demonstrations": len(demos), "min_zeta": MIN_ZETA, "features": features,
        "n_true": int(truth.sum()), "n_learned": int(predicted.sum()),
        "n_true_positive": scores.n_true_positive, "n_false_positive": scores.n_false_positive,
        "n_false_negative": scores.n_false_negative,
        "precision": float(scores.precision), "recall": float(scores.recall),
        "converged": bool(learned.converged), "n_iter": int(learned.n_iter),
        "warnings": [str(c.message) for c in caught],
    }
    return world, demos, learned, data


def _methods():
    """(key, label, w_c) of every method of the comparison, in table order."""
    out = [("greedy", "Greedy", None)]
    for w_c in WEIGHTS_W_C:
        out += [(f"wa-{w_c}", "WA", w_c), (f"mdft-{w_c}", "MDFT", w_c)]
    return out


def _orchestrators(s, world, learned, gen):
    import orchestration as orch

    from .experiments.orchestrators import (
        penalty_per_trajectory,
        shortest_path_length,
        violations_per_trajectory,
    )

    nominal = world.nominal_mdp
    prefs = orch.action_preferences(nominal, learned.constrained)
    mdft_settings = dict(phi1=0.01, phi2=0.01, beta=2.0, sigma2=1.0, n_steps=100)
    methods = _methods()
    gens = gen.spawn(len(methods))
    runs, rows = {}, []
    shortest = shortest_path_length(world)
    for (key, label, w_c), g in zip(methods, gens):
        if key == "greedy":
            o = orch.GreedyOrchestrator.from_preferences(prefs)
        elif label == "WA":
            o = orch.WeightedAverageOrchestrator.from_preferences(prefs, (1.0 - w_c, w_c))
        else:
            o = orch.MDFTOrchestrator.from_preferences(prefs, (1.0 - w_c, w_c), **mdft_settings)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # cut trajectories are counted
            traj = orch.rollout(o, s["n_rollouts"], rng=g, max_length=s["max_length"])
        runs[key] = traj
        length = traj.lengths.astype(float)
        penalty = penalty_per_trajectory(nominal, learned.penalties, traj)
        violations = violations_per_trajectory(world, traj).astype(float)
        n = len(traj)

        def se(x):
            return float(np.std(x, ddof=1) / math.sqrt(n)) if n > 1 else float("nan")

        rows.append({
            "method": label, "key": key,
            "w_n": None if w_c is None else round(1.0 - w_c, 10), "w_c": w_c,
            "length": float(length.mean()), "length_se": se(length),
            "penalty": float(penalty.mean()), "penalty_se": se(penalty),
            "violations": float(violations.mean()), "violations_se": se(violations),
            "reached": float(np.mean(traj.reached_terminal)), "n_trajectories": n,
            "shortest_path": shortest,
        })
    return runs, rows


# ----------------------------------------------------------------------------- tables
def _pm(mean, se, digits):
    if se is None or not math.isfinite(se):
        return f"{mean:.{digits}f}"
    return f"{mean:.{digits}f} ± {se:.{digits}f}"


def _tables(effects, constraints, orchestrators, s) -> tuple:
    eff_rows = []
    for e in effects:
        share = " ".join(f"{p:.3f}" for p in e["ternary"])
        binary = " ".join(f"{p:.3f}" for p in e["binary"])
        eff_rows.append((e["name"], " ".join(e["labels"]), share, binary,
                         f"{e['effect_size']:+.3f}", f"{e['standard_error']:.3f}",
                         "-" if e["z"] is None else f"{e['z']:.1f}",
                         "yes" if e["shown"] else "no"))
    effects_table = TourTable(
        "Context effects",
        ("effect", "options", "shares with third", "binary shares", "effect", "s.e.", "z",
         "shown"),
        tuple(eff_rows),
        (f"Canonical parameters, threshold 17.5, {s['n_samples']:,} trials per option set; "
         "an effect is shown when it exceeds 3 standard errors in the expected direction.",),
    )
    c_rows = []
    for f in constraints["features"]:
        verdict = ("found" if f["learned"] else "missed") if f["true"] else "false alarm"
        c_rows.append((f["name"], "yes" if f["true"] else "no", f"{f['penalty']:.1f}",
                       f"{f['zeta']:.2f}", verdict))
    c = constraints
    notes = (f"{c['n_demonstrations']} demonstrations, MESC-IRL "
             f"({'converged' if c['converged'] else 'not converged'} in {c['n_iter']} "
             f"iterations); a feature is learned as a constraint when zeta >= {MIN_ZETA:g}.",
             f"precision {c['precision']:.2f} ({c['n_true_positive']} of {c['n_learned']} "
             f"learned constraints are real), recall {c['recall']:.2f} "
             f"({c['n_true_positive']} of {c['n_true']} real constraints found).")
    constraints_table = TourTable(
        "Constraints learned from demonstrations",
        ("feature", "true constraint", "learned penalty", "zeta", "verdict"),
        tuple(c_rows), notes,
    )
    o_rows = []
    for r in orchestrators:
        weights = "-" if r["w_c"] is None else f"({r['w_n']:.1f}, {r['w_c']:.1f})"
        o_rows.append((r["method"], weights, _pm(r["length"], r["length_se"], 1),
                       _pm(r["penalty"], r["penalty_se"], 1),
                       _pm(r["violations"], r["violations_se"], 2), f"{r['reached']:.2f}"))
    shortest = orchestrators[0]["shortest_path"] if orchestrators else 0
    orch_table = TourTable(
        "Orchestrators",
        ("method", "(w_n, w_c)", "path length", "learned penalty", "violations", "reached goal"),
        tuple(o_rows),
        (f"{s['n_rollouts']} trajectories per method in the paper's world (slip "
         f"{s['p_slip']:g}; shortest path {shortest} steps); means ± standard errors per "
         "trajectory. Penalty: the learned penalties along the path; violations: truly "
         "constrained features entered or taken.",),
    )
    return effects_table, constraints_table, orch_table


def _highlights(effects, constraints, orchestrators) -> tuple:
    """One sentence per step, computed from its numbers."""
    shown = [e for e in effects if e["shown"]]
    zs = ", ".join(f"{e['name']} z = {e['z']:.1f}" if e["z"] is not None else e["name"]
                   for e in effects)
    first = f"{len(shown)} of {len(effects)} context effects shown ({zs})."
    c = constraints
    second = (f"{c['n_true_positive']} of {c['n_true']} true constraints learned with "
              f"{c['n_false_positive']} false alarm{'s' if c['n_false_positive'] != 1 else ''} "
              f"(precision {c['precision']:.2f}, recall {c['recall']:.2f}).")
    by = {(r["method"], r["w_c"]): r for r in orchestrators}
    lo, hi = WEIGHTS_W_C[0], WEIGHTS_W_C[-1]
    md_lo, md_hi = by[("MDFT", lo)], by[("MDFT", hi)]
    fewer = sum(by[("MDFT", w)]["violations"] < by[("WA", w)]["violations"] for w in WEIGHTS_W_C)
    third = (f"From w_c = {lo:g} to {hi:g}, MDFT's violations go from {md_lo['violations']:.2f} "
             f"to {md_hi['violations']:.2f} per trajectory and its paths from "
             f"{md_lo['length']:.1f} to {md_hi['length']:.1f} steps; MDFT violates fewer "
             f"constraints than WA at {fewer} of {len(WEIGHTS_W_C)} weights.")
    return first, second, third


# ----------------------------------------------------------------------------- output
def _write_figures(out, dpi, effects, world, demos, learned, runs, rows, gen) -> dict:
    figures = {
        "effects.png": lambda: _effects_figure(effects),
        "constraints.png": lambda: _constraints_figure(world, demos, learned),
        "trajectories.png": lambda: _trajectories_figure(world, runs, gen),
        "tradeoff.png": lambda: _tradeoff_figure(rows),
    }
    files = {}
    for name, make in figures.items():
        path = out / name
        make().savefig(path, dpi=dpi)
        files[name] = path
    return files


def _write_report(result) -> None:
    """``results.json`` and ``report.html`` of a finished tour."""
    from ._tour_report import render_html

    result.files["results.json"].write_text(json.dumps(result.to_dict(), indent=2))
    result.files["report.html"].write_text(render_html(result), encoding="utf-8")


def _effects_figure(effects):
    from matplotlib.figure import Figure

    from mdft.plot import plot_context_effects

    return plot_context_effects(effects, fig=Figure())


def _constraints_figure(world, demos, learned):
    from matplotlib.figure import Figure

    from irl.plot import plot_feature_values

    fig = Figure(figsize=(8.5, 4.6), layout="constrained")
    grid = fig.add_gridspec(2, 2, width_ratios=[2.2, 1])
    axes = [fig.add_subplot(grid[:, 0]), fig.add_subplot(grid[0, 1]), fig.add_subplot(grid[1, 1])]
    plot_feature_values(axes, world, learned.zeta, vmin=0.0, vmax=1.0,
                        label="zeta (probability of a constraint)",
                        trajectories=demos.subset(range(min(20, len(demos)))))
    axes[0].set_title("learned zeta per cell; hatched: true constraints; blue: demonstrations",
                      fontsize="small")
    return fig


def _trajectories_figure(world, runs, gen):
    from matplotlib.figure import Figure

    from .plot import plot_rollouts

    fig = Figure(figsize=(3.9 * len(WEIGHTS_W_C), 4.5), layout="constrained")
    axes = np.atleast_1d(fig.subplots(1, len(WEIGHTS_W_C)))
    for ax, w_c in zip(axes, WEIGHTS_W_C):
        plot_rollouts(ax, world, {"WA": runs[f"wa-{w_c}"], "MDFT": runs[f"mdft-{w_c}"]},
                      n_shown=15, rng=gen, colors=_COLOURS)
        ax.get_legend().remove()  # one legend for the figure, below the panels
        ax.set_title(f"weights (w_n, w_c) = ({1 - w_c:.1f}, {w_c:.1f})", fontsize="medium")
    handles, labels = axes[0].get_legend_handles_labels()
    legend = fig.legend(handles, labels, loc="outside lower center", ncols=len(labels),
                        frameon=False)
    for handle in legend.legend_handles:
        handle.set_alpha(1.0)
    return fig


def _tradeoff_figure(rows):
    from .experiments.plot import new_figure, plot_weight_sweep

    fig, axes = new_figure(2, width=4.6, height=3.4)
    greedy = next(r for r in rows if r["key"] == "greedy")
    for ax, metric, label in zip(axes, ("length", "violations"),
                                 ("path length (steps)", "violations per trajectory")):
        curves = {}
        for method in ("WA", "MDFT"):
            mine = [r for r in rows if r["method"] == method]
            curves[method] = (np.array([r[metric] for r in mine]),
                              np.array([r[f"{metric}_se"] for r in mine]))
        ax.set_prop_cycle(color=list(_COLOURS))  # WA and MDFT as in the trajectories figure
        plot_weight_sweep(ax, list(WEIGHTS_W_C), curves, baselines={"Greedy": greedy[metric]},
                          ylabel=label)
    fig.suptitle("The goal traded off against the constraints (means ± s.e.)")
    return fig
