"""Compiled kernels of the exact threshold method (:mod:`mdft.threshold_exact`).

Nothing here validates its input: :func:`mdft.threshold_probabilities` checks
and converts everything once. The kernels build the rows of the transient
matrix ``Q`` and the absorbing matrix ``R`` of the lattice Markov chain.

Coordinates
-----------
A preference state is ``P = E z + (s / n) 1``: ``z`` holds its coordinates
in an orthonormal basis ``E`` (n x 2) of the plane of zero-sum vectors (for two
options the second column of ``E`` is zero and the second axis has a single
cell), and ``s = 1^T P`` is the summed preference. The valence never changes
``s``; the feedback ``S`` moves it deterministically.

* ``edges1``/``edges2``: cell edges along the two axes of ``z``.
* ``top[i1, i2] = max_i (E z)_i`` at the centre of cell ``(i1, i2)``: the cell
  lies inside the transient region of level ``s`` when ``top + s / n < theta``.
* ``levels``: the summed-preference levels; ``index[l, i1, i2]`` is the state
  number of cell ``(i1, i2)`` on level ``l``, or -1.
* ``CM[:, j] = C M e_j`` and ``A[:, j] = E^T C M e_j``: the mean valence in
  preference and in lattice coordinates when attribute ``j`` is attended.
* ``sd_opt[i]``: standard deviation of the noise of ``P_i``; ``sd_axis[k]``:
  of coordinate ``z_k`` (the basis is chosen so the two are independent);
  ``sd_cell[k]``: the standard deviation used to integrate over the cells
  (``sd_axis`` less the lattice's own spread when that correction is on).
* ``pair_sd[i, k]`` and ``pair_rho[i, k]``: standard deviation of
  ``P_k - P_i`` and its correlation with ``P_i`` (used for simultaneous
  crossings, where the engine chooses the largest preference).
"""

from __future__ import annotations

import math

import numpy as np
from numba import prange

from ._numba import njit, njit_inline, njit_parallel

_SQRT2 = math.sqrt(2.0)

# Gauss-Legendre nodes and weights on [-1, 1], 10 points.
_GL_X = np.array([
    -0.9739065285171717, -0.8650633666889845, -0.6794095682990244, -0.4333953941292472,
    -0.1488743389816312, 0.1488743389816312, 0.4333953941292472, 0.6794095682990244,
    0.8650633666889845, 0.9739065285171717,
])
_GL_W = np.array([
    0.0666713443086881, 0.1494513491505806, 0.2190863625159820, 0.2692667193099963,
    0.2955242247147529, 0.2955242247147529, 0.2692667193099963, 0.2190863625159820,
    0.1494513491505806, 0.0666713443086881,
])
_N_PANELS = 6
# Cell probabilities below this are left out of a row (and the row renormalised).
_CUT = 1e-12
# Consecutive settled steps before the geometric tail takes over.
_SETTLE = 20


@njit
def norm_sf(x):
    """Upper tail ``1 - Phi(x)`` of the standard normal."""
    return 0.5 * math.erfc(x / _SQRT2)


@njit
def upper(mean, sd, bound):
    """``Pr(X >= bound)`` for ``X ~ N(mean, sd^2)``; a step when ``sd == 0``."""
    if sd > 0.0:
        return norm_sf((bound - mean) / sd)
    return 1.0 if mean >= bound else 0.0


@njit
def cdf(mean, sd, x):
    """``Pr(X < x)`` for ``X ~ N(mean, sd^2)``; a step when ``sd == 0``."""
    if sd > 0.0:
        return 0.5 * math.erfc((mean - x) / (sd * _SQRT2))
    return 1.0 if mean < x else 0.0


