"""Compiled kernels of the moment chain for three options (:mod:`mdft.threshold_exact`).

Nothing here validates its input. The states are cells of the zero-sum plane
only; instead of levels of the summed preference ``s = 1^T P``, every state
carries, besides its probability ``x``, the first moment ``m = E[s 1{state}]``
of the sum. A state's transition depends on ``s`` (through the thresholds and,
slightly, through ``S``); it is evaluated at ``s_ref - delta`` and
``s_ref + delta`` around the state's reference sum, and applied as their mean
(``T0``) plus the slope (``T1``) times the state's deviation from ``s_ref``:
exact to first order in the deviation, with the two-point mean standing for a
spread ``delta`` of the sum within the state. The region ``{P_i < theta}`` moves
with the sum, so each of the two evaluations places a cut cell's mass at the
centroid of the part of the cell inside the region at that sum (the cell's
centre once it lies wholly inside); the state's own position is that centroid
at its reference sum. With ``edge``, every row also carries the edge terms of
:mod:`mdft._plane_boundary`.

The build runs on numba's threads: it evaluates the sources it has
discovered, a block at a time, in parallel parts and adds their rows in
order, so the chain is the same for any number of parts. The kernels that
step the chain are in :mod:`mdft._plane_step`.
"""

from __future__ import annotations

import math

import numpy as np

from numba import prange

from ._numba import njit, njit_parallel
from ._plane_boundary import add_edge_terms
from ._plane import (absorb3, classify, cut_mass_with, centroid, interval_mass, phi_cdf,
                     _CUT)

# A step whose staying mass finds no cell (every candidate below the kernel cut) may count
# it as chosen when it is below this; otherwise the resolution is refused.
_NEGLIGIBLE = 1e-7
OK = 0
TOO_MANY_STATES = 1
LOST_MASS = 2
# A target window reaches this many standard deviations of its component either way: a cell
# beyond gets at most the normal tail there (1e-7), not above _CUT (unless little of the step
# stays: its share of what stays is then more, but the tail is left out all the same; 5.7
# instead changed answers by 2e-10 on 43 random models).
_REACH = 5.2
# A component's edge terms are left out where the weight they move exceeds this share of
# its staying mass.
_EDGE_SHARE = 0.5
# The build evaluates at most this many discovered sources at a time (in parallel parts).
_BLOCK_SOURCES = 256


