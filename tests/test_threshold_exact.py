"""Tests of mdft.threshold_probabilities, the lattice method for threshold stopping.

References used here:

* gambler's ruin (noise-free walk with steps of +-1): exact closed forms in
  discrete time, which the lattice reproduces to rounding when its cell
  centres sit on the walk's positions;
* the Wiener first-passage formulas for a Brownian motion with drift between
  two barriers, with Siegmund's continuity correction for a discrete-time
  Gaussian walk;
* a Nystrom solution of the first-passage integral equations on a fine grid
  (density at points, plain NumPy), independent of the lattice code;
* the Monte Carlo engine, mdft.simulate, on the canonical context-effect sets.

Two options with the MDFT contrast: with ``P0 = 0`` and the parametric ``S``
(symmetric, equal row sums), ``P1 + P2`` stays 0, so ``x = P1 = -P2`` and

    x(t+1) = lam x(t) + (M[0, j] - M[1, j]) + eps1 - eps2,
    lam = S[0, 0] - S[0, 1] = 1 - phi2 + phi2 exp(-phi1 D12**2),

a one-dimensional walk with Gaussian-mixture steps of noise variance
``2 sigma2``, absorbed at ``x >= theta`` (option 0) and ``x <= -theta``
(option 1). With ``phi2 = 0``, ``S = I`` and ``lam = 1``; with one attribute
the drift per step is constant, ``d = M[0, 0] - M[1, 0]``.
"""

import json
import math
import os
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.special import ndtr

import mdft
from mdft import MDFTModel, threshold_probabilities

# Siegmund's constant: a Gaussian random walk with step sd s stopped at a
# barrier a behaves like Brownian motion stopped at a + RHO * s.
RHO = 0.5825971579390106

A, B = (1.0, 3.0), (3.0, 1.0)
CANONICAL = dict(phi1=0.022, phi2=0.05, beta=12.0, sigma2=1.0)
SETS = {
    "similarity": [A, B, (0.9, 3.1)],
    "compromise": [A, B, (2.0, 2.0)],
    "attraction": [A, B, (0.5, 2.5)],
}


