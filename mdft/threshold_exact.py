"""Threshold stopping without Monte Carlo noise: choice and response-time distributions.

The preference process ``P(t+1) = S P(t) + C (M W(t+1) + eps(t+1))``, stopped
when some ``P_i`` reaches ``theta``, is approximated by an absorbing Markov
chain on a grid of the preference state: a lattice for two options
(Diederich & Busemeyer 2003) and a moment chain for three (cells of the
zero-sum plane of the preferences, cut to the size of each step, each
carrying the first moments of the summed preference instead of levels of
it). The probability of stopping at a step is computed from
the state exactly; only the part that stays is put on the grid. The grid is
chosen from the model (noise, attention spread, threshold), and every answer
is computed at two resolutions: their difference (for three options, plus a
bound on the moment closure's error) is the reported error estimate, and the
resolution is refined until the estimate meets the
tolerance, or an error is raised. See ``docs/threshold_exact.md``.
"""

from __future__ import annotations

import logging
import math
from functools import partial

import numpy as np

from ._lattice_chain import UnboundedSum, build_chain, chain_sum_bounds, sum_is_constant
from ._lattice_moving import MAX_MOVING_STEPS, build_moving_chain, moving_sum_steps
from ._plane_chain import TooManyStates
from ._plane_passes import HALF_STEP, KAPPA, REFINE, narrow_everywhere, plane_runs
from ._threshold_bound import (decision_bound, tolerance_level, undecided_answer,
                               within_tolerances)
from ._threshold_fallback import (CONTROLLED_PROBE_SHARE, CONTROLLED_REACH, PROBE_BATCH,
                                  OverBudget, controlled_probe_work, predicted_trials,
                                  predicted_work, refuse_if_far_over_budget, simulated_answer,
                                  steps_per_walk)
from ._threads import fitted_to_the_load
from ._threshold_solve import error_estimate, own_error, solve_chain, with_errors
from ._validation import MAX_STEPS, MAX_THETA, as_count, as_generator, as_scalar
from .model import MDFTModel
from .threshold_result import ThresholdProbabilities, ThresholdToleranceError

__all__ = ["ThresholdProbabilities", "ThresholdToleranceError", "threshold_probabilities"]

logger = logging.getLogger(__name__)

_MAX_OPTIONS = 3
_METHODS = ("propagate", "solve")
_FALLBACKS = ("simulation", "raise")
# Two options: lattice spacing at most this many per-step standard deviations, at least
# this many cells per theta.
_BINARY_SPACING = 0.5
_BINARY_MIN_CELLS = 40
_BINARY_MAX_CELLS = 3_000
# Three options: the grids of the schedule are those of mdft._plane_passes (KAPPA, then
# refinements by REFINE with a half step of HALF_STEP before each). A half step's answer is
# compared with the refinement before it, the change scaled by 1 / (sqrt(2) - 1) (the error
# falling with the square of the cell size over a ratio of 2**(1/4)). A half step is run
# only where that may meet the tolerances: after the first comparison (whose factor makes
# it pessimistic) where its grid term is within _FIRST_HALF_REACH times the room the
# closure leaves, later where the grid term of the refinement before it, times 1 / sqrt(2)
# (what second order leaves at the half step), fills at most _HALF_STEP_ROOM of that room.
_HALF_STEP_FACTOR = 1.0 / (HALF_STEP**2 - 1.0)
_HALF_STEP_ROOM = 0.5
_FIRST_HALF_REACH = 10.0
# Three options: the coarsest grid (a cell and a half per standard deviation of a step) is
# often outside the range where the error falls with the square of the cell size, so the
# first comparison counts as if the error fell only in proportion to it: the change is
# scaled by 1 / (sqrt(2) - 1). Later comparisons are taken as they are.
# The two-option lattice's first comparison (of n / 2 and n cells, or n and 2 n where the sum
# moves) counts alike, as if the error fell by only sqrt(2) per doubling: with a start away
# from 0 it fell by 1.5 there, and the plain change was half the error of the finer answer.
_FIRST_PAIR_FACTOR = 1.0 / (REFINE - 1.0)
# Three options, simulation fallback: the cost of building a nonzero of the chain and of
# simulating one step of one trial, in units of propagating a nonzero by one step (measured
# with benchmarks/bench_threshold_work.py: a simulated trial-step costs about 10 (14 before
# the fallback's trials drew one normal fewer per step, 17 before they held their stream in
# local variables, 30 before two and three options stepped in scalars), building a nonzero
# about 150, 100-590 from chain to chain); the fallback simulates when that costs less than
# the next refinement.
_BUILD_WORK = 150.0
_SIM_STEP_WORK = 10.0
# The same count decides before the first pass that counts, from the first pilot's answer:
# where simulating costs less than _EARLY_SHARE of that pass, its probes and the next (the
# coarse pilot's prediction is rougher than a counted pass's), the call simulates; if the
# trials then need more than _SIM_OVERRUN times the passes' work, the chain goes on instead.
_EARLY_SHARE = 0.6
_SIM_OVERRUN = 2.0
# Where plain trials are predicted to cost more than the chain, but by at most
# CONTROLLED_REACH times, a probe of plain and controlled trials (costing at most
# CONTROLLED_PROBE_SHARE of the chain's work) measures what control variates save; once per
# call (_controls_may_pay), and only where the chain's work is at least _PROBE_MIN_WORK
# (about a second on an idle 2-core machine; on shorter calls the probes that find no saving
# cost more than the rare ones that do save). The early hand-over's simulations on a budget
# of at least that may also go on to controlled trials where their plain probe is over it.
_PROBE_MIN_WORK = 1e9
# A pass whose noise is narrower than its cells is not trusted, and the refinement goes on
# to the first resolution where it is not; where that resolution's states, predicted from the
# narrow pass's (a plane grid: the square of the ratio of the resolutions), exceed
# max_states by more than this factor, the chain stops there instead of refining towards it.
_NARROW_STATES_MARGIN = 1.5


