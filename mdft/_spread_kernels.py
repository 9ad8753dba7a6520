"""Compiled trials that record where a three-option walk went before it decided.

The moment chain of ``threshold_probabilities`` needs the plane of reference sums that the
walks' summed preference follows and the spread of that sum among the walks about to decide
(:mod:`mdft._plane_spread`). These kernels run the threshold trials of
:func:`mdft._kernels.reduced_trial` (the same draws and arithmetic) and keep, instead of
the choice, the preferences before the deciding step and the sums of the products of the
preferences over every step a walk stood undecided. Nothing here validates its input.
"""

from __future__ import annotations

from numba import prange

from ._kernels import load_words, reduced_coefficients, reduced_draws, store_words
from ._numba import njit, njit_parallel


@njit
def walk_trial(state, S, CM, L, cuts, P0, n_steps, theta, out, moments):
    """One three-option threshold trial on the stream ``state``: its decision step, with
    ``out`` the preferences the step before (``-1`` undecided, ``out`` untouched). Each
    step after which the walk stands undecided at ``p`` adds ``v v^T``, ``v = (1, p)``, to
    the upper triangle of ``moments`` (4 x 4). The step is written out as in
    :func:`mdft._kernels.reduced_trial` (a helper taking the coefficients as a tuple made
    that kernel 1.35 times slower)."""
    r = L.shape[1]
    (s00, s01, s02, s10, s11, s12, s20, s21, s22,
     l00, l01, l10, l11, l20, l21) = reduced_coefficients(S, L, True)
    w0, w1, w2, w3 = load_words(state)
    p0 = P0[0]
    p1 = P0[1]
    p2 = P0[2]
    for t in range(1, n_steps + 1):
        j, z0, z1, w0, w1, w2, w3 = reduced_draws(w0, w1, w2, w3, cuts, r)
        q0 = s00 * p0 + s01 * p1 + s02 * p2 + CM[0, j] + l00 * z0 + l01 * z1
        q1 = s10 * p0 + s11 * p1 + s12 * p2 + CM[1, j] + l10 * z0 + l11 * z1
        q2 = s20 * p0 + s21 * p1 + s22 * p2 + CM[2, j] + l20 * z0 + l21 * z1
        if q0 >= theta or q1 >= theta or q2 >= theta:
            out[0] = p0
            out[1] = p1
            out[2] = p2
            store_words(state, w0, w1, w2, w3)
            return t
        p0, p1, p2 = q0, q1, q2
        moments[0, 0] += 1.0
        moments[0, 1] += p0
        moments[0, 2] += p1
        moments[0, 3] += p2
        moments[1, 1] += p0 * p0
        moments[1, 2] += p0 * p1
        moments[1, 3] += p0 * p2
        moments[2, 2] += p1 * p1
        moments[2, 3] += p1 * p2
        moments[3, 3] += p2 * p2
    store_words(state, w0, w1, w2, w3)
    return -1


@njit_parallel
def walks(states, bounds, S, CM, L, cuts, P0, n_steps, theta, out, steps, moments):
    """:func:`walk_trial` for trials ``bounds[c] <= k < bounds[c + 1]`` on stream
    ``states[c]``, the chunks in parallel: ``steps[k]``, ``out[k]`` and each chunk's
    ``moments[c]`` (so that their sum, taken in order, does not depend on the threads)."""
    for c in prange(bounds.shape[0] - 1):
        for k in range(bounds[c], bounds[c + 1]):
            steps[k] = walk_trial(states[c], S, CM, L, cuts, P0, n_steps, theta, out[k],
                                  moments[c])
