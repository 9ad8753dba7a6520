"""Compiled trials of the simulation fallback that also record martingale control variates.

Nothing here validates its input: :func:`mdft.simulate._controlled_trials` builds the
arguments from a checked model and calls these functions.

A trial of two or three options runs as :func:`mdft._kernels.reduced_trial` does (the same
draws and arithmetic, so the same choices and steps from the same stream) and also sums,
over its steps ``t = 1 .. T``, the products ``m(y(t-1), t) xi(t)``:

- ``xi(t)`` is the step's random part in the zero-sum plane, ``E (C M (e_j - w) + L z)``:
  the attention's deviation from its mean and the noise, centred, so that its expectation
  given everything before step ``t`` is zero;
- ``m`` runs over :data:`N_MONOMIALS` monomials of the plane position before the step,
  ``y = E (P(t-1) - P(0)) / scale``: those of degree at most 3, and ``t / time_scale``
  times those of degree at most 2.

Each ``m`` is known before step ``t`` is drawn, so every sum is a martingale stopped at
the trial's end, a bounded time, and has expectation zero exactly: a control variate
(:mod:`mdft._control_variates`). Two options use the first plane axis only (the second
axis is zero, and so are the sums that involve it).
"""

from __future__ import annotations

import numpy as np
from numba import prange

from ._kernels import (load_words, reduced_choice, reduced_coefficients, reduced_draws,
                       store_words)
from ._numba import njit, njit_inline, njit_parallel

#: Monomials of the position: ten of degree <= 3, and six of degree <= 2 times the step.
N_MONOMIALS = 16
#: Control sums a trial records: each monomial times each of the two axes of ``xi``.
N_CONTROLS = 2 * N_MONOMIALS


def gram_size(n_options):
    """Side of each fold's sums of ``v v^T`` for ``n_options`` options. ``v`` holds, in
    order: 1, the :data:`N_CONTROLS` control sums, the indicators of the options and of
    ending undecided, and each option's indicator times the decision step."""
    return 1 + N_CONTROLS + 2 * n_options + 1


@njit_inline
def _monomials(y0, y1, tau):
    """The :data:`N_MONOMIALS` monomials of the position ``(y0, y1)`` and the scaled step
    ``tau``, in the order of the control sums."""
    a = y0 * y0
    b = y0 * y1
    c = y1 * y1
    return (1.0, y0, y1, a, b, c, a * y0, a * y1, c * y0, c * y1,
            tau, tau * y0, tau * y1, tau * a, tau * b, tau * c)


@njit_inline
def _accumulate(acc, m, x):
    """``acc + m x``, elementwise, for the 16-tuples ``acc`` and ``m``."""
    return (acc[0] + m[0] * x, acc[1] + m[1] * x, acc[2] + m[2] * x, acc[3] + m[3] * x,
            acc[4] + m[4] * x, acc[5] + m[5] * x, acc[6] + m[6] * x, acc[7] + m[7] * x,
            acc[8] + m[8] * x, acc[9] + m[9] * x, acc[10] + m[10] * x, acc[11] + m[11] * x,
            acc[12] + m[12] * x, acc[13] + m[13] * x, acc[14] + m[14] * x,
            acc[15] + m[15] * x)


@njit_inline
def _store(acc, a, b):
    """Write the sums of the two axes into ``acc``, interleaved: ``acc[2k] = a[k]``,
    ``acc[2k + 1] = b[k]``."""
    for k in range(N_MONOMIALS):
        acc[2 * k] = a[k]
        acc[2 * k + 1] = b[k]


