"""Compiled trials of the simulation fallback that also record martingale control variates.

Nothing here validates its input: :func:`mdft.simulate._controlled_trials` builds the
arguments from a checked model and calls these functions.

A trial of two or three options runs as :func:`mdft._kernels.reduced_trial` does (the same
draws and arithmetic, so the same choices and steps from the same stream) and also records
sums over its steps ``t = 1 .. T``. :func:`controlled_trial` records the monomials' sums:

- the products ``m(y(t-1), t) xi(t)`` along both plane axes. ``xi(t)`` is the step's random
  part in the zero-sum plane, ``E (C M (e_j - w) + L z)``: the attention's deviation from
  its mean and the noise, centred, so that its expectation given everything before step
  ``t`` is zero. ``m`` runs over :data:`N_MONOMIALS` monomials of the plane position
  ``y = E (P - P(0)) / theta``: those of degree at most 3, and ``t / time_scale`` times
  those of degree at most 2.

:func:`rich_trial` records those and, for each option ``i``:

- near its threshold: ``u^3`` and ``u^9``, ``u = max(0, 1 + (P_i(t-1) - theta) / theta)``,
  alone and times ``t / time_scale``, times option ``i``'s part of the step's random part
  (:data:`N_NEAR` sums in all);
- its crossing hazard: the chance ``a_i(t)`` that the step takes ``P_i`` to ``theta``,
  given the state before it and the attribute attended (a normal tail: only the noise is
  left to draw), summed over the steps that count (the step's mean within
  :data:`HAZARD_REACH` standard deviations below ``theta``), alone and times ``t``. The
  trial records ``F_i - sum_t a_i(t)`` and ``T F_i - sum_t t a_i(t)``, ``F_i`` the
  indicator that its last step counted and took ``P_i`` to ``theta``.

Each sum's terms have expectation zero given everything before them (``m`` and the state
are known before ``xi(t)`` and the noise of step ``t`` are drawn; whether a step counts is
known once its attribute is drawn, and the indicator that a counted step takes ``P_i`` past
``theta`` has expectation ``a_i(t)``; a trial goes on only while no option has reached it),
so every sum is a martingale stopped at the trial's end, a bounded time, and has
expectation zero: a control variate (:mod:`mdft._control_variates`). The hazards' normal
tail has a relative error below 1.2e-7 (:func:`_upper_tail`), the only departure from zero.
Two options use the first plane axis only (the second axis is zero, and so are the sums
that involve it, and the third option's).
"""

from __future__ import annotations

import math

import numpy as np
from numba import prange

from ._kernels import (load_words, reduced_choice, reduced_coefficients, reduced_draws,
                       store_words)
from ._numba import njit, njit_inline, njit_parallel

#: Monomials of the position that multiply both axes of ``xi``: ten of degree <= 3, and six
#: of degree <= 2 times the step.
N_MONOMIALS = 16
#: Functions of an option's distance to the threshold that multiply that option's part of
#: ``xi``: for each of three options, two powers that rise steeply towards it (like
#: exponentials), alone and times the step.
N_NEAR = 12
#: Hazard sums a trial records: each option's, alone and weighted by the step.
N_HAZARDS = 6
#: Control sums a trial records: the monomials times each axis of ``xi``, the functions near
#: the thresholds, then the hazard sums.
N_CONTROLS = 2 * N_MONOMIALS + N_NEAR + N_HAZARDS
#: The monomials' sums come first: trials without ``rich`` record only these.
POLYNOMIAL_CONTROLS = 2 * N_MONOMIALS
#: A step counts in an option's hazard sum only where the option's mean after the step
#: lies within this many standard deviations below the threshold (its chance to cross
#: there is at least 3e-5); so does the crossing itself. Which steps count is known before
#: their noise is drawn, so the sums stay martingales; the steps left out save the tail's
#: evaluation where a crossing is least likely.
HAZARD_REACH = 4.0
#: Trials of a fold whose products of control sums are added to the fold's sums together,
#: four at a time: each sum is then read and written once per four trials, not once per
#: trial (the products of 50 sums took 2.5 times as long one trial at a time).
GROUP = 4


