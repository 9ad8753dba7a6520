"""Compiled boundary terms of the moment chain's rows (:mod:`mdft._plane_moment`).

Nothing here validates its input. A row spreads a step's staying mass over the cells with a
Gaussian narrowed by ``h_k^2 / 12`` along each axis ``k``, so that, inside the region, a
smooth function's mean over the cells (each at its centre, a cut cell at the centroid of its
inside part) matches its mean over the step to second order in the cell size. At the
region's edge the two leave terms of that order: for the expectation of a smooth ``V`` over
the staying walkers, the row falls short of the step by::

    (1 / 24) * line integral over the edge of
        sum_k h_k^2 n_k [f d_k V + d_k f (V - Vbar)] ds

where ``f`` is the step's density, ``n`` the edge's outward normal, and ``Vbar`` the mean of
``V`` over the row (the second term comes from scaling the row to the exact probability of
staying). :func:`add_edge_terms` adds them back: a sum over the cut cells, each holding a
piece of a threshold line, with ``f`` and its gradient at the piece's midpoint, and ``V``
and its gradient there taken from the cut cell and its two neighbours on the inner side. The
weights it adds sum to the ``Vbar`` term's, which the caller takes from the row in proportion
to its cells: the row's staying mass is unchanged.
"""

from __future__ import annotations

import math

from ._numba import njit


@njit
def _clip_polygon(xs, ys, n, gx, gy, bound, out_x, out_y):
    """The polygon ``(xs, ys)[:n]`` clipped to ``gx x + gy y < bound`` into
    ``out_x``, ``out_y``; returns its number of vertices."""
    m = 0
    for k in range(n):
        k2 = k + 1 if k + 1 < n else 0
        fa = gx * xs[k] + gy * ys[k] - bound
        fb = gx * xs[k2] + gy * ys[k2] - bound
        if fa < 0.0:
            out_x[m] = xs[k]
            out_y[m] = ys[k]
            m += 1
        if (fa < 0.0) != (fb < 0.0):
            t = fa / (fa - fb)
            out_x[m] = xs[k] + t * (xs[k2] - xs[k])
            out_y[m] = ys[k] + t * (ys[k2] - ys[k])
            m += 1
    return m


@njit
def inside_centroid(c1, c2, h1, h2, ex, ey, bound, poly):
    """Centroid of the part of the cell centred at ``(c1, c2)`` inside the region
    ``{ex[i] z1 + ey[i] z2 < bound}`` (exact: the rectangle clipped by the three
    half-planes); ``(c1, c2, 0.0)`` when nothing of it is inside, else ``(g1, g2, area)``.
    ``poly`` is work space of at least 4 x 8 entries."""
    xs = poly[0]
    ys = poly[1]
    xs[0] = c1 - 0.5 * h1
    ys[0] = c2 - 0.5 * h2
    xs[1] = c1 + 0.5 * h1
    ys[1] = c2 - 0.5 * h2
    xs[2] = c1 + 0.5 * h1
    ys[2] = c2 + 0.5 * h2
    xs[3] = c1 - 0.5 * h1
    ys[3] = c2 + 0.5 * h2
    n = 4
    src = 0
    for i in range(3):
        dst = 2 - src
        n = _clip_polygon(poly[src], poly[src + 1], n, ex[i], ey[i], bound, poly[dst],
                          poly[dst + 1])
        src = dst
        if n < 3:
            return c1, c2, 0.0
    xs = poly[src]
    ys = poly[src + 1]
    area = 0.0
    g1 = 0.0
    g2 = 0.0
    for k in range(n):
        k2 = k + 1 if k + 1 < n else 0
        # about the cell's centre, for accuracy
        x0 = xs[k] - c1
        y0 = ys[k] - c2
        x1 = xs[k2] - c1
        y1 = ys[k2] - c2
        cr = x0 * y1 - x1 * y0
        area += cr
        g1 += (x0 + x1) * cr
        g2 += (y0 + y1) * cr
    if area <= 0.0:
        return c1, c2, 0.0
    return c1 + g1 / (3.0 * area), c2 + g2 / (3.0 * area), 0.5 * area


@njit
def _below(t0, td, u_lo, u_hi):
    """``[u_lo, u_hi]`` narrowed to where ``t0 + u td < 0``; ``(u_lo, u_hi, ok)``, not ok
    when nothing of the line is there."""
    if abs(td) < 1e-14:
        return u_lo, u_hi, t0 < 0.0
    lim = -t0 / td
    if td > 0.0:
        return u_lo, min(u_hi, lim), True
    return max(u_lo, lim), u_hi, True


