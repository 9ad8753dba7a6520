"""Tests of the three-option chain's edge terms (``mdft._plane_boundary``,
``threshold_probabilities(..., edge_correction=True)``).

The terms are checked where they come from: one Gaussian step near a threshold line, whose
staying walkers' mean of a quadratic ``V`` has a closed form. A row of the chain (narrowed
Gaussian on the cells, cut cells at their centroids, scaled to the exact probability of
staying) misses it by a term of second order in the cell size; with the edge terms the
miss is of third order. Then the call itself, against simulation on random models.
"""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.stats import norm

import mdft
from mdft import _plane, _plane_boundary

from threshold_models import assert_within_stated_error, canonical, random_model, SETS


def _lines(alpha, bound):
    """Three threshold lines in the form the kernels take: line 0 at angle ``alpha`` with
    ``bound`` (its gradient of norm 0.8), lines 1 and 2 far away (``bound`` >= 1)."""
    ex = (0.8 * math.cos(alpha), -0.01, 0.01)
    ey = (0.8 * math.sin(alpha), 0.0, -0.01)
    return ex, ey, 0.8 * bound


@settings(deadline=None, max_examples=300)
@given(c1=st.floats(-2.0, 2.0), c2=st.floats(-2.0, 2.0), h1=st.floats(0.1, 2.0),
       h2=st.floats(0.1, 2.0), bound=st.floats(0.2, 2.0),
       g=st.lists(st.floats(-1.0, 1.0), min_size=6, max_size=6))
def test_inside_centroid_is_that_of_the_clipped_cell(c1, c2, h1, h2, bound, g):
    """The exact area and centroid of a cell's part inside ``{ex[i] z1 + ey[i] z2 < bound}``
    equal those of a fine midpoint rule (400 x 400 points)."""
    ex, ey = tuple(g[:3]), tuple(g[3:])
    m = 400
    x = c1 - 0.5 * h1 + (np.arange(m) + 0.5) * h1 / m
    y = c2 - 0.5 * h2 + (np.arange(m) + 0.5) * h2 / m
    X, Y = np.meshgrid(x, y, indexing="ij")
    inside = np.ones(X.shape, dtype=bool)
    for i in range(3):
        inside &= ex[i] * X + ey[i] * Y < bound
    g1, g2, area = _plane_boundary.inside_centroid(c1, c2, h1, h2, ex, ey, bound,
                                                    np.empty((4, 8)))
    assert area == pytest.approx(inside.mean() * h1 * h2, abs=0.01 * h1 * h2)
    if inside.mean() > 0.05:
        assert g1 == pytest.approx(X[inside].mean(), abs=0.01 * h1)
        assert g2 == pytest.approx(Y[inside].mean(), abs=0.01 * h2)
    if area == 0.0:
        assert (g1, g2) == (c1, c2)


def _quadratic(c, x, y):
    """``V(x, y) = c0 + c1 x + c2 y + c3 x^2 + 2 c4 x y + c5 y^2``."""
    return c[0] + c[1] * x + c[2] * y + c[3] * x * x + 2 * c[4] * x * y + c[5] * y * y


def _exact_mean(mu, sd, alpha, bound, c):
    """``E[V(Z) 1{n . Z < bound}]`` for ``Z ~ N(mu, diag(sd)^2)``, ``n`` at angle ``alpha``:
    with ``Z = mu + diag(sd) U``, in the coordinates of ``U`` across the line (truncated above)
    and along it."""
    n = np.array([math.cos(alpha), math.sin(alpha)])
    D = np.diag(sd)
    g = D @ n
    m = g / np.linalg.norm(g)
    t = np.array([-m[1], m[0]])
    d = (bound - n @ mu) / np.linalg.norm(g)
    m0, m1, m2 = norm.cdf(d), -norm.pdf(d), norm.cdf(d) - d * norm.pdf(d)
    lin = np.array([c[1], c[2]])
    quad = np.array([[c[3], c[4]], [c[4], c[5]]])
    lin_u = D @ (lin + 2 * quad @ mu)
    quad_u = D @ quad @ D
    return (_quadratic(c, mu[0], mu[1]) * m0 + (lin_u @ m) * m1 + (m @ quad_u @ m) * m2
            + (t @ quad_u @ t) * m0)