def _three_options(model=None, *args, **kwargs):
    """Whether a call of :func:`threshold_probabilities` may run the three-option chain,
    whose steps run on numba's threads (for :func:`mdft._threads.fitted_to_the_load`)."""
    return getattr(model, "n_options", None) == 3


@fitted_to_the_load(_three_options)
def threshold_probabilities(model, theta, *, max_steps=10_000, atol=1e-3, rt_rtol=3e-3,
                            n_cells=None, resolution=None, method="propagate", tol=1e-10,
                            tail_tol=1e-6, max_iter=2_000, max_states=100_000,
                            fallback="simulation", rng=None, edge_correction=False):
    """Choice probabilities and response-time distribution of threshold stopping.

    The stopped MDFT process becomes an absorbing Markov chain on a grid of
    the preference state, solved without Monte Carlo noise, at a resolution
    chosen from the model and refined until the estimated error meets
    ``atol`` and ``rt_rtol``. Works for two and three options; with more
    options (no chain) the default fallback simulates to the tolerances.

    Parameters
    ----------
    model : MDFTModel
        The model. The chain needs two or three options, ``sigma2 > 0`` and a
        contrast ``C`` whose columns sum to zero (the standard one does);
        more options, no noise, another contrast and a feedback matrix with a
        column sum above 1 are simulated (``fallback="simulation"``).
    theta : float
        Threshold, > 0 and at most 1e300: option ``i`` is chosen at the first step where
        ``P_i >= theta``; if several preferences reach it at the same step,
        the largest is chosen (as :func:`mdft.simulate` does).
    max_steps : int, default 10_000
        Step limit of ``method="propagate"`` (at most 10,000,000, as for
        ``mdft.Threshold``); mass not absorbed by then is
        ``p_undecided``. Ignored by ``method="solve"``.
    atol : float, default 1e-3
        Tolerance of the estimated error of the choice probabilities (and of
        ``p_undecided``).
    rt_rtol : float, default 3e-3
        Tolerance of the estimated relative error of the mean response times.
    n_cells : int, optional
        Two options only: a fixed lattice resolution (cells per ``theta``,
        at least 4) instead of the one chosen from the model. The error is
        still estimated and checked.
    resolution : float, optional
        Three options only: the first cell size in per-step standard
        deviations (default 1.0; between 0.3 and 2). Refinements divide it by
        ``sqrt(2)``, with a half step (``2**(1/4)``) before each where it may
        answer (``docs/threshold_exact.md``, section 4).
    edge_correction : bool, default False
        Three options only: add back, in every row of the chain, the terms of
        second order in the cell size that its variance correction leaves at
        the thresholds. The answers then converge steadily as the grid is
        refined, and the error estimate (a comparison of two grids) holds
        where the default chain's coarse grids agree by chance, above all on
        the mean times of long deliberations; calls take about 1.6 times as
        long in the median, as they refine to finer grids
        (``docs/threshold_exact.md``, section 2, "Edge terms").
    method : {"propagate", "solve"}, default "propagate"
        ``"propagate"`` applies the chain step by step and returns the
        response-time distribution; it stops early once the undecided mass is
        below ``tol`` or the geometric tail is reached (``tail_tol``).
        ``"solve"`` solves ``(I - Q^T) y = x_1`` (sparse LU up to 3,000
        states, above that BiCGSTAB, with restarted GMRES if it fails) for
        the long-run (unlimited time) probabilities and mean response times.
        For three options it was 1.4-9.4 times slower than ``"propagate"`` on
        random models (``docs/threshold_exact.md``, section 6).
    tol : float, default 1e-10
        ``"propagate"``: undecided mass at which propagation stops.
        ``"solve"``: relative residual of the iterative solver.
    tail_tol : float, default 1e-6
        ``"propagate"``, two options: once the undecided mass decays by a
        constant factor per step and the options' shares of each step's
        choices stay fixed (relative changes below ``tail_tol`` for 20 steps in
        a row), the rest of ``rt_pmf`` is filled in geometrically. Three
        options (any ``tail_tol > 0``): the rest is filled in geometrically
        once the change that the remaining drift of the decay and of the
        shares may still make is within 1 % of ``atol`` and ``rt_rtol``; that
        change is added to the error estimate. 0 propagates every step.
    max_iter : int, default 2000
        Iteration limit of the iterative solver, per right-hand side.
    max_states : int, default 100_000
        Largest chain the method may build to meet the tolerances.
    fallback : {"simulation", "raise"}, default "simulation"
        What to do when the chain cannot meet ``atol`` and ``rt_rtol`` within
        ``max_states``, or no chain can answer for the model (more than three
        options, no noise, a contrast whose columns do not sum to zero, or a
        feedback matrix whose worst case of the summed preference has no finite
        range) (``method="propagate"`` only): ``"simulation"``
        simulates trials in growing batches until three standard errors of
        every probability are within ``atol`` and of every mean response time
        within ``rt_rtol`` (``engine="simulation"``; the error fields are those
        three standard errors), raising if that needs more than 2e9
        trial-steps. It also simulates, for three options, where simulating
        to the tolerances is counted to cost less than the chain's next
        grid, or (from the first pilot pass's answer) than its first passes
        (``docs/threshold_exact.md``, section 4). ``"raise"`` raises
        ValueError at once and never simulates (what fitting uses: a
        likelihood must not switch to a noisy method mid-optimisation).
    rng : None, int or numpy.random.Generator
        Source of the fallback's trials; None uses a fixed seed, so calls are
        repeatable.

    Returns
    -------
    ThresholdProbabilities
        Frozen dataclass with ``probabilities``, ``p_undecided``, ``rt_pmf``,
        ``mean_response_times``, the grid used and the error estimates.

    Raises
    ------
    ValueError
        Bad arguments; a model with more than three options, without noise,
        with a contrast whose columns do not sum to zero, or with a feedback
        matrix under which the chain's worst case of the summed preference is
        not bounded (a column sum of ``S`` above 1), unless the fallback
        simulates it; an initial preference at or above ``theta``; a feedback matrix
        under which the summed preference is unstable (equal
        column sums of magnitude above 1, as with ``phi2 > 2 / n_options`` and
        ``phi1 = 0``); a model for which
        the estimated error cannot be brought below the tolerances within
        ``max_states`` states (or, judged from the last three comparisons,
        within the finer grids still possible) and the fallback is off or over
        its budget.
    ThresholdToleranceError
        The last case with the fallback off (``fallback="raise"`` or
        ``method="solve"``): the chain ran and its estimated error stayed
        beyond ``atol`` or ``rt_rtol``. A subclass of ``ValueError``.

    Notes
    -----
    First (``method="propagate"``, any number of options), the probability
    that some preference reaches ``theta`` within ``max_steps`` steps is
    bounded from the mean path and the spread of the linear dynamics
    (Hoeffding's and Bernstein's bounds on the attention switches, the
    Gaussian noise, a union over options and steps; well under a
    millisecond; where they miss the tolerances, the Chernoff bound from the
    attention terms' exact moment generating function, milliseconds). Where
    that bound is within ``atol`` and, weighed as a rarely chosen option's
    mean time is, within ``rt_rtol`` (a bound of at most
    ``0.01 * rt_rtol``), the answer is "undecided" (``engine="bound"``:
    probabilities 0, ``p_undecided`` 1, mean times NaN) with the bound as
    its error, and no chain is built.

    A three-option call runs on numba's threads (``numba.set_num_threads``
    chooses), but on one where a few empty parallel regions, timed first,
    show the cores busy; the answer is the same to the bit either way
    (``docs/threshold_exact.md``, "Decisions").

    Every valence ``C (M W + eps)`` sums to zero, so only the feedback ``S``
    moves the summed preference ``s = 1^T P``, deterministically. The chain's
    states are grid cells of the zero-sum plane (one axis for two options,
    two for three). When ``S`` moves ``s`` alike on every walk (two options,
    rows and columns of ``S`` summing alike, as the parametric ``S`` does, and
    a start ``P0`` that does not sum to zero), only the two-option lattice's
    thresholds move, and it steps them with the sum, cutting the cells they
    fall in; when ``s`` depends on the walk, the two-option lattice adds levels
    of ``s``; the three-option chain instead carries, on every cell, the
    probability and the first two moments of ``s`` there, and applies each
    state's transition linearised around a reference sum fitted by a pilot
    pass (exact to first order in the deviation; the spread of ``s`` within a
    state enters through a two-point average, each point placing a cut cell's
    mass where the region lies at its sum; the larger of the changes that a
    spread smaller by ``sqrt(2)`` and each cell's reference sum set to the
    walks' own mean sum make is added to the error estimate). From a state,
    the step given the attended attribute ``j`` is Gaussian with mean
    ``S P + C M e_j``; the probability that it ends with option ``i``
    chosen is a normal (two options) or bivariate normal (three) tail; the
    rest is put on the cells inside the region ``{P_i < theta}``. The cell
    size follows the per-step spread, and the Gaussian is narrowed (variance
    correction) so that the chain's per-step covariance equals the model's.

    Examples
    --------
    >>> import mdft
    >>> model = mdft.MDFTModel([[1, 3], [3, 1]], [0.5, 0.5],
    ...                        phi1=0.022, phi2=0.05, beta=12.0)
    >>> res = mdft.threshold_probabilities(model, 17.5)
    >>> res.probabilities.round(3)
    array([0.5, 0.5])
    >>> round(float(res.mean_response_times[0]))
    143
    >>> res.rt_pmf.shape
    (10000, 2)
    >>> bool(res.error_probabilities < 1e-3)
    True
    """
    (theta, max_steps, atol, rt_rtol, tol, max_iter, tail_tol, max_states, n_cells,
     resolution) = _checked_arguments(model, theta, max_steps, atol, rt_rtol, n_cells,
                                      resolution, method, tol, tail_tol, max_iter, max_states,
                                      fallback, rng, edge_correction)
    n = model.n_options

    bounded = _undecided_within_tolerances(model, theta, max_steps, atol, rt_rtol, method)
    if bounded is not None:
        return bounded
    solve = dict(method=method, max_steps=max_steps, tol=tol, tail_tol=tail_tol,
                 max_iter=max_iter)
    closure = dict(error=(0.0, 0.0), settled=True)
    probed = []  # the probe of controlled trials, once run (_controls_may_pay)
    reason = _no_chain(model, theta, resolution)
    if reason:
        runs = []  # no chain holds the states, or no pass can be trusted: refuse (or simulate)
    elif n == 2:
        runs = _binary_runs(model, theta, n_cells, max_states, solve)
    else:
        cheaper = None
        if fallback == "simulation" and method == "propagate":
            cheaper = partial(_simulated_if_cheaper, model=model, theta=theta,
                              max_steps=max_steps, atol=atol, rt_rtol=rt_rtol, rng=rng,
                              probed=probed)
        runs = plane_runs(model, theta, resolution or KAPPA, max_states, solve, closure,
                           (atol, rt_rtol), cheaper, bool(edge_correction))
    coarse = fine = None
    # the comparison partner of the next pass: the last pass that was not a half step
    partner = partner_tail = None
    partner_index = -1
    grid_errors = []  # each comparison's grid term (probabilities, mean times)
    try_half = True  # whether the next half step may meet the tolerances
    closure_bound = False  # refused for the closure's term, which more states cannot lower
    for index, compute in enumerate(runs):
        half = compute.half
        if half and (not try_half or compute.narrow()):
            continue
        try:
            result = compute()
        except TooManyStates as exc:
            reason = str(exc)
            break
        if result.engine == "simulation":
            return result  # the pilots foresaw that simulating costs less than the chain
        coarse, fine = partner, result
        # the change that each pass's extrapolated tail may make (three options)
        own_tail = (own_error(result.error_probabilities), own_error(result.error_mean_rt))
        tails = [partner_tail or (0.0, 0.0), own_tail]
        first_pair = partner_index == 0
        if not half:
            partner, partner_tail, partner_index = result, own_tail, index
        spread_p, spread_rt = _closure_term(closure)
        bound_reason = _closure_bound(closure, (spread_p, spread_rt), atol, rt_rtol)
        if bound_reason:
            reason = bound_reason
            closure_bound = True
            break
        narrow = closure.get("narrow", False)
        if narrow:
            beyond = _trusted_beyond(runs[index + 1:], result, max_states)
            if beyond:
                reason = _narrow(result) + beyond
                break
        if coarse is None:
            continue
        grid_p, grid_rt = _grid_term(fine, coarse, first_pair, half)
        err_p = grid_p + (tails[0][0] + tails[1][0])
        err_rt = grid_rt + (tails[0][1] + tails[1][1])
        fine = with_errors(fine, err_p + spread_p, err_rt + spread_rt)
        logger.debug("resolution %.3g: estimated error %.2g and %.2g, of which the closure's "
                     "%.2g and %.2g", fine.resolution, err_p + spread_p, err_rt + spread_rt,
                     spread_p, spread_rt)
        if err_p + spread_p <= atol and err_rt + spread_rt <= rt_rtol and not narrow:
            return fine
        if not half:
            try_half = _half_step_may_answer((grid_p, grid_rt), tails[1], (spread_p, spread_rt),
                                             (atol, rt_rtol), first_pair)
        if fallback == "simulation" and method == "propagate" and fine.engine == "plane":
            # the next pass has about four times the nonzeros of this one, twice for a half
            # step
            ratio = HALF_STEP if half or try_half else REFINE
            answer, handed = _simulated_if_finer_costs_more(
                fine, ratio**4 * closure["nonzeros"], probed, model=model, theta=theta,
                max_steps=max_steps, atol=atol, rt_rtol=rt_rtol, rng=rng)
            if answer is not None:
                return answer
            if handed:
                reason = handed
                break
        if narrow:
            reason = _narrow(fine)
            continue
        reason = _not_yet(fine, (err_p, err_rt), (spread_p, spread_rt), atol, rt_rtol)
        if fine.engine == "plane" and not half:
            grid_errors.append((err_p, err_rt))
            # the refinements still possible (half steps aside): each has about twice the
            # states
            left = sum(not run.half for run in runs[index + 1:])
            left = min(left, int(math.log2(max_states / max(fine.n_states, 1))))
            hopeless = _out_of_reach(grid_errors, (spread_p, spread_rt), (atol, rt_rtol), left)
            if hopeless:
                reason += hopeless
                break
    return _after_refusal(model, theta, max_steps, atol, rt_rtol, rng, fallback, method,
                          max_states, runs, fine, reason, closure_bound)


