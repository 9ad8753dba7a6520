"""``mdft warmup``: compile, or load from numba's on-disk cache, every kernel up front."""

from __future__ import annotations

from ._core import arg, subcommand
from .tour import _Steps


@subcommand(
    "warmup",
    help="compile the numba kernels of mdft and irl now (first run only; cached afterwards)",
    description=(
        "Compile, or load from numba's on-disk cache, every compiled kernel of mdft and irl, "
        "so that no later command pauses to compile. A first run after installation takes "
        "about a minute of CPU time; later runs only load the cache, in about a second."
    ),
    arguments=(arg("--quiet", action="store_true", help="no progress lines"),),
)
def _warmup_command(args) -> int:
    import irl
    import mdft

    reports = []
    for package in (mdft, irl):
        steps = _Steps(args.quiet)
        try:
            reports.append(package.warmup(progress=steps))
        finally:
            steps.close()
    for name, report in zip(("mdft", "irl"), reports):
        print(f"{name}: {report.total_seconds:.1f} s")
        print(report.summary())
    return 0