@njit
def _row(z1, z2, s, S, ex, ey, reach, CM, w, shrunk, sd_cell, exact, sd_exact, theta, o1, o2,
         h1, h2, n1, n2, sd_opt, pair_sd, pair_rho, scratch, tmp, marg1, marg2, ends, absorbed,
         box, edge, poly, cuts):
    """One source at ``(z, s)``: choices into ``absorbed``, staying mass added to ``scratch``
    (its bounding box in ``box``); returns ``(s_next, lost)``.

    Small inputs come as tuples (value types; an array argument costs two atomic reference
    counts per call): ``S`` (3 x 3), the lines ``ex``, ``ey`` (the columns of ``E``),
    ``reach[i]``, the half-extent of a cell along line ``i`` (:func:`mdft._plane.classify`),
    ``sd_cell``, ``sd_exact``, ``sd_opt``, ``pair_sd`` and ``pair_rho``. ``tmp`` is zero on
    entry and on return; ``marg1`` (3, n1), ``marg2`` (3, n2) and ``ends`` are work space
    (:func:`_margins`, :func:`mdft._plane.cut_mass_with`). ``edge``: add each narrowed
    component's edge terms (:func:`mdft._plane_boundary.add_edge_terms`), with the work
    space ``poly`` and ``cuts`` (:func:`_edge_work`)."""
    J = w.shape[0]
    P0 = ex[0] * z1 + ey[0] * z2 + s / 3.0
    P1 = ex[1] * z1 + ey[1] * z2 + s / 3.0
    P2 = ex[2] * z1 + ey[2] * z2 + s / 3.0
    m0 = S[0][0] * P0 + S[0][1] * P1 + S[0][2] * P2
    m1 = S[1][0] * P0 + S[1][1] * P1 + S[1][2] * P2
    m2 = S[2][0] * P0 + S[2][1] * P1 + S[2][2] * P2
    s_next = m0 + m1 + m2
    zm1 = ex[0] * m0 + ex[1] * m1 + ex[2] * m2
    zm2 = ey[0] * m0 + ey[1] * m1 + ey[2] * m2
    bound = theta - s_next / 3.0
    lost = False
    for i in range(3):
        absorbed[i] = 0.0
    for j in range(J):
        if w[j] <= 0.0:
            continue
        p_abs, pa0, pa1, pa2 = absorb3(m0 + CM[0, j], m1 + CM[1, j], m2 + CM[2, j], theta,
                                       sd_opt, pair_sd, pair_rho)
        part = (pa0, pa1, pa2)
        stay = 1.0 - p_abs
        if stay <= 1e-14:
            for i in range(3):
                absorbed[i] += w[j] * part[i] / p_abs
            continue
        inside = 0.0
        # cells that would get less than this share of the step's staying mass are left out
        cut = _CUT * stay
        # the cells written to tmp (an empty range: none)
        lo1 = n1
        hi1 = -1
        lo2 = n2
        hi2 = -1
        narrowed = True
        n_cut = 0
        for attempt in range(2):
            if attempt == 0:
                mu1 = zm1 + shrunk[0, j]
                mu2 = zm2 + shrunk[1, j]
                sd1 = sd_cell[0]
                sd2 = sd_cell[1]
            else:
                for a in range(lo1, hi1 + 1):
                    for b in range(lo2, hi2 + 1):
                        tmp[a, b] = 0.0
                lo1 = n1
                hi1 = -1
                lo2 = n2
                hi2 = -1
                narrowed = False
                mu1 = zm1 + exact[0, j]
                mu2 = zm2 + exact[1, j]
                sd1 = sd_exact[0]
                sd2 = sd_exact[1]
            # the window: cells within _REACH standard deviations of the mean (the cells
            # beyond get less than _CUT)
            w_lo1 = max(int(math.floor((mu1 - _REACH * sd1 - o1) / h1 + 0.5)), 0)
            w_hi1 = min(int(math.floor((mu1 + _REACH * sd1 - o1) / h1 + 0.5)), n1 - 1)
            w_lo2 = max(int(math.floor((mu2 - _REACH * sd2 - o2) / h2 + 0.5)), 0)
            w_hi2 = min(int(math.floor((mu2 + _REACH * sd2 - o2) / h2 + 0.5)), n2 - 1)
            inside = 0.0
            n_cut = 0
            _margins(w_lo1, w_hi1, o1, h1, mu1, sd1, marg1)
            p2max = _margins(w_lo2, w_hi2, o2, h2, mu2, sd2, marg2)
            for a in range(w_lo1, w_hi1 + 1):
                pa = marg1[0, a]
                if pa * p2max < cut:
                    continue  # every cell of the column gets less than the cut
                c1 = o1 + a * h1
                e0 = ex[0] * c1
                e1 = ex[1] * c1
                e2 = ex[2] * c1
                for b in range(w_lo2, w_hi2 + 1):
                    v = pa * marg2[0, b]
                    if v < cut:
                        continue
                    c2 = o2 + b * h2
                    # where the cell lies (mdft._plane.classify): outside, across, inside
                    t0 = e0 + ey[0] * c2
                    t1 = e1 + ey[1] * c2
                    t2 = e2 + ey[2] * c2
                    if (t0 - reach[0] >= bound or t1 - reach[1] >= bound
                            or t2 - reach[2] >= bound):
                        continue
                    if (t0 + reach[0] >= bound or t1 + reach[1] >= bound
                            or t2 + reach[2] >= bound):
                        v = cut_mass_with(c1 - 0.5 * h1, c1 + 0.5 * h1, c2 - 0.5 * h2,
                                          c2 + 0.5 * h2, mu1, sd1, mu2, sd2, ex, ey, bound,
                                          marg2[1, b], marg2[2, b], ends)
                        if v < cut:
                            continue
                        if edge:
                            cuts[n_cut, 0] = a
                            cuts[n_cut, 1] = b
                            n_cut += 1
                    tmp[a, b] = v
                    inside += v
                    if a < lo1:
                        lo1 = a
                    hi1 = a
                    if b < lo2:
                        lo2 = b
                    if b > hi2:
                        hi2 = b
            if inside >= 0.5 * stay:
                break
        if inside <= 0.0:
            if stay < _NEGLIGIBLE and p_abs > 0.0:
                # no cell keeps the sliver that stays: count it with the choices
                for i in range(3):
                    absorbed[i] += w[j] * part[i] / p_abs
            else:
                lost = True
            continue
        # the edge terms (mdft._plane_boundary), unless the Gaussian was not narrowed, or
        # they come to a large share of what stays (a step that mostly ends, its density
        # steep across the cells at the edge: the expansion behind them does not hold)
        moved = 0.0
        if edge and narrowed:
            moved = add_edge_terms(cuts, n_cut, o1, o2, h1, h2, n1, n2, ex, ey, reach, bound,
                                  mu1, mu2, sd1, sd2, w[j], scratch, box, poly)
            if abs(moved) > _EDGE_SHARE * stay:
                add_edge_terms(cuts, n_cut, o1, o2, h1, h2, n1, n2, ex, ey, reach, bound,
                               mu1, mu2, sd1, sd2, -w[j], scratch, box, poly)
                moved = 0.0
        scale = w[j] * (stay - moved) / inside
        for a in range(lo1, hi1 + 1):
            for b in range(lo2, hi2 + 1):
                scratch[a, b] += scale * tmp[a, b]
                tmp[a, b] = 0.0
        box[0] = min(box[0], lo1)
        box[1] = max(box[1], hi1)
        box[2] = min(box[2], lo2)
        box[3] = max(box[3], hi2)
        for i in range(3):
            absorbed[i] += w[j] * part[i]
    return s_next, lost


