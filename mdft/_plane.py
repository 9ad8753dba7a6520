"""Compiled helpers of the three-option chain (:mod:`mdft._plane_moment`).

Nothing here validates its input: :func:`mdft.threshold_probabilities`
checks and converts everything once.

A preference state is ``P = E z + (s / 3) 1``: ``z`` holds its coordinates in
an orthonormal basis ``E`` (3 x 2) of the plane of zero-sum vectors, and
``s = 1^T P`` is the summed preference. The grid has cells of size
``h1 x h2`` in the plane; the transient region at sum ``s`` is
``{(E z)_i < theta - s / 3}``. The helpers give the exact probability that a
Gaussian step ends with each option chosen (normal and bivariate normal
tails), the Gaussian mass of a cell cut by the region's edge (one-dimensional
Gauss-Legendre quadrature), whether a cell lies inside, outside or across the
edge, and the centroid of a cut cell's inside part.
"""

from __future__ import annotations

import math

import numpy as np

from ._lattice import _GL_W, _GL_X, joint_upper, upper
from ._numba import njit

_SQRT2 = math.sqrt(2.0)
# A window reaches this many component standard deviations around its mean.
_WIDTH = 6.5
# Gauss-Legendre rule of the cut cells' pieces (smooth once split at their breaks, and no wider
# than a standard deviation). Four nodes: on 65,000 random cut cells (cells of 0.5-1.5
# standard deviations, any orientation of the lines) the error of a cell's mass against a
# twelve-node rule was at most 1.6e-7 of the component's mass (99 % below 4e-9), about the
# cut below; six nodes took 5-7 % longer in all and moved no answer by 1e-6.
_PIECE_X, _PIECE_W = np.polynomial.legendre.leggauss(4)
# Target cells that would receive less than this share of a step's staying mass are left out
# (and the row renormalised). 1e-8 instead of 1e-11 dropped a quarter of the nonzeros; 1e-7
# instead of 1e-8 drops another (docs/threshold_exact.md, section 2).
_CUT = 1e-7


@njit
def phi_cdf(x):
    """Standard normal CDF."""
    return 0.5 * math.erfc(-x / _SQRT2)


@njit
def interval_mass(lo, hi, mu, sd):
    """``Pr(lo <= X < hi)`` for ``X ~ N(mu, sd^2)``; an indicator when ``sd == 0``."""
    if hi <= lo:
        return 0.0
    if sd > 0.0:
        return phi_cdf((hi - mu) / sd) - phi_cdf((lo - mu) / sd)
    return 1.0 if (lo <= mu and mu < hi) else 0.0


@njit
def absorb3(mu0, mu1, mu2, theta, sd_opt, pair_sd, pair_rho):
    """Probability that the step ends with each option chosen: ``(total, p0, p1, p2)``.

    ``mu0, mu1, mu2`` is the mean of ``P``; ``sd_opt`` (3), ``pair_sd`` and ``pair_rho``
    (3 x 3) are tuples (value types: no reference counting per call). Option ``i`` is
    chosen when ``P_i >= theta`` and ``P_i`` is the largest preference:
    ``Pr(P_i >= theta) - sum_k Pr(P_i >= theta, P_k > P_i)`` (all three past the
    threshold cannot happen below a summed preference of ``3 theta``). A joint term is at
    most either tail and is skipped when one of them is below 1e-15.
    """
    muP = (mu0, mu1, mu2)
    tails = (upper(mu0, sd_opt[0], theta), upper(mu1, sd_opt[1], theta),
             upper(mu2, sd_opt[2], theta))
    out0 = 0.0
    out1 = 0.0
    out2 = 0.0
    total = 0.0
    for i in range(3):
        pi = tails[i]
        if pi <= 0.0:
            continue
        for k in range(3):
            if k == i or min(tails[i], tails[k]) < 1e-15:
                continue
            pi -= joint_upper(muP[i], sd_opt[i], theta, muP[k] - muP[i], pair_sd[i][k], 0.0,
                              pair_rho[i][k], _GL_X, _GL_W)
        if pi < 0.0:
            pi = 0.0
        if i == 0:
            out0 = pi
        elif i == 1:
            out1 = pi
        else:
            out2 = pi
        total += pi
    return total, out0, out1, out2