def gram_size(n_options):
    """Side of each fold's sums of ``v v^T`` for ``n_options`` options. ``v`` holds, in
    order: 1, the :data:`N_CONTROLS` control sums, the indicators of the options and of
    ending undecided, and each option's indicator times the decision step."""
    return 1 + N_CONTROLS + 2 * n_options + 1


def symmetric(grams):
    """The full, symmetric sums of ``v v^T`` from the kernels' (..., size, size) ``grams``,
    which hold each product once: the targets' products with the control sums below the
    diagonal (:func:`_add_targets`), every other above it or on it."""
    upper = np.triu(grams) + np.swapaxes(np.tril(grams, -1), -1, -2)
    return upper + np.swapaxes(np.triu(upper, 1), -1, -2)


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
def _near(p0, p1, p2, inv_theta, theta, three):
    """The six functions of the distances to the threshold, option by option: ``u^3`` and
    ``u^9``, ``u = max(0, 1 + d)``, ``d = (P_i - theta) / theta`` (like ``exp(3 d)`` and
    ``exp(9 d)`` near the threshold, in a few products); zero for a third option that is
    not there."""
    u0 = max(0.0, 1.0 + (p0 - theta) * inv_theta)
    u1 = max(0.0, 1.0 + (p1 - theta) * inv_theta)
    u2 = max(0.0, 1.0 + (p2 - theta) * inv_theta) if three else 0.0
    c0 = u0 * u0 * u0
    c1 = u1 * u1 * u1
    c2 = u2 * u2 * u2
    return (c0, c0 * c0 * c0, c1, c1 * c1 * c1, c2, c2 * c2 * c2)


@njit_inline
def _accumulate_near(acc, e, tau, x0, x1, x2):
    """``acc`` plus, for each option ``i``, its two functions ``e`` (alone, then times
    ``tau``) times its part ``x_i`` of ``xi``: a 12-tuple, option by option."""
    a0 = e[0] * x0
    a1 = e[1] * x0
    a2 = e[2] * x1
    a3 = e[3] * x1
    a4 = e[4] * x2
    a5 = e[5] * x2
    return (acc[0] + a0, acc[1] + a1, acc[2] + tau * a0, acc[3] + tau * a1,
            acc[4] + a2, acc[5] + a3, acc[6] + tau * a2, acc[7] + tau * a3,
            acc[8] + a4, acc[9] + a5, acc[10] + tau * a4, acc[11] + tau * a5)


@njit_inline
def _upper_tail(g):
    """``Pr(Z >= g)`` for a standard normal ``Z``, to a relative error below 1.2e-7 for every
    ``g``: the Chebyshev-fitted ``erfc`` of Press et al. (Numerical Recipes, section 6.2),
    a quarter of the time of ``math.erfc``."""
    z = abs(g) * 0.7071067811865476
    t = 1.0 / (1.0 + 0.5 * z)
    poly = (-1.26551223 + t * (1.00002368 + t * (0.37409196 + t * (0.09678418 + t * (
        -0.18628806 + t * (0.27886807 + t * (-1.13520398 + t * (1.48851587 + t * (
            -0.82215223 + t * 0.17087277)))))))))
    tail = 0.5 * t * math.exp(poly - z * z)
    return tail if g >= 0.0 else 1.0 - tail


@njit_inline
def _hazard(mean, theta, inv_sd):
    """``(a, counted)``: whether a step whose mean (given the attribute attended) is
    ``mean`` counts in the hazard sum (within :data:`HAZARD_REACH` standard deviations below
    ``theta``; ``inv_sd`` is one over the step noise's standard deviation, zero where there
    is no noise), and its chance ``a`` to reach ``theta`` (:func:`_upper_tail`; 0 where it
    does not count)."""
    if inv_sd <= 0.0:
        return (1.0, True) if mean >= theta else (0.0, False)
    g = (theta - mean) * inv_sd
    if g >= HAZARD_REACH:
        return 0.0, False
    return _upper_tail(g), True