def plain(M, w, sigma2=1.0):
    """A model with ``S = I`` (phi2 = 0), whose spectral radius 1 warns by design."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", mdft.UnstableFeedbackWarning)
        return MDFTModel(M, w, phi1=0.0, phi2=0.0, beta=1.0, sigma2=sigma2)


def canonical(options, w=(0.5, 0.5)):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", mdft.UnstableFeedbackWarning)
        return MDFTModel(options, list(w), **CANONICAL)


def nystrom_binary(model, theta, n_grid=1500):
    """First-passage probabilities and conditional mean times of the binary walk.

    Solves ``u(x) = b(x) + int K(x, y) u(y) dy`` on a midpoint grid of
    ``(-theta, theta)`` with the Gaussian density at the grid points.
    """
    S = model.S
    lam = S[0, 0] - S[0, 1]
    a = model.M[0] - model.M[1]
    w = model.w
    sd = math.sqrt(2.0 * model.sigma2)
    dy = 2 * theta / n_grid
    y = -theta + dy * (np.arange(n_grid) + 0.5)

    def kernel(x):
        mean = lam * np.asarray(x)[:, None, None] + a[None, :, None]
        dens = np.exp(-0.5 * ((y[None, None, :] - mean) / sd) ** 2) / (sd * math.sqrt(2 * math.pi))
        K = (w[None, :, None] * dens).sum(axis=1) * dy
        up = (w[None, :] * ndtr((mean[:, :, 0] - theta) / sd)).sum(axis=1)
        down = (w[None, :] * ndtr((-theta - mean[:, :, 0]) / sd)).sum(axis=1)
        return K, up, down

    K, up, down = kernel(y)
    I = np.eye(n_grid)
    U = np.linalg.solve(I - K, np.column_stack([up, down]))
    V = np.linalg.solve(I - K, U)  # E[T 1{option}] from each grid point
    K0, up0, down0 = kernel([0.0])
    probs = np.array([up0[0], down0[0]]) + K0[0] @ U
    weighted = probs + K0[0] @ V
    return probs, weighted / probs


# ---------------------------------------------------------------- exact references
@pytest.mark.parametrize("method", ["solve", "propagate"])
def test_gamblers_ruin_is_reproduced_exactly(method):
    # steps +1 with probability p, -1 otherwise; absorbed at +-5 (theta = 4.5)
    p = 0.6
    q = 1 - p
    model = plain([[1, 0], [0, 1]], [p, q], sigma2=0.0)
    # 2*sqrt(2)*35 cells rounds up to 99 = 9 * 11: the cell centres lie on the
    # walk's positions sqrt(2) * k in the lattice coordinate (P1 - P2) / sqrt(2)
    with pytest.warns(RuntimeWarning, match="noise is zero"):
        res = threshold_probabilities(model, 4.5, n_cells=35, method=method)
    r, N = q / p, 5
    win = (1 - r**N) / (1 - r ** (2 * N))
    duration = N / (q - p) - 2 * N / (q - p) * win
    tol = 1e-10 if method == "solve" else 1e-7
    np.testing.assert_allclose(res.probabilities, [win, 1 - win], atol=tol)
    assert res.probabilities @ res.mean_response_times == pytest.approx(duration, rel=tol)


@pytest.mark.parametrize("drift, theta", [(0.1, 20.0), (0.05, 30.0), (0.0, 20.0)])
def test_wiener_first_passage_with_continuity_correction(drift, theta):
    # One attribute, phi2 = 0: x = P1 is a Gaussian walk with drift `drift` and
    # step variance 2 sigma2 = 2. The Wiener formulas for barriers +-a,
    #   Pr(+a first) = 1 / (1 + exp(-2 mu a / s^2)),  E[T] = (a / mu) tanh(mu a / s^2),
    # hold for the discrete-time walk with a = theta + RHO * s (Siegmund 1979);
    # the remaining error is O(s^2 / theta^2) in probability and a fraction of a step
    # in time. Without the correction the probability is off by about 0.008 here.
    model = plain([[drift], [0.0]], [1.0])
    res = threshold_probabilities(model, theta, n_cells=100, method="solve")
    s = math.sqrt(2.0)
    a = theta + RHO * s
    if drift > 0:
        p_win = 1 / (1 + math.exp(-2 * drift * a / s**2))
        mean_t = a / drift * math.tanh(drift * a / s**2)
    else:
        p_win, mean_t = 0.5, a * a / s**2
    assert res.probabilities[0] == pytest.approx(p_win, abs=2e-4)
    assert res.probabilities @ res.mean_response_times == pytest.approx(mean_t, rel=3e-3)


def test_binary_walk_matches_nystrom_reference():
    # feedback lam < 1, unequal attention: no closed form; compare with an
    # independent quadrature of the same discrete-time process
    model = canonical([A, B], w=(0.6, 0.4))
    probs, times = nystrom_binary(model, 17.5)
    res = threshold_probabilities(model, 17.5, method="solve")
    np.testing.assert_allclose(res.probabilities, probs, atol=2e-4)
    np.testing.assert_allclose(res.mean_response_times, times, rtol=2e-3)
    prop = threshold_probabilities(model, 17.5)  # geometric tail at tail_tol=1e-7
    np.testing.assert_allclose(prop.probabilities, res.probabilities, atol=1e-6)
    np.testing.assert_allclose(prop.mean_response_times, res.mean_response_times, rtol=1e-5)


def test_refining_the_lattice_reduces_the_error():
    model = canonical([A, B], w=(0.6, 0.4))
    probs, times = nystrom_binary(model, 17.5, n_grid=2500)
    errors = []
    for n_cells in (8, 16, 32):
        res = threshold_probabilities(model, 17.5, n_cells=n_cells, method="solve")
        errors.append(abs(res.mean_response_times[0] - times[0]))
    assert all(e2 < e1 for e1, e2 in zip(errors, errors[1:]))


# ---------------------------------------------------------------- against Monte Carlo
@pytest.mark.parametrize("name", sorted(SETS))
def test_canonical_sets_agree_with_monte_carlo(name):
    # 40_000 trials: standard errors <= 0.0025, so 0.01 is 4 of them; the
    # lattice at n_cells=8 is within about 0.002 of its limit (docs table)
    model = canonical(SETS[name])
    exact = threshold_probabilities(model, 17.5, n_cells=8)
    sim = mdft.simulate(model, 40_000, stopping=mdft.Threshold(17.5, max_steps=10_000), rng=1)
    assert exact.p_undecided < 1e-6
    np.testing.assert_allclose(exact.probabilities, sim.probabilities, atol=0.01)
    assert np.all(np.abs(exact.probabilities - sim.probabilities) < 4 * sim.standard_errors + 0.003)
    # mean response times of the options chosen in at least 100 trials: within 4 standard
    # errors of the Monte Carlo mean plus the lattice's documented 2 % at n_cells=8
    for i in np.flatnonzero(sim.counts >= 100):
        rt = sim.response_times(i)
        se = rt.std(ddof=1) / math.sqrt(rt.size)
        gap = abs(exact.mean_response_times[i] - rt.mean())
        assert gap < 4 * se + 0.02 * rt.mean(), (i, exact.mean_response_times[i], rt.mean(), se)


def test_binary_canonical_is_symmetric():
    res = threshold_probabilities(canonical([A, B]), 17.5)
    np.testing.assert_allclose(res.probabilities, [0.5, 0.5], atol=1e-9)
    assert res.n_levels == 1  # the summed preference stays 0: a one-dimensional lattice
    assert res.mean_response_times[0] == pytest.approx(res.mean_response_times[1], rel=1e-9)


# ---------------------------------------------------------------- invariants
def test_distribution_accounts_for_all_mass():
    model = canonical(SETS["compromise"])
    res = threshold_probabilities(model, 10.0, max_steps=60, n_cells=6)
    assert res.rt_pmf.shape == (60, 3)
    assert res.p_undecided > 0.05
    np.testing.assert_allclose(res.rt_pmf.sum(axis=0), res.probabilities, atol=1e-12)
    assert res.probabilities.sum() + res.p_undecided == pytest.approx(1.0, abs=1e-10)
    assert np.all(res.rt_pmf >= 0)
    # a longer run agrees step by step on the first 60 steps
    longer = threshold_probabilities(model, 10.0, max_steps=500, n_cells=6)
    np.testing.assert_allclose(longer.rt_pmf[:60], res.rt_pmf, atol=1e-12)


def test_solve_and_propagate_agree_for_three_options():
    model = canonical(SETS["attraction"])
    prop = threshold_probabilities(model, 10.0, n_cells=6, tail_tol=0.0)
    solved = threshold_probabilities(model, 10.0, n_cells=6, method="solve", tol=1e-12)
    assert solved.rt_pmf is None and solved.p_undecided == 0.0
    np.testing.assert_allclose(prop.probabilities, solved.probabilities, atol=1e-8)
    np.testing.assert_allclose(prop.mean_response_times[:2], solved.mean_response_times[:2],
                               rtol=1e-6)


def test_iterative_solver_and_its_warning(monkeypatch):
    from mdft import threshold_exact

    model = canonical(SETS["compromise"])
    direct = threshold_probabilities(model, 10.0, n_cells=6, method="solve")
    monkeypatch.setattr(threshold_exact, "_DIRECT_SOLVE_MAX_STATES", 0)
    gmres = threshold_probabilities(model, 10.0, n_cells=6, method="solve", tol=1e-12)
    assert gmres.converged and gmres.n_iter > 0 and direct.n_iter == 0
    np.testing.assert_allclose(gmres.probabilities, direct.probabilities, atol=1e-8)
    with pytest.warns(RuntimeWarning, match="did not reach tol"):
        bad = threshold_probabilities(model, 10.0, n_cells=6, method="solve", max_iter=1)
    assert not bad.converged


def test_geometric_tail_matches_full_propagation():
    model = canonical(SETS["similarity"])
    full = threshold_probabilities(model, 10.0, n_cells=6, tail_tol=0.0)
    tail = threshold_probabilities(model, 10.0, n_cells=6)
    assert tail.tail_start is not None and full.tail_start is None
    assert tail.n_iter < full.n_iter
    np.testing.assert_allclose(tail.probabilities, full.probabilities, atol=1e-7)
    np.testing.assert_allclose(tail.rt_pmf, full.rt_pmf, atol=1e-8)


@settings(deadline=None, max_examples=15)
@given(
    a=st.lists(st.floats(0.0, 4.0), min_size=2, max_size=2),
    b=st.lists(st.floats(0.0, 4.0), min_size=2, max_size=2),
    w0=st.floats(0.05, 0.95),
    phi2=st.floats(0.0, 0.1),
    sigma2=st.floats(0.3, 3.0),
    theta=st.floats(2.0, 15.0),
)
def test_binary_invariants(a, b, w0, phi2, sigma2, theta):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = MDFTModel([a, b], [w0, 1 - w0], phi1=0.02, phi2=phi2, beta=2.0, sigma2=sigma2)
        swapped = MDFTModel([b, a], [w0, 1 - w0], phi1=0.02, phi2=phi2, beta=2.0, sigma2=sigma2)
        res = threshold_probabilities(model, theta, max_steps=400, n_cells=20)
        res_sw = threshold_probabilities(swapped, theta, max_steps=400, n_cells=20)
    assert np.all(res.probabilities >= 0) and 0.0 <= res.p_undecided <= 1.0
    assert res.probabilities.sum() + res.p_undecided == pytest.approx(1.0, abs=1e-9)
    np.testing.assert_allclose(res.rt_pmf.sum(axis=0), res.probabilities, atol=1e-12)
    # swapping the two options mirrors the one-dimensional lattice exactly
    np.testing.assert_allclose(res_sw.probabilities, res.probabilities[::-1], atol=1e-9)


def test_permuting_options_permutes_probabilities():
    options = SETS["compromise"]
    order = [2, 0, 1]
    res = threshold_probabilities(canonical(options), 10.0, n_cells=8)
    perm = threshold_probabilities(canonical([options[i] for i in order]), 10.0, n_cells=8)
    # the lattice is laid out differently for the two orders: agreement to lattice error
    np.testing.assert_allclose(perm.probabilities, res.probabilities[order], atol=3e-3)


_SMALL_CASE = """
import json, warnings
import mdft
warnings.simplefilter("ignore")
S = [[0.95, -0.02], [-0.05, 0.97]]  # a moving summed preference: a two-dimensional lattice
model = mdft.MDFTModel.from_matrices([[1, 3], [3, 1]], [0.6, 0.4], S=S)
res = mdft.threshold_probabilities(model, 4.0, n_cells=6, max_steps=300)
print(json.dumps([res.probabilities.tolist(), res.mean_response_times.tolist()]))
"""


def test_compiled_and_interpreted_kernels_agree():
    root = Path(__file__).resolve().parents[1]
    out = []
    for disable in ("0", "1"):
        env = dict(os.environ, NUMBA_DISABLE_JIT=disable)
        run = subprocess.run([sys.executable, "-c", _SMALL_CASE], cwd=root, env=env,
                             capture_output=True, text=True, timeout=300, check=True)
        out.append(json.loads(run.stdout.strip().splitlines()[-1]))
    np.testing.assert_allclose(out[0][0], out[1][0], rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(out[0][1], out[1][1], rtol=1e-12)


def test_result_is_frozen_and_reports_the_lattice():
    res = threshold_probabilities(canonical([A, B]), 5.0, n_cells=20)
    assert res.n_cells == 20 and res.spacing == pytest.approx(0.25)
    assert res.theta == 5.0 and res.method == "propagate"
    with pytest.raises(AttributeError, match="cannot assign to field 'theta'"):
        res.theta = 1.0


# ---------------------------------------------------------------- bad input
def test_bad_theta():
    model = canonical([A, B])
    with pytest.raises(ValueError, match="theta must be > 0"):
        threshold_probabilities(model, 0.0)
    with pytest.raises(ValueError, match="theta must be > 0"):
        threshold_probabilities(model, -3.0)
    with pytest.raises(ValueError, match="theta must be finite"):
        threshold_probabilities(model, float("inf"))
    with pytest.raises(TypeError, match="theta must be a real number"):
        threshold_probabilities(model, "17.5")


def test_bad_resolution_and_limits():
    model = canonical([A, B])
    with pytest.raises(ValueError, match="n_cells must be an integer >= 4"):
        threshold_probabilities(model, 5.0, n_cells=2)
    with pytest.raises(TypeError, match="n_cells must be an integer"):
        threshold_probabilities(model, 5.0, n_cells=10.5)
    with pytest.raises(ValueError, match="max_steps must be an integer >= 1"):
        threshold_probabilities(model, 5.0, max_steps=0)
    with pytest.raises(TypeError, match="max_steps must be an integer"):
        threshold_probabilities(model, 5.0, max_steps=1e3)
    with pytest.raises(ValueError, match="tol must be > 0"):
        threshold_probabilities(model, 5.0, tol=0.0)
    with pytest.raises(ValueError, match="tail_tol must be >= 0"):
        threshold_probabilities(model, 5.0, tail_tol=-1.0)
    with pytest.raises(ValueError, match="max_iter must be an integer >= 1"):
        threshold_probabilities(model, 5.0, max_iter=0)
    with pytest.raises(ValueError, match="method must be one of"):
        threshold_probabilities(model, 5.0, method="exact")
    with pytest.raises(TypeError, match="variance_correction must be True or False"):
        threshold_probabilities(model, 5.0, variance_correction="yes")
    with pytest.raises(ValueError, match="lattice states"):
        threshold_probabilities(canonical(SETS["compromise"]), 17.5, n_cells=10_000)


def test_coarse_lattice_warns():
    # spacing 17.5 / 5 = 3.5 against a per-step noise sd of 1.5 in the lattice plane
    with pytest.warns(RuntimeWarning, match=r"lattice spacing .* raise n_cells above 8"):
        threshold_probabilities(canonical(SETS["compromise"]), 17.5, n_cells=5, max_steps=5)


def test_default_resolution_follows_the_lattice_dimension():
    assert threshold_probabilities(canonical([A, B]), 5.0, max_steps=5).n_cells == 100
    S = np.array([[0.95, -0.02], [-0.05, 0.97]])  # unequal column sums: the sum moves
    moving = MDFTModel.from_matrices([A, B], [0.6, 0.4], S=S)
    res = threshold_probabilities(moving, 5.0, max_steps=5)
    assert res.n_cells == 25 and res.n_levels > 1
    assert threshold_probabilities(canonical(SETS["compromise"]), 5.0, max_steps=5).n_cells == 8


def test_two_options_with_a_moving_sum_agree_with_monte_carlo():
    S = np.array([[0.95, -0.02], [-0.05, 0.97]])
    model = MDFTModel.from_matrices([A, B], [0.6, 0.4], S=S)
    exact = threshold_probabilities(model, 10.0)
    sim = mdft.simulate(model, 40_000, stopping=mdft.Threshold(10.0), rng=3)
    # two options at the default n_cells=25: the lattice error is far below the standard
    # errors (0.0018 in probability), so both checks are stated in standard errors alone
    assert np.all(np.abs(exact.probabilities - sim.probabilities) < 4 * sim.standard_errors)
    for i in range(2):
        rt = sim.response_times(i)
        se = rt.std(ddof=1) / math.sqrt(rt.size)
        assert abs(exact.mean_response_times[i] - rt.mean()) < 4 * se


def test_too_many_options_points_to_simulation():
    model = canonical([A, B, (2.0, 2.0), (0.5, 2.5)])
    with pytest.raises(ValueError, match=r"4 options.*at most 3.*mdft.simulate"):
        threshold_probabilities(model, 17.5)


def test_bad_model():
    with pytest.raises(TypeError, match="model must be an MDFTModel"):
        threshold_probabilities({"M": [[1, 2]]}, 5.0)
    C = np.array([[1.0, 0.0], [0.0, 1.0]])
    model = MDFTModel.from_matrices([[1.0], [0.0]], [1.0], S=0.9 * np.eye(2), C=C)
    with pytest.raises(ValueError, match="columns summing to zero"):
        threshold_probabilities(model, 5.0)
    started = canonical([A, B]).replace(P0=[6.0, -6.0])
    with pytest.raises(ValueError, match="P0 must lie below theta"):
        threshold_probabilities(started, 5.0)