@njit
def _y_interval(x, ex, ey, bound, ylo, yhi):
    """The part of ``[ylo, yhi]`` with ``ex[i] x + ey[i] y < bound`` for every ``i``."""
    for i in range(len(ex)):
        rest = bound - ex[i] * x
        if ey[i] > 1e-14:
            lim = rest / ey[i]
            if lim < yhi:
                yhi = lim
        elif ey[i] < -1e-14:
            lim = rest / ey[i]
            if lim > ylo:
                ylo = lim
        elif rest <= 0.0:
            return 0.0, 0.0
    return ylo, yhi


@njit
def _breaks(lo, hi, ylo, yhi, ex, ey, bound, out, start):
    """Points of ``(lo, hi)`` where the inside part of the column at ``x`` changes form:
    a line meets the cell's bottom or top edge (a kink), a line parallel to the y axis (a
    jump), two lines meet (a kink). Written to ``out[start:]`` in increasing order; their
    number is returned."""
    n = start
    m = len(ex)
    for i in range(m):
        if abs(ey[i]) > 1e-14:
            if abs(ex[i]) <= 1e-14:
                continue
            for k in range(2):
                yy = ylo if k == 0 else yhi
                x = (bound - ey[i] * yy) / ex[i]
                if lo < x and x < hi:
                    out[n] = x
                    n += 1
        elif abs(ex[i]) > 1e-14:
            x = bound / ex[i]
            if lo < x and x < hi:
                out[n] = x
                n += 1
        for k in range(i + 1, m):
            det = ex[i] * ey[k] - ex[k] * ey[i]
            if abs(det) > 1e-14:
                x = bound * (ey[k] - ey[i]) / det
                if lo < x and x < hi:
                    out[n] = x
                    n += 1
    for a in range(start + 1, n):  # insertion sort: a handful of points
        v = out[a]
        b = a - 1
        while b >= start and out[b] > v:
            out[b + 1] = out[b]
            b -= 1
        out[b + 1] = v
    return n - start


@njit
def cut_mass(xlo, xhi, ylo, yhi, mx, sx, my, sy, ex, ey, bound):
    """Gaussian mass ``N(mx, sx^2) x N(my, sy^2)`` of the cell ``[xlo, xhi) x [ylo, yhi)``
    cut by the half-planes ``ex[i] x + ey[i] y < bound``.

    Integrates over ``x`` with the closed-form mass over ``y`` at each node:
    the range is split where the inside part of the column changes form
    (:func:`_breaks`), so that each piece is smooth, and each piece is
    integrated by composite four-point Gauss-Legendre on panels no wider than
    ``sx``, nor than ``sy |ey_i / ex_i|`` for a line ``i`` that cuts the piece's
    columns (the distance along ``x`` over which it moves their end by ``sy``). A
    component much narrower than the cell along ``x`` is taken as a point there.
    :func:`cut_mass_with` is the same with the caller's buffers.
    """
    cdf_lo = phi_cdf((ylo - my) / sy) if sy > 0.0 else 0.0
    cdf_hi = phi_cdf((yhi - my) / sy) if sy > 0.0 else 0.0
    ends = np.empty(3 * len(ex) + 2)
    return cut_mass_with(xlo, xhi, ylo, yhi, mx, sx, my, sy, ex, ey, bound, cdf_lo, cdf_hi,
                         ends)


