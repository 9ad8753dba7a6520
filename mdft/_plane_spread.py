"""The spread of the summed preference that the three-option moment chain uses.

Within a state of the moment chain (a cell of the zero-sum plane) the walks' sums
``s = 1^T P`` differ; the chain evaluates a state's step at ``s_ref +- delta``
(``docs/threshold_exact.md``, section 2). The sum matters where a step may end at a
threshold, and there the walks with the larger sums have left already. So ``delta`` is
measured among the walks about to decide: a short simulation records the preferences of
each walk the step before it decides, and ``delta`` is the standard deviation of those
sums about the plane of reference sums. The pilots' own measure (the occupation-weighted
spread of the sum within the states, from a second moment carried without the selection
at the thresholds) stays where this one cannot be made. On the 78 three-option models of
four random draws where both were measured, the pilots' spread was 0.27-5.8 times this one
(median 1.05; above 1.2 on 29 of them, and 1.6-5.8 on the ten largest), and on models where
the difference mattered it made mean times run short by up to 1.2 %."""

from __future__ import annotations

import numpy as np

from . import _spread_kernels
from .simulate import _chunk_layout, _reduced_args

#: Trials of the first batch, and at most in all.
FIRST_TRIALS = 500
MAX_TRIALS = 4_000
#: Trial-steps in all, the first batch's included (the second is cut to fit): about
#: 0.02-0.03 s on two threads. The first batch alone may take more (``FIRST_TRIALS`` times the step
#: limit at most).
MAX_WORK = 2_000_000
#: Fewer walks than this decided after the first step: the spread is not measured here.
MIN_DECIDED = 200
#: Seed of the trials (the chain's answers are repeatable).
SEED = 20_261


def _trials(args, n, gen):
    """Decision steps (``-1`` undecided) and the preferences the step before, of ``n``
    trials on the streams of :func:`mdft.simulate._chunk_layout` drawn from ``gen``."""
    S, CM, L, cuts, P0, max_steps, theta = args
    states, bounds, _, steps = _chunk_layout(gen, n)
    out = np.zeros((n, 3))
    _spread_kernels.last_states(states, bounds, S, CM, L, cuts, P0, max_steps, theta, out,
                                steps)
    return steps, out


def absorbed_spread(model, theta, max_steps, E, ref):
    """The standard deviation of the sums, about the plane ``ref = (r0, r1, r2)`` over the
    plane coordinates ``z = E^T P``, of the walks the step before they decide (after the
    first step: from the exact start the chain needs no spread); None where fewer than
    :data:`MIN_DECIDED` such walks were simulated, or the model has no three-option
    trials of :func:`mdft._kernels.reduced_trial` (noise of rank above two).

    :data:`FIRST_TRIALS` trials are simulated, then more, up to :data:`MAX_TRIALS` in all,
    as far as :data:`MAX_WORK` trial-steps in all go at the first batch's steps per trial.
    """
    args = _reduced_args(model, theta, max_steps)
    if args is None or model.n_options != 3:
        return None
    gen = np.random.default_rng(SEED)
    steps, last = _trials(args, FIRST_TRIALS, gen)
    per_trial = float(np.where(steps > 0, steps, max_steps).mean())
    more = min(MAX_TRIALS - FIRST_TRIALS, int(MAX_WORK / per_trial) - FIRST_TRIALS)
    if more > 0:
        steps2, last2 = _trials(args, more, gen)
        steps = np.concatenate([steps, steps2])
        last = np.concatenate([last, last2])
    kept = steps >= 2
    if int(kept.sum()) < MIN_DECIDED:
        return None
    P = last[kept]
    z = P @ E
    deviation = P.sum(axis=1) - (ref[0] + z @ np.asarray(ref[1:], dtype=np.float64))
    return float(np.std(deviation, ddof=1))
