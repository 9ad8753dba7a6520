"""Compiled kernels of the two-option lattice whose thresholds move (:mod:`mdft._lattice_moving`).

Nothing here validates its input. The lattice is one row of cells along the coordinate
``z = (P_1 - P_2) / sqrt(2)``, whose transient region at sum ``s`` is ``|z| < B`` with
``B = sqrt(2) (theta - s / 2)``. Where the summed preference moves on its own (the same on
every walk), ``z`` moves independently of it, so each cell's spread over the cells (one
window per attended attribute) is the same at every step and is computed once
(:func:`spreads`). What changes from step to step is the region, whose ends may cut a cell
(:func:`region`), and how much of each step is absorbed. A cut cell holds only the part of
a step that lands inside the region, and its mass sits at the middle of that part, from
where its own step is computed afresh (:func:`cut_source`). Otherwise a step is that of
:func:`mdft._lattice.row`: the choices exactly from the source's position, the rest spread
over the cells inside and scaled to what stays.
"""

from __future__ import annotations

import math

import numpy as np

from ._lattice import _CUT, cdf, upper, window
from ._numba import njit, njit_inline

# A region's end within this share of a cell of a cell edge lies on it (no cut cell).
_ON_EDGE = 1e-9


@njit
def spread(mu, sd, width, edges, out):
    """The cell probabilities of ``N(mu, sd^2)`` within ``width`` sd of ``mu`` (those at most
    the lattice's cut set to zero) into ``out``; returns the first cell and their count."""
    n_cells = edges.shape[0] - 1
    lo, hi = window(mu, sd, width, n_cells, edges)
    for a in range(lo, hi + 1):
        v = cdf(mu, sd, edges[a + 1]) - cdf(mu, sd, edges[a])
        out[a - lo] = v if v > _CUT else 0.0
    return lo, hi - lo + 1


@njit
def spreads(centres, slope, shift, sd, width, edges, max_count):
    """Every source's spread over the cells, one per attended attribute: the step from
    ``z = centres[a]`` has mean ``slope z + shift[j]`` and standard deviation ``sd``.
    Returns ``(first, count, cum, values)``: source ``a``'s spread when ``j`` is attended
    starts at cell ``first[j, a]`` and covers ``count[j, a]`` cells with probabilities
    ``values[j, a, :count]``, whose running sums are ``cum[j, a]`` (shapes ``(J, n)``,
    ``(J, n)``, ``(J, n, max_count + 1)`` and ``(J, n, max_count)``)."""
    J = shift.shape[0]
    n = centres.shape[0]
    first = np.zeros((J, n), dtype=np.int64)
    count = np.zeros((J, n), dtype=np.int64)
    cum = np.zeros((J, n, max_count + 1))
    values = np.zeros((J, n, max_count))
    for j in range(J):
        for a in range(n):
            first[j, a], count[j, a] = spread(slope * centres[a] + shift[j], sd, width, edges,
                                              values[j, a])
            for k in range(count[j, a]):
                cum[j, a, k + 1] = cum[j, a, k] + values[j, a, k]
    return first, count, cum, values


@njit
def region(edges, bound):
    """The cells with a part inside ``|z| < bound``: ``[lo, hi)`` (empty where
    ``lo >= hi``), and the inside part of the end cells, ``[part_lo, part_hi]`` of cell
    ``lo`` and ``[hi_lo, hi_hi]`` of cell ``hi - 1`` (the whole cell where the region ends
    on its edge)."""
    n = edges.shape[0] - 1
    tol = _ON_EDGE * (edges[1] - edges[0])
    lo = 0
    while lo < n and edges[lo + 1] <= -bound + tol:
        lo += 1
    hi = n
    while hi > lo and edges[hi - 1] >= bound - tol:
        hi -= 1
    if lo >= hi:
        return lo, hi, 0.0, 0.0, 0.0, 0.0
    lo_lo = max(edges[lo], -bound) if edges[lo] < -bound - tol else edges[lo]
    lo_hi = min(edges[lo + 1], bound) if edges[lo + 1] > bound + tol else edges[lo + 1]
    hi_lo = max(edges[hi - 1], -bound) if edges[hi - 1] < -bound - tol else edges[hi - 1]
    hi_hi = min(edges[hi], bound) if edges[hi] > bound + tol else edges[hi]
    return lo, hi, lo_lo, lo_hi, hi_lo, hi_hi


@njit
def region_at(edges, theta, s):
    """:func:`region` of the thresholds at sum ``s``, ``|z| < sqrt(2) (theta - s / 2)``."""
    return region(edges, math.sqrt(2.0) * (theta - 0.5 * s))


@njit_inline
def _is_cut(edges, b, part_lo, part_hi):
    """Whether the inside part ``[part_lo, part_hi]`` of cell ``b`` is less than the cell."""
    return part_lo != edges[b] or part_hi != edges[b + 1]


