"""Simulation fallback of :func:`mdft.threshold_probabilities`.

When the chain cannot bring its estimated error below the tolerances,
``fallback="simulation"`` answers by Monte Carlo instead of refusing: trials are
simulated in growing batches until three standard errors of every probability
(and of ``p_undecided``) are within ``atol`` and three standard errors of every
mean response time are within ``rt_rtol`` of it, or until a work budget is spent,
when it raises. The error fields of the result are those three standard errors,
so the answer carries the same kind of guarantee as the chain's, statistically.
"""

from __future__ import annotations

import math

import numpy as np

from ._validation import as_generator
from .simulate import _fallback_trials

#: First batch of trials, and the largest number of trials times mean decision steps.
FIRST_BATCH = 100_000
#: On a budget (``max_work`` given, the early hand-over of threshold_probabilities), the
#: first batch is simulated in two parts: the first PROBE_BATCH trials predict the work, and
#: a prediction over the budget stops the simulation there.
PROBE_BATCH = 5_000
MAX_WORK = 2_000_000_000
#: The fallback refuses without simulating where the chain's last answer predicts more than
#: this many times MAX_WORK (the prediction is about right; near the budget itself, the first
#: batch of trials decides).
PREDICTED_OVER = 2.0
#: Options chosen less often than this weigh in on the mean-time error with p / this.
RT_WEIGHT_FLOOR = 0.01
#: Seed of the fallback's trials when the caller gives none (so calls are repeatable).
DEFAULT_SEED = 20_260


def _errors(counts, n_undecided, sums, squares):
    """Three standard errors of the probabilities and the weighted relative ones of mean times."""
    n = counts.sum() + n_undecided
    shares = np.append(counts, n_undecided) / n
    # (p (1 - p) + 1 / n) / n keeps the bound honest for shares near 0 or 1
    err_p = 3.0 * float(np.sqrt((shares * (1.0 - shares) + 1.0 / n) / n).max())
    err_rt = 0.0
    for i, c in enumerate(counts):
        if c < 2:  # no spread to measure: as uncertain as the option's weight allows
            if c > 0:
                err_rt = max(err_rt, min(1.0, shares[i] / RT_WEIGHT_FLOOR))
            continue
        mean = sums[i] / c
        var = max(squares[i] / c - mean * mean, 0.0) * c / (c - 1)
        rel = 3.0 * math.sqrt(var / c) / mean
        err_rt = max(err_rt, min(1.0, shares[i] / RT_WEIGHT_FLOOR) * rel)
    return err_p, err_rt


def predicted_trials(max_steps, probabilities, p_undecided, rt_pmf, atol, rt_rtol):
    """Trials that :func:`simulated_answer` would simulate for a model whose answer is about
    known, and their mean number of steps: ``(trials, steps_per_trial)``.

    The errors of its stopping rule (:func:`_errors`) are computed for a notional number of
    trials from the probabilities and the response-time distribution (``rt_pmf``, steps by
    options); they shrink as one over the square root of the trials, which gives the trials
    needed.
    """
    times = np.arange(1, rt_pmf.shape[0] + 1, dtype=np.float64)
    n = 1e9
    err_p, err_rt = _errors(n * probabilities, n * p_undecided, n * (times @ rt_pmf),
                            n * ((times**2) @ rt_pmf))
    trials = max(n * max((err_p / atol) ** 2, (err_rt / rt_rtol) ** 2), FIRST_BATCH)
    return trials, steps_per_walk(rt_pmf, p_undecided, max_steps)


def steps_per_walk(rt_pmf, p_undecided, max_steps):
    """Mean steps a walk (or trial) runs: its decision step, or ``max_steps`` undecided."""
    times = np.arange(1, rt_pmf.shape[0] + 1, dtype=np.float64)
    return float(times @ rt_pmf.sum(axis=1)) + p_undecided * max_steps


def predicted_work(max_steps, probabilities, p_undecided, rt_pmf, atol, rt_rtol):
    """Simulated steps (trials times steps per trial) of :func:`predicted_trials`."""
    trials, per_trial = predicted_trials(max_steps, probabilities, p_undecided, rt_pmf, atol,
                                         rt_rtol)
    return trials * per_trial