@njit_inline
def bivariate_upper(h, k, rho, gl_x, gl_w):
    """``Pr(X > h, Y > k)`` for standard normals with correlation ``rho``, ``|rho| < 1``.

    Plackett's identity: the derivative in ``rho`` is the bivariate density,
    so the probability is ``Phi(-h) Phi(-k)`` plus the integral of the
    density from 0 to ``rho``, taken over ``asin(rho)`` with composite
    Gauss-Legendre quadrature.
    """
    base = norm_sf(h) * norm_sf(k)
    if rho == 0.0:
        return base
    top = math.asin(rho)
    width = top / _N_PANELS
    hk = h * k
    hs = 0.5 * (h * h + k * k)
    acc = 0.0
    for p in range(_N_PANELS):
        mid = (p + 0.5) * width
        for q in range(gl_x.shape[0]):
            sn = math.sin(mid + 0.5 * width * gl_x[q])
            acc += gl_w[q] * math.exp((sn * hk - hs) / (1.0 - sn * sn))
    value = base + acc * 0.5 * width / (2.0 * math.pi)
    return min(max(value, 0.0), 1.0)


@njit_inline
def joint_upper(mx, sx, a, my, sy, b, rho, gl_x, gl_w):
    """``Pr(X >= a, Y > b)`` for jointly normal ``X``, ``Y`` (either may be degenerate)."""
    if sx == 0.0 and sy == 0.0:
        return 1.0 if (mx >= a and my > b) else 0.0
    if sx == 0.0:
        return upper(my, sy, b) if mx >= a else 0.0
    if sy == 0.0:
        return upper(mx, sx, a) if my > b else 0.0
    return bivariate_upper((a - mx) / sx, (b - my) / sy, rho, gl_x, gl_w)


@njit
def absorption(muP, s_next, theta, sd_opt, pair_sd, pair_rho, out, gl_x, gl_w):
    """Add to ``out[i]`` the probability that the step ends with option ``i`` chosen.

    ``muP`` is the mean of ``P(t+1)``. Option ``i`` is chosen when
    ``P_i >= theta`` and ``P_i`` is the largest preference. For two options
    ``P_1 + P_2 = s_next`` is known, so the event is one-dimensional; for
    three, ``Pr(P_i >= theta) - sum_k Pr(P_i >= theta, P_k > P_i)`` (all three
    above ``theta`` cannot happen: the caller checked ``s_next < 3 theta``).
    Returns the total.
    """
    n = muP.shape[0]
    total = 0.0
    if n == 2:
        bound = max(theta, 0.5 * s_next)
        p1 = upper(muP[0], sd_opt[0], bound)
        # P_2 >= bound  <=>  P_1 <= s_next - bound
        p2 = upper(muP[1], sd_opt[1], bound)
        if sd_opt[0] == 0.0 and muP[0] == muP[1] and muP[0] >= theta:
            # exact tie of a noise-free step: broken at random, as the engine does
            p1 = 0.5
            p2 = 0.5
        out[0] += p1
        out[1] += p2
        return p1 + p2
    for i in range(n):
        pi = upper(muP[i], sd_opt[i], theta)
        if pi <= 1e-300:
            continue
        for k in range(n):
            if k == i:
                continue
            if upper(muP[k], sd_opt[k], theta) <= 1e-300:
                continue
            pi -= joint_upper(muP[i], sd_opt[i], theta, muP[k] - muP[i], pair_sd[i, k], 0.0,
                              pair_rho[i, k], gl_x, gl_w)
        pi = max(pi, 0.0)
        out[i] += pi
        total += pi
    return total


@njit
def window(mean, sd, width, n_cells, edges):
    """First and last cell (inclusive) within ``width`` sd of ``mean``."""
    h = edges[1] - edges[0]
    lo = int(math.floor((mean - width * sd - edges[0]) / h))
    hi = int(math.floor((mean + width * sd - edges[0]) / h))
    if lo < 0:
        lo = 0
    if hi > n_cells - 1:
        hi = n_cells - 1
    return lo, hi