def _checked_arguments(model, theta, max_steps, atol, rt_rtol, n_cells, resolution, method,
                       tol, tail_tol, max_iter, max_states, fallback, rng, edge_correction):
    """The arguments of :func:`threshold_probabilities`, checked, and those it uses as
    numbers converted: ``(theta, max_steps, atol, rt_rtol, tol, max_iter, tail_tol,
    max_states, n_cells, resolution)``. Also checks that ``P0`` lies below ``theta`` and
    that the summed preference is not unstable under ``S``."""
    if not isinstance(model, MDFTModel):
        raise TypeError(f"model must be an MDFTModel (got {type(model).__name__})")
    n = model.n_options
    theta = as_scalar("theta", theta, low=0.0, low_inclusive=False, high=MAX_THETA)
    if method not in _METHODS:
        raise ValueError(f"method must be one of {_METHODS} (got {method!r})")
    max_steps = as_count("max_steps", max_steps, low=1, high=MAX_STEPS)
    atol = as_scalar("atol", atol, low=0.0, low_inclusive=False, high=0.5)
    rt_rtol = as_scalar("rt_rtol", rt_rtol, low=0.0, low_inclusive=False, high=0.5)
    tol = as_scalar("tol", tol, low=0.0, low_inclusive=False, high=0.1)
    max_iter = as_count("max_iter", max_iter, low=1)
    tail_tol = as_scalar("tail_tol", tail_tol, low=0.0, high=0.1)
    max_states = as_count("max_states", max_states, low=10)
    if fallback not in _FALLBACKS:
        raise ValueError(f"fallback must be one of {_FALLBACKS} (got {fallback!r})")
    if rng is not None:
        as_generator("rng", rng)  # checked here, used only if a simulation answers
    if n_cells is not None:
        if n != 2:
            raise ValueError(
                f"n_cells sets the two-option lattice (got a model with {n} options); "
                "for three options set resolution="
            )
        n_cells = as_count("n_cells", n_cells, low=4)
    if resolution is not None:
        if n != 3:
            raise ValueError(
                f"resolution sets the three-option grid (got a model with {n} options); "
                "for two options set n_cells="
            )
        resolution = as_scalar("resolution", resolution, low=0.3, high=2.0)
    if not isinstance(edge_correction, (bool, np.bool_)):
        raise TypeError(f"edge_correction must be True or False (got {edge_correction!r})")
    if edge_correction and n != 3:
        raise ValueError(
            f"edge_correction corrects the three-option chain (got a model with {n} options)"
        )
    P0 = np.asarray(model.P0)
    if np.any(P0 >= theta):
        raise ValueError(
            f"the initial preference P0 must lie below theta={theta:g} for every option "
            f"(got P0={P0.tolist()})"
        )
    sums = np.asarray(model.S).sum(axis=0)
    if np.ptp(sums) <= 1e-12 and abs(sums[0]) > 1.0 + 1e-12:
        # S multiplies the summed preference by sums[0] at every step: it stays at 0 only
        # in exact arithmetic, and any rounding grows geometrically (as in mdft.simulate)
        raise ValueError(
            f"the feedback matrix S multiplies the summed preference 1^T P by {sums[0]:.6g} at "
            "every step (equal column sums of magnitude above 1), so it is unstable: it stays "
            "bounded only in exact arithmetic and any rounding grows without bound; lower "
            "phi2 (mdft.simulate runs such a model, but its choices then follow the rounding)"
        )
    return (theta, max_steps, atol, rt_rtol, tol, max_iter, tail_tol, max_states, n_cells,
            resolution)