@njit
def cut_mass_with(xlo, xhi, ylo, yhi, mx, sx, my, sy, ex, ey, bound, cdf_lo, cdf_hi, ends):
    """:func:`cut_mass` given the normal CDFs ``cdf_lo = Phi((ylo - my) / sy)`` and
    ``cdf_hi = Phi((yhi - my) / sy)`` of the cell's own edges (used when ``sy > 0``)
    and a work array ``ends`` of at least ``3 len(ex) + 2`` entries. ``ex`` and ``ey``
    may be tuples (no reference counting in the loops over the nodes)."""
    width = xhi - xlo
    if sx <= width / 64.0:
        if not (xlo <= mx and mx < xhi):
            return 0.0
        a, b = _y_interval(mx, ex, ey, bound, ylo, yhi)
        return interval_mass(a, b, my, sy)
    lo = max(xlo, mx - _WIDTH * sx)
    hi = min(xhi, mx + _WIDTH * sx)
    if hi <= lo:
        return 0.0
    ends[0] = lo
    n_ends = 1 + _breaks(lo, hi, ylo, yhi, ex, ey, bound, ends, 1)
    ends[n_ends] = hi
    norm = 1.0 / (sx * math.sqrt(2.0 * math.pi))
    total = 0.0
    for piece in range(n_ends):
        p0 = ends[piece]
        p1 = ends[piece + 1]
        if p1 <= p0:
            continue
        # panels no wider than sx, nor than the distance along x over which a line that
        # cuts the column moves its end by sy (the column's mass then changes on that scale)
        limit = sx
        if sy > 0.0:
            xm = 0.5 * (p0 + p1)
            for i in range(len(ex)):
                if abs(ey[i]) > 1e-14 and abs(ex[i]) > 1e-14:
                    y = (bound - ex[i] * xm) / ey[i]
                    if ylo < y and y < yhi:
                        limit = min(limit, sy * abs(ey[i] / ex[i]))
        n_pan = min(max(int(math.ceil((p1 - p0) / limit)), 1), 64)
        step = (p1 - p0) / n_pan
        acc = 0.0
        for p in range(n_pan):
            mid = p0 + (p + 0.5) * step
            for q in range(_PIECE_X.shape[0]):
                x = mid + 0.5 * step * _PIECE_X[q]
                a, b = _y_interval(x, ex, ey, bound, ylo, yhi)
                if b <= a:
                    continue
                u = (x - mx) / sx
                if sy > 0.0:
                    mass = ((cdf_hi if b == yhi else phi_cdf((b - my) / sy))
                            - (cdf_lo if a == ylo else phi_cdf((a - my) / sy)))
                else:
                    mass = interval_mass(a, b, my, sy)
                acc += _PIECE_W[q] * norm * math.exp(-0.5 * u * u) * mass
        total += acc * 0.5 * step
    return total


@njit
def classify(c1, c2, h1, h2, E, bound):
    """0: the cell lies inside ``{(E z)_i < bound}``; 2: outside; 1: cut by its edge."""
    state = 0
    for i in range(3):
        centre = E[i, 0] * c1 + E[i, 1] * c2
        reach = 0.5 * (abs(E[i, 0]) * h1 + abs(E[i, 1]) * h2)
        if centre - reach >= bound:
            return 2
        if centre + reach >= bound:
            state = 1
    return state


@njit
def centroid(c1, c2, h1, h2, E, bound):
    """Centroid of the part of a cut cell inside the region (midpoint rule, 16 x 16)."""
    m = 16
    acc1 = 0.0
    acc2 = 0.0
    count = 0
    for a in range(m):
        x = c1 - 0.5 * h1 + (a + 0.5) * h1 / m
        for b in range(m):
            y = c2 - 0.5 * h2 + (b + 0.5) * h2 / m
            inside = True
            for i in range(3):
                if E[i, 0] * x + E[i, 1] * y >= bound:
                    inside = False
                    break
            if inside:
                acc1 += x
                acc2 += y
                count += 1
    if count == 0:
        return c1, c2, False
    return acc1 / count, acc2 / count, True