@njit
def row(z1, z2, s, S, E, CM, A, w, theta, edges1, edges2, top, levels, index, sd_opt,
        sd_cell, pair_sd, pair_rho, width, gl_x, gl_w, scratch, p1, p2, absorbed,
        out_cols, out_vals, write):
    """Transition probabilities from the preference state ``(z1, z2, s)``.

    Adds the choice probabilities of this step to ``absorbed`` (length n),
    and returns the number of transient targets. With ``write`` the targets'
    state numbers and probabilities go to ``out_cols`` and ``out_vals``.
    ``scratch`` (at least n1 x n2), ``p1`` (n1) and ``p2`` (n2) are work arrays;
    ``scratch`` is left zero.
    """
    n = S.shape[0]
    n1 = edges1.shape[0] - 1
    n2 = edges2.shape[0] - 1
    n_levels = levels.shape[0]
    J = w.shape[0]
    # deterministic part: m = S P
    P = np.empty(n)
    for i in range(n):
        P[i] = E[i, 0] * z1 + E[i, 1] * z2 + s / n
    m = np.empty(n)
    s_next = 0.0
    for i in range(n):
        acc = 0.0
        for k in range(n):
            acc += S[i, k] * P[k]
        m[i] = acc
        s_next += acc
    zd1 = 0.0
    zd2 = 0.0
    for i in range(n):
        zd1 += E[i, 0] * m[i]
        zd2 += E[i, 1] * m[i]
    bound = theta - s_next / n
    # level of s_next: linear split between levels l and l + 1
    if n_levels == 1:
        lev = 0
        frac = 0.0
    else:
        u = (s_next - levels[0]) / (levels[1] - levels[0])
        if u <= 0.0:
            lev = 0
            frac = 0.0
        elif u >= n_levels - 1:
            lev = n_levels - 2
            frac = 1.0
        else:
            lev = int(math.floor(u))
            if lev > n_levels - 2:
                lev = n_levels - 2
            frac = u - lev
    muP = np.empty(n)
    part = np.zeros(n)
    lo1_all = n1
    hi1_all = -1
    lo2_all = n2
    hi2_all = -1
    spill = 0.0
    for j in range(J):
        if w[j] <= 0.0:
            continue
        for i in range(n):
            muP[i] = m[i] + CM[i, j]
            part[i] = 0.0
        p_abs = absorption(muP, s_next, theta, sd_opt, pair_sd, pair_rho, part, gl_x, gl_w)
        mu1 = zd1 + A[0, j]
        mu2 = zd2 + A[1, j]
        lo1, hi1 = window(mu1, sd_cell[0], width, n1, edges1)
        if n2 == 1:
            lo2 = 0
            hi2 = 0
        else:
            lo2, hi2 = window(mu2, sd_cell[1], width, n2, edges2)
        for a in range(lo1, hi1 + 1):
            p1[a] = cdf(mu1, sd_cell[0], edges1[a + 1]) - cdf(mu1, sd_cell[0], edges1[a])
        for b in range(lo2, hi2 + 1):
            if n2 == 1:
                p2[b] = 1.0
            else:
                p2[b] = cdf(mu2, sd_cell[1], edges2[b + 1]) - cdf(mu2, sd_cell[1], edges2[b])
        inside = 0.0
        for a in range(lo1, hi1 + 1):
            for b in range(lo2, hi2 + 1):
                v = p1[a] * p2[b]
                if top[a, b] < bound and v > _CUT:
                    inside += v
        stay = 1.0 - p_abs
        if stay < 0.0:
            stay = 0.0
        if inside > 0.0 and stay > 0.0:
            scale = w[j] * stay / inside
            for a in range(lo1, hi1 + 1):
                for b in range(lo2, hi2 + 1):
                    v = p1[a] * p2[b]
                    if top[a, b] < bound and v > _CUT:
                        scratch[a, b] += scale * v
            if lo1 < lo1_all:
                lo1_all = lo1
            if hi1 > hi1_all:
                hi1_all = hi1
            if lo2 < lo2_all:
                lo2_all = lo2
            if hi2 > hi2_all:
                hi2_all = hi2
            for i in range(n):
                absorbed[i] += w[j] * part[i]
        elif p_abs > 0.0:
            # no lattice cell inside the region near the mean: the whole step is absorbed
            for i in range(n):
                absorbed[i] += w[j] * part[i] / p_abs
        else:
            spill += w[j]
    if spill > 0.0:
        # the mean lies beyond every threshold yet no option is chosen: cannot happen
        # for a valid model, but keep the row stochastic by giving it to the largest option
        best = 0
        for i in range(1, n):
            if m[i] > m[best]:
                best = i
        absorbed[best] += spill
    count = 0
    for a in range(lo1_all, hi1_all + 1):
        for b in range(lo2_all, hi2_all + 1):
            v = scratch[a, b]
            if v == 0.0:
                continue
            scratch[a, b] = 0.0
            if n_levels == 1:
                if write:
                    out_cols[count] = index[0, a, b]
                    out_vals[count] = v
                count += 1
                continue
            t0 = index[lev, a, b]
            t1 = index[lev + 1, a, b]
            v1 = v * frac
            v0 = v - v1
            if t1 < 0:
                v0 = v
                v1 = 0.0
            if t0 < 0:
                t0 = t1
                v0 = v0 + v1
                v1 = 0.0
            if v0 > 0.0:
                if write:
                    out_cols[count] = t0
                    out_vals[count] = v0
                count += 1
            if v1 > 0.0:
                if write:
                    out_cols[count] = t1
                    out_vals[count] = v1
                count += 1
    return count