def _after_refusal(model, theta, max_steps, atol, rt_rtol, rng, fallback, method,
                   max_states, runs, fine, reason, closure_bound):
    """What :func:`threshold_probabilities` does once the chain has not answered (``runs``
    its passes, empty where no chain could be built; ``fine`` the last answer, or None;
    ``reason`` why): the simulated answer with the default fallback, or a ValueError
    saying why (``closure_bound``: refused for the closure's term, which more states
    cannot lower)."""
    if fallback == "simulation" and method == "propagate":
        if runs:
            reason = f"within max_states={max_states}: {reason}"
        predicted = None
        if fine is not None:
            # the chain's last answer tells about how much simulating would take: far over
            # the budget, say so now instead of after a first batch of trials
            refuse_if_far_over_budget(reason, max_steps, fine, atol, rt_rtol)
            predicted = predicted_trials(max_steps, fine.probabilities, fine.p_undecided,
                                         fine.rt_pmf, atol, rt_rtol)
        logger.info("threshold_probabilities: the chain refused (%s); simulating", reason)
        return _simulated(model, theta, max_steps, atol, rt_rtol, rng, reason,
                          predicted=predicted)
    if not runs:
        raise ValueError(
            f"threshold_probabilities cannot vouch for this model: {reason}. With "
            "fallback='simulation' and method='propagate' (the defaults) it is simulated to "
            "the tolerances; or estimate threshold stopping with mdft.simulate(model, "
            "n_samples, stopping=mdft.Threshold(theta))"
        )
    raise_what = "atol or rt_rtol" if closure_bound else "max_states, atol or rt_rtol"
    raise ThresholdToleranceError(
        "threshold_probabilities cannot vouch for this model within max_states="
        f"{max_states}: {reason}. Raise {raise_what}, or estimate threshold "
        "stopping with mdft.simulate(model, n_samples, stopping=mdft.Threshold(theta))"
    )


