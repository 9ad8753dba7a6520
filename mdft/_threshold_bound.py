"""A bound on the probability of deciding at all, for :func:`mdft.threshold_probabilities`.

Where ``theta`` lies far beyond where the preferences go within ``max_steps`` steps,
every trial ends undecided but for a vanishing share, and the chain (or the simulation
fallback) spends seconds confirming it. :func:`decision_bound` bounds that share from
the moments of the linear dynamics alone (:func:`mdft._kernels.reach_bound`: the mean
path, Hoeffding's and Bernstein's bounds on the attention switches, the Gaussian noise
and a union over options and steps), in well under a millisecond for ten thousand steps
of three options. When the bound is within the tolerances, ``threshold_probabilities``
answers "undecided" with the bound as its error (:func:`undecided_answer`).
"""

from __future__ import annotations

import math

import numpy as np

from . import _kernels
from ._threshold_fallback import RT_WEIGHT_FLOOR


def decision_bound(model, theta, max_steps):
    """Upper bound on the probability that some option is chosen within ``max_steps``
    steps of threshold stopping at ``theta`` (1.0 where the bound says nothing).

    ``model`` is a validated :class:`mdft.MDFTModel`, ``theta > 0`` and ``max_steps >= 1``
    (checked by the caller).
    """
    f64 = np.float64
    return float(_kernels.reach_bound(
        np.ascontiguousarray(model.S, dtype=f64), np.ascontiguousarray(model.C, dtype=f64),
        np.ascontiguousarray(np.asarray(model.C) @ np.asarray(model.M), dtype=f64),
        np.ascontiguousarray(model.w, dtype=f64), np.ascontiguousarray(model.P0, dtype=f64),
        float(model.sigma2), float(theta), int(max_steps)))


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


def theta_for_bound(model, max_steps, target):
    """The lowest threshold (to about 1e-12 relative) whose :func:`decision_bound` is at most
    ``target`` (bisection: the bound falls as ``theta`` rises). Used by the checks and the
    benchmark, which compare the bound with simulations at a chosen level."""
    lo, hi = float(np.max(model.P0)), max(1.0, 2.0 * float(np.max(model.P0)))
    while decision_bound(model, hi, max_steps) > target:
        lo, hi = hi, 2.0 * hi
        if not math.isfinite(hi):
            raise ValueError(f"no finite threshold brings the bound to {target:g}")
    while hi - lo > 1e-12 * hi:
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if decision_bound(model, mid, max_steps) > target else (lo, mid)
    return hi