def refuse_if_far_over_budget(reason, max_steps, answer, atol, rt_rtol):
    """Raise at once (without simulating) where ``answer``, the chain's last result, predicts
    more than :data:`PREDICTED_OVER` times :data:`MAX_WORK` trial-steps; otherwise nothing."""
    trials, per_trial = predicted_trials(max_steps, answer.probabilities, answer.p_undecided,
                                         answer.rt_pmf, atol, rt_rtol)
    if trials * per_trial > PREDICTED_OVER * MAX_WORK:
        raise over_budget(reason, trials, per_trial,
                          f" (predicted from the chain's answer at {answer.n_states} states)")


class OverBudget(ValueError):
    """Simulating to the tolerances would take more trial-steps than the budget allows."""


def over_budget(reason, trials, per_trial, how=""):
    """The error raised when simulating to the tolerances would exceed :data:`MAX_WORK`."""
    return OverBudget(
        f"threshold_probabilities cannot vouch for this model: the chain refused "
        f"({reason}), and its simulation fallback would need about {trials:.3g} trials "
        f"of {per_trial:.0f} steps on average{how}, more than its budget of {MAX_WORK:.3g} "
        f"trial-steps. Raise atol or rt_rtol, or run mdft.simulate(model, n_samples, "
        f"stopping=mdft.Threshold(theta)) for as long as you can afford"
    )


def simulated_answer(model, theta, max_steps, atol, rt_rtol, rng, reason, make_result,
                     max_work=None, probe_work=None):
    """The simulated answer, or :class:`OverBudget` when ``max_work`` trial-steps (at most
    :data:`MAX_WORK`, the default) cannot meet the tolerances.

    Every answer rests on at least :data:`FIRST_BATCH` trials. Without ``max_work`` the
    first batch is always simulated; with it, its first :data:`PROBE_BATCH` trials predict
    the work first, which must then be within ``probe_work`` too, when given (the budget of
    a hand-over that nothing else predicted). ``make_result(probabilities, p_undecided,
    rt_pmf, mean_rt, n_trials, err_p, err_rt)`` builds the result object; ``reason`` says
    why the chain refused.
    """
    budgeted = max_work is not None
    max_work = MAX_WORK if max_work is None else min(max_work, MAX_WORK)
    gen = as_generator("rng", DEFAULT_SEED if rng is None else rng)
    n_opt = model.n_options
    counts = np.zeros(n_opt, dtype=np.int64)
    n_undecided = 0
    sums = np.zeros(n_opt)
    squares = np.zeros(n_opt)
    hist = np.zeros((max_steps, n_opt))
    work = 0.0
    batch = min(PROBE_BATCH, FIRST_BATCH) if budgeted else FIRST_BATCH
    while True:
        choices, all_steps = _fallback_trials(model, batch, theta, max_steps, gen)
        chosen = choices >= 0
        steps = all_steps[chosen]
        opts = choices[chosen]
        undecided = batch - int(chosen.sum())
        counts += np.bincount(opts, minlength=n_opt)
        n_undecided += undecided
        sums += np.bincount(opts, weights=steps, minlength=n_opt)
        squares += np.bincount(opts, weights=steps.astype(np.float64) ** 2, minlength=n_opt)
        hist += np.bincount((steps - 1) * n_opt + opts,
                            minlength=max_steps * n_opt).reshape(max_steps, n_opt)
        work += float(steps.sum()) + float(undecided) * max_steps
        n = int(counts.sum()) + n_undecided
        err_p, err_rt = _errors(counts, n_undecided, sums, squares)
        if n >= FIRST_BATCH and err_p <= atol and err_rt <= rt_rtol:
            break
        # trials needed: errors shrink as 1 / sqrt(n)
        need = max(n * max((err_p / atol) ** 2, (err_rt / rt_rtol) ** 2) * 1.1, FIRST_BATCH)
        per_trial = work / n
        # the probe's prediction must be within probe_work as well
        probing = n < FIRST_BATCH and probe_work is not None
        if need * per_trial > (min(max_work, probe_work) if probing else max_work):
            raise over_budget(reason, need, per_trial)
        # after the probe, the rest of the first batch
        batch = FIRST_BATCH - n if n < FIRST_BATCH else int(min(max(need - n, FIRST_BATCH),
                                                                4 * n))
    with np.errstate(invalid="ignore", divide="ignore"):
        mean_rt = np.where(counts > 0, sums / np.where(counts > 0, counts, 1), np.nan)
    return make_result(counts / n, n_undecided / n, hist / n, mean_rt, n, err_p, err_rt)
