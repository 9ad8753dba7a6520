"""Compiled kernels of the plane chain for three options (:mod:`mdft.threshold_exact`).

Nothing here validates its input: :func:`mdft.threshold_probabilities`
checks and converts everything once.

Coordinates
-----------
A preference state is ``P = E z + (s / 3) 1``: ``z`` holds its coordinates in
an orthonormal basis ``E`` (3 x 2) of the plane of zero-sum vectors, chosen
along the principal axes of the per-step spread, and ``s = 1^T P`` is the
summed preference, which the valence never changes.

The grid has cells of size ``h1 x h2`` in the plane, the cell ``(a, b)``
centred at ``(o1 + a h1, o2 + b h2)``, and levels ``s_lo + l hs`` of the sum.
A state is a cell of a level that meets the transient region
``{P_i < theta}``; it sits at the centroid of the part of the cell inside the
region. States are discovered from the start by following the transitions
(breadth first), so only the reachable part of the region is stored.

From a state, attribute ``j`` gives ``P(t+1) ~ N(S P + C M e_j, sigma2 C C^T)``.
The probability of choosing each option at the step is computed from that
Gaussian exactly (normal and bivariate normal tails); the remainder is put on
the cells it reaches inside the region, in proportion to the Gaussian's mass
on ``cell ∩ region`` (products of normal CDF differences, or one-dimensional
Gauss-Legendre quadrature for cells the threshold cuts). That Gaussian's
component means and variances are corrected (``shrink``, ``sd_cell``) so that
the chain's per-step covariance, which the jump to a cell's centroid widens by
``h^2 / 12`` along each axis, equals the model's.
"""

from __future__ import annotations

import math

import numpy as np

from ._lattice import joint_upper, upper
from ._numba import njit

_SQRT2 = math.sqrt(2.0)
# A window reaches this many component standard deviations around its mean.
_WIDTH = 6.5
# Target cells that would receive less than this are left out (and the row renormalised);
# 1e-8 instead of 1e-11 drops a quarter of the nonzeros and changes answers by < 1e-5.
_CUT = 1e-8
# Status codes of build().
OK = 0
TOO_MANY_STATES = 1
LOST_MASS = 2


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
def absorb3(muP, theta, sd_opt, pair_sd, pair_rho, out, gl_x, gl_w):
    """Probability that the step ends with each option chosen; added to ``out``; total returned.

    Option ``i`` is chosen when ``P_i >= theta`` and ``P_i`` is the largest
    preference: ``Pr(P_i >= theta) - sum_k Pr(P_i >= theta, P_k > P_i)`` (all
    three past the threshold cannot happen below a summed preference of
    ``3 theta``). A joint term is at most either tail and is skipped when one
    of them is below 1e-15.
    """
    total = 0.0
    tails = np.empty(3)
    for i in range(3):
        tails[i] = upper(muP[i], sd_opt[i], theta)
    for i in range(3):
        pi = tails[i]
        if pi <= 0.0:
            continue
        for k in range(3):
            if k == i or min(tails[i], tails[k]) < 1e-15:
                continue
            pi -= joint_upper(muP[i], sd_opt[i], theta, muP[k] - muP[i], pair_sd[i, k], 0.0,
                              pair_rho[i, k], gl_x, gl_w)
        if pi < 0.0:
            pi = 0.0
        out[i] = pi
        total += pi
    return total


