"""Compile (or load from numba's on-disk cache) every compiled kernel of :mod:`mdft` once.

The kernels are compiled with ``cache=True`` (``mdft/_numba.py``): the first call of a
kernel in a fresh installation compiles it, which takes seconds, and stores the machine
code beside the package (or in numba's user cache where the package folder is read-only);
later sessions load it in milliseconds. :func:`warmup` makes that first, slow call happen
at a moment of the user's choosing, with a word about each step, instead of as silence
in the middle of the first simulation.
"""

from __future__ import annotations

import logging
import time
import warnings
from dataclasses import dataclass

import numpy as np

from ._repr import compact_repr

__all__ = ["WarmupReport", "warmup"]

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class WarmupReport:
    """What :func:`warmup` did.

    Attributes
    ----------
    steps : tuple of str
        The engines warmed, in order.
    seconds : tuple of float
        Wall time of each step: seconds when it compiled, milliseconds when it loaded
        the kernels from the cache.
    total_seconds : float
        Sum of ``seconds``.
    """

    __repr__ = compact_repr

    steps: tuple
    seconds: tuple
    total_seconds: float

    def summary(self) -> str:
        """A text table of the steps and their times.

        Examples
        --------
        >>> print(WarmupReport(("a",), (1.5,), 1.5).summary())
        step                                        seconds
        a                                             1.500
        total                                         1.500
        """
        lines = [f"{'step':<40s} {'seconds':>10s}"]
        lines += [f"{name:<40s} {sec:10.3f}" for name, sec in zip(self.steps, self.seconds)]
        lines.append(f"{'total':<40s} {self.total_seconds:10.3f}")
        return "\n".join(lines)

    def to_dict(self) -> dict:
        """The report as JSON-ready builtins."""
        return {"steps": list(self.steps), "seconds": [float(s) for s in self.seconds],
                "total_seconds": float(self.total_seconds)}


def _steps():
    """(label, function) pairs, each a small call that reaches some kernels."""
    from .model import MDFTModel
    from .decide import decide
    from .simulate import _controlled_trials, _fallback_trials, simulate
    from .stopping import FixedTime, Threshold
    from . import _plane_krylov, _threshold_bound
    from .threshold_exact import threshold_probabilities

    M3 = [[1.0, 3.0], [3.0, 1.0], [2.0, 2.0]]
    w = [0.5, 0.5]
    canon = dict(phi1=0.022, phi2=0.05, beta=12.0)
    m2 = MDFTModel(M3[:2], w, **canon)
    m3 = MDFTModel(M3, w, **canon)
    # Each engine runs its chunks in the calling thread for small jobs and in parallel
    # for large ones (mdft.simulate._PARALLEL_WORK steps of work); both kernels are warmed.
    return [
        ("simulate, fixed time", lambda: (
            simulate(m3, 64, stopping=FixedTime(20), rng=0),
            simulate(m3, 2_000, stopping=FixedTime(100), rng=0))),
        ("simulate, threshold", lambda: (
            simulate(m3, 64, stopping=Threshold(5.0, max_steps=50), rng=0, n_trajectories=1),
            simulate(m3, 100, stopping=Threshold(3.0, max_steps=2_000), rng=0))),
        ("decide", lambda: (
            decide(M3, w, n_steps=10, rng=0, **canon),
            decide(np.array([M3] * 2_000), w, n_steps=100, rng=0, **canon))),
        ("threshold_probabilities", lambda: (
            threshold_probabilities(m2, 3.0, max_steps=20, n_cells=5),
            threshold_probabilities(m3, 3.0, max_steps=20),
            _plane_krylov.compile_kernels(), _threshold_bound.compile_kernels(),
            # the simulation fallback's trials, in the calling thread and in parallel
            _fallback_trials(m3, 64, 5.0, 50, np.random.default_rng(0)),
            _fallback_trials(m3, 100, 3.0, 2_000, np.random.default_rng(0)),
            # and its trials with control variates, the same two ways
            _controlled_trials(m3, 64, 5.0, 50, np.random.default_rng(0), 10.0),
            _controlled_trials(m3, 100, 3.0, 2_000, np.random.default_rng(0), 10.0))),
    ]


def warmup(progress=None) -> WarmupReport:
    """Compile, or load from the on-disk cache, every numba kernel of :mod:`mdft`.

    Runs each engine once on a tiny problem. In a fresh installation this compiles the
    kernels (about a minute of CPU time) and caches them on disk; afterwards it only loads
    them (about a second). Nothing else changes: results
    of later calls are the same with or without a warm-up.

    Parameters
    ----------
    progress : callable, optional
        Called as ``progress(done, total, step)`` before each step (``done`` steps
        finished out of ``total``, ``step`` names the engine being warmed) and once more
        with ``done == total`` and ``step = "done"``. Every step is also logged at INFO
        level on the ``mdft.warmup`` logger.

    Returns
    -------
    WarmupReport

    Examples
    --------
    >>> import mdft
    >>> seen = []
    >>> report = mdft.warmup(progress=lambda done, total, step: seen.append(step))
    >>> seen
    ['simulate, fixed time', 'simulate, threshold', 'decide', 'threshold_probabilities', 'done']
    >>> len(report.seconds)
    4
    """
    if progress is not None and not callable(progress):
        raise TypeError(
            f"progress must be None or a callable progress(done, total, step) (got {progress!r})"
        )
    steps = _steps()
    names, seconds = [], []
    for done, (name, run) in enumerate(steps):
        logger.info("compiling or loading the %s kernels (%d of %d)", name, done + 1,
                    len(steps))
        if progress is not None:
            progress(done, len(steps), name)
        start = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # tiny problems: their warnings mean nothing
            run()
        names.append(name)
        seconds.append(time.perf_counter() - start)
    if progress is not None:
        progress(len(steps), len(steps), "done")
    total = float(sum(seconds))
    logger.info("mdft kernels ready in %.2f s", total)
    return WarmupReport(tuple(names), tuple(seconds), total)