@njit_parallel
def count_rows(states, S, E, CM, A, w, theta, edges1, edges2, top, levels, index, sd_opt,
               sd_cell, pair_sd, pair_rho, width, gl_x, gl_w, n_chunks):
    """Number of transient targets of every state (``states[r] = (level, i1, i2)``)."""
    n_states = states.shape[0]
    n = S.shape[0]
    counts = np.zeros(n_states, dtype=np.int64)
    n1 = edges1.shape[0] - 1
    n2 = edges2.shape[0] - 1
    size = (n_states + n_chunks - 1) // n_chunks
    for c in prange(n_chunks):
        scratch = np.zeros((n1, n2))
        p1 = np.zeros(n1)
        p2 = np.zeros(n2)
        absorbed = np.zeros(n)
        dummy_c = np.zeros(1, dtype=np.int64)
        dummy_v = np.zeros(1)
        for r in range(c * size, min((c + 1) * size, n_states)):
            l, a, b = states[r, 0], states[r, 1], states[r, 2]
            z1 = 0.5 * (edges1[a] + edges1[a + 1])
            z2 = 0.5 * (edges2[b] + edges2[b + 1])
            counts[r] = row(z1, z2, levels[l], S, E, CM, A, w, theta, edges1, edges2, top,
                            levels, index, sd_opt, sd_cell, pair_sd, pair_rho, width, gl_x,
                            gl_w, scratch, p1, p2, absorbed, dummy_c, dummy_v, False)
    return counts


@njit_parallel
def fill_rows(states, indptr, S, E, CM, A, w, theta, edges1, edges2, top, levels, index,
              sd_opt, sd_cell, pair_sd, pair_rho, width, gl_x, gl_w, n_chunks, cols, vals,
              absorbing):
    """Write the rows of ``Q`` (CSR ``indptr``, ``cols``, ``vals``) and of ``R``.

    ``absorbing`` is dense, (n_states, n_options).
    """
    n_states = states.shape[0]
    n1 = edges1.shape[0] - 1
    n2 = edges2.shape[0] - 1
    size = (n_states + n_chunks - 1) // n_chunks
    for c in prange(n_chunks):
        scratch = np.zeros((n1, n2))
        p1 = np.zeros(n1)
        p2 = np.zeros(n2)
        for r in range(c * size, min((c + 1) * size, n_states)):
            l, a, b = states[r, 0], states[r, 1], states[r, 2]
            z1 = 0.5 * (edges1[a] + edges1[a + 1])
            z2 = 0.5 * (edges2[b] + edges2[b + 1])
            start = indptr[r]
            row(z1, z2, levels[l], S, E, CM, A, w, theta, edges1, edges2, top, levels, index,
                sd_opt, sd_cell, pair_sd, pair_rho, width, gl_x, gl_w, scratch, p1, p2,
                absorbing[r], cols[start:indptr[r + 1]], vals[start:indptr[r + 1]], True)