@njit
def _y_interval(x, ex, ey, bound, ylo, yhi):
    """The part of ``[ylo, yhi]`` with ``ex[i] x + ey[i] y < bound`` for every ``i``."""
    for i in range(ex.shape[0]):
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
def cut_mass(xlo, xhi, ylo, yhi, mx, sx, my, sy, ex, ey, bound, gl_x, gl_w):
    """Gaussian mass ``N(mx, sx^2) x N(my, sy^2)`` of the cell ``[xlo, xhi) x [ylo, yhi)``
    cut by the half-planes ``ex[i] x + ey[i] y < bound``.

    Integrates over ``x`` (composite Gauss-Legendre on panels no wider than
    ``sx``) with the closed-form mass over ``y`` at each node. A component
    much narrower than the cell along ``x`` is taken as a point there.
    """
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
    n_pan = int(math.ceil((hi - lo) / sx))
    if n_pan < 1:
        n_pan = 1
    if n_pan > 64:
        n_pan = 64
    step = (hi - lo) / n_pan
    acc = 0.0
    norm = 1.0 / (sx * math.sqrt(2.0 * math.pi))
    for p in range(n_pan):
        mid = lo + (p + 0.5) * step
        for q in range(gl_x.shape[0]):
            x = mid + 0.5 * step * gl_x[q]
            a, b = _y_interval(x, ex, ey, bound, ylo, yhi)
            if b <= a:
                continue
            u = (x - mx) / sx
            acc += gl_w[q] * norm * math.exp(-0.5 * u * u) * interval_mass(a, b, my, sy)
    return acc * 0.5 * step


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