def _closure_term(closure):
    """The moment closure's error term ``(probabilities, mean times)``: the largest of its
    probes (:func:`mdft._plane_passes.plane_runs`), plus the reference term where the
    reference sums were refitted (a cut pilot) and the negative choices the pass clipped (the
    closure's error made visible). Zero for two options."""
    spread_p, spread_rt = closure["error"]
    reference = closure.get("reference", (0.0, 0.0))
    return spread_p + reference[0] + closure.get("clipped", 0.0), spread_rt + reference[1]


def _closure_bound(closure, spread, atol, rt_rtol):
    """Why no finer pass can meet the tolerances, the closure's term alone being beyond them
    (known once measured on a grid finer than the coarsest, or far beyond the tolerances
    there); "" where it leaves room."""
    spread_p, spread_rt = spread
    gross = closure["settled"] or (spread_p > _FIRST_PAIR_FACTOR * atol
                                   or spread_rt > _FIRST_PAIR_FACTOR * rt_rtol)
    if not gross or (spread_p <= atol and spread_rt <= rt_rtol):
        return ""
    what = ("the spread of the summed preference and the plane of its reference sums"
            if "reference" not in closure else
            "the spread of the summed preference and the fit of its reference sums "
            "(refitted after the pilot pass's closure ran away)")
    if closure.get("clipped", 0.0) > 1e-3 * atol:
        what += f", with the {closure['clipped']:.2g} of negative choices its closure clipped,"
    return (f"{what} alone may change the probabilities by {spread_p:.2g} (atol={atol:g}) "
            f"and the mean response times by {spread_rt:.2g} relative (rt_rtol={rt_rtol:g}), "
            "whatever the resolution")