@njit
def cut_source(edges, b, part_lo, part_hi, slope, shift, sd_axis, correct, width, max_count):
    """A cut cell as a source: its position (the middle of its inside part) and its spread
    (:func:`spreads` of that one position, with the variance correction of the part's own
    width where ``correct``)."""
    z = 0.5 * (part_lo + part_hi)
    part = part_hi - part_lo
    sd = math.sqrt(max(sd_axis * sd_axis - part * part / 12.0, 0.0)) if correct else sd_axis
    first, count, cum, values = spreads(np.array([z]), slope, shift, sd, width, edges,
                                        max_count)
    return z, sd, first, count, cum, values


@njit_inline
def _upper_far(mean, sd, bound):
    """``Pr(X >= bound)`` for ``X ~ N(mean, sd^2)``, 0 beyond 9 sd (below 1.2e-19: the
    lattice's cells leave out far more)."""
    if sd > 0.0 and bound - mean > 9.0 * sd:
        return 0.0
    return upper(mean, sd, bound)


@njit_inline
def add_row(z, s, s_next, weight, a, first, count, cum, values, sd, slope, shift, S, CM, w,
            theta, edges, reg, sd_opt, y, absorbed):
    """Add ``weight`` times the step from the state ``z`` at sum ``s`` to ``y`` (the cells)
    and ``absorbed`` (the options), the next sum being ``s_next``, whose region is ``reg``
    (:func:`region`). The state's spread is that of source ``a`` of ``first``, ``count``,
    ``cum`` and ``values`` (:func:`spreads`, standard deviation ``sd``; a cut target cell
    takes the part of it inside the region). The choices are those of
    :func:`mdft._lattice.absorption` for two options. Returns the first and one past the
    last cell reached."""
    lo_in, hi_in, lo_lo, lo_hi, hi_lo, hi_hi = reg
    J = w.shape[0]
    r2 = 1.0 / np.sqrt(2.0)
    p0 = r2 * z + 0.5 * s
    p1 = -r2 * z + 0.5 * s
    m0 = S[0, 0] * p0 + S[0, 1] * p1
    m1 = S[1, 0] * p0 + S[1, 1] * p1
    bound = max(theta, 0.5 * s_next)
    cut_lo = lo_in < hi_in and _is_cut(edges, lo_in, lo_lo, lo_hi)
    cut_hi = lo_in < hi_in - 1 and _is_cut(edges, hi_in - 1, hi_lo, hi_hi)
    spill = 0.0
    lo_all = hi_in
    hi_all = lo_in
    for j in range(J):
        if w[j] <= 0.0:
            continue
        c0 = _upper_far(m0 + CM[0, j], sd_opt[0], bound)
        c1 = _upper_far(m1 + CM[1, j], sd_opt[1], bound)
        p_abs = c0 + c1
        # the part of the spread inside the region
        f = first[j, a]
        lo = max(f, lo_in)
        hi = min(f + count[j, a], hi_in)
        kept = cum[j, a, hi - f] - cum[j, a, lo - f] if hi > lo else 0.0
        mu = slope * z + shift[j]
        v_lo = v_hi = 0.0
        if hi > lo and cut_lo and lo == lo_in:
            v_lo = cdf(mu, sd, lo_hi) - cdf(mu, sd, lo_lo)
            kept += v_lo - values[j, a, lo - f]
        if hi > lo and cut_hi and hi == hi_in:
            v_hi = cdf(mu, sd, hi_hi) - cdf(mu, sd, hi_lo)
            kept += v_hi - values[j, a, hi - 1 - f]
        stay = max(1.0 - p_abs, 0.0)
        if kept > 0.0 and stay > 0.0:
            scale = weight * w[j] * stay / kept
            row = values[j, a]
            for b in range(lo, hi):
                y[b] += scale * row[b - f]
            if cut_lo and lo == lo_in:
                y[lo] += scale * (v_lo - row[lo - f])
            if cut_hi and hi == hi_in:
                y[hi - 1] += scale * (v_hi - row[hi - 1 - f])
            lo_all = min(lo_all, lo)
            hi_all = max(hi_all, hi)
            absorbed[0] += weight * w[j] * c0
            absorbed[1] += weight * w[j] * c1
        elif p_abs > 0.0:
            # no cell inside near the mean: the whole step is absorbed
            absorbed[0] += weight * w[j] * c0 / p_abs
            absorbed[1] += weight * w[j] * c1 / p_abs
        else:
            spill += weight * w[j]
    if spill > 0.0:
        # cannot happen for a valid model (as in mdft._lattice.row): kept stochastic
        absorbed[0 if m0 >= m1 else 1] += spill
    return lo_all, hi_all