@njit
def build(z_start, s_start, S, E, CM, w, shrunk, sd_cell, exact, sd_exact, theta, o1, o2, h1, h2, n1, n2,
          s_lo, hs, n_levels, sd_opt, pair_sd, pair_rho, gl_x, gl_w, max_states):
    """Discover the reachable states from the exact start and build the chain.

    ``shrunk[:, j]``: component mean offsets in the plane (relative to
    ``E^T S P``) after the variance correction; ``sd_cell``: component
    standard deviations along the two axes after it.

    Returns ``(status, pos, lev, row_ptr, cols, vals, absorb, start_cols,
    start_vals, start_abs, max_gap)``; ``max_gap`` is the largest difference,
    over rows and attributes, between the Gaussian mass found on the cells and
    the exact probability of staying (before renormalisation).
    """
    J = w.shape[0]
    index = np.full((n_levels, n1, n2), -1, dtype=np.int64)
    cap = 1024
    pos = np.empty((cap, 2))
    lev = np.empty(cap, dtype=np.int64)
    n_states = 0
    vcap = 1 << 16
    cols = np.empty(vcap, dtype=np.int64)
    vals = np.empty(vcap)
    row_ptr = np.zeros(cap + 1, dtype=np.int64)
    absorb = np.zeros((cap, 3))
    n_vals = 0
    scratch = np.zeros((n1, n2))
    tmp = np.zeros((n1, n2))
    p1 = np.zeros(n1)
    p2 = np.zeros(n2)
    part = np.zeros(3)
    muP = np.empty(3)
    ex = E[:, 0].copy()
    ey = E[:, 1].copy()
    start_cols = np.empty(0, dtype=np.int64)
    start_vals = np.empty(0)
    start_abs = np.zeros(3)
    max_gap = 0.0
    n_fallback = 0
    status = OK
    r = -1  # -1: the start; then states in order of discovery
    while r < n_states:
        if r < 0:
            z1 = z_start[0]
            z2 = z_start[1]
            s = s_start
        else:
            z1 = pos[r, 0]
            z2 = pos[r, 1]
            s = s_lo + lev[r] * hs
        # deterministic part m = S P
        m0 = 0.0
        m1 = 0.0
        m2 = 0.0
        P0 = E[0, 0] * z1 + E[0, 1] * z2 + s / 3.0
        P1 = E[1, 0] * z1 + E[1, 1] * z2 + s / 3.0
        P2 = E[2, 0] * z1 + E[2, 1] * z2 + s / 3.0
        m0 = S[0, 0] * P0 + S[0, 1] * P1 + S[0, 2] * P2
        m1 = S[1, 0] * P0 + S[1, 1] * P1 + S[1, 2] * P2
        m2 = S[2, 0] * P0 + S[2, 1] * P1 + S[2, 2] * P2
        s_next = m0 + m1 + m2
        zm1 = E[0, 0] * m0 + E[1, 0] * m1 + E[2, 0] * m2
        zm2 = E[0, 1] * m0 + E[1, 1] * m1 + E[2, 1] * m2
        bound = theta - s_next / 3.0
        if n_levels == 1:
            l0 = 0
            frac = 0.0
        else:
            u = (s_next - s_lo) / hs
            l0 = int(math.floor(u))
            if l0 < 0:
                l0 = 0
            if l0 > n_levels - 2:
                l0 = n_levels - 2
            frac = u - l0
            if frac < 0.0:
                frac = 0.0
            if frac > 1.0:
                frac = 1.0
        lo1_all = n1
        hi1_all = -1
        lo2_all = n2
        hi2_all = -1
        absorbed = np.zeros(3)
        for j in range(J):
            if w[j] <= 0.0:
                continue
            muP[0] = m0 + CM[0, j]
            muP[1] = m1 + CM[1, j]
            muP[2] = m2 + CM[2, j]
            for i in range(3):
                part[i] = 0.0
            p_abs = absorb3(muP, theta, sd_opt, pair_sd, pair_rho, part, gl_x, gl_w)
            stay = 1.0 - p_abs
            if stay <= 1e-14:
                for i in range(3):
                    absorbed[i] += w[j] * part[i] / p_abs
                continue
            inside = 0.0
            lo1 = 0
            hi1 = -1
            lo2 = 0
            hi2 = -1
            for attempt in range(2):
                if attempt == 0:
                    mu1 = zm1 + shrunk[0, j]
                    mu2 = zm2 + shrunk[1, j]
                    sd1 = sd_cell[0]
                    sd2 = sd_cell[1]
                else:
                    # the corrected kernel finds far less room inside than the model's:
                    # place the mass that stays with the model's own kernel
                    for a in range(lo1, hi1 + 1):
                        for b in range(lo2, hi2 + 1):
                            tmp[a, b] = 0.0
                    mu1 = zm1 + exact[0, j]
                    mu2 = zm2 + exact[1, j]
                    sd1 = sd_exact[0]
                    sd2 = sd_exact[1]
                lo1 = int(math.floor((mu1 - _WIDTH * sd1 - o1) / h1 + 0.5))
                hi1 = int(math.floor((mu1 + _WIDTH * sd1 - o1) / h1 + 0.5))
                lo2 = int(math.floor((mu2 - _WIDTH * sd2 - o2) / h2 + 0.5))
                hi2 = int(math.floor((mu2 + _WIDTH * sd2 - o2) / h2 + 0.5))
                lo1 = max(lo1, 0)
                lo2 = max(lo2, 0)
                hi1 = min(hi1, n1 - 1)
                hi2 = min(hi2, n2 - 1)
                inside = 0.0
                for a in range(lo1, hi1 + 1):
                    c1 = o1 + a * h1
                    p1[a] = interval_mass(c1 - 0.5 * h1, c1 + 0.5 * h1, mu1, sd1)
                for b in range(lo2, hi2 + 1):
                    c2 = o2 + b * h2
                    p2[b] = interval_mass(c2 - 0.5 * h2, c2 + 0.5 * h2, mu2, sd2)
                for a in range(lo1, hi1 + 1):
                    c1 = o1 + a * h1
                    for b in range(lo2, hi2 + 1):
                        tmp[a, b] = 0.0
                        v = p1[a] * p2[b]
                        if v < _CUT:
                            continue
                        c2 = o2 + b * h2
                        kind = classify(c1, c2, h1, h2, E, bound)
                        if kind == 2:
                            continue
                        if kind == 1:
                            v = cut_mass(c1 - 0.5 * h1, c1 + 0.5 * h1, c2 - 0.5 * h2,
                                         c2 + 0.5 * h2, mu1, sd1, mu2, sd2, ex, ey, bound,
                                         gl_x, gl_w)
                            if v < _CUT:
                                continue
                        tmp[a, b] = v
                        inside += v
                if inside >= 0.5 * stay:
                    break
                n_fallback += 1
            if inside <= 0.0:
                if stay > max_gap:
                    max_gap = stay
                status = LOST_MASS
                continue
            gap = abs(inside - stay)
            if gap > max_gap:
                max_gap = gap
            scale = w[j] * stay / inside
            for a in range(lo1, hi1 + 1):
                for b in range(lo2, hi2 + 1):
                    scratch[a, b] += scale * tmp[a, b]
                    tmp[a, b] = 0.0
            lo1_all = min(lo1_all, lo1)
            hi1_all = max(hi1_all, hi1)
            lo2_all = min(lo2_all, lo2)
            hi2_all = max(hi2_all, hi2)
            for i in range(3):
                absorbed[i] += w[j] * part[i]
        # emit the row: split every target cell between the two levels around s_next
        row_start = n_vals
        for a in range(lo1_all, hi1_all + 1):
            for b in range(lo2_all, hi2_all + 1):
                v = scratch[a, b]
                if v == 0.0:
                    continue
                scratch[a, b] = 0.0
                n_out = 1
                lv0 = 0
                sh0 = v
                lv1 = 0
                sh1 = 0.0
                if n_levels > 1:
                    lv0 = l0
                    if frac > 0.0:
                        up_bound = theta - (s_lo + (l0 + 1) * hs) / 3.0
                        if classify(o1 + a * h1, o2 + b * h2, h1, h2, E, up_bound) != 2:
                            n_out = 2
                            sh0 = v * (1.0 - frac)
                            lv1 = l0 + 1
                            sh1 = v * frac
                for side in range(n_out):
                    lv = lv0 if side == 0 else lv1
                    share = sh0 if side == 0 else sh1
                    if share <= 0.0:
                        continue
                    t = index[lv, a, b]
                    if t < 0:
                        if n_states >= max_states:
                            status = TOO_MANY_STATES
                            break
                        if n_states == pos.shape[0]:
                            cap = 2 * pos.shape[0]
                            pos2 = np.empty((cap, 2))
                            pos2[:n_states] = pos[:n_states]
                            pos = pos2
                            lev2 = np.empty(cap, dtype=np.int64)
                            lev2[:n_states] = lev[:n_states]
                            lev = lev2
                            ab2 = np.zeros((cap, 3))
                            ab2[:n_states] = absorb[:n_states]
                            absorb = ab2
                            rp2 = np.zeros(cap + 1, dtype=np.int64)
                            rp2[:n_states + 1] = row_ptr[:n_states + 1]
                            row_ptr = rp2
                        c1 = o1 + a * h1
                        c2 = o2 + b * h2
                        lb = theta - (s_lo + lv * hs) / 3.0
                        g1 = c1
                        g2 = c2
                        if classify(c1, c2, h1, h2, E, lb) == 1:
                            g1, g2, _ok = centroid(c1, c2, h1, h2, E, lb)
                        pos[n_states, 0] = g1
                        pos[n_states, 1] = g2
                        lev[n_states] = lv
                        t = n_states
                        index[lv, a, b] = t
                        n_states += 1
                    if n_vals == cols.shape[0]:
                        vcap = 2 * cols.shape[0]
                        c2a = np.empty(vcap, dtype=np.int64)
                        c2a[:n_vals] = cols[:n_vals]
                        cols = c2a
                        v2a = np.empty(vcap)
                        v2a[:n_vals] = vals[:n_vals]
                        vals = v2a
                    cols[n_vals] = t
                    vals[n_vals] = share
                    n_vals += 1
                if status == TOO_MANY_STATES:
                    break
            if status == TOO_MANY_STATES:
                break
        if status == TOO_MANY_STATES:
            break
        if r < 0:
            start_cols = cols[row_start:n_vals].copy()
            start_vals = vals[row_start:n_vals].copy()
            n_vals = row_start
            for i in range(3):
                start_abs[i] = absorbed[i]
        else:
            row_ptr[r + 1] = n_vals
            for i in range(3):
                absorb[r, i] = absorbed[i]
        r += 1
    return (status, pos[:n_states].copy(), lev[:n_states].copy(), row_ptr[:n_states + 1].copy(),
            cols[:n_vals].copy(), vals[:n_vals].copy(), absorb[:n_states].copy(), start_cols,
            start_vals, start_abs, max_gap, n_fallback)