def _grid_term(fine, coarse, first_pair, half):
    """The grid's part of the error estimate of ``fine``: its change from ``coarse``, scaled
    where the first pair is not yet in the asymptotic range and where a half step is a
    quarter of a doubling away from its partner."""
    err_p, err_rt = error_estimate(fine, coarse)
    if first_pair or half:
        factor = _HALF_STEP_FACTOR if half else _FIRST_PAIR_FACTOR
        err_p, err_rt = factor * err_p, factor * err_rt
    return err_p, err_rt


def _half_step_may_answer(grid, own_tail, spread, tolerances, first_pair):
    """Whether the half step after a refinement may meet the tolerances. Second order leaves
    ``1 / sqrt(2)`` of the refinement's grid term there (with its tail counted for both): run
    it where that fills at most :data:`_HALF_STEP_ROOM` of the room the closure leaves; after
    the first comparison, whose grid term is mostly the coarsest grid's own error, where that
    term is within :data:`_FIRST_HALF_REACH` times the room."""
    room, shrink = (_FIRST_HALF_REACH, 1.0) if first_pair else (_HALF_STEP_ROOM, REFINE)
    return all(g / shrink + 2.0 * tail <= room * (tol - sp)
               for g, tail, sp, tol in zip(grid, own_tail, spread, tolerances))


def _not_yet(fine, errors, spread, atol, rt_rtol):
    """The reason a pass's answer is not yet within the tolerances: its estimate, with the
    closure's share of it."""
    err_p, err_rt = errors
    spread_p, spread_rt = spread
    reason = (f"estimated error {err_p + spread_p:.2g} in the probabilities (atol={atol:g}) "
              f"and {err_rt + spread_rt:.2g} relative in the mean response times "
              f"(rt_rtol={rt_rtol:g}) at {fine.n_states} states")
    if spread_p > 0.0 or spread_rt > 0.0:
        reason += (f", of which the moment closure of the summed preference, which no "
                   f"resolution lowers, accounts for {spread_p:.2g} and {spread_rt:.2g}")
    return reason


def _no_chain(model, theta, resolution):
    """Why no chain can answer for the model, known before building any, or "": more than
    three options; no noise; a contrast whose columns do not sum to zero; a summed
    preference whose worst case has no finite range below ``n * theta``; noise narrower
    than the cells of every three-option grid of the schedule."""
    if model.n_options > _MAX_OPTIONS:
        return (f"the model has {model.n_options} options; the chain handles at most "
                f"{_MAX_OPTIONS} (its state space grows with every option)")
    if not model.sigma2 > 0.0:
        return (f"the model has no noise (sigma2={model.sigma2:g}), and the chain needs "
                "sigma2 > 0 to vouch for its answer (nothing else smooths its rounding of "
                "each step)")
    C = np.asarray(model.C)
    col = np.abs(C.sum(axis=0)).max()
    if col > 1e-9 * max(1.0, np.abs(C).max()):
        return (f"the chain needs a contrast C with columns summing to zero (largest column "
                f"sum {col:.3g}): it relies on valences that leave the summed preference "
                "unchanged")
    S = np.asarray(model.S, dtype=np.float64)
    s0 = float(np.sum(model.P0))
    if not sum_is_constant(S, s0):
        try:
            chain_sum_bounds(S, theta, s0)
        except UnboundedSum as exc:
            return str(exc)
    if model.n_options == 3:
        return narrow_everywhere(model, theta, resolution or KAPPA)
    return ""


def _undecided_within_tolerances(model, theta, max_steps, atol, rt_rtol, method):
    """The answer "undecided" where the bound on deciding at all meets the tolerances
    (``method="propagate"`` only: the long run has no step limit), else None."""
    if method != "propagate":
        return None
    bound = decision_bound(model, theta, max_steps, target=tolerance_level(atol, rt_rtol))
    if not within_tolerances(bound, atol, rt_rtol):
        return None
    logger.info("threshold_probabilities: some option is chosen within %d steps with "
                "probability at most %.2g; answering undecided", max_steps, bound)
    return ThresholdProbabilities(theta=float(theta),
                                  **undecided_answer(model.n_options, max_steps, bound))


def _out_of_reach(grid_errors, spread, tolerances, left):
    """Why no pass still possible can meet the tolerances, or "" (three options).

    ``grid_errors``: the grid term of each trusted comparison so far (probabilities, mean
    times; none where the noise is narrower than the cells); ``spread``: the closure's
    term; ``left``: the passes still possible. From the third comparison on (the first is
    not yet in the asymptotic range), the grid term is taken to fall per refinement by the
    smallest of the last two ratios observed and of 1/2 (second order, as section 4 of
    ``docs/threshold_exact.md`` takes it): an optimistic rate. If even then it stays above
    the room the closure's term leaves in either tolerance after every pass still possible,
    refining is hopeless.
    """
    if len(grid_errors) < 3 or left < 1:
        return ""  # too few comparisons to tell; or the last pass, refused as it stands
    names = ("the probabilities", "the mean response times")
    for q in range(2):
        room = tolerances[q] - spread[q]
        g0, g1, g2 = (e[q] for e in grid_errors[-3:])
        if room <= 0.0 or g2 <= room:
            continue
        rate = min(0.5, g2 / g1 if g1 > 0.0 else 0.5, g1 / g0 if g0 > 0.0 else 0.5)
        if g2 * rate**left > room:
            return (f"; its grid term in {names[q]} went {g0:.2g}, {g1:.2g}, {g2:.2g} over the "
                    f"last three comparisons, and falling by {rate:.2g} per refinement it "
                    f"would stay above the {room:.2g} the closure leaves after the "
                    f"{left} finer grid{'s' if left > 1 else ''} still possible")
    return ""


