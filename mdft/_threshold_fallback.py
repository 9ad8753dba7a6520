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

from ._control_kernels import N_CONTROLS, POLYNOMIAL_CONTROLS
from ._control_variates import ControlledSums
from ._validation import as_generator
from .simulate import _controlled_trials, _fallback_trials

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
#: Time of a trial with control variates, in trials without, is about CONTROLLED_COST plus
#: CONTROLLED_TRIAL_COST over the mean steps of a trial (each trial adds its sums to its
#: fold's totals): measured, twice, 2.13-2.20 at 1,400 steps a trial, 2.2-2.3 at 170-280
#: and 2.4-2.7 at 39-55 (200,000 trials of seven models on two threads).
CONTROLLED_COST = 2.15
CONTROLLED_TRIAL_COST = 18.0
#: The same for the trials that also record the sums near the thresholds and the hazards
#: (``rich``, :mod:`mdft._control_kernels`), which cost more where the walks stay near the
#: thresholds: 3.93 times a plain trial in the median, 2.95-5.47, on twelve models of
#: ``benchmarks/bench_threshold_work.py`` (50,000 trials each, two threads); 2.6-5.7 on
#: seven slow simulated models of 16-1,500 steps. Their products are added a group of
#: trials at a time since (:data:`mdft._control_kernels.GROUP`), which took the part per
#: trial from about 30 plain steps to 20 (six models of 16-1,500 steps, timed in turn with
#: the kernel before: 10 % less time at 16 steps a trial, 5 % at 55-96, 2 % at 1,500).
RICH_COST = 3.6
RICH_TRIAL_COST = 20.0
#: Where the chain's last answer predicts more than this many times the plain trials that a
#: controlled batch is worth beyond the first batch, the controlled trials start at once.
CONTROLLED_AT_ONCE = 2.0
#: On a budget with ``probe_controls``, where the plain probe predicts more than the budget
#: but at most CONTROLLED_REACH times it, CONTROLLED_PROBE trials with control variates
#: predict their own work, provided they cost at most CONTROLLED_PROBE_SHARE of the budget.
CONTROLLED_PROBE = 10_000
#: Otherwise the first controlled batch has this many trials with every control (``rich``),
#: on which the trials that follow choose between every control and the monomials alone.
RICH_PROBE = 20_000
CONTROLLED_REACH = 20.0
CONTROLLED_PROBE_SHARE = 0.15
#: Options chosen fewer times than this have the plain mean time of the controlled trials.
CONTROLLED_MIN_COUNT = 100
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
        err_rt = max(err_rt, _rt_error(c, shares[i], sums[i], squares[i]))
    return err_p, err_rt


def _rt_error(count, share, total, square):
    """Three standard errors of an option's mean time over it, weighted by
    ``min(1, share / RT_WEIGHT_FLOOR)``, from its ``count`` choices, the ``total`` of their
    steps and of their squares; 0 for an option never chosen."""
    if count < 2:  # no spread to measure: as uncertain as the option's weight allows
        return min(1.0, share / RT_WEIGHT_FLOOR) if count > 0 else 0.0
    mean = total / count
    var = max(square / count - mean * mean, 0.0) * count / (count - 1)
    rel = 3.0 * math.sqrt(var / count) / mean
    return min(1.0, share / RT_WEIGHT_FLOOR) * rel


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