@njit
def _margins(lo, hi, o, h, mu, sd, marg):
    """``marg[0, a] = interval_mass(c - h / 2, c + h / 2, mu, sd)`` for the cells ``a`` in
    ``[lo, hi]`` (centre ``c = o + a h``), with the normal CDFs at their lower and upper
    edges in ``marg[1, a]`` and ``marg[2, a]`` when ``sd > 0`` (an edge shared with the
    previous cell is evaluated once); returns the largest mass."""
    top = 0.0
    if sd > 0.0:
        prev_edge = 0.0
        prev_cdf = 0.0
        for a in range(lo, hi + 1):
            c = o + a * h
            e_lo = c - 0.5 * h
            e_hi = c + 0.5 * h
            f_lo = prev_cdf if (a > lo and e_lo == prev_edge) else phi_cdf((e_lo - mu) / sd)
            f_hi = phi_cdf((e_hi - mu) / sd)
            v = f_hi - f_lo if e_lo < e_hi else 0.0
            marg[0, a] = v
            marg[1, a] = f_lo
            marg[2, a] = f_hi
            prev_edge = e_hi
            prev_cdf = f_hi
            if v > top:
                top = v
    else:
        for a in range(lo, hi + 1):
            c = o + a * h
            v = interval_mass(c - 0.5 * h, c + 0.5 * h, mu, sd)
            marg[0, a] = v
            if v > top:
                top = v
    return top


@njit
def _grow(a, n, cap):
    """``a`` (rows, 3 or 2 columns) with room for ``cap`` rows; the first ``n`` kept."""
    b = np.zeros((cap, a.shape[1]))
    b[:n] = a[:n]
    return b


@njit
def _doubled(cap, need):
    """``cap`` doubled until it holds ``need``."""
    while cap < need:
        cap *= 2
    return cap


@njit
def _grow1(a, n, cap):
    """``a`` (1-D) with room for ``cap`` entries; the first ``n`` kept, the rest unset (not
    zeroed: writing zeros would touch memory that may never be used)."""
    b = np.empty(cap, dtype=a.dtype)
    b[:n] = a[:n]
    return b


@njit
def _place(c1, c2, h1, h2, E, bound, z1, z2):
    """Where the mass of the cell centred at ``(c1, c2)`` lies when the region's edge is at
    ``bound``: the centre of a cell inside, the centroid of a cut cell's inside part, and
    ``(z1, z2)`` for a cell outside."""
    kind = classify(c1, c2, h1, h2, E, bound)
    if kind == 0:
        return c1, c2
    if kind == 1:
        g1, g2, ok = centroid(c1, c2, h1, h2, E, bound)
        if ok:
            return g1, g2
    return z1, z2


