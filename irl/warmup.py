"""Compile (or load from numba's on-disk cache) every compiled kernel of :mod:`irl` once.

The kernels are compiled with ``cache=True`` (``irl/_numba.py``); :func:`warmup` runs
each engine on the paper's small world so that compilation happens at a moment of the
user's choosing, announced step by step, rather than in the middle of the first fit.
"""

from __future__ import annotations

import logging
import time
import warnings
from dataclasses import dataclass

from ._repr import compact_repr

__all__ = ["WarmupReport", "warmup"]

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class WarmupReport:
    """What :func:`warmup` did: the engines warmed (``steps``), the wall time of each
    (``seconds``) and their sum (``total_seconds``)."""

    __repr__ = compact_repr

    steps: tuple
    seconds: tuple
    total_seconds: float

    def summary(self) -> str:
        """A text table of the steps and their times."""
        rows = [f"{'step':<40s} {'seconds':>10s}"]
        rows += [f"{name:<40s} {sec:10.3f}" for name, sec in zip(self.steps, self.seconds)]
        return "\n".join(rows + [f"{'total':<40s} {self.total_seconds:10.3f}"])

    def to_dict(self) -> dict:
        """The report as JSON-ready builtins."""
        return {"steps": list(self.steps), "seconds": [float(s) for s in self.seconds],
                "total_seconds": float(self.total_seconds)}


def _steps():
    from .demonstrations import generate_demonstrations
    from .io import load_paper_worlds
    from .mesc import mesc_irl
    from .planning import soft_value_iteration, state_action_visitation, value_iteration

    world = load_paper_worlds("scobee_example")[0]  # builds the transitions (a kernel)
    mdp = world.nominal_mdp
    demos = {}

    def plan():
        value_iteration(mdp)
        soft = soft_value_iteration(mdp)
        state_action_visitation(mdp, soft.policy)
        finite = soft_value_iteration(mdp, horizon=5)
        state_action_visitation(mdp, finite.policy)

    def demonstrate():
        demos["set"] = generate_demonstrations(world.constrained_mdp, 2, rng=0)

    return [
        ("planning and visitation", plan),
        ("demonstrations", demonstrate),
        ("mesc_irl", lambda: mesc_irl(mdp, demos["set"], max_iter=2)),
    ]


def warmup(progress=None) -> WarmupReport:
    """Compile, or load from the on-disk cache, every numba kernel of :mod:`irl`.

    Parameters
    ----------
    progress : callable, optional
        Called as ``progress(done, total, step)`` before each step and once more with
        ``done == total`` and ``step = "done"``. Each step is also logged at INFO level
        on the ``irl.warmup`` logger.

    Returns
    -------
    WarmupReport

    Examples
    --------
    >>> import irl
    >>> report = irl.warmup()
    >>> report.steps
    ('planning and visitation', 'demonstrations', 'mesc_irl')
    """
    if progress is not None and not callable(progress):
        raise TypeError(
            f"progress must be None or a callable progress(done, total, step) (got {progress!r})"
        )
    steps = _steps()
    seconds = []
    for done, (name, run) in enumerate(steps):
        logger.info("compiling or loading the %s kernels (%d of %d)", name, done + 1,
                    len(steps))
        if progress is not None:
            progress(done, len(steps), name)
        start = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # tiny problems: their warnings mean nothing
            run()
        seconds.append(time.perf_counter() - start)
    if progress is not None:
        progress(len(steps), len(steps), "done")
    logger.info("irl kernels ready in %.2f s", sum(seconds))
    return WarmupReport(tuple(name for name, _ in steps), tuple(seconds), float(sum(seconds)))