class _Tally:
    """Counts, sums and squares of the decision steps by option, the histogram of the steps,
    and the trial-steps simulated, over a run of trials."""

    def __init__(self, n_options, max_steps):
        self.counts = np.zeros(n_options, dtype=np.int64)
        self.n_undecided = 0
        self.sums = np.zeros(n_options)
        self.squares = np.zeros(n_options)
        self.hist = np.zeros((max_steps, n_options))
        self.work = 0.0

    @property
    def n(self):
        return int(self.counts.sum()) + self.n_undecided

    @property
    def mean_step(self):
        """Mean decision step of the trials that decided (1 where none did)."""
        return float(self.sums.sum()) / max(int(self.counts.sum()), 1)

    def add(self, choices, all_steps):
        n_opt = self.counts.shape[0]
        chosen = choices >= 0
        steps = all_steps[chosen]
        opts = choices[chosen]
        undecided = choices.shape[0] - int(chosen.sum())
        self.counts += np.bincount(opts, minlength=n_opt)
        self.n_undecided += undecided
        self.sums += np.bincount(opts, weights=steps, minlength=n_opt)
        self.squares += np.bincount(opts, weights=steps.astype(np.float64) ** 2,
                                    minlength=n_opt)
        self.hist += np.bincount((steps - 1) * n_opt + opts,
                                 minlength=self.hist.size).reshape(self.hist.shape)
        self.work += float(steps.sum()) + float(undecided) * self.hist.shape[0]

    def merge(self, other):
        """Add the trials of another tally."""
        self.counts += other.counts
        self.n_undecided += other.n_undecided
        self.sums += other.sums
        self.squares += other.squares
        self.hist += other.hist
        self.work += other.work

    def errors(self):
        return _errors(self.counts, self.n_undecided, self.sums, self.squares)

    def answer(self, make_result, err_p, err_rt):
        """The plain estimates: shares of the trials and mean steps."""
        n = self.n
        counts = self.counts
        with np.errstate(invalid="ignore", divide="ignore"):
            mean_rt = np.where(counts > 0, self.sums / np.where(counts > 0, counts, 1), np.nan)
        return make_result(counts / n, self.n_undecided / n, self.hist / n, mean_rt, n, err_p,
                           err_rt)


def controlled_cost(steps_per_trial, rich=True):
    """Time of a trial with control variates (``rich``: all of them; else the monomials'
    alone), in trials without, for trials of ``steps_per_trial`` steps on average."""
    steps = max(steps_per_trial, 1.0)
    if rich:
        return RICH_COST + RICH_TRIAL_COST / steps
    return CONTROLLED_COST + CONTROLLED_TRIAL_COST / steps


def _trials_needed(n, err_p, err_rt, atol, rt_rtol):
    """Trials that bring the errors within the tolerances, as they shrink as 1 / sqrt(n)."""
    return n * max((err_p / atol) ** 2, (err_rt / rt_rtol) ** 2)


def controlled_probe_work(per_trial):
    """Trial-steps, in plain ones, of the :data:`CONTROLLED_PROBE` controlled trials that
    test whether control variates bring a simulation within its budget."""
    return CONTROLLED_PROBE * per_trial * controlled_cost(per_trial)