@njit
def _compact(sA, sB, box, cell, vals_a, vals_b, k0, cap):
    """Move the cells of ``box`` that either evaluation reached from ``sA``, ``sB`` (zeroed
    on the way) to ``cell`` (rows ``(a, b)``), ``vals_a``, ``vals_b`` from ``k0`` on, in the
    order the chain stores them; returns their number (when it exceeds ``cap``, only the
    first ``cap`` are written; all are zeroed)."""
    count = 0
    for a in range(box[0], box[1] + 1):
        for b in range(box[2], box[3] + 1):
            vA = sA[a, b]
            vB = sB[a, b]
            if vA == 0.0 and vB == 0.0:
                continue
            sA[a, b] = 0.0
            sB[a, b] = 0.0
            if count < cap:
                k = k0 + count
                cell[k, 0] = a
                cell[k, 1] = b
                vals_a[k] = vA
                vals_b[k] = vB
            count += 1
    return count


@njit
def _source(z1, z2, s_mid, d, St, ex, ey, reach, CM, w, shrunk, sdc, exact, sde, theta, o1, o2,
            h1, h2, n1, n2, sdo, psd, prho, sA, sB, tmp, marg1, marg2, ends, aA, aB, box, edge,
            poly, cuts):
    """Both evaluations of one source (at ``s_mid - d`` and ``s_mid + d``; one when ``d``
    is 0) into ``sA``, ``sB``, ``aA``, ``aB`` and ``box``; returns ``(snA, snB, lost)``."""
    box[0] = n1
    box[1] = -1
    box[2] = n2
    box[3] = -1
    snA, lostA = _row(z1[0], z2[0], s_mid - d, St, ex, ey, reach, CM, w, shrunk, sdc, exact,
                      sde, theta, o1, o2, h1, h2, n1, n2, sdo, psd, prho, sA, tmp, marg1,
                      marg2, ends, aA, box, edge, poly, cuts)
    if d > 0.0:
        snB, lostB = _row(z1[1], z2[1], s_mid + d, St, ex, ey, reach, CM, w, shrunk, sdc,
                          exact, sde, theta, o1, o2, h1, h2, n1, n2, sdo, psd, prho, sB, tmp,
                          marg1, marg2, ends, aB, box, edge, poly, cuts)
    else:
        snB = snA
        lostB = lostA
        for i in range(3):
            aB[i] = aA[i]
        for a in range(box[0], box[1] + 1):
            for b in range(box[2], box[3] + 1):
                sB[a, b] = sA[a, b]
    return snA, snB, lostA or lostB


@njit
def _small(S, E, h1, h2, sd_cell, sd_exact, sd_opt, pair_sd, pair_rho):
    """The small inputs of :func:`_row` as tuples (value types: no reference counting per
    call): ``S``, the lines ``ex``, ``ey`` (the columns of ``E``), each line's ``reach``
    across a cell, ``sd_cell``, ``sd_exact``, ``sd_opt``, ``pair_sd``, ``pair_rho``."""
    St = ((S[0, 0], S[0, 1], S[0, 2]), (S[1, 0], S[1, 1], S[1, 2]), (S[2, 0], S[2, 1], S[2, 2]))
    ex = (E[0, 0], E[1, 0], E[2, 0])
    ey = (E[0, 1], E[1, 1], E[2, 1])
    reach = (0.5 * (abs(E[0, 0]) * h1 + abs(E[0, 1]) * h2),
             0.5 * (abs(E[1, 0]) * h1 + abs(E[1, 1]) * h2),
             0.5 * (abs(E[2, 0]) * h1 + abs(E[2, 1]) * h2))
    sdc = (sd_cell[0], sd_cell[1])
    sde = (sd_exact[0], sd_exact[1])
    sdo = (sd_opt[0], sd_opt[1], sd_opt[2])
    psd = ((pair_sd[0, 0], pair_sd[0, 1], pair_sd[0, 2]),
           (pair_sd[1, 0], pair_sd[1, 1], pair_sd[1, 2]),
           (pair_sd[2, 0], pair_sd[2, 1], pair_sd[2, 2]))
    prho = ((pair_rho[0, 0], pair_rho[0, 1], pair_rho[0, 2]),
            (pair_rho[1, 0], pair_rho[1, 1], pair_rho[1, 2]),
            (pair_rho[2, 0], pair_rho[2, 1], pair_rho[2, 2]))
    return St, ex, ey, reach, sdc, sde, sdo, psd, prho