@njit_inline
def _store_monomials(acc, a, b):
    """Write the monomials' sums of the two axes into ``acc``, interleaved:
    ``acc[2k] = a[k]``, ``acc[2k + 1] = b[k]``."""
    for k in range(N_MONOMIALS):
        acc[2 * k] = a[k]
        acc[2 * k + 1] = b[k]


@njit_inline
def _store(acc, a, b, near, h, ht, crossed, t_end):
    """Write the trial's sums into ``acc``: the monomials' (:func:`_store_monomials`), the
    sums near the thresholds, then each option's hazard control ``F_i - h_i`` and its
    step-weighted one ``t_end F_i - ht_i`` (``crossed``: ``F_i``, the indicator that the
    last step took option ``i`` past the threshold and counted)."""
    _store_monomials(acc, a, b)
    for k in range(N_NEAR):
        acc[2 * N_MONOMIALS + k] = near[k]
    base = 2 * N_MONOMIALS + N_NEAR
    for i in range(3):
        acc[base + i] = crossed[i] - h[i]
        acc[base + 3 + i] = t_end * crossed[i] - ht[i]


@njit_inline
def _plane_terms(plane):
    """The entries of ``plane`` (:func:`controlled_trial`) as scalars: the axes ``E``, the
    start's coordinates, ``1 / theta``, ``1 / time_scale`` and ``E L``."""
    return (plane[0, 0], plane[0, 1], plane[0, 2], plane[1, 0], plane[1, 1], plane[1, 2],
            plane[0, 3], plane[1, 3], plane[0, 4], plane[1, 4],
            plane[0, 5], plane[0, 6], plane[1, 5], plane[1, 6])


@njit_inline
def _start(P0, three):
    """The starting preferences as three scalars (the third zero for two options)."""
    return P0[0], P0[1], (P0[2] if three else 0.0)


@njit_inline
def _zeros16():
    """Sixteen zeros: the monomials' sums before the first step."""
    z = 0.0
    return (z, z, z, z, z, z, z, z, z, z, z, z, z, z, z, z)


@njit
def controlled_trial(state, S, CM, L, cuts, P0, n_steps, theta, plane, P, acc):
    """:func:`mdft._kernels.reduced_trial`, writing the trial's control sums to ``acc``.

    ``plane`` (2, 7 + J) holds, row by row for the two plane axes: ``E`` (columns 0-2,
    zero where there is no third option), the start's coordinates (column 3), ``1 / theta``
    and ``1 / time_scale`` (column 4, rows 0 and 1), ``E L`` padded to two columns (columns
    5-6) and ``E C M (I - w 1^T)`` (columns 7 on, one per attribute). Only the monomials'
    sums are written (the first :data:`POLYNOMIAL_CONTROLS` of ``acc``).
    """
    three = P0.shape[0] == 3
    r = L.shape[1]
    (s00, s01, s02, s10, s11, s12, s20, s21, s22,
     l00, l01, l10, l11, l20, l21) = reduced_coefficients(S, L, three)
    (e00, e01, e02, e10, e11, e12, c0, c1, inv_scale, inv_time,
     g00, g01, g10, g11) = _plane_terms(plane)
    w0, w1, w2, w3 = load_words(state)
    p0, p1, p2 = _start(P0, three)
    a = b = _zeros16()
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
            _store_monomials(acc, a, b)
            return reduced_choice(state, P, p0, p1, p2, three), t
    store_words(state, w0, w1, w2, w3)
    _store_monomials(acc, a, b)
    return -1, -1