@njit
def controlled_trial(state, S, CM, L, cuts, P0, n_steps, theta, plane, P, acc):
    """:func:`mdft._kernels.reduced_trial`, writing the trial's control sums to ``acc``.

    ``plane`` (2, 7 + J) holds, row by row for the two plane axes: ``E`` (columns 0-2,
    zero where there is no third option), the start's coordinates (column 3), ``1 / scale`` and
    ``1 / time_scale`` (column 4, rows 0 and 1), ``E L`` padded to two columns (columns
    5-6) and ``E C M (I - w 1^T)`` (columns 7 on, one per attribute).
    """
    three = P0.shape[0] == 3
    r = L.shape[1]
    (s00, s01, s02, s10, s11, s12, s20, s21, s22,
     l00, l01, l10, l11, l20, l21) = reduced_coefficients(S, L, three)
    e00, e01, e02 = plane[0, 0], plane[0, 1], plane[0, 2]
    e10, e11, e12 = plane[1, 0], plane[1, 1], plane[1, 2]
    c0, c1 = plane[0, 3], plane[1, 3]
    inv_scale, inv_time = plane[0, 4], plane[1, 4]
    g00, g01, g10, g11 = plane[0, 5], plane[0, 6], plane[1, 5], plane[1, 6]
    w0, w1, w2, w3 = load_words(state)
    p0 = P0[0]
    p1 = P0[1]
    p2 = P0[2] if three else 0.0
    zero = 0.0
    a = (zero, zero, zero, zero, zero, zero, zero, zero, zero, zero, zero, zero, zero, zero,
         zero, zero)
    b = a
    for t in range(1, n_steps + 1):
        y0 = (e00 * p0 + e01 * p1 + e02 * p2 - c0) * inv_scale
        y1 = (e10 * p0 + e11 * p1 + e12 * p2 - c1) * inv_scale
        j, z0, z1, w0, w1, w2, w3 = reduced_draws(w0, w1, w2, w3, cuts, r)
        x0 = plane[0, 7 + j] + g00 * z0 + g01 * z1
        x1 = plane[1, 7 + j] + g10 * z0 + g11 * z1
        m = _monomials(y0, y1, t * inv_time)
        a = _accumulate(a, m, x0)
        b = _accumulate(b, m, x1)
        # the step of mdft._kernels.reduced_trial, in the same order
        q0 = s00 * p0 + s01 * p1 + s02 * p2 + CM[0, j] + l00 * z0 + l01 * z1
        q1 = s10 * p0 + s11 * p1 + s12 * p2 + CM[1, j] + l10 * z0 + l11 * z1
        if three:
            p2 = s20 * p0 + s21 * p1 + s22 * p2 + CM[2, j] + l20 * z0 + l21 * z1
        p0, p1 = q0, q1
        if p0 >= theta or p1 >= theta or (three and p2 >= theta):
            store_words(state, w0, w1, w2, w3)
            _store(acc, a, b)
            return reduced_choice(state, P, p0, p1, p2, three), t
    store_words(state, w0, w1, w2, w3)
    _store(acc, a, b)
    return -1, -1


@njit_inline
def _add_trial(gram, acc, choice, step, n_options):
    """Add the trial's ``v v^T`` to the upper triangle of ``gram``, with
    ``v = (1, acc, e_choice, step e_choice)`` (:func:`gram_size`)."""
    K = acc.shape[0]
    gram[0, 0] += 1.0
    for a in range(K):
        va = acc[a]
        gram[0, 1 + a] += va
        for b in range(a, K):
            gram[1 + a, 1 + b] += va * acc[b]
    # the targets: one indicator (an option's, or undecided's) and, if chosen, the step
    hit = 1 + K + (choice if choice >= 0 else n_options)
    gram[0, hit] += 1.0
    for a in range(K):
        gram[1 + a, hit] += acc[a]
    gram[hit, hit] += 1.0
    if choice >= 0:
        timed = 1 + K + n_options + 1 + choice
        gram[0, timed] += step
        for a in range(K):
            gram[1 + a, timed] += acc[a] * step
        gram[hit, timed] += step
        gram[timed, timed] += step * step


@njit
def controlled_chunk(state, first, stop, S, CM, L, cuts, P0, n_steps, theta, plane, choices,
                     steps, grams):
    """Trials ``first <= k < stop`` with :func:`controlled_trial` on one stream; writes
    ``choices[k - first]`` and ``steps[k - first]`` and adds each trial's products to the
    upper triangle of ``grams[k % 2]`` (:func:`_add_trial`)."""
    n = P0.shape[0]
    P = np.empty(n)
    acc = np.empty(N_CONTROLS)
    for k in range(first, stop):
        choice, step = controlled_trial(state, S, CM, L, cuts, P0, n_steps, theta, plane, P,
                                        acc)
        choices[k - first] = choice
        steps[k - first] = step
        _add_trial(grams[k % 2], acc, choice, step, n)


@njit_parallel
def controlled_chunks(states, bounds, S, CM, L, cuts, P0, n_steps, theta, plane, choices,
                      steps, grams):
    """:func:`controlled_chunk` for every chunk ``c`` (stream ``states[c]``, sums
    ``grams[c]``), in parallel."""
    n_chunks = bounds.shape[0] - 1
    origin = bounds[0]
    for c in prange(n_chunks):
        lo = bounds[c] - origin
        hi = bounds[c + 1] - origin
        controlled_chunk(states[c], bounds[c], bounds[c + 1], S, CM, L, cuts, P0, n_steps,
                         theta, plane, choices[lo:hi], steps[lo:hi], grams[c])
