"""What an experiment is, and :func:`reproduce`, which runs one and writes its outputs.

An :class:`Experiment` names its settings (the paper's sizes and a quick
version), splits the work into independent units (:mod:`.runner`), and turns
the units' results into a :class:`Report`: a summary table, a JSON-ready
results dictionary and figures. :func:`reproduce` runs the units through an
executor, then writes ``results.json``, ``summary.txt`` and the PNG figures
into the output folder.
"""

from __future__ import annotations

import importlib
import io
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

from .runner import RunResult, Unit, run_units, write_atomically

__all__ = ["EXPERIMENTS", "Experiment", "Report", "get_experiment", "reproduce"]

#: Experiment name -> module of :mod:`orchestration.experiments` defining ``EXPERIMENT``.
EXPERIMENTS = {
    "orchestrators": "orchestrators",
    "mdft-vs-wa": "mdft_vs_wa",
    "hard-constraints": "hard_constraints",
    "soft-constraints": "soft_constraints",
    "transfer": "transfer",
}


@dataclass(frozen=True)
class Report:
    """What an experiment found.

    Attributes
    ----------
    name : str
        The experiment.
    title : str
        One line saying what was run.
    header : tuple of str
    rows : tuple of tuple of str
        The summary table.
    notes : tuple of str
        Lines printed under the table (findings, caveats).
    data : dict
        JSON-ready results (written to ``results.json``).
    figures : dict
        ``file name -> matplotlib Figure``; not kept after writing.
    files : tuple of pathlib.Path
        Files written by :func:`reproduce`.
    """

    name: str
    title: str
    header: tuple
    rows: tuple
    notes: tuple = ()
    data: dict = field(default_factory=dict, repr=False)
    figures: dict = field(default_factory=dict, repr=False)
    files: tuple = ()

    def text(self) -> str:
        """The summary: title, table and notes, as printed and written to ``summary.txt``.

        Examples
        --------
        >>> print(Report("x", "A test", ("a", "b"), (("1", "2"),), ("fine",)).text())
        A test
        <BLANKLINE>
        a  b
        -  -
        1  2
        <BLANKLINE>
        fine
        """
        widths = [max(len(str(c)) for c in col) for col in zip(self.header, *self.rows)]

        def line(cells):
            return "  ".join(str(c).ljust(w) for c, w in zip(cells, widths)).rstrip()

        lines = [self.title, "", line(self.header), "  ".join("-" * w for w in widths)]
        lines += [line(r) for r in self.rows]
        if self.notes:
            lines += [""] + list(self.notes)
        return "\n".join(lines)


@dataclass(frozen=True)
class Experiment:
    """An experiment: settings, units, one work function and a summary.

    Attributes
    ----------
    name : str
    description : str
    settings : callable
        ``settings(quick: bool) -> dict``: the paper's sizes, or a small version.
    units : callable
        ``units(settings) -> list of Unit``.
    work : callable
        ``work(params, seed) -> dict``, module-level (pickled to workers).
    summarise : callable
        ``summarise(settings, results: dict key -> result) -> Report``.
    """

    name: str
    description: str
    settings: Callable
    units: Callable
    work: Callable
    summarise: Callable


def get_experiment(name: str) -> Experiment:
    """The experiment called ``name`` (one of :data:`EXPERIMENTS`).

    Examples
    --------
    >>> get_experiment("hard-constraints").name
    'hard-constraints'
    """
    if name not in EXPERIMENTS:
        raise ValueError(f"experiment must be one of {sorted(EXPERIMENTS)} (got {name!r})")
    return importlib.import_module(f"{__package__}.{EXPERIMENTS[name]}").EXPERIMENT


def _settings(experiment: Experiment, quick: bool, overrides) -> dict:
    settings = dict(experiment.settings(bool(quick)))
    overrides = dict(overrides or {})
    unknown = sorted(set(overrides) - set(settings))
    if unknown:
        raise ValueError(
            f"settings of {experiment.name!r} are {sorted(settings)} (got unknown {unknown})"
        )
    settings.update(overrides)
    return json.loads(json.dumps(settings))


def _json_safe(value):
    """``value`` with NaN and infinities replaced by None (strict JSON)."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {str(k): _json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_safe(v) for v in value]
    return value


def reproduce(name: str, out, *, quick: bool = False, settings=None, seed: int = 0,
              executor=None, progress: Callable | None = None) -> Report:
    """Run an experiment and write its results, summary and figures into ``out``.

    Parameters
    ----------
    name : str
        One of :data:`EXPERIMENTS`.
    out : str or path
        Output folder. Finished units are kept in ``out/units`` so that an
        interrupted run resumes where it stopped.
    quick : bool
        A small version (well under a minute) instead of the paper's sizes.
    settings : dict, optional
        Overrides of individual settings (see each experiment's docs page).
    seed : int
        Seed of the run (>= 0).
    executor : concurrent.futures.Executor, optional
        Where the units run (see :mod:`orchestration.experiments.runner`);
        default in this process.
    progress : callable, optional
        ``progress(n_done, n_total)`` after each unit.

    Returns
    -------
    Report
        With ``files`` listing what was written.

    Examples
    --------
    >>> import tempfile
    >>> report = reproduce("hard-constraints", tempfile.mkdtemp(), seed=0,
    ...                    settings=dict(n_demonstrations=[5], n_repeats=1, zeta_levels=[0.6],
    ...                                  n_model_trajectories=20))
    >>> report.header[:2]
    ('method', 'demos')
    """
    experiment = get_experiment(name)
    settings = _settings(experiment, quick, settings)
    units = experiment.units(settings)
    run: RunResult = run_units(
        experiment.work, units, out, seed=seed,
        identity={"experiment": experiment.name, "settings": settings},
        executor=executor, progress=progress,
    )
    report = experiment.summarise(settings, run.results)
    out = Path(out)
    files = []
    data = _json_safe({"experiment": experiment.name, "seed": seed, "settings": settings,
                       **report.data})
    write_atomically(out / "results.json", json.dumps(data, indent=1, allow_nan=False))
    files.append(out / "results.json")
    write_atomically(out / "summary.txt", report.text() + "\n")
    files.append(out / "summary.txt")
    for file_name, fig in report.figures.items():
        buffer = io.BytesIO()
        fig.savefig(buffer, format="png", dpi=100)
        write_atomically(out / file_name, buffer.getvalue())
        files.append(out / file_name)
    return Report(report.name, report.title, report.header, report.rows, report.notes,
                  report.data, {}, tuple(files))


def units_of(name: str, *, quick: bool = False, settings=None) -> list[Unit]:
    """The units an experiment would run (for inspection and tests)."""
    experiment = get_experiment(name)
    return experiment.units(_settings(experiment, quick, settings))