@njit
def first_row(z1, z2, s, S, E, CM, A, w, theta, edges1, edges2, top, levels, index, sd_opt,
              sd_cell, pair_sd, pair_rho, width, gl_x, gl_w, absorbed):
    """Transient targets of the exact initial state (not a cell centre): ``(cols, vals)``."""
    n1 = edges1.shape[0] - 1
    n2 = edges2.shape[0] - 1
    scratch = np.zeros((n1, n2))
    p1 = np.zeros(n1)
    p2 = np.zeros(n2)
    tmp = np.zeros(absorbed.shape[0])
    dummy_c = np.zeros(1, dtype=np.int64)
    dummy_v = np.zeros(1)
    count = row(z1, z2, s, S, E, CM, A, w, theta, edges1, edges2, top, levels, index, sd_opt,
                sd_cell, pair_sd, pair_rho, width, gl_x, gl_w, scratch, p1, p2, tmp, dummy_c,
                dummy_v, False)
    cols = np.empty(count, dtype=np.int64)
    vals = np.empty(count)
    row(z1, z2, s, S, E, CM, A, w, theta, edges1, edges2, top, levels, index, sd_opt, sd_cell,
        pair_sd, pair_rho, width, gl_x, gl_w, scratch, p1, p2, absorbed, cols, vals, True)
    return cols, vals


@njit
def propagate(row_ptr, cols, vals, absorb, x, rt_pmf, tol, tail_tol):
    """Apply the chain step by step: ``rt_pmf[t] = R^T x``, ``x <- Q^T x``.

    ``x`` holds the transient distribution after the first step and is
    updated in place; ``rt_pmf[0]`` must already hold the first step's
    choices. Stops once the transient mass is below ``tol``, or, with
    ``tail_tol > 0``, once for ``_SETTLE`` steps in a row neither the per-step
    decay of the undecided mass nor any option's share of the step's choices
    changed by more than ``tail_tol`` (relative), and the step's choices
    decayed at that same rate: the chain is then in its slowest mode and the
    remaining rows are geometric. Returns
    ``(steps, tail_start, mass)``.
    """
    n_states = x.shape[0]
    n_steps = rt_pmf.shape[0]
    n = rt_pmf.shape[1]
    y = np.zeros(n_states)
    mass = 0.0
    for r in range(n_states):
        mass += x[r]
    steps = 1
    prev_ratio = -1.0
    settled = 0
    for t in range(1, n_steps):
        if mass < tol:
            return steps, n_steps, mass
        total = 0.0
        for i in range(n):
            rt_pmf[t, i] = 0.0
        for r in range(n_states):
            xr = x[r]
            if xr == 0.0:
                continue
            for i in range(n):
                rt_pmf[t, i] += xr * absorb[r, i]
            for q in range(row_ptr[r], row_ptr[r + 1]):
                y[cols[q]] += xr * vals[q]
        new_mass = 0.0
        for r in range(n_states):
            x[r] = y[r]
            y[r] = 0.0
            new_mass += x[r]
        for i in range(n):
            total += rt_pmf[t, i]
        steps = t + 1
        ratio = new_mass / mass if mass > 0.0 else 0.0
        mass = new_mass
        if tail_tol > 0.0 and total > 0.0 and t > 1:
            settled = settle_count(rt_pmf, t, total, ratio, prev_ratio, settled, tail_tol)
            if settled >= _SETTLE and ratio < 1.0:
                return steps, t + 1, mass * fill_tail(rt_pmf, t, ratio)
        prev_ratio = ratio
    return steps, n_steps, mass


@njit
def settle_count(rt_pmf, t, total, ratio, prev_ratio, settled, tail_tol):
    """Consecutive settled steps up to step ``t`` (``total``: its choices; ``ratio``:
    its decay of the undecided mass), given ``settled`` up to step ``t - 1``."""
    n = rt_pmf.shape[1]
    prev_total = 0.0
    for i in range(n):
        prev_total += rt_pmf[t - 1, i]
    # in the slowest mode the step's choices decay at the rate of the undecided mass;
    # before it (mass still on its way to the thresholds) they grow
    calm = (prev_total > 0.0 and abs(ratio - prev_ratio) <= tail_tol * ratio
            and abs(total / prev_total - ratio) <= tail_tol * ratio)
    if calm:
        for i in range(n):
            if abs(rt_pmf[t, i] / total - rt_pmf[t - 1, i] / prev_total) > tail_tol:
                calm = False
    return settled + 1 if calm else 0


@njit
def fill_tail(rt_pmf, t, ratio):
    """Fill the rows after ``t`` geometrically; returns the undecided mass's factor."""
    factor = 1.0
    for u in range(t + 1, rt_pmf.shape[0]):
        factor *= ratio
        for i in range(rt_pmf.shape[1]):
            rt_pmf[u, i] = rt_pmf[t, i] * factor
    return factor