@njit
def _edge_work(edge, n1, n2):
    """Work space of the edge terms of one part: a clipped cell's polygon, and the cut
    cells of a component (a threshold line crosses at most ``n1 + n2 + 1`` cells); one
    entry each without them."""
    poly = np.empty((4, 8 if edge else 1))
    cuts = np.empty((3 * (n1 + n2) + 8 if edge else 1, 2), dtype=np.int64)
    return poly, cuts


@njit
def _sources_of_part(part, zs, s_mid, d, S, E, CM, w, shrunk, sd_cell, exact, sd_exact, theta,
                     o1, o2, h1, h2, n1, n2, sd_opt, pair_sd, pair_rho, work, margs, ends,
                     boxes, cap, cell, vals_a, vals_b, counts, absorbed, s_next, lost, edge):
    """The sources ``part, part + n_parts, ...`` of a block (see
    :func:`_sources_in_parts`), with the work space of that part."""
    n_parts = work.shape[0]
    St, ex, ey, reach, sdc, sde, sdo, psd, prho = _small(S, E, h1, h2, sd_cell, sd_exact,
                                                         sd_opt, pair_sd, pair_rho)
    sA = work[part, 0]
    sB = work[part, 1]
    tmp = work[part, 2]
    marg1 = margs[part, 0]
    marg2 = margs[part, 1]
    box = boxes[part]
    poly, cuts = _edge_work(edge, n1, n2)
    for i in range(part, zs.shape[0], n_parts):
        snA, snB, lst = _source(
            (zs[i, 0], zs[i, 1]), (zs[i, 2], zs[i, 3]), s_mid[i], d[i], St, ex, ey, reach,
            CM, w, shrunk, sdc, exact, sde, theta, o1, o2, h1, h2, n1, n2, sdo, psd, prho,
            sA, sB, tmp, marg1, marg2, ends[part], absorbed[i, 0], absorbed[i, 1], box, edge,
            poly, cuts)
        s_next[i, 0] = snA
        s_next[i, 1] = snB
        lost[i] = lst
        counts[i] = _compact(sA, sB, box, cell, vals_a, vals_b, i * cap, cap)


@njit_parallel
def _sources_in_parts(zs, s_mid, d, S, E, CM, w, shrunk, sd_cell, exact, sd_exact, theta, o1,
                      o2, h1, h2, n1, n2, sd_opt, pair_sd, pair_rho, work, margs, ends, boxes,
                      cap, cell, vals_a, vals_b, counts, absorbed, s_next, lost, edge):
    """Both evaluations of each source of a block (``zs[i] = (z1A, z1B, z2A, z2B)``),
    sources dealt in turn to ``work.shape[0]`` parts on numba's threads, each part with its
    own work space. Source ``i``'s cells go to ``cell``, ``vals_a``, ``vals_b`` from
    ``i * cap`` (``counts[i]`` of them; more than ``cap`` when they did not fit, and the
    caller evaluates the source again with that much room),
    its choices to ``absorbed[i]`` and its next sums to ``s_next[i]``."""
    for part in prange(work.shape[0]):
        # the part as int64: numba compiles the (large) callee once for each integer type
        # it is called with, and the parallel loop's index comes as int64 and as uint64
        _sources_of_part(np.int64(part), zs, s_mid, d, S, E, CM, w, shrunk, sd_cell, exact,
                         sd_exact, theta, o1, o2, h1, h2, n1, n2, sd_opt, pair_sd, pair_rho,
                         work, margs, ends, boxes, cap, cell, vals_a, vals_b, counts, absorbed,
                         s_next, lost, edge)


@njit
def _cell_of(c, o, h):
    """Index of the grid cell centred at ``c`` on an axis with first centre ``o``."""
    return int(round((c - o) / h))


