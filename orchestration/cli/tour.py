"""``mdft tour``: the whole story of the package in about a minute.

A thin layer over :func:`orchestration.tour`: show its steps on stderr as they
run (compilation included, announced as such), print its three tables, where
the figures and the report went, and the next commands to try.
"""

from __future__ import annotations

import json
import sys
import threading
import time

from ._core import UsageError, arg, non_negative_int, subcommand

DEFAULT_OUT = "mdft-tour"


class _Steps:
    """The tour's steps on stderr.

    A line when a step starts (``[1/5] compiling ...``) and one with the time it
    took when it ends; on a terminal the second line is a clock that ticks every
    second while the step runs.
    """

    def __init__(self, quiet: bool, stream=None):
        self.stream = stream if stream is not None else sys.stderr
        self.quiet = quiet
        self.live = not quiet and self.stream.isatty()
        self.started: float | None = None
        self._stop = threading.Event()
        self._ticker: threading.Thread | None = None

    def __call__(self, done: int, total: int, step: str) -> None:
        now = time.perf_counter()
        if self.quiet:
            return
        self._end_step(now)
        if done < total:
            print(f"[{done + 1}/{total}] {step} ...", file=self.stream, flush=True)
            self.started = now
            if self.live:
                self._start_ticker()

    def _end_step(self, now) -> None:
        if self.started is None:
            return
        self._stop_ticker()
        took = f"      done in {now - self.started:.1f} s"
        print(f"\r{took}\033[K" if self.live else took, file=self.stream, flush=True)
        self.started = None

    def _start_ticker(self) -> None:
        stop = threading.Event()
        started = self.started
        assert started is not None  # a step has begun

        def tick():
            while not stop.wait(1.0):
                self.stream.write(f"\r      {time.perf_counter() - started:.0f} s\033[K")
                self.stream.flush()

        self._stop = stop
        self._ticker = threading.Thread(target=tick, daemon=True)
        self._ticker.start()

    def _stop_ticker(self) -> None:
        if self._ticker is not None:
            self._stop.set()
            self._ticker.join()
            self._ticker = None

    def close(self) -> None:
        """Stop the clock of an unfinished step (the run failed or was interrupted)."""
        self._stop_ticker()
        if self.live and self.started is not None:
            self.stream.write("\n")
            self.stream.flush()
        self.started = None


def next_commands_text() -> str:
    """The closing lines: commands to try next and where the documentation is."""
    from .._tour_report import DOCS, NEXT_COMMANDS

    width = max(len(c) for c, _ in NEXT_COMMANDS)
    lines = ["Next commands to try:"]
    lines += [f"  {c.ljust(width)}  {d}" for c, d in NEXT_COMMANDS]
    lines.append(f"Documentation: {', '.join(DOCS)}")
    return "\n".join(lines)


@subcommand(
    "tour",
    help="the whole story in about a minute: context effects, learned constraints, orchestrators",
    description=(
        "Run the three context effects of MDFT, learn the constraints of the paper's world from "
        "demonstrations, and compare the Greedy, weighted-average and MDFT orchestrators "
        "trading the goal off against them. Prints the tables, writes PNG figures, "
        "results.json and a one-page HTML report (report.html) into the output folder. About a "
        "minute on a quiet machine, compilation of the kernels on a first run included."
    ),
    arguments=(
        arg("--out", metavar="DIR", default=DEFAULT_OUT,
            help="output folder (created if needed; files of the same names are replaced)"),
        arg("--seed", type=non_negative_int, default=0,
            help="seed of the run; the same seed gives the same numbers (default: 0)"),
        arg("--quick", action="store_true", help="small sizes: a few seconds once compiled"),
        arg("--json", action="store_true",
            help="print the results as JSON instead of the tables (progress stays on stderr)"),
        arg("--quiet", action="store_true", help="no progress lines"),
    ),
)
def _tour_command(args) -> int:
    from pathlib import Path

    from ..guided_tour import tour

    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise UsageError(f"--out: {args.out!r} exists and is not a folder; name a folder")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UsageError(f"--out: cannot create the folder {args.out!r} "
                         f"({exc.strerror or exc})") from None
    steps = _Steps(args.quiet)
    try:
        result = tour(out, rng=args.seed, quick=args.quick, progress=steps)
    except OSError as exc:
        where = f" {exc.filename!r}" if exc.filename else ""
        raise UsageError(f"--out: cannot write{where} ({exc.strerror or exc})") from None
    finally:
        steps.close()
    if args.json:
        payload = result.to_dict()
        payload["out_dir"] = str(result.out_dir)
        print(json.dumps(payload, indent=2))
        return 0
    for number, table in enumerate(result.tables, start=1):
        print(f"\n{number}. {table.title}")
        print(table.text())
        for note in table.notes:
            print(f"   {note}")
    print("\nIn short:")
    for line in result.highlights:
        print(f"- {line}")
    compiled = ", compilation included" if result.compiled is False else ""
    print(f"\nFigures, results.json and report.html written to {str(result.out_dir)!r} "
          f"({result.seconds['total']:.0f} s{compiled}); open "
          f"{str(result.files['report.html'])!r} in a browser.")
    print()
    print(next_commands_text())
    return 0