def simulated_answer(model, theta, max_steps, atol, rt_rtol, rng, reason, make_result,
                     max_work=None, probe_work=None, predicted=None, probe_controls=False):
    """The simulated answer, or :class:`OverBudget` when ``max_work`` trial-steps (at most
    :data:`MAX_WORK`, the default) cannot meet the tolerances.

    A first batch of :data:`FIRST_BATCH` plain trials answers where it meets the
    tolerances. Without ``max_work`` it is always simulated; with it, its first
    :data:`PROBE_BATCH` trials predict the work first, which must then be within
    ``probe_work`` too, when given (the budget of a hand-over that nothing else predicted).
    Where the first batch falls short by more plain trials than a batch with control
    variates is worth (:func:`controlled_cost` times :data:`FIRST_BATCH`), those go on
    (:func:`_controlled_answer`), or plain ones where they do not pay. Without ``max_work``,
    ``predicted`` (the plain trials and steps per trial that the chain's last answer
    predicts, :func:`predicted_trials`) may skip the plain first batch: where it predicts
    more than :data:`CONTROLLED_AT_ONCE` times that worth, the controlled trials start at once.
    With ``probe_controls`` (and a budget), a probe whose plain trials predict more than the
    budget, but at most :data:`CONTROLLED_REACH` times it, goes on to
    :data:`CONTROLLED_PROBE` controlled trials where those cost at most
    :data:`CONTROLLED_PROBE_SHARE` of the budget: their own prediction, at their cost per
    trial, then decides whether the simulation goes on, with them (where they do not pay,
    they join the plain trials, which are judged again).
    ``make_result(probabilities, p_undecided, rt_pmf, mean_rt, n_trials, err_p, err_rt)``
    builds the result object; ``reason`` says why the chain refused.
    """
    budgeted = max_work is not None
    max_work = MAX_WORK if max_work is None else min(max_work, MAX_WORK)
    gen = as_generator("rng", DEFAULT_SEED if rng is None else rng)
    plain = _Tally(model.n_options, max_steps)
    batch = min(PROBE_BATCH, FIRST_BATCH) if budgeted else FIRST_BATCH
    try_controls = True
    if (predicted is not None and not budgeted and predicted[0] - FIRST_BATCH
            > CONTROLLED_AT_ONCE * controlled_cost(predicted[1], rich=False) * FIRST_BATCH):
        answer = _controlled_answer(model, theta, max_steps, atol, rt_rtol, gen, reason,
                                    make_result, max_work, predicted[1], plain)
        if answer is not None:
            return answer
        try_controls = False
        batch = max(FIRST_BATCH - plain.n, 0)  # the controlled trials that did not pay count
    while True:
        if batch:
            plain.add(*_fallback_trials(model, batch, theta, max_steps, gen))
        n = plain.n
        err_p, err_rt = plain.errors()
        if n >= FIRST_BATCH and err_p <= atol and err_rt <= rt_rtol:
            return plain.answer(make_result, err_p, err_rt)
        need = max(_trials_needed(n, err_p, err_rt, atol, rt_rtol) * 1.1, FIRST_BATCH)
        per_trial = plain.work / n
        probe = None  # the budget of a controlled probe, where one is tried
        if n < FIRST_BATCH:
            # the probe's prediction must be within probe_work as well
            limit = max_work if probe_work is None else min(max_work, probe_work)
            if need * per_trial <= limit:
                batch = FIRST_BATCH - n  # the rest of the first batch
                continue
            if not (probe_controls and try_controls
                    and need * per_trial <= CONTROLLED_REACH * limit
                    and controlled_probe_work(per_trial) <= CONTROLLED_PROBE_SHARE * limit):
                raise over_budget(reason, need, per_trial)
            probe = limit - plain.work
        # controls, unless fewer plain trials are left than a controlled batch is worth
        if probe is not None or (try_controls
                                 and need - n > controlled_cost(per_trial, rich=False)
                                 * FIRST_BATCH):
            try_controls = False
            answer = _controlled_answer(model, theta, max_steps, atol, rt_rtol, gen, reason,
                                        make_result, max_work - plain.work, plain.mean_step,
                                        plain, probe_work=probe)
            if answer is not None:
                return answer
            batch = 0  # controls that do not pay joined the plain trials: judge them all
            continue
        if need * per_trial > max_work:
            raise over_budget(reason, need, per_trial)
        batch = int(min(max(need - n, FIRST_BATCH), 4 * n))


