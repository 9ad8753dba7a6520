"""Helpers shared by the experiments: means with standard errors, table cells, soft trajectories."""

from __future__ import annotations

import math
import warnings

import numpy as np


def mean_se(values):
    """Mean and standard error of the finite values (NaN, NaN if there are none).

    Examples
    --------
    >>> mean_se([1.0, 2.0, 3.0])
    (2.0, 0.5773502691896258)
    >>> mean_se([4.0])
    (4.0, nan)
    """
    x = np.asarray([v for v in values if v is not None], dtype=float)
    x = x[np.isfinite(x)]
    if x.size == 0:
        return float("nan"), float("nan")
    se = float(x.std(ddof=1) / math.sqrt(x.size)) if x.size > 1 else float("nan")
    return float(x.mean()), se


def ratio_se(numerators, denominators):
    """Ratio of means ``mean(a) / mean(b)`` over paired values and its delta-method standard error.

    ``se = sd(a - r b) / (sqrt(n) |mean(b)|)``; NaN where ``mean(b)`` is 0.

    Examples
    --------
    >>> r, se = ratio_se([2.0, 4.0, 6.0], [1.0, 2.0, 3.0])
    >>> r, se
    (2.0, 0.0)
    """
    a = np.asarray(numerators, dtype=float)
    b = np.asarray(denominators, dtype=float)
    if a.size == 0 or b.mean() == 0:
        return float("nan"), float("nan")
    r = float(a.mean() / b.mean())
    if a.size < 2:
        return r, float("nan")
    return r, float(np.std(a - r * b, ddof=1) / (math.sqrt(a.size) * abs(b.mean())))


def cell(mean, se=None, *, digits=3) -> str:
    """``"0.123 ± 0.004"`` (or ``"-"`` where the mean is not finite).

    Examples
    --------
    >>> cell(0.12345, 0.0042)
    '0.123 ± 0.004'
    >>> cell(float("nan"))
    '-'
    """
    if mean is None or not math.isfinite(mean):
        return "-"
    if se is None or not math.isfinite(se):
        return f"{mean:.{digits}f}"
    return f"{mean:.{digits}f} ± {se:.{digits}f}"


def soft_trajectories(mdp, n, rng):
    """``n`` trajectories of the soft (maximum causal entropy) policy of ``mdp``.

    A trajectory cut at the step limit is kept (it still counts in the
    visitation metrics); the warning about it is not shown.
    """
    import irl

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return irl.generate_demonstrations(mdp, n, rng=rng)
