"""Compiled kernels of the bound on deciding at all (:mod:`mdft._threshold_bound`).

Nothing here validates its input: :func:`mdft._threshold_bound.decision_bound` converts
the model once and calls these functions.

Both kernels walk the powers of the feedback matrix step by step. With
``P(t) = S P(t-1) + C (M W(t) + eps(t))``, the preference ``P_i(t)`` is its mean
``a_i(t) = (S^t P0)_i + sum_{k<t} (S^k C M w)_i`` plus ``Z = sum_{k<t} (X_k + Y_k)``, a sum
of independent, zero-mean terms, one per earlier step ``t - k``: the attention term
``X_k = (S^k C M (e_j - w))_i`` (attribute ``j`` drawn with probability ``w_j``) and the
Gaussian noise term ``Y_k`` of variance ``noise_var (S^k C C^T S^kT)_ii``. The step's
block ``B = S^k [C M | C | S P0]`` holds both terms' columns and ``S^(k+1) P0``.
"""

from __future__ import annotations

import math

import numpy as np

from ._numba import njit

#: Relative margin within which a mean counts as reaching ``theta``: the kernels sum the
#: mean path in another order than the simulation, so a noiseless path that touches
#: ``theta`` there may fall a few units in the last place short of it here.
ROUNDING = 1e-9


@njit
def _start(S, C, CM, P0):
    """``(B, nxt, drift, size)``: the block ``[C M | C | S P0]`` of step ``k = 0``, room for
    the next one, and the options' mean drifts and the sums of their terms' sizes, zero."""
    n = S.shape[0]
    m = CM.shape[1]
    B = np.empty((n, m + n + 1))
    B[:, :m] = CM
    B[:, m:m + n] = C
    for i in range(n):
        acc = 0.0
        for l in range(n):
            acc += S[i, l] * P0[l]
        B[i, m + n] = acc
    return B, np.empty_like(B), np.zeros(n), np.zeros(n)


@njit
def _advance(S, B, out):
    """``out = S B``: the next step's block."""
    n = S.shape[0]
    for i in range(n):
        for l in range(B.shape[1]):
            acc = 0.0
            for r in range(n):
                acc += S[i, r] * B[r, l]
            out[i, l] = acc


@njit
def _terms(B, w, noise_var, i, m, n):
    """Option ``i``'s terms of one step: ``(mean, lo, hi, attention, gauss)``, the mean of
    the attention term's values, its smallest and largest value over the attributes with
    ``w_j > 0``, its variance, and the variance of the noise term."""
    mean = 0.0
    for j in range(m):
        mean += B[i, j] * w[j]
    lo = math.inf
    hi = -math.inf
    attention = 0.0
    for j in range(m):
        if w[j] > 0.0:
            lo = min(lo, B[i, j])
            hi = max(hi, B[i, j])
            attention += w[j] * (B[i, j] - mean) ** 2
    gauss = 0.0
    for l in range(m, m + n):
        gauss += B[i, l] * B[i, l]
    return mean, lo, hi, attention, gauss * noise_var


@njit
def _gap(theta, start, drift, size):
    """``z = theta - (start + drift)``, the distance of an option's mean below ``theta``, or
    0.0 where it is within :data:`ROUNDING` of the magnitudes summed (``size``: the sum
    of the drift's terms' sizes)."""
    z = theta - (start + drift)
    if z <= ROUNDING * (abs(theta) + abs(start) + size):
        return 0.0
    return z


@njit
def _mean_step(B, nxt, k, i, mean, drift, size, theta):
    """Add option ``i``'s mean term ``mean`` of step ``k`` to its drift: ``(z, moved)``, its
    :func:`_gap` below ``theta`` and whether the mean path still changes in floating point
    (the drift, or ``S^t P0`` against the block before, ``nxt``)."""
    last = B.shape[1] - 1
    moved = drift[i] + mean != drift[i] or (k > 0 and nxt[i, last] != B[i, last])
    drift[i] += mean
    size[i] += abs(mean)
    return _gap(theta, B[i, last], drift[i], size[i]), moved


@njit
def reach_bound(S, C, CM, w, P0, noise_var, theta, max_steps):
    """Upper bound on the probability that some preference reaches ``theta`` within
    ``max_steps`` steps of ``P(t) = S P(t-1) + C (M W(t) + eps(t))``.

    With ``z = theta - a_i(t) > 0`` (the module's notation), ``P(Z >= z)`` is at most the
    smaller of Hoeffding's ``exp(-z^2 / (2 H))`` (``H``: the noise variances plus a
    quarter of each attention term's range squared) and Bernstein's
    ``exp(-z^2 / (2 (V + b z / 3)))`` (``V``: the variance of ``Z``; ``b``: the largest
    value an attention term takes; the Gaussian terms meet Bernstein's moment condition for
    any ``b``). The union over options and steps bounds the probability of any decision.
    Returns 1.0 (no bound) where some mean reaches ``theta`` (within :data:`ROUNDING`) or
    a power of ``S`` stops being finite. Once the sums no longer change in floating point,
    every later step adds the same terms, counted at once.
    """
    n = S.shape[0]
    m = CM.shape[1]
    B, nxt, drift, size = _start(S, C, CM, P0)
    hoeffding = np.zeros(n)
    variance = np.zeros(n)
    top = np.zeros(n)
    total = 0.0
    for k in range(max_steps):
        settled = True
        step = 0.0
        for i in range(n):
            mean, lo, hi, attention, gauss = _terms(B, w, noise_var, i, m, n)
            new_h = hoeffding[i] + 0.25 * (hi - lo) ** 2 + gauss
            new_v = variance[i] + attention + gauss
            z, moved = _mean_step(B, nxt, k, i, mean, drift, size, theta)
            if moved or new_h != hoeffding[i] or new_v != variance[i]:
                settled = False
            hoeffding[i] = new_h
            variance[i] = new_v
            top[i] = max(top[i], hi - mean)
            if not (z > 0.0 and math.isfinite(hoeffding[i])):
                return 1.0
            if hoeffding[i] > 0.0:
                exponent = z * z / hoeffding[i]
                bernstein = variance[i] + top[i] * z / 3.0
                if bernstein > 0.0:
                    exponent = max(exponent, z * z / bernstein)
                step += math.exp(-0.5 * exponent)
        if settled and k > 0:
            # every later step adds the same terms
            return min(1.0, total + step * (max_steps - k))
        total += step
        if total >= 1.0:
            return 1.0
        # the next step's B; nxt keeps this one (its S^t P0 is compared with the next)
        _advance(S, B, nxt)
        B, nxt = nxt, B
    return total


