"""A bound on the probability of deciding at all, for :func:`mdft.threshold_probabilities`.

Where ``theta`` lies far beyond where the preferences go within ``max_steps`` steps,
every trial ends undecided but for a vanishing share, and the chain (or the simulation
fallback) spends seconds confirming it. :func:`decision_bound` bounds that share from
the linear dynamics alone (:mod:`mdft._bound_kernels`): the mean path, a bound on the
tail of the attention switches and the Gaussian noise at each step, and a union over
options and steps. Hoeffding's and Bernstein's bounds come first, in well under a
millisecond for ten thousand steps of three options; where they miss the level the
caller needs, the exact moment generating function (Chernoff) is tried, a few to a few
tens of milliseconds. When the bound is within the tolerances,
``threshold_probabilities`` answers "undecided" with the bound as its error
(:func:`undecided_answer`).
"""

from __future__ import annotations

import math

import numpy as np

from . import _bound_kernels
from ._threshold_fallback import RT_WEIGHT_FLOOR


#: Exponents of the Chernoff bound per option, and how far they reach each way from the
#: Gaussian optimum (``mdft._bound_kernels.chernoff_grid``): neighbours 1.24 times apart,
#: which costs at most 1.2 % of the best exponent where the spread is Gaussian.
CHERNOFF_POINTS = 33
CHERNOFF_SPREAD = 30.0


def decision_bound(model, theta, max_steps, target=None):
    """Upper bound on the probability that some option is chosen within ``max_steps``
    steps of threshold stopping at ``theta`` (1.0 where the bound says nothing).

    ``model`` is a validated :class:`mdft.MDFTModel`, ``theta > 0`` and ``max_steps >= 1``
    (checked by the caller). Without ``target``, Hoeffding's and Bernstein's bound
    (:func:`mdft._bound_kernels.reach_bound`). With ``target``, where that bound exceeds
    it, the Chernoff bound too (:func:`mdft._bound_kernels.chernoff_bound`), and the
    smaller of the two; the Chernoff bound stops as soon as it passes ``target``.
    """
    args = kernel_args(model, theta, max_steps)
    bound = float(_bound_kernels.reach_bound(*args))
    if target is None or bound <= target:
        return bound
    return min(bound, chernoff_bound(args, target))


def kernel_args(model, theta, max_steps):
    """The arguments of the kernels of :mod:`mdft._bound_kernels` for these inputs."""
    f64 = np.float64
    return (np.ascontiguousarray(model.S, dtype=f64), np.ascontiguousarray(model.C, dtype=f64),
            np.ascontiguousarray(np.asarray(model.C) @ np.asarray(model.M), dtype=f64),
            np.ascontiguousarray(model.w, dtype=f64),
            np.ascontiguousarray(model.P0, dtype=f64), float(model.sigma2), float(theta),
            int(max_steps))


def chernoff_bound(args, limit=1.0):
    """The Chernoff bound for :func:`kernel_args` ``args`` (1.0 where it says nothing or
    passes ``limit``)."""
    grid = _bound_kernels.chernoff_grid(*args, CHERNOFF_POINTS, CHERNOFF_SPREAD)
    if grid.shape[0] == 0:
        return 1.0
    return float(_bound_kernels.chernoff_bound(*args, grid, float(limit)))


def bound_errors(bound):
    """``(error_probabilities, error_mean_rt)`` of the "undecided" answer under ``bound``.

    An option chosen with probability ``p <= bound`` weighs in on the mean-time error with
    ``p / RT_WEIGHT_FLOOR`` (as everywhere in ``threshold_probabilities``), and the answer's
    mean time for it (NaN) counts as wrong by 100 %.
    """
    return bound, min(1.0, bound / RT_WEIGHT_FLOOR)


def within_tolerances(bound, atol, rt_rtol):
    """Whether the "undecided" answer under ``bound`` meets ``atol`` and ``rt_rtol``."""
    err_p, err_rt = bound_errors(bound)
    return err_p <= atol and err_rt <= rt_rtol


def tolerance_level(atol, rt_rtol):
    """The largest bound that :func:`within_tolerances` accepts."""
    return min(atol, RT_WEIGHT_FLOOR * rt_rtol)


def undecided_answer(n_options, max_steps, bound):
    """The fields of the answer "no option is chosen within ``max_steps`` steps" whose error
    is at most ``bound``: a dict for :class:`mdft.ThresholdProbabilities`."""
    err_p, err_rt = bound_errors(bound)
    return dict(
        probabilities=np.zeros(n_options), p_undecided=1.0,
        rt_pmf=np.zeros((max_steps, n_options)),
        mean_response_times=np.full(n_options, math.nan), max_steps=max_steps, n_cells=0,
        spacing=math.nan, n_levels=1, n_states=0, method="bound", n_iter=0, converged=True,
        tail_start=None, engine="bound", resolution=math.nan, error_probabilities=err_p,
        error_mean_rt=err_rt,
    )


def theta_for_bound(model, max_steps, target, chernoff=False):
    """The lowest threshold (to about 1e-12 relative) whose :func:`decision_bound` is at most
    ``target`` (bisection: the bound falls as ``theta`` rises); with ``chernoff=True``, the
    bound ``decision_bound(..., target=target)``, which tries the Chernoff bound too. Used by
    the checks and the benchmark, which compare the bound with simulations at a chosen
    level."""
    level = target if chernoff else None

    def above(theta):
        return decision_bound(model, theta, max_steps, target=level) > target

    lo, hi = float(np.max(model.P0)), max(1.0, 2.0 * float(np.max(model.P0)))
    while above(hi):
        lo, hi = hi, 2.0 * hi
        if not math.isfinite(hi):
            raise ValueError(f"no finite threshold brings the bound to {target:g}")
    while hi - lo > 1e-12 * hi:
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if above(mid) else (lo, mid)
    return hi


def compile_kernels():
    """Compile (or load) the Chernoff bound's kernels (mdft.warmup): the warm-up's calls
    are answered by Hoeffding's and Bernstein's bound or by the chain, and may never try
    it. Called with a model's arrays, as every call passes them."""
    from .model import MDFTModel

    model = MDFTModel([[1.0, 3.0], [3.0, 1.0]], [0.5, 0.5], phi1=0.022, phi2=0.05, beta=12.0)
    return chernoff_bound(kernel_args(model, 10.0, 3))