def _controlled_answer(model, theta, max_steps, atol, rt_rtol, gen, reason, make_result,
                       max_work, time_scale, plain, probe_work=None):
    """The answer from trials with control variates; :class:`OverBudget` when ``max_work``
    trial-steps cannot meet the tolerances; None where the model has none
    (:func:`mdft.simulate._controlled_trials`), where the budget has no room for their
    first batch, or where they do not pay (their trials then join the tally ``plain``).

    The first controlled batch has :data:`RICH_PROBE` trials that record every control
    (``rich``); the controls measure time in units of ``time_scale`` steps (the plain trials'
    mean decision step, or the one predicted). The answer rests on the controlled trials
    alone, at least :data:`FIRST_BATCH` of them, with the estimates and errors of
    :class:`mdft._control_variates.ControlledSums`. After each batch of every control, the
    trials the monomials alone would ask for, at their lower cost, are compared with those
    every control asks for, on the same trials; where the monomials need less time, the
    sums keep only theirs, and the batches that follow record only theirs. After each
    batch, the trials the controlled errors ask for, times :func:`controlled_cost`, are
    compared with those the plain errors of the same trials ask for; where the controls do
    not pay, the controlled trials join the plain ones.

    With ``probe_work``, the first batch is a probe of :data:`CONTROLLED_PROBE` trials, and
    :class:`OverBudget` is raised after it where the trials its errors ask for, at their cost
    (:func:`controlled_cost`), would take more than ``probe_work`` plain trial-steps; every
    answer still rests on at least :data:`FIRST_BATCH` controlled trials.
    """
    tally = _Tally(model.n_options, max_steps)
    sums = ControlledSums(model.n_options, N_CONTROLS)
    rich = True
    batch = RICH_PROBE if probe_work is None else CONTROLLED_PROBE
    per_trial = plain.work / plain.n if plain.n else time_scale
    if batch * per_trial > max_work:
        return None
    while True:
        out = _controlled_trials(model, batch, theta, max_steps, gen, time_scale, rich)
        if out is None:
            return None
        choices, steps, grams = out
        sums.add(grams)
        tally.add(choices, steps)
        n = tally.n
        per_trial = tally.work / n
        answer, err_p, err_rt = _controlled_estimates(sums, tally, max_steps, make_result)
        if n >= FIRST_BATCH and err_p <= atol and err_rt <= rt_rtol:
            return answer
        need = max(_trials_needed(n, err_p, err_rt, atol, rt_rtol) * 1.1, FIRST_BATCH)
        if rich:
            # the monomials alone, on the same trials: where they need fewer trials' time,
            # the trials that follow record only their sums
            fewer = sums.restricted(POLYNOMIAL_CONTROLS)
            _, poly_p, poly_rt = _controlled_estimates(fewer, tally, max_steps, make_result)
            poly_need = max(_trials_needed(n, poly_p, poly_rt, atol, rt_rtol) * 1.1,
                            FIRST_BATCH)
            if (poly_need * controlled_cost(per_trial, rich=False)
                    < need * controlled_cost(per_trial)):
                rich, sums, need = False, fewer, poly_need
        plain_need = _trials_needed(n, *tally.errors(), atol, rt_rtol) * 1.1
        if need * controlled_cost(per_trial, rich) >= plain_need:
            plain.merge(tally)
            return None
        if (probe_work is not None and n < FIRST_BATCH
                and need * per_trial * controlled_cost(per_trial, rich) > probe_work):
            raise over_budget(reason, need, per_trial, " with control variates")
        if need * per_trial > max_work:
            raise over_budget(reason, need, per_trial)
        # (after a probe, at least the rest of a first batch)
        batch = int(max(min(max(need - n, FIRST_BATCH), 4 * n), FIRST_BATCH - n))


def _controlled_estimates(sums, tally, max_steps, make_result):
    """``(answer, err_p, err_rt)`` from the control-variate estimates; the plain estimates
    of the same trials where those are not all valid (a probability below 0, or 0 for an
    option chosen, a mean time outside ``[1, max_steps]``)."""
    n_opt = tally.counts.shape[0]
    means, cov = sums.estimate()
    probs = means[:n_opt]
    p_undecided = means[n_opt]
    times = means[n_opt + 1:]
    n = tally.n
    counts = tally.counts
    err_p = 3.0 * float(np.sqrt(np.diag(cov)[:n_opt + 1] + 1.0 / n**2).max())
    err_rt = 0.0
    mean_rt = np.full(n_opt, np.nan)
    valid = bool(np.all(probs >= 0.0) and p_undecided >= 0.0)
    for i in range(n_opt):
        if counts[i] == 0:
            continue
        if counts[i] < CONTROLLED_MIN_COUNT or not valid:
            # too few choices to fit on: the plain mean and its error
            mean_rt[i] = tally.sums[i] / counts[i]
            err_rt = max(err_rt, _rt_error(counts[i], counts[i] / n, tally.sums[i],
                                           tally.squares[i]))
            continue
        if not probs[i] > 0.0:
            valid = False
            continue
        mean = times[i] / probs[i]
        c = np.zeros(2 * n_opt + 1)
        c[n_opt + 1 + i] = 1.0
        c[i] = -mean
        rel = 3.0 * math.sqrt(max(float(c @ cov @ c), 0.0)) / probs[i] / mean
        valid = valid and 1.0 <= mean <= max_steps and math.isfinite(rel)
        mean_rt[i] = mean
        err_rt = max(err_rt, min(1.0, probs[i] / RT_WEIGHT_FLOOR) * rel)
    if not valid:
        err_p, err_rt = tally.errors()
        return tally.answer(make_result, err_p, err_rt), err_p, err_rt
    shares = counts / n
    with np.errstate(invalid="ignore", divide="ignore"):
        scale = np.where(counts > 0, probs / np.where(counts > 0, shares, 1.0), 0.0)
    answer = make_result(probs, float(p_undecided), tally.hist / n * scale, mean_rt, n, err_p,
                         err_rt)
    return answer, err_p, err_rt