@njit
def _line_piece(i, c1, c2, h1, h2, ex, ey, bound):
    """The piece of threshold line ``i`` (``ex[i] z1 + ey[i] z2 = bound``) inside the cell
    centred at ``(c1, c2)`` and on the inner side of the other two lines: ``(length,
    p1, p2)`` with ``(p1, p2)`` its midpoint (length 0 when there is none)."""
    gx = ex[i]
    gy = ey[i]
    g2 = gx * gx + gy * gy
    # the line: z0 + u d, with d along it, cut by the cell's four sides and the other lines
    z01 = gx * bound / g2
    z02 = gy * bound / g2
    d1 = -gy
    d2 = gx
    lo1 = c1 - 0.5 * h1
    lo2 = c2 - 0.5 * h2
    u_lo, u_hi, ok = _below(lo1 - z01, -d1, -math.inf, math.inf)
    if ok:
        u_lo, u_hi, ok = _below(z01 - (lo1 + h1), d1, u_lo, u_hi)
    if ok:
        u_lo, u_hi, ok = _below(lo2 - z02, -d2, u_lo, u_hi)
    if ok:
        u_lo, u_hi, ok = _below(z02 - (lo2 + h2), d2, u_lo, u_hi)
    for k in range(3):
        if ok and k != i:
            u_lo, u_hi, ok = _below(ex[k] * z01 + ey[k] * z02 - bound, ex[k] * d1 + ey[k] * d2,
                                    u_lo, u_hi)
    if not ok or u_hi <= u_lo:
        return 0.0, c1, c2
    um = 0.5 * (u_lo + u_hi)
    return (u_hi - u_lo) * math.sqrt(g2), z01 + um * d1, z02 + um * d2


@njit
def _cell_inside(c1, c2, ex, ey, reach, bound):
    """Whether any of the cell centred at ``(c1, c2)`` may lie inside the region."""
    for i in range(3):
        if ex[i] * c1 + ey[i] * c2 - reach[i] >= bound:
            return False
    return True


@njit
def add_edge_terms(cuts, n_cut, o1, o2, h1, h2, n1, n2, ex, ey, reach, bound, mu1, mu2, sd1,
                   sd2, weight, scratch, box, poly):
    """Add ``weight`` times the edge terms of one Gaussian component (mean ``(mu1, mu2)``,
    standard deviations ``sd1``, ``sd2``) to ``scratch``, widening ``box``; the cut cells
    that received mass are ``cuts[:n_cut]`` (rows ``(a, b)``). Returns the sum ``b`` of the
    terms' weights on ``V`` at the pieces: the caller takes ``b`` times the row's shares (the
    ``Vbar`` term) from the row, which keeps its mass."""
    bsum = 0.0
    k1 = h1 * h1 / 24.0
    k2 = h2 * h2 / 24.0
    norm = 1.0 / (2.0 * math.pi * sd1 * sd2)
    for q in range(n_cut):
        a = cuts[q, 0]
        b = cuts[q, 1]
        c1 = o1 + a * h1
        c2 = o2 + b * h2
        g1, g2, area = inside_centroid(c1, c2, h1, h2, ex, ey, bound, poly)
        if area <= 0.0:
            continue
        for i in range(3):
            ell, p1, p2 = _line_piece(i, c1, c2, h1, h2, ex, ey, bound)
            if ell <= 0.0:
                continue
            gn = math.sqrt(ex[i] * ex[i] + ey[i] * ey[i])
            nx = ex[i] / gn
            ny = ey[i] / gn
            # the neighbours on the inner side along each axis
            a2 = a - 1 if nx >= 0.0 else a + 1
            b2 = b - 1 if ny >= 0.0 else b + 1
            if a2 < 0 or a2 >= n1 or b2 < 0 or b2 >= n2:
                continue
            # a neighbour outside the region (near a corner) leaves the piece out, as does
            # one whose clipped part is empty
            cx1 = o1 + a2 * h1
            cy2 = o2 + b2 * h2
            if (not _cell_inside(cx1, c2, ex, ey, reach, bound)
                    or not _cell_inside(c1, cy2, ex, ey, reach, bound)):
                continue
            x1, x2, area_x = inside_centroid(cx1, c2, h1, h2, ex, ey, bound, poly)
            y1, y2, area_y = inside_centroid(c1, cy2, h1, h2, ex, ey, bound, poly)
            if area_x <= 0.0 or area_y <= 0.0:
                continue
            # V(q) ~ V_c + G . (q - g), with G from M G = (V_c - V_x, V_c - V_y), the
            # rows of M being g - x and g - y
            m11 = g1 - x1
            m12 = g2 - x2
            m21 = g1 - y1
            m22 = g2 - y2
            det = m11 * m22 - m12 * m21
            if abs(det) <= 1e-12 * (h1 * h2):
                continue
            # the density and its gradient at the piece's midpoint
            u1 = (p1 - mu1) / sd1
            u2 = (p2 - mu2) / sd2
            f = norm * math.exp(-0.5 * (u1 * u1 + u2 * u2))
            f1 = -f * u1 / sd1
            f2 = -f * u2 / sd2
            # the terms: cv . grad V + cp (V(p) - Vbar)
            cv1 = ell * k1 * nx * f
            cv2 = ell * k2 * ny * f
            cp = ell * (k1 * nx * f1 + k2 * ny * f2)
            e1 = p1 - g1
            e2 = p2 - g2
            # G = M^-1 r: a vector c . G = (M^-T c) . r, r = (V_c - V_x, V_c - V_y)
            r1 = (m22 * (cv1 + cp * e1) - m21 * (cv2 + cp * e2)) / det
            r2 = (-m12 * (cv1 + cp * e1) + m11 * (cv2 + cp * e2)) / det
            scratch[a, b] += weight * (cp + r1 + r2)
            scratch[a2, b] -= weight * r1
            scratch[a, b2] -= weight * r2
            bsum += cp
            box[0] = min(box[0], a, a2)
            box[1] = max(box[1], a, a2)
            box[2] = min(box[2], b, b2)
            box[3] = max(box[3], b, b2)
    return bsum
