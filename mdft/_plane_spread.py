"""The walks that fit the summed preference for the three-option moment chain.

Within a state of the moment chain (a cell of the zero-sum plane) the walks' sums
``s = 1^T P`` differ; the chain evaluates a state's step at a reference sum ``s_ref``, a
plane over the state's coordinates, plus and minus a spread ``delta``
(``docs/threshold_exact.md``, section 2). A short simulation of the walks gives both:

* the plane: the least-squares fit of the sum on the plane coordinates over every step at
  which a walk stood undecided (the occupation the chain's states hold), from the sums of
  the products of the preferences that the trials add up (:func:`walk_plane`);
* the spread: the sum matters where a step may end at a threshold, and there the walks with
  the larger sums have left already. So ``delta`` is measured among the walks about to
  decide: the standard deviation, about the plane, of the sums of each walk the step before
  it decides (:func:`spread_about`).

Where the walks cannot give them (too few decide, or the model has no reduced trials), the
chain's pilot passes fit the plane from their own occupation and measure their own spread
(a second moment carried without the selection at the thresholds). On the 78 three-option
models of four random draws where both spreads were measured, the pilots' spread was
0.27-5.8 times the walks' (median 1.05; above 1.2 on 29 of them, and 1.6-5.8 on the ten
largest), and on models where the difference mattered it made mean times run short by up
to 1.2 %."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from . import _spread_kernels
from ._control_kernels import symmetric
from .simulate import _chunk_layout, _reduced_args

#: Trials of the first batch, and at most in all.
FIRST_TRIALS = 500
MAX_TRIALS = 4_000
#: Trial-steps in all, the first batch's included (the second is cut to fit): about
#: 0.02-0.03 s on two threads. The first batch alone may take more (``FIRST_TRIALS`` times the step
#: limit at most).
MAX_WORK = 2_000_000
#: Fewer walks than this decided after the first step: neither the spread nor the plane is
#: measured here.
MIN_DECIDED = 200
#: A plane whose least-squares system has a condition number above this is not fitted.
MAX_CONDITION = 1e12
#: Seed of the trials (the chain's answers are repeatable).
SEED = 20_261


@dataclass(frozen=True)
class Walks:
    """Simulated walks: each one's decision step (``-1`` undecided), its preferences the
    step before (``last``, rows of undecided walks unset), and ``moments``, the sum of
    ``v v^T``, ``v = (1, P)``, over every step at which a walk stood undecided at ``P``."""

    steps: np.ndarray
    last: np.ndarray
    moments: np.ndarray

    def lengths(self, max_steps):
        """The steps each walk ran: its decision step, or ``max_steps`` undecided."""
        return np.where(self.steps > 0, self.steps, max_steps)


def _trials(args, n, gen):
    """Decision steps (``-1`` undecided), the preferences the step before, and the summed
    products of the undecided preferences, of ``n`` trials on the streams of
    :func:`mdft.simulate._chunk_layout` drawn from ``gen``."""
    S, CM, L, cuts, P0, max_steps, theta = args
    states, bounds, _, steps = _chunk_layout(gen, n)
    out = np.zeros((n, 3))
    moments = np.zeros((bounds.shape[0] - 1, 4, 4))
    _spread_kernels.walks(states, bounds, S, CM, L, cuts, P0, max_steps, theta, out, steps,
                          moments)
    return steps, out, symmetric(moments.sum(axis=0))


def simulate_walks(model, theta, max_steps):
    """:data:`FIRST_TRIALS` walks, then more, up to :data:`MAX_TRIALS` in all, as far as
    :data:`MAX_WORK` trial-steps in all go at the first batch's steps per trial; None where
    the model has no three-option trials of :func:`mdft._kernels.reduced_trial` (noise of
    rank above two)."""
    args = _reduced_args(model, theta, max_steps)
    if args is None or model.n_options != 3:
        return None
    gen = np.random.default_rng(SEED)
    walks = Walks(*_trials(args, FIRST_TRIALS, gen))
    per_trial = float(walks.lengths(max_steps).mean())
    more = min(MAX_TRIALS - FIRST_TRIALS, int(MAX_WORK / per_trial) - FIRST_TRIALS)
    if more > 0:
        steps, last, moments = _trials(args, more, gen)
        walks = Walks(np.concatenate([walks.steps, steps]), np.concatenate([walks.last, last]),
                      walks.moments + moments)
    return walks


def _decided(walks):
    """The preferences, the step before, of the walks that decided after the first step;
    None where fewer than :data:`MIN_DECIDED` did."""
    kept = walks.steps >= 2
    if int(kept.sum()) < MIN_DECIDED:
        return None
    return walks.last[kept]


def walk_plane(walks, E):
    """The reference sums ``(r0, r1, r2)``: the least-squares plane ``r0 + r1 z1 + r2 z2`` of
    the sum over the plane coordinates ``z = E^T P`` at every step a walk stood undecided;
    None where fewer than :data:`MIN_DECIDED` walks decided after the first step, or the
    fit is not determined (sums that overflowed, or a condition number above
    :data:`MAX_CONDITION`)."""
    # (preferences that grow without bound can overflow the sums)
    if _decided(walks) is None or not np.isfinite(walks.moments).all():
        return None
    # v = (1, P): the regressors are (1, E^T P) and the target 1^T P
    A = np.zeros((3, 4))
    A[0, 0] = 1.0
    A[1:, 1:] = E.T
    weighted = A @ walks.moments
    gram = weighted @ A.T
    if not np.linalg.cond(gram) <= MAX_CONDITION:
        return None
    return np.linalg.solve(gram, weighted @ np.array([0.0, 1.0, 1.0, 1.0]))


def spread_about(walks, E, ref):
    """The standard deviation of the sums, about the plane ``ref = (r0, r1, r2)`` over the
    plane coordinates ``z = E^T P``, of the walks the step before they decide (after the
    first step: from the exact start the chain needs no spread); None where fewer than
    :data:`MIN_DECIDED` such walks were simulated, or their sums overflowed."""
    P = _decided(walks)
    if P is None or not np.isfinite(P).all():
        return None
    z = P @ E
    deviation = P.sum(axis=1) - (ref[0] + z @ np.asarray(ref[1:], dtype=np.float64))
    spread = float(np.std(deviation, ddof=1))
    return spread if math.isfinite(spread) else None