def _controls_may_pay(answer, sim_work, chain_work, max_steps, probed):
    """Whether to probe trials with control variates (once per call, recorded in ``probed``)
    where plain ones, predicted from ``answer`` to take ``sim_work``, cost more than
    ``chain_work``: where that is at least ``_PROBE_MIN_WORK``, they cost at most
    ``CONTROLLED_REACH`` times it, and the probe (``PROBE_BATCH`` plain trials and
    ``controlled_probe_work``) at most ``CONTROLLED_PROBE_SHARE`` of it."""
    if probed or chain_work < _PROBE_MIN_WORK or not sim_work < CONTROLLED_REACH * chain_work:
        return False
    per_trial = steps_per_walk(answer.rt_pmf, answer.p_undecided, max_steps)
    probe = _SIM_STEP_WORK * (PROBE_BATCH * per_trial + controlled_probe_work(per_trial))
    if not probe <= CONTROLLED_PROBE_SHARE * chain_work:
        return False
    probed.append(True)
    return True


def _controlled_if_cheaper(model, theta, max_steps, atol, rt_rtol, rng, why, chain_work):
    """The simulated answer where a probe of plain and controlled trials finds that they
    cost at most :data:`_SIM_OVERRUN` times the next pass's ``chain_work``; None where they
    cost more (the refinement goes on)."""
    logger.info("threshold_probabilities: %s; probing them", why)
    try:
        return _simulated(model, theta, max_steps, atol, rt_rtol, rng, why,
                          max_work=_SIM_OVERRUN * chain_work / _SIM_STEP_WORK,
                          probe_work=chain_work / _SIM_STEP_WORK, probe_controls=True)
    except OverBudget:
        logger.info("threshold_probabilities: the probe says they cost more; refining")
        return None


def _narrow(result):
    """Why a pass whose noise is narrower than its cells does not answer."""
    return (f"the noise is narrower than the cells (spacing {result.spacing:.3g}) over sqrt(3) "
            f"at {result.n_states} states, where the estimate itself is not trusted")


def _trusted_beyond(later, result, max_states):
    """Why the first of the ``later`` passes whose noise is not narrower than its cells is
    out of reach, or "" when it may be within ``max_states``: its states, predicted from
    those of ``result`` (a narrow pass's answer) as the square of the ratio of their
    resolutions (a plane grid of cells that many times smaller), exceed ``max_states`` by
    more than ``_NARROW_STATES_MARGIN`` times."""
    for run in later:
        if not run.narrow():
            states = result.n_states * (result.resolution / run.kappa) ** 2
            if states <= _NARROW_STATES_MARGIN * max_states:
                return ""
            return (f"; the first resolution where it is, {run.kappa:.3g}, would need about "
                    f"{states:.3g} states")
    return ""


def _simulated_if_cheaper(answer, nonzeros, steps, *, model, theta, max_steps, atol, rt_rtol,
                          rng, probed=None):
    """The simulated answer where simulating to the tolerances is predicted to cost less than
    ``_EARLY_SHARE`` of building and running ``nonzeros`` for ``steps`` steps (the chain's
    passes ahead, at the least); None where it is not, or where the trials turn out to need
    more than ``_SIM_OVERRUN`` times that work (the chain then goes on).

    The prediction comes from ``answer``, the first pilot's, or, where that pilot was cut
    (``answer`` None: its closure ran away, and its answer predicts nothing), from the
    first trials of the simulation itself. Where plain trials cost more than that share,
    trials with control variates may still cost less: ``_controls_may_pay`` decides whether a
    probe of them (``probed``: whether one has run in the call) measures it.
    """
    chain_work = nonzeros * (_BUILD_WORK + steps)
    probe_work = None
    if answer is None:
        probe_work = _EARLY_SHARE * chain_work / _SIM_STEP_WORK
        reason = (f"the first pilot pass was cut, and its passes ahead would take "
                  f"{chain_work:.3g} units of work at the least")
    else:
        sim_work = _simulation_work(answer, max_steps, atol, rt_rtol)
        reason = (f"the first pilot pass predicts {sim_work:.3g} units of work for simulating "
                  f"to the tolerances, against {chain_work:.3g} for the chain's next passes")
        if not sim_work < _EARLY_SHARE * chain_work:
            if probed is None or not _controls_may_pay(answer, sim_work,
                                                       _EARLY_SHARE * chain_work, max_steps,
                                                       probed):
                return None
            probe_work = _EARLY_SHARE * chain_work / _SIM_STEP_WORK
            reason += ", where trials with control variates may cost less"
    logger.info("threshold_probabilities: %s; simulating", reason)
    try:
        return _simulated(model, theta, max_steps, atol, rt_rtol, rng, reason,
                          max_work=_SIM_OVERRUN * chain_work / _SIM_STEP_WORK,
                          probe_work=probe_work,
                          probe_controls=_EARLY_SHARE * chain_work >= _PROBE_MIN_WORK)
    except OverBudget:
        logger.info("threshold_probabilities: the trials need more than predicted; "
                    "building the chain")
        return None


