"""``mdft reproduce``: run the paper's experiments, with a progress bar, resumable.

A thin layer over :func:`orchestration.experiments.reproduce`: choose the
executor (local processes or a Dask cluster), show progress on stderr, print
each experiment's summary table.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

from ._core import UsageError, arg, bounded_int, non_negative_int, subcommand

#: Default output folders (a quick run never mixes with a full one).
DEFAULT_OUT = "results"
DEFAULT_OUT_QUICK = "results-quick"


def _experiment_names():
    from orchestration.experiments import EXPERIMENTS

    return list(EXPERIMENTS)


def _default_workers() -> int:
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not on Linux
        return max(1, os.cpu_count() or 1)


class _ProgressBar:
    """A tqdm bar on stderr for one experiment, or nothing when quiet or not on a terminal."""

    def __init__(self, label: str, quiet: bool):
        self.label = label
        self.enabled = not quiet and sys.stderr.isatty()
        self.bar = None

    def __call__(self, done: int, total: int) -> None:
        if not self.enabled:
            return
        if self.bar is None:
            from tqdm import tqdm

            self.bar = tqdm(total=total, initial=done, desc=self.label, unit="unit",
                            file=sys.stderr, dynamic_ncols=True)
        else:
            self.bar.update(done - self.bar.n)

    def close(self):
        if self.bar is not None:
            self.bar.close()


def _executor(args):
    from orchestration.experiments import dask_executor, local_executor

    if args.scheduler is not None:
        if args.workers is not None:
            raise UsageError("give either --workers (local processes) or --scheduler (a Dask "
                             "cluster), not both")
        try:
            return dask_executor(args.scheduler)
        except ImportError as exc:
            raise UsageError(str(exc)) from None
    return local_executor(args.workers if args.workers is not None else _default_workers())


@subcommand(
    "reproduce",
    help="run the paper's experiments: tables, figures and results files",
    description=(
        "Run one of the paper's experiments (or all of them) and write its figures (PNG), "
        "results.json and summary.txt into the output folder; print the summary table. "
        "Finished units of work are saved as they complete: run the same command again to "
        "resume an interrupted run. Experiments: orchestrators (Figure 6 and the JS figure), "
        "mdft-vs-wa, hard-constraints (Figure 3), soft-constraints (appendix), transfer, all."
    ),
    arguments=(
        arg("experiment", metavar="EXPERIMENT",
            help="orchestrators, mdft-vs-wa, hard-constraints, soft-constraints, transfer or all"),
        arg("--quick", action="store_true",
            help="a small version that runs in well under a minute (default: the paper's sizes)"),
        arg("--out", metavar="DIR", default=None,
            help=f"output folder (default: {DEFAULT_OUT}/EXPERIMENT, or {DEFAULT_OUT_QUICK}/"
                 "EXPERIMENT with --quick); with 'all', one subfolder per experiment"),
        arg("--workers", type=bounded_int(1024), metavar="N", default=None,
            help="local worker processes (default: the number of CPUs; 1 runs in this process)"),
        arg("--scheduler", metavar="ADDRESS", default=None,
            help="run on the Dask cluster whose scheduler is at ADDRESS, e.g. tcp://host:8786 "
                 "(needs the 'dask' extra)"),
        arg("--seed", type=non_negative_int, default=0,
            help="seed of the run; the same seed gives the same results whatever the executor"),
        arg("--quiet", action="store_true", help="no progress bar"),
    ),
)
def _reproduce_command(args) -> int:
    from orchestration.experiments import RunMismatchError, reproduce

    names = _experiment_names()
    if args.experiment == "all":
        chosen = names
    elif args.experiment in names:
        chosen = [args.experiment]
    else:
        raise UsageError(f"EXPERIMENT must be one of {', '.join(names + ['all'])} "
                         f"(got {args.experiment!r})")
    base = Path(args.out) if args.out is not None else Path(
        DEFAULT_OUT_QUICK if args.quick else DEFAULT_OUT)
    single = args.experiment != "all" and args.out is not None
    folders = {name: base if single else base / name for name in chosen}
    for folder in folders.values():
        if folder.exists() and not folder.is_dir():
            raise UsageError(f"--out: {str(folder)!r} exists and is not a folder")
    try:
        executor_context = _executor(args)
        with executor_context as executor:
            for name in chosen:
                bar = _ProgressBar(name, args.quiet)
                try:
                    report = reproduce(name, folders[name], quick=args.quick, seed=args.seed,
                                       executor=executor, progress=bar)
                finally:
                    bar.close()
                print(report.text())
                print(f"\nwritten to {folders[name]}: "
                      f"{', '.join(p.name for p in report.files)}\n", flush=True)
    except RunMismatchError as exc:
        raise UsageError(f"--out: {exc}") from None
    except OSError as exc:
        raise UsageError(str(exc)) from None
    except KeyboardInterrupt:
        print(f"mdft reproduce: interrupted; finished units are saved in {str(base)!r}: run the "
              "same command again to resume", file=sys.stderr)
        return 130
    return 0