@njit
def rich_trial(state, S, CM, L, cuts, P0, n_steps, theta, plane, opt, P, acc):
    """:func:`controlled_trial` with every control: the sums near the thresholds and the
    hazards too (all :data:`N_CONTROLS` written to ``acc``), at about 1.2-2.2 times its
    cost. ``plane`` is as there; ``opt`` (3, 1 + J) holds, row by row for the options (zero
    where there is no third): one over the standard deviation of the option's step noise,
    ``sqrt((L L^T)_ii)`` (column 0; zero without noise), and ``C M (I - w 1^T)`` (columns 1
    on, one per attribute).

    The step is :func:`mdft._kernels.reduced_trial`'s, its noise added last to the mean
    given the attribute attended (the same rounding), whose tails are the hazards.
    """
    three = P0.shape[0] == 3
    r = L.shape[1]
    # the sums near the thresholds and the hazards' (with whether the last step counted)
    zero = 0.0
    near = (zero, zero, zero, zero, zero, zero, zero, zero, zero, zero, zero, zero)
    n0 = n1 = n2 = False
    h0 = h1 = h2 = 0.0
    ht0 = ht1 = ht2 = 0.0
    (s00, s01, s02, s10, s11, s12, s20, s21, s22,
     l00, l01, l10, l11, l20, l21) = reduced_coefficients(S, L, three)
    (e00, e01, e02, e10, e11, e12, c0, c1, inv_scale, inv_time,
     g00, g01, g10, g11) = _plane_terms(plane)
    inv0, inv1, inv2 = opt[0, 0], opt[1, 0], opt[2, 0]
    a = b = _zeros16()
    w0, w1, w2, w3 = load_words(state)
    p0, p1, p2 = _start(P0, three)
    for t in range(1, n_steps + 1):
        y0 = (e00 * p0 + e01 * p1 + e02 * p2 - c0) * inv_scale
        y1 = (e10 * p0 + e11 * p1 + e12 * p2 - c1) * inv_scale
        e = _near(p0, p1, p2, inv_scale, theta, three)
        j, z0, z1, w0, w1, w2, w3 = reduced_draws(w0, w1, w2, w3, cuts, r)
        x0 = plane[0, 7 + j] + g00 * z0 + g01 * z1
        x1 = plane[1, 7 + j] + g10 * z0 + g11 * z1
        tau = t * inv_time
        m = _monomials(y0, y1, tau)
        a = _accumulate(a, m, x0)
        b = _accumulate(b, m, x1)
        near = _accumulate_near(near, e, tau, opt[0, 1 + j] + l00 * z0 + l01 * z1,
                                opt[1, 1 + j] + l10 * z0 + l11 * z1,
                                opt[2, 1 + j] + l20 * z0 + l21 * z1)
        # the step of mdft._kernels.reduced_trial, in the same order
        u0 = s00 * p0 + s01 * p1 + s02 * p2 + CM[0, j]
        u1 = s10 * p0 + s11 * p1 + s12 * p2 + CM[1, j]
        k, n0 = _hazard(u0, theta, inv0)
        h0 += k
        ht0 += t * k
        k, n1 = _hazard(u1, theta, inv1)
        h1 += k
        ht1 += t * k
        q0 = u0 + l00 * z0 + l01 * z1
        q1 = u1 + l10 * z0 + l11 * z1
        if three:
            u2 = s20 * p0 + s21 * p1 + s22 * p2 + CM[2, j]
            k, n2 = _hazard(u2, theta, inv2)
            h2 += k
            ht2 += t * k
            p2 = u2 + l20 * z0 + l21 * z1
        p0, p1 = q0, q1
        if p0 >= theta or p1 >= theta or (three and p2 >= theta):
            store_words(state, w0, w1, w2, w3)
            crossed = (1.0 if n0 and p0 >= theta else 0.0, 1.0 if n1 and p1 >= theta else 0.0,
                       1.0 if n2 and three and p2 >= theta else 0.0)
            _store(acc, a, b, near, (h0, h1, h2), (ht0, ht1, ht2), crossed, float(t))
            return reduced_choice(state, P, p0, p1, p2, three), t
    store_words(state, w0, w1, w2, w3)
    _store(acc, a, b, near, (h0, h1, h2), (ht0, ht1, ht2), (0.0, 0.0, 0.0), 0.0)
    return -1, -1