@njit_inline
def add_source(b, x_b, s, s_next, reg_src, reg, centres, spreads_, sd_cell, sd_axis, correct,
               width, slope, shift, S, CM, w, theta, edges, sd_opt, y, absorbed):
    """Add the step of the mass ``x_b`` of cell ``b`` of the region ``reg_src`` at sum ``s``
    (its own position and spread where the region cuts it) towards the region ``reg``."""
    first, count, cum, values = spreads_
    lo_src, hi_src, lo_lo, lo_hi, hi_lo, hi_hi = reg_src
    part_lo = part_hi = 0.0
    cut = False
    if b == lo_src and _is_cut(edges, b, lo_lo, lo_hi):
        part_lo, part_hi, cut = lo_lo, lo_hi, True
    elif b == hi_src - 1 and _is_cut(edges, b, hi_lo, hi_hi):
        part_lo, part_hi, cut = hi_lo, hi_hi, True
    if not cut:
        return add_row(centres[b], s, s_next, x_b, b, first, count, cum, values, sd_cell, slope,
                       shift, S, CM, w, theta, edges, reg, sd_opt, y, absorbed)
    z, sd, f1, n1, c1, v1 = cut_source(edges, b, part_lo, part_hi, slope, shift, sd_axis,
                                       correct, width, values.shape[2] + 2)
    return add_row(z, s, s_next, x_b, 0, f1, n1, c1, v1, sd, slope, shift, S, CM, w, theta,
                   edges, reg, sd_opt, y, absorbed)


@njit
def run_steps(x, sums, centres, spreads_, sd_cell, sd_axis, correct, width, slope, shift, S,
              CM, w, theta, edges, sd_opt, rt_pmf, tol):
    """Steps ``2, 3, ...`` of the walks while the sum moves: step ``t + 1`` goes from
    ``sums[t]`` to ``sums[t + 1]`` and ``rt_pmf[t]`` receives its choices (``rt_pmf[0]``,
    step 1's, is already there); ``x`` (the cells after step 1) is updated in place. Stops
    early once the undecided mass is below ``tol``. Returns the steps done."""
    n_cells = x.shape[0]
    n_steps = rt_pmf.shape[0]
    y = np.zeros(n_cells)
    absorbed = np.zeros(2)
    mass = 0.0
    for a in range(n_cells):
        mass += x[a]
    # each step's target region is the next step's source region
    reg = region_at(edges, theta, sums[1])
    for t in range(1, n_steps):
        if mass < tol:
            return t
        absorbed[0] = 0.0
        absorbed[1] = 0.0
        reg_src = reg
        reg = region_at(edges, theta, sums[t + 1])
        for b in range(n_cells):
            if x[b] == 0.0:
                continue
            add_source(b, x[b], sums[t], sums[t + 1], reg_src, reg, centres, spreads_, sd_cell,
                       sd_axis, correct, width, slope, shift, S, CM, w, theta, edges, sd_opt,
                       y, absorbed)
        mass = 0.0
        for a in range(n_cells):
            x[a] = y[a]
            y[a] = 0.0
            mass += x[a]
        rt_pmf[t, 0] = absorbed[0]
        rt_pmf[t, 1] = absorbed[1]
    return n_steps


@njit
def settled_rows(s, centres, spreads_, sd_cell, sd_axis, correct, width, slope, shift, S, CM,
                 w, theta, edges, sd_opt):
    """The fixed chain once the sum has settled at ``s``: the rows of the cells of its
    region ``[lo, hi)`` (state ``b - lo``) in CSR ``(indptr, cols, vals)``, and their
    choices ``(hi - lo, 2)``."""
    reg = region_at(edges, theta, s)
    lo = reg[0]
    n_states = max(reg[1] - lo, 0)
    y = np.zeros(centres.shape[0])
    absorbing = np.zeros((n_states, 2))
    indptr = np.zeros(n_states + 1, dtype=np.int64)
    for write in range(2):
        if write:
            cols = np.empty(indptr[-1], dtype=np.int64)
            vals = np.empty(indptr[-1])
        else:
            cols = np.empty(0, dtype=np.int64)
            vals = np.empty(0)
        for r in range(n_states):
            absorbing[r, 0] = 0.0
            absorbing[r, 1] = 0.0
            b_lo, b_hi = add_source(lo + r, 1.0, s, s, reg, reg, centres, spreads_, sd_cell,
                                    sd_axis, correct, width, slope, shift, S, CM, w, theta,
                                    edges, sd_opt, y, absorbing[r])
            k = indptr[r]
            for b in range(b_lo, b_hi):
                v = y[b]
                if v == 0.0:
                    continue
                y[b] = 0.0
                if write:
                    cols[k] = b - lo
                    vals[k] = v
                k += 1
            if not write:
                indptr[r + 1] = k
    return indptr, cols, vals, absorbing, lo