def _row_mean(mu, sd, alpha, bound, r, offset, c, edge):
    """The same mean over one row of the chain: cells of ``r`` standard deviations along each
    axis (origin ``offset``), the Gaussian narrowed by ``h_k^2 / 12`` along axis ``k``, cut
    cells at the centroids of their inside parts, the row scaled to the exact probability of
    staying; with ``edge``, the edge terms added. Also returns the weight that the terms
    added in all, less the mass they took from the row (zero)."""
    ex, ey, b = _lines(alpha, bound)
    h1, h2 = r * sd[0], r * sd[1]
    s1, s2 = math.sqrt(sd[0] ** 2 - h1 * h1 / 12.0), math.sqrt(sd[1] ** 2 - h2 * h2 / 12.0)
    n_cells = int(math.ceil(30.0 / r))
    o1 = offset[0] * h1 - (n_cells // 2) * h1
    o2 = offset[1] * h2 - (n_cells // 2) * h2
    reach = tuple(0.5 * (abs(ex[i]) * h1 + abs(ey[i]) * h2) for i in range(3))
    centres1 = o1 + h1 * np.arange(n_cells)
    centres2 = o2 + h2 * np.arange(n_cells)
    C1, C2 = np.meshgrid(centres1, centres2, indexing="ij")
    T = [ex[i] * C1 + ey[i] * C2 for i in range(3)]
    outside = np.any([T[i] - reach[i] >= b for i in range(3)], axis=0)
    cut = ~outside & np.any([T[i] + reach[i] >= b for i in range(3)], axis=0)
    m1 = norm.cdf((centres1 + h1 / 2 - mu[0]) / s1) - norm.cdf((centres1 - h1 / 2 - mu[0]) / s1)
    m2 = norm.cdf((centres2 + h2 / 2 - mu[1]) / s2) - norm.cdf((centres2 - h2 / 2 - mu[1]) / s2)
    mass = np.where(outside, 0.0, np.outer(m1, m2))
    P1, P2 = C1.copy(), C2.copy()
    poly = np.empty((4, 8))
    cuts = []
    for a, bb in zip(*np.nonzero(cut)):
        mass[a, bb] = _plane.cut_mass(C1[a, bb] - h1 / 2, C1[a, bb] + h1 / 2, C2[a, bb] - h2 / 2,
                                      C2[a, bb] + h2 / 2, mu[0], s1, mu[1], s2, ex, ey, b)
        P1[a, bb], P2[a, bb], area = _plane_boundary.inside_centroid(
            C1[a, bb], C2[a, bb], h1, h2, ex, ey, b, poly)
        if mass[a, bb] > 0.0:
            cuts.append((a, bb))
    n = np.array([math.cos(alpha), math.sin(alpha)])
    stay = norm.cdf((bound - n @ mu) / np.linalg.norm(np.asarray(sd) * n))
    row = mass / mass.sum() * stay
    if not edge:
        return float((row * _quadratic(c, P1, P2)).sum()), 0.0
    scratch = np.zeros_like(row)
    box = np.array([n_cells, -1, n_cells, -1])
    cuts = np.array(cuts, dtype=np.int64).reshape(-1, 2)
    moved = _plane_boundary.add_edge_terms(cuts, cuts.shape[0], o1, o2, h1, h2, n_cells,
                                           n_cells, ex, ey, reach, b, mu[0], mu[1], s1, s2,
                                           1.0, scratch, box, poly)
    row = row * (stay - moved) / stay + scratch
    return float((row * _quadratic(c, P1, P2)).sum()), float(scratch.sum() - moved)


def _misses(seed, rs):
    """A random step near a random line and a random quadratic ``V``: the row's miss of the
    exact mean at each cell size (``rs``, in standard deviations), without and with the
    edge terms. The standard deviations along the axes differ (each from 0.5 to 2), as the
    grid's do."""
    rng = np.random.default_rng(seed)
    alpha = rng.uniform(0.0, 2 * math.pi)
    n = np.array([math.cos(alpha), math.sin(alpha)])
    sd = np.exp(rng.uniform(math.log(0.5), math.log(2.0), 2))
    spread = float(np.linalg.norm(sd * n))  # the step's standard deviation across the line
    bound = rng.uniform(1.0, 4.0) * spread
    # the mean from 1 standard deviation beyond the line to 2 inside it
    mu = ((bound - spread * rng.uniform(-1.0, 2.0)) * n
          + rng.uniform(-2.0, 2.0) * np.array([-n[1], n[0]]))
    c = np.concatenate([rng.normal(size=3), 0.2 * rng.normal(size=3)])
    offset = rng.uniform(-0.5, 0.5, 2)
    exact = _exact_mean(mu, sd, alpha, bound, c)
    out = []
    for r in rs:
        plain, _ = _row_mean(mu, sd, alpha, bound, r, offset, c, False)
        corrected, leak = _row_mean(mu, sd, alpha, bound, r, offset, c, True)
        assert abs(leak) < 1e-12
        out.append((plain - exact, corrected - exact))
    return np.array(out)


def test_edge_terms_leave_a_rows_mean_a_third_order_miss():
    """Over 12 random steps near an oblique line (the mean from one standard deviation beyond
    it to two inside, any angle, any placement of the grid, standard deviations of 0.5-2
    along the axes and cells in proportion), the row's miss of the exact mean of a quadratic
    ``V`` falls by about 4 from cells of 0.5 to 0.25 standard deviations without the edge
    terms (second order: 4.0 on these steps) and by about 8 with them (third order:
    8.1); at 0.25 the terms leave 21 % of the miss (14 % on 40 other steps). The
    terms move no mass."""
    misses = np.array([_misses(seed, (0.5, 0.25)) for seed in range(12)])  # (seed, h, kind)
    total = np.abs(misses).sum(axis=0)
    plain_rate = total[0, 0] / total[1, 0]
    edge_rate = total[0, 1] / total[1, 1]
    assert 3.0 < plain_rate < 5.0, plain_rate
    assert edge_rate > 6.0, edge_rate
    assert total[1, 1] < 0.25 * total[1, 0], total


@pytest.mark.parametrize("seed", [1, 3, 6])
def test_the_corrected_chain_is_within_its_stated_error_of_simulation(seed):
    """Random three-option models of the documented range (one option chosen after about
    128 steps; 95 % and 4 % options after 11-13; one after 181): the chain with the edge
    terms answers, and is within its own error estimate (no further slack) of 200,000
    simulated trials, up to 4 standard errors."""
    model, theta = random_model(np.random.default_rng(seed), 3)
    res = mdft.threshold_probabilities(model, theta, edge_correction=True, fallback="raise")
    assert res.engine == "plane"
    assert_within_stated_error(res, model, theta, 200_000, seed)


def test_the_corrected_and_default_chains_agree_within_their_estimates():
    """The compromise set at theta = 10: the two chains' answers differ by less than the sum
    of their error estimates."""
    model = canonical(SETS["compromise"])
    plain = mdft.threshold_probabilities(model, 10.0, fallback="raise")
    edge = mdft.threshold_probabilities(model, 10.0, edge_correction=True, fallback="raise")
    assert edge.engine == plain.engine == "plane"
    gap = np.abs(edge.probabilities - plain.probabilities).max()
    assert gap <= edge.error_probabilities + plain.error_probabilities
    rel = np.abs(edge.mean_response_times / plain.mean_response_times - 1.0).max()
    assert rel <= edge.error_mean_rt + plain.error_mean_rt


def test_edge_correction_takes_a_bool_and_three_options():
    model = canonical(SETS["compromise"])
    with pytest.raises(TypeError, match=r"edge_correction must be True or False \(got 'yes'\)"):
        mdft.threshold_probabilities(model, 12.0, edge_correction="yes")
    binary = canonical([(1.0, 3.0), (3.0, 1.0)])
    with pytest.raises(ValueError, match=r"edge_correction corrects the three-option chain "
                                         r"\(got a model with 2 options\)"):
        mdft.threshold_probabilities(binary, 12.0, edge_correction=True)
