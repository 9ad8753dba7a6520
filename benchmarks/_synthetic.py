"""Synthetic choice data with decision steps, shared by the fitting benchmarks."""

from __future__ import annotations

import warnings

import mdft


def threshold_trials(M, w, params, subsets, theta, max_steps, n_trials, rng):
    """Simulated threshold-stopped trials on each subset, as ``ChoiceData`` with steps.

    ``M``: evaluations of the whole option set; ``params``: ``phi1``, ``phi2``, ``beta`` and
    ``sigma2``; ``n_trials``: trials per subset, or a callable drawing that number before
    each subset's simulation. Trials undecided within ``max_steps`` are left out (choice
    data have no such category). ``rng`` is consumed in subset order.
    """
    offered, choices, steps = [], [], []
    for s in subsets:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", mdft.UnstableFeedbackWarning)
            model = mdft.MDFTModel(M[s], w, **params)
        n = n_trials() if callable(n_trials) else n_trials
        sim = mdft.simulate(model, n, stopping=mdft.Threshold(theta, max_steps), rng=rng)
        ok = sim.choices >= 0
        offered += [s] * int(ok.sum())
        choices += [s[c] for c in sim.choices[ok]]
        steps += sim.decision_steps[ok].tolist()
    return mdft.ChoiceData.from_trials(offered, choices, response_times=steps)