@njit_inline
def _add_targets(gram, acc, choice, step, n_options, used):
    """Add the trial's terms of ``v v^T`` (:func:`gram_size`) other than the products of
    two control sums: the count, the sums, and the targets (one indicator, an option's or
    undecided's, and, if chosen, the step) with the sums and each other. The targets'
    products with the sums go to the targets' rows, below the diagonal (a row is contiguous
    in memory, a column is not); the rest to the upper triangle. Only the first ``used``
    sums of ``acc`` are read."""
    K = acc.shape[0]
    gram[0, 0] += 1.0
    for a in range(used):
        gram[0, 1 + a] += acc[a]
    hit = 1 + K + (choice if choice >= 0 else n_options)
    gram[0, hit] += 1.0
    row = gram[hit]
    for a in range(used):
        row[1 + a] += acc[a]
    gram[hit, hit] += 1.0
    if choice >= 0:
        timed = 1 + K + n_options + 1 + choice
        gram[0, timed] += step
        row = gram[timed]
        for a in range(used):
            row[1 + a] += acc[a] * step
        gram[hit, timed] += step
        gram[timed, timed] += step * step


@njit_inline
def _add_products(gram, group, n_group, used):
    """Add the products of the control sums of the first ``n_group`` trials of ``group``
    (one trial a row) to the upper triangle of ``gram``: four trials in one sweep, so that
    each sum of ``gram`` is read and written once for the four, then those left one by one."""
    full = n_group - n_group % 4
    for i in range(0, full, 4):
        for a in range(used):
            g0 = group[i, a]
            g1 = group[i + 1, a]
            g2 = group[i + 2, a]
            g3 = group[i + 3, a]
            row = gram[1 + a]
            for b in range(a, used):
                row[1 + b] += (g0 * group[i, b] + g1 * group[i + 1, b]) + (
                    g2 * group[i + 2, b] + g3 * group[i + 3, b])
    for i in range(full, n_group):
        for a in range(used):
            va = group[i, a]
            row = gram[1 + a]
            for b in range(a, used):
                row[1 + b] += va * group[i, b]


@njit
def controlled_chunk(state, first, stop, S, CM, L, cuts, P0, n_steps, theta, plane, opt,
                     rich, choices, steps, grams):
    """Trials ``first <= k < stop`` with :func:`controlled_trial` on one stream; writes
    ``choices[k - first]`` and ``steps[k - first]`` and adds each trial's products to
    ``grams[k % 2]`` (:func:`_add_targets`, and the products of its control sums,
    :data:`GROUP` trials of the fold at a time, :func:`_add_products`; :func:`symmetric`
    gives the full sums)."""
    n = P0.shape[0]
    P = np.empty(n)
    acc = np.zeros(N_CONTROLS)
    used = N_CONTROLS if rich else POLYNOMIAL_CONTROLS
    groups = np.zeros((2, GROUP, N_CONTROLS))
    filled = np.zeros(2, dtype=np.int64)
    for k in range(first, stop):
        if rich:
            choice, step = rich_trial(state, S, CM, L, cuts, P0, n_steps, theta, plane, opt, P,
                                      acc)
        else:
            choice, step = controlled_trial(state, S, CM, L, cuts, P0, n_steps, theta, plane,
                                            P, acc)
        choices[k - first] = choice
        steps[k - first] = step
        fold = k % 2
        _add_targets(grams[fold], acc, choice, step, n, used)
        group = groups[fold]
        group[filled[fold], :used] = acc[:used]
        filled[fold] += 1
        if filled[fold] == GROUP:
            _add_products(grams[fold], group, GROUP, used)
            filled[fold] = 0
    for fold in range(2):
        _add_products(grams[fold], groups[fold], filled[fold], used)


@njit_parallel
def controlled_chunks(states, bounds, S, CM, L, cuts, P0, n_steps, theta, plane, opt, rich,
                      choices, steps, grams):
    """:func:`controlled_chunk` for every chunk ``c`` (stream ``states[c]``, sums
    ``grams[c]``), in parallel."""
    n_chunks = bounds.shape[0] - 1
    origin = bounds[0]
    for c in prange(n_chunks):
        lo = bounds[c] - origin
        hi = bounds[c + 1] - origin
        controlled_chunk(states[c], bounds[c], bounds[c + 1], S, CM, L, cuts, P0, n_steps,
                         theta, plane, opt, rich, choices[lo:hi], steps[lo:hi], grams[c])