@njit
def mark_near(allowed, pts, o1, o2, h1, h2, r1, r2):
    """Set ``allowed`` on every cell whose centre lies within ``r1`` (axis 1) and ``r2``
    (axis 2) of one of the points ``pts`` (rows ``(z1, z2)``)."""
    n1, n2 = allowed.shape
    for k in range(pts.shape[0]):
        a_lo = max(0, int(math.ceil((pts[k, 0] - r1 - o1) / h1)))
        a_hi = min(n1 - 1, int(math.floor((pts[k, 0] + r1 - o1) / h1)))
        b_lo = max(0, int(math.ceil((pts[k, 1] - r2 - o2) / h2)))
        b_hi = min(n2 - 1, int(math.floor((pts[k, 1] + r2 - o2) / h2)))
        for a in range(a_lo, a_hi + 1):
            for b in range(b_lo, b_hi + 1):
                allowed[a, b] = True


@njit
def build(z_start, s_start, S, E, CM, w, shrunk, sd_cell, exact, sd_exact, theta, o1, o2,
          h1, h2, n1, n2, sd_opt, pair_sd, pair_rho, ref, s_lo, s_hi, delta, max_states,
          n_parts, first_slot, allowed, ref_map, map_grid, edge):
    """Discover the reachable cells from the exact start and build the moment chain.

    ``ref = (r0, r1, r2)``: the reference sum of the cell at ``z`` is
    ``r0 + r1 z1 + r2 z2``, clipped to ``[s_lo, s_hi]``, unless ``ref_map`` (the walks'
    mean sums per cell of a pass, NaN where it has none; empty: none) holds a value for
    the cell of that pass's grid around the cell's centre: ``map_grid = (o1, o2, h1, h2)``
    is that grid's origin and cell size (the closure's plane probe gives the grid's own).
    The states are
    discovered breadth first; the sources waiting to be evaluated (up to
    :data:`_BLOCK_SOURCES` at a time) are evaluated in ``n_parts`` parts on
    numba's threads and then added in order, so the chain is the same for any
    ``n_parts``. Each source's cells get a slot of ``first_slot`` entries at
    first, widened as wider sources are met (a source that does not fit is
    evaluated again alone). ``allowed`` (``n1 x n2``, or empty for every cell): the cells
    whose rows are evaluated; a state discovered in another cell is a *frontier* state, with
    an empty row (its mass leaves the chain, and :func:`propagate` counts it). ``edge``:
    the rows carry the edge terms (:mod:`mdft._plane_boundary`). Returns
    ``(status, pos, sref, snext, row_ptr, cols, t0, t1, r0, r1, start_cols, start_vals,
    start_abs, start_snext, frontier)``.
    """
    index = np.full((n1, n2), -1, dtype=np.int64)
    every = allowed.size == 0
    cap = 1024
    pos = np.empty((cap, 2))
    centre = np.empty((cap, 2))
    frontier = np.zeros(cap, dtype=np.bool_)
    sref = np.empty(cap)
    snext = np.empty(cap)
    n_states = 0
    vcap = 1 << 16
    cols = np.empty(vcap, dtype=np.int32)
    t0 = np.empty(vcap)
    t1 = np.empty(vcap)
    row_ptr = np.zeros(cap + 1, dtype=np.int64)
    ab0 = np.zeros((cap, 3))
    ab1 = np.zeros((cap, 3))
    n_vals = 0
    # work space of each part (dense scratch of the two evaluations and of _row), allocated once
    work = np.zeros((n_parts, 3, n1, n2))
    margs = np.zeros((n_parts, 2, 3, max(n1, n2)))
    ends = np.zeros((n_parts, 3 * 3 + 2))
    boxes = np.zeros((n_parts, 4), dtype=np.int64)
    # a block's evaluated sources: cells (slots of `slot` entries), choices, next sums
    slot = first_slot
    blk_cell = np.empty((0, 2), dtype=np.int32)
    blk_a = np.empty(0)
    blk_b = np.empty(0)
    start_cols = np.empty(0, dtype=np.int64)
    start_vals = np.empty(0)
    start_abs = np.zeros(3)
    start_snext = 0.0
    status = OK
    r = -1
    while r < n_states:
        # the block: the start alone, then the sources discovered and not yet evaluated
        r_end = 0 if r < 0 else min(n_states, r + _BLOCK_SOURCES)
        # the block's sources to evaluate: those in allowed cells (frontier states are not)
        srcs = np.empty(r_end - r, dtype=np.int64)
        n_blk = 0
        for q in range(r, r_end):
            if q < 0 or every or allowed[_cell_of(centre[q, 0], o1, h1),
                                         _cell_of(centre[q, 1], o2, h2)]:
                srcs[n_blk] = q
                n_blk += 1
            else:
                frontier[q] = True
        zs = np.empty((n_blk, 4))
        s_mid = np.empty(n_blk)
        dd = np.empty(n_blk)
        for i in range(n_blk):
            q = srcs[i]
            if q < 0:
                z1 = z_start[0]
                z2 = z_start[1]
                s_mid[i] = s_start
                dd[i] = 0.0
            else:
                z1 = pos[q, 0]
                z2 = pos[q, 1]
                s_mid[i] = sref[q]
                dd[i] = delta
            zs[i, 0] = z1
            zs[i, 1] = z1
            zs[i, 2] = z2
            zs[i, 3] = z2
            if q >= 0 and delta > 0.0:
                # the inside part of a cut cell, and so where its mass lies, moves with the sum
                zA1, zA2 = _place(centre[q, 0], centre[q, 1], h1, h2, E,
                                  theta - (s_mid[i] - delta) / 3.0, z1, z2)
                zB1, zB2 = _place(centre[q, 0], centre[q, 1], h1, h2, E,
                                  theta - (s_mid[i] + delta) / 3.0, z1, z2)
                zs[i, 0] = zA1
                zs[i, 1] = zB1
                zs[i, 2] = zA2
                zs[i, 3] = zB2
        if blk_cell.shape[0] < n_blk * slot:
            blk_cell = np.empty((n_blk * slot, 2), dtype=np.int32)
            blk_a = np.empty(n_blk * slot)
            blk_b = np.empty(n_blk * slot)
        counts = np.empty(n_blk, dtype=np.int64)
        absorbed = np.empty((n_blk, 2, 3))
        s_next = np.empty((n_blk, 2))
        lost = np.zeros(n_blk, dtype=np.bool_)
        _sources_in_parts(zs, s_mid, dd, S, E, CM, w, shrunk, sd_cell, exact, sd_exact, theta,
                          o1, o2, h1, h2, n1, n2, sd_opt, pair_sd, pair_rho, work, margs, ends,
                          boxes, slot, blk_cell, blk_a, blk_b, counts, absorbed, s_next, lost,
                          edge)
        widest = 0
        i = -1
        for q in range(r, r_end):
            if q >= 0 and frontier[q]:
                # no row: its mass leaves the chain (ab0, ab1 stay zero)
                row_ptr[q + 1] = n_vals
                snext[q] = sref[q]
                continue
            i += 1
            if lost[i]:
                status = LOST_MASS
            cell = blk_cell
            va = blk_a
            vb = blk_b
            k0 = i * slot
            n_new = counts[i]
            if n_new > slot:
                # more cells than the slot: evaluate the source again alone, with room for all
                cell = np.empty((n_new, 2), dtype=np.int32)
                va = np.empty(n_new)
                vb = np.empty(n_new)
                k0 = 0
                _sources_in_parts(zs[i:i + 1], s_mid[i:i + 1], dd[i:i + 1], S, E, CM, w, shrunk,
                                  sd_cell, exact, sd_exact, theta, o1, o2, h1, h2, n1, n2,
                                  sd_opt, pair_sd, pair_rho, work[:1], margs[:1], ends[:1],
                                  boxes[:1], n_new, cell, va, vb, counts[i:i + 1],
                                  absorbed[i:i + 1], s_next[i:i + 1], lost[i:i + 1], edge)
            widest = max(widest, n_new)
            row_start = n_vals
            # room for the row's nonzeros and new states before the loop over its cells:
            # arrays reassigned inside that loop would be reference-counted at every cell
            if n_vals + n_new > cols.shape[0]:
                vcap = _doubled(cols.shape[0], n_vals + n_new)
                cols = _grow1(cols, n_vals, vcap)
                t0 = _grow1(t0, n_vals, vcap)
                t1 = _grow1(t1, n_vals, vcap)
            if n_states + n_new > pos.shape[0]:
                cap = _doubled(pos.shape[0], n_states + n_new)
                pos = _grow(pos, n_states, cap)
                centre = _grow(centre, n_states, cap)
                fr2 = np.zeros(cap, dtype=np.bool_)
                fr2[:n_states] = frontier[:n_states]
                frontier = fr2
                ab0 = _grow(ab0, n_states, cap)
                ab1 = _grow(ab1, n_states, cap)
                sref = _grow1(sref, n_states, cap)
                snext = _grow1(snext, n_states, cap)
                rp2 = np.zeros(cap + 1, dtype=np.int64)
                rp2[:n_states + 1] = row_ptr[:n_states + 1]
                row_ptr = rp2
            d = dd[i]
            for k in range(k0, k0 + n_new):
                a = cell[k, 0]
                b = cell[k, 1]
                vA = va[k]
                vB = vb[k]
                t = index[a, b]
                if t < 0:
                    if n_states >= max_states:
                        status = TOO_MANY_STATES
                        break
                    c1 = o1 + a * h1
                    c2 = o2 + b * h2
                    mapped = False
                    if ref_map.size > 0:
                        ac = int(math.floor((c1 - map_grid[0]) / map_grid[2] + 0.5))
                        bc = int(math.floor((c2 - map_grid[1]) / map_grid[3] + 0.5))
                        if (0 <= ac < ref_map.shape[0] and 0 <= bc < ref_map.shape[1]
                                and not math.isnan(ref_map[ac, bc])):
                            mapped = True
                            sr = min(max(ref_map[ac, bc], s_lo), s_hi)
                    if not mapped:
                        sr = min(max(ref[0] + ref[1] * c1 + ref[2] * c2, s_lo), s_hi)
                    g1, g2 = _place(c1, c2, h1, h2, E, theta - sr / 3.0, c1, c2)
                    pos[n_states, 0] = g1
                    pos[n_states, 1] = g2
                    centre[n_states, 0] = c1
                    centre[n_states, 1] = c2
                    if not mapped:
                        sr = min(max(ref[0] + ref[1] * g1 + ref[2] * g2, s_lo), s_hi)
                    sref[n_states] = sr
                    t = n_states
                    index[a, b] = t
                    n_states += 1
                cols[n_vals] = t
                t0[n_vals] = 0.5 * (vA + vB)
                t1[n_vals] = (vB - vA) / (2.0 * d) if d > 0.0 else 0.0
                n_vals += 1
            if status == TOO_MANY_STATES:
                break
            if q < 0:
                start_cols = cols[row_start:n_vals].astype(np.int64)
                start_vals = t0[row_start:n_vals].copy()
                n_vals = row_start
                for j in range(3):
                    start_abs[j] = absorbed[i, 0, j]
                start_snext = s_next[i, 0]
            else:
                row_ptr[q + 1] = n_vals
                for j in range(3):
                    aA = absorbed[i, 0, j]
                    aB = absorbed[i, 1, j]
                    ab0[q, j] = 0.5 * (aA + aB)
                    ab1[q, j] = (aB - aA) / (2.0 * d) if d > 0.0 else 0.0
                snext[q] = 0.5 * (s_next[i, 0] + s_next[i, 1])
        if status == TOO_MANY_STATES:
            break
        # the next block's slots: room for the widest source so far, and a quarter more
        slot = max(slot, widest + widest // 4)
        r = r_end
    # the nonzeros are returned as views of their buffers: a copy would touch as much memory
    # again (the buffers' unused ends were never written)
    return (status, pos[:n_states].copy(), sref[:n_states].copy(), snext[:n_states].copy(),
            row_ptr[:n_states + 1].copy(), cols[:n_vals], t0[:n_vals], t1[:n_vals],
            ab0[:n_states].copy(), ab1[:n_states].copy(), start_cols, start_vals, start_abs,
            start_snext, frontier[:n_states].copy())