def _simulated_if_finer_costs_more(fine, next_nonzeros, probed, *, model, theta, max_steps,
                                   atol, rt_rtol, rng):
    """Simulate instead of building the next, finer pass (about ``next_nonzeros`` nonzeros)
    where that costs less: a deterministic count of work, in steps of one nonzero, from the
    answer and errors of ``fine``. Returns ``(answer, reason)``: the answer of trials with control
    variates where a probe (once per call: ``probed``) finds them cheaper; else ``(None,
    reason)`` where plain trials cost less (the reason the fallback is told); else ``(None,
    None)``: refine."""
    chain_work = next_nonzeros * (_BUILD_WORK + fine.n_iter)
    sim_work = _simulation_work(fine, max_steps, atol, rt_rtol)
    found = (f"estimated error {fine.error_probabilities:.2g} in the probabilities and "
             f"{fine.error_mean_rt:.2g} relative in the mean response times at "
             f"{fine.n_states} states, where ")
    if sim_work < chain_work:
        return None, found + "simulating costs less than a finer grid"
    if _controls_may_pay(fine, sim_work, chain_work, max_steps, probed):
        why = found + "trials with control variates may cost less than a finer grid"
        return _controlled_if_cheaper(model, theta, max_steps, atol, rt_rtol, rng, why,
                                      chain_work), None
    return None, None


def _simulation_work(answer, max_steps, atol, rt_rtol):
    """Work of simulating to the tolerances, predicted from ``answer``, in units of
    propagating a nonzero by one step."""
    return _SIM_STEP_WORK * predicted_work(max_steps, answer.probabilities, answer.p_undecided,
                                           answer.rt_pmf, atol, rt_rtol)


def _simulated(model, theta, max_steps, atol, rt_rtol, rng, reason, max_work=None,
               probe_work=None, predicted=None, probe_controls=False):
    """The simulation fallback's answer as a ThresholdProbabilities (``engine="simulation"``)."""
    return simulated_answer(model, theta, max_steps, atol, rt_rtol, rng, reason,
                            partial(_simulated_result, theta=theta, max_steps=max_steps),
                            max_work=max_work, probe_work=probe_work, predicted=predicted,
                            probe_controls=probe_controls)


def _simulated_result(probabilities, p_undecided, rt_pmf, mean_rt, n_trials, err_p, err_rt,
                      *, theta, max_steps):
    return ThresholdProbabilities(
        probabilities=probabilities, p_undecided=float(p_undecided), rt_pmf=rt_pmf,
        mean_response_times=mean_rt, theta=float(theta), max_steps=max_steps, n_cells=0,
        spacing=math.nan, n_levels=1, n_states=0, method="simulation", n_iter=int(n_trials),
        converged=True, tail_start=None, engine="simulation", resolution=math.nan,
        error_probabilities=float(err_p), error_mean_rt=float(err_rt),
    )


def _step_sd_binary(model):
    """Per-step standard deviation of the lattice coordinate ``(P_1 - P_2) / sqrt(2)``."""
    C = np.asarray(model.C)
    e = np.array([1.0, -1.0]) / math.sqrt(2.0)
    noise = model.sigma2 * float(e @ C @ C.T @ e)
    drift = e @ C @ np.asarray(model.M)
    w = np.asarray(model.w)
    mean = float(drift @ w)
    att = float(((drift - mean) ** 2) @ w)
    return math.sqrt(noise + att)


def _binary_runs(model, theta, n_cells, max_states, solve):
    """Computations of increasing resolution for two options."""
    sd = _step_sd_binary(model)
    # a sum that moves alike on every walk moves only the thresholds: no levels (section 3)
    n_moving = moving_sum_steps(model, theta)
    moving = n_moving is not None and (solve["method"] == "propagate"
                                       or n_moving <= MAX_MOVING_STEPS)
    if n_cells is None:
        fine = max(_BINARY_MIN_CELLS, int(math.ceil(theta / (_BINARY_SPACING * sd))))
        sizes = [max(4, fine // 2), fine, 2 * fine, 4 * fine]
        if not moving and not sum_is_constant(np.asarray(model.S), float(np.sum(model.P0))):
            # where the sum moves, the lattice's levels make its coarsest answers erratic
            # (one came within 0.1 % of the next, both 0.4 % off): the first comparison is
            # between the default number of cells and twice that
            sizes = [fine, 2 * fine, 4 * fine, 8 * fine]
        sizes = [c for c in sizes if c <= _BINARY_MAX_CELLS] or sizes[:2]
    else:
        sizes = [max(4, n_cells // 2), n_cells]

    def make(cells):
        def compute():
            if moving:
                steps = solve["max_steps"] if solve["method"] == "propagate" else None
                chain = build_moving_chain(model, theta, cells, True, n_moving, steps,
                                           solve["tol"])
            else:
                chain = build_chain(model, theta, cells, True)
            if chain.Q.shape[0] > max_states:
                raise TooManyStates(f"n_cells={cells} gives {chain.Q.shape[0]} states")
            spec = dict(engine="lattice", n_cells=cells, resolution=spacing / sd)
            return solve_chain(chain, theta, spacing, spec, **solve)
        spacing = theta / cells
        compute.half = False  # every lattice pass is a refinement (no half steps)
        return compute

    return [make(c) for c in sizes]