@njit
def chernoff_grid(S, C, CM, w, P0, noise_var, theta, max_steps, n_lambda, spread):
    """The exponents ``lambda`` at which :func:`chernoff_bound` evaluates each option's
    bound: ``n_lambda`` values spaced evenly in ``log lambda`` from ``c / spread`` to
    ``c * spread``, where ``c = z / V`` is the Gaussian optimum at step ``max_steps``, or
    where the sums stop changing (``z = theta - a_i``, ``V`` the variance of ``Z``).
    Returns an empty grid (no bound) as soon as some mean reaches ``theta`` (within
    :data:`ROUNDING`), or where ``Z`` has no variance."""
    n = S.shape[0]
    m = CM.shape[1]
    B, nxt, drift, size = _start(S, C, CM, P0)
    variance = np.zeros(n)
    gaps = np.zeros(n)
    for k in range(max_steps):
        settled = k > 0
        for i in range(n):
            mean, lo, hi, attention, gauss = _terms(B, w, noise_var, i, m, n)
            gaps[i], moved = _mean_step(B, nxt, k, i, mean, drift, size, theta)
            if moved or variance[i] + attention + gauss != variance[i]:
                settled = False
            variance[i] += attention + gauss
            if not gaps[i] > 0.0:
                return np.empty((0, n_lambda))
        if settled or k + 1 == max_steps:
            break
        _advance(S, B, nxt)
        B, nxt = nxt, B
    grid = np.empty((n, n_lambda))
    for i in range(n):
        centre = gaps[i] / variance[i] if variance[i] > 0.0 else math.nan
        if not 0.0 < centre < math.inf:
            return np.empty((0, n_lambda))
        for l in range(n_lambda):
            grid[i, l] = centre * spread ** (2.0 * l / (n_lambda - 1) - 1.0)
    return grid


@njit
def chernoff_bound(S, C, CM, w, P0, noise_var, theta, max_steps, grid, limit):
    """Upper bound on the same probability as :func:`reach_bound`, from the moment
    generating function of ``Z`` itself (Chernoff): ``P(Z >= z) <= exp(K(lambda) -
    lambda z)`` for every ``lambda > 0``, with ``K(lambda) = sum_k log E exp(lambda X_k) +
    lambda^2 V_Y / 2`` exact (the attention terms take finitely many values; ``V_Y`` is
    the variance of the noise terms). Each option's bound at each step is the smallest over
    the ``lambda`` of its row of ``grid``, and the union over options and steps bounds the
    probability of any decision.

    Where the attention terms dominate the spread, this is far below Hoeffding's and
    Bernstein's bounds, which know only their range or their largest value. It costs
    ``grid.shape[1]`` exponentials per attribute, option and step, so it stops as soon as
    the union passes ``limit`` (the level the caller needs) and returns 1.0 there, as
    where some mean reaches ``theta`` (within :data:`ROUNDING`). Once the sums no longer
    change in floating point, every later step adds the same terms, counted at once.
    """
    n = S.shape[0]
    m = CM.shape[1]
    n_lambda = grid.shape[1]
    B, nxt, drift, size = _start(S, C, CM, P0)
    K = np.zeros((n, n_lambda))
    total = 0.0
    for k in range(max_steps):
        settled = True
        step = 0.0
        for i in range(n):
            mean, lo, hi, attention, gauss = _terms(B, w, noise_var, i, m, n)
            z, moved = _mean_step(B, nxt, k, i, mean, drift, size, theta)
            if moved:
                settled = False
            if not z > 0.0:
                return 1.0
            best = math.inf
            for l in range(n_lambda):
                lam = grid[i, l]
                # log E exp(lam X_k), shifted by its largest exponent; at least 0 (Jensen)
                peak = -math.inf
                for j in range(m):
                    if w[j] > 0.0:
                        peak = max(peak, lam * (B[i, j] - mean))
                acc = 0.0
                for j in range(m):
                    if w[j] > 0.0:
                        acc += w[j] * math.exp(lam * (B[i, j] - mean) - peak)
                new = K[i, l] + max(peak + math.log(acc), 0.0) + 0.5 * lam * lam * gauss
                if new != K[i, l]:
                    settled = False
                K[i, l] = new
                exponent = new - lam * z
                if exponent < best:
                    best = exponent
            step += math.exp(best)
        if settled and k > 0:
            # every later step adds the same terms
            total += step * (max_steps - k)
            return min(1.0, total) if total <= limit else 1.0
        total += step
        if not total <= limit:
            return 1.0
        _advance(S, B, nxt)
        B, nxt = nxt, B
    return min(1.0, total)
