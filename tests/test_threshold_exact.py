"""Tests of mdft.threshold_probabilities: threshold stopping by absorbing Markov chains.

References used here:

* the Wiener first-passage formulas for a Brownian motion with drift between
  two barriers, with Siegmund's continuity correction for a discrete-time
  Gaussian walk;
* a Nystrom solution of the first-passage integral equations on a fine grid
  (density at points, plain NumPy), independent of the lattice code;
* the Monte Carlo engine, mdft.simulate, on random two- and three-option models
  drawn across the documented range and on the cases an earlier lattice got wrong.

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
import re
import subprocess
import sys
import warnings
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st
from scipy.special import ndtr

import mdft
from mdft import MDFTModel, _plane_passes, _threshold_solve, threshold_probabilities
from threshold_models import (A, B, CANONICAL, SETS, assert_matches_simulation,
                              assert_within_stated_error, canonical, drawn, plain, random_model)

# Siegmund's constant: a Gaussian random walk with step sd s stopped at a
# barrier a behaves like Brownian motion stopped at a + RHO * s.
RHO = 0.5825971579390106


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
        # loose tolerances: the coarse lattices are the point of this test
        res = threshold_probabilities(model, 17.5, n_cells=n_cells, method="solve", atol=0.5,
                                      rt_rtol=0.5)
        errors.append(abs(res.mean_response_times[0] - times[0]))
    assert all(e2 < e1 for e1, e2 in zip(errors, errors[1:]))


# ---------------------------------------------------------------- against Monte Carlo


@pytest.mark.parametrize("seed", [12, 13])
def test_random_ternary_models_agree_with_simulation(seed):
    # thresholds up to 20 keep the test fast; the benchmark covers 5-60 with 10**6 trials
    model, theta = random_model(np.random.default_rng(seed), 3, theta_range=(5.0, 20.0))
    res = threshold_probabilities(model, theta)
    assert res.engine == "plane"
    assert res.error_probabilities <= 1e-3 and res.error_mean_rt <= 3e-3
    assert_matches_simulation(res, model, theta, 50_000, seed)


@pytest.mark.parametrize("seed", [33, 34, 36])
def test_three_options_within_the_stated_error(seed):
    # random models whose feedback moves the summed preference (carried as moments): the
    # answer is within its own error estimate of a 200,000-trial simulation, or refused
    model, theta = random_model(np.random.default_rng(seed), 3, theta_range=(5.0, 25.0))
    assert np.ptp(model.S.sum(axis=0)) > 1e-3
    try:
        res = threshold_probabilities(model, theta, fallback="raise")
    except ValueError as exc:
        assert "cannot vouch" in str(exc) and "mdft.simulate" in str(exc)
        return
    assert_within_stated_error(res, model, theta, 200_000, seed)


@pytest.mark.parametrize("seed", [21, 22])
def test_random_binary_models_agree_with_simulation(seed):
    model, theta = random_model(np.random.default_rng(seed), 2)
    res = threshold_probabilities(model, theta)
    assert res.engine == "lattice"
    assert_matches_simulation(res, model, theta, 50_000, seed)


@pytest.mark.parametrize("seed", [31, 32, 33, 34, 35, 36])
def test_random_binary_models_with_a_moving_start_agree_with_simulation(seed):
    # random models across the documented range, each entry of the start uniform within
    # +-0.4 theta: the lattice with moving thresholds against the Monte Carlo engine
    rng = np.random.default_rng(seed)
    model, theta = random_model(rng, 2, theta_range=(5.0, 40.0))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", mdft.UnstableFeedbackWarning)
        model = model.replace(P0=rng.uniform(-0.4, 0.4, 2) * theta)
    res = threshold_probabilities(model, theta)
    assert res.engine in ("lattice", "bound") and res.n_levels == 1
    if res.engine == "lattice":
        assert_within_stated_error(res, model, theta, 100_000, seed)


# a two-option model whose summed preference moves (P0 sums to -3.9 and decays by 0.974 per
# step) and which decides by rare excursions: 40 % undecided after 10,000 steps
DRIFTING_SUM = dict(M=[[2.74829, 1.22471, 1.42913], [1.21077, 1.80356, 1.71555]],
                    w=[0.309942, 0.565592, 0.124466], phi1=0.0927564, phi2=0.0187506,
                    beta=4.304894, sigma2=0.358692, P0=[-2.997064, -0.914327])


def levels_only(monkeypatch):
    """Make the two-option lattice carry levels of the sum even where the sum moves alike on
    every walk (where the lattice with moving thresholds would answer)."""
    monkeypatch.setattr(mdft.threshold_exact, "moving_sum_steps", lambda model, theta: None)


def test_binary_lattice_with_levels_does_not_depend_on_where_the_thresholds_fall(monkeypatch):
    # With levels of the sum, the lattice's cells had edges on the thresholds of the lowest
    # level only, and where the walks settle (sum 0) a threshold fell anywhere within a cell:
    # n_cells 56, 60, 80 and 90 gave 0.6031, 0.5837, 0.5975 and 0.5931 for option 0, and 40
    # and 80 agreed, so the call answered 0.5975 with an estimate of 8e-4 (10^6 simulated
    # trials: 0.5918, se 0.0005). The edges now lie on the thresholds of the settled sum.
    levels_only(monkeypatch)
    model = MDFTModel(**DRIFTING_SUM)
    assert np.ptp(model.S.sum(axis=0)) < 1e-12 and abs(sum(DRIFTING_SUM["P0"])) > 3
    answers = [threshold_probabilities(model, 35.5567, n_cells=cells, atol=0.5, rt_rtol=0.5)
               for cells in (56, 60, 80, 90)]
    assert all(res.n_levels > 1 for res in answers)
    p = np.array([res.probabilities[0] for res in answers])
    assert np.ptp(p) < 3e-4, p
    assert abs(p.mean() - 0.5918) < 0.0025, p


def test_binary_lattice_with_moving_thresholds_converges_to_the_lattice_with_levels(
        monkeypatch):
    # The same model on the lattice whose thresholds move with the sum (no levels): every
    # cell count gives the same answer to 4e-4, converging from above (0.59321, 0.59301,
    # 0.59291 and 0.59284 at 40, 56, 80 and 160 cells), and the call agrees with the lattice
    # with levels of the sum, a discretisation of its own, within both estimates.
    model = MDFTModel(**DRIFTING_SUM)
    answers = [threshold_probabilities(model, 35.5567, n_cells=cells, atol=0.5, rt_rtol=0.5)
               for cells in (40, 56, 60, 80, 90)]
    assert all(res.engine == "lattice" and res.n_levels == 1 for res in answers)
    p = np.array([res.probabilities[0] for res in answers])
    assert np.ptp(p) < 4e-4 and np.all(np.diff(p) < 0), p
    moving = threshold_probabilities(model, 35.5567)
    levels_only(monkeypatch)
    levels = threshold_probabilities(model, 35.5567)
    assert levels.n_levels > 1
    room = moving.error_probabilities + levels.error_probabilities
    np.testing.assert_allclose(moving.probabilities, levels.probabilities, atol=room)
    assert abs(moving.p_undecided - levels.p_undecided) <= room
    np.testing.assert_allclose(moving.mean_response_times[0], levels.mean_response_times[0],
                               rtol=moving.error_mean_rt + levels.error_mean_rt)


# a shorter deliberation whose sum moves (P0 sums to -6)
SHORT_DRIFTING_SUM = dict(M=[[1.0, 3.0], [3.0, 1.2]], w=[0.55, 0.45], phi1=0.03, phi2=0.05,
                          beta=5.0, sigma2=1.0, P0=[-4.0, -2.0])


def uneven_sums(params):
    """The model of ``params`` with a feedback matrix whose column sums differ by 0.01, so
    that the summed preference depends on the walk (the lattice then carries levels)."""
    model = MDFTModel(**params)
    S = np.array(model.S)
    S[0, 0] -= 0.01
    return MDFTModel.from_matrices(params["M"], params["w"], S=S, sigma2=params["sigma2"],
                                   P0=params["P0"])


@pytest.mark.parametrize("seed", [15, 16])
def test_binary_lattice_with_moving_thresholds_agrees_with_simulation(seed):
    model = MDFTModel(**SHORT_DRIFTING_SUM)
    res = threshold_probabilities(model, 10.0)
    assert res.engine == "lattice" and res.n_levels == 1
    assert_within_stated_error(res, model, 10.0, 200_000, seed)
    # without a step limit: the steps while the sum moves, then the settled chain solved
    solved = threshold_probabilities(model, 10.0, method="solve")
    np.testing.assert_allclose(solved.probabilities, res.probabilities, atol=1e-9)
    np.testing.assert_allclose(solved.mean_response_times, res.mean_response_times, rtol=1e-6)


# a model of the random draws (seed 11, model 23, of scratch mvcmp.py) whose start sums to 2
CUT_START = dict(M=[[2.18962, 2.98139], [3.77633, 3.46553]], w=[0.501272, 0.498728],
                 phi1=0.0549674, phi2=0.0183468, beta=7.31551, sigma2=0.671499, P0=[2.0, 0.0])


def test_binary_lattice_cuts_the_cells_its_moving_thresholds_fall_in():
    # A start summing to 2 moves the thresholds inwards by up to 1.4 in z, within the cells
    # next to the settled thresholds. Where such a cell kept the whole of every step landing
    # in it (as the lattice with levels does), the mean time ran erratically, 1.1 % short at
    # 28 cells and still 0.2 % at 80 (102.47, 102.56, 102.83, 103.36 and 103.58 steps at 28,
    # 40, 55, 80 and 110 cells). Cut to the part inside the thresholds, with its mass at the
    # middle of that part, every cell count is within 0.03 % of 440 cells', as with a start
    # summing to zero.
    model = MDFTModel(**CUT_START)
    theta = 49.4861

    def mean_time(cells):
        res = threshold_probabilities(model, theta, n_cells=cells, atol=0.5, rt_rtol=0.5)
        assert res.engine == "lattice" and res.n_levels == 1
        return res.mean_response_times[1]

    fine = mean_time(440)
    coarse = np.array([mean_time(cells) for cells in (28, 40, 55, 80, 110)])
    assert np.all(np.abs(coarse / fine - 1.0) < 3e-4), (coarse, fine)
    # and the call's own answer is within its estimate of the finest lattice
    res = threshold_probabilities(model, theta)
    assert abs(res.mean_response_times[1] / fine - 1.0) <= res.error_mean_rt


def test_binary_lattice_with_moving_thresholds_within_a_short_step_limit():
    # a step limit within the steps while the sum moves: the answer is the stepped part alone
    for steps in (3, 20):
        model = MDFTModel(**SHORT_DRIFTING_SUM)
        res = threshold_probabilities(model, 10.0, max_steps=steps)
        assert res.engine == "lattice" and res.rt_pmf.shape == (steps, 2)
        assert abs(res.probabilities.sum() + res.p_undecided - 1.0) < 1e-9
        sim = mdft.simulate(model, 200_000, stopping=mdft.Threshold(10.0, max_steps=steps),
                            rng=steps)
        gap = np.abs(np.append(res.probabilities, res.p_undecided)
                     - np.append(sim.probabilities, sim.p_undecided))
        assert np.all(gap < 4 * math.sqrt(0.25 / 200_000) + res.error_probabilities), gap


def test_binary_lattice_with_levels_of_a_sum_that_depends_on_the_walk_agrees_with_simulation():
    model = uneven_sums(SHORT_DRIFTING_SUM)
    res = threshold_probabilities(model, 10.0)
    assert res.engine == "lattice" and res.n_levels > 1
    assert_within_stated_error(res, model, 10.0, 200_000, 15)


def test_a_lattice_over_its_state_limit_falls_back_or_refuses():
    # levels of a moving sum times 2,000 cells: far over the lattice's limit, which the
    # default fallback answers by simulation and fallback="raise" names
    model = uneven_sums(SHORT_DRIFTING_SUM)
    res = threshold_probabilities(model, 10.0, n_cells=2000, atol=0.004, rt_rtol=0.01)
    assert res.engine == "simulation"
    with pytest.raises(ValueError, match=r"n_cells=\d+ gives about \d+ lattice states \(the "
                                         r"lattice's limit is 300000\)"):
        threshold_probabilities(model, 10.0, n_cells=2000, fallback="raise")


def test_a_start_far_below_a_small_threshold_is_refused_before_any_lattice_is_stored(
        monkeypatch):
    # the lattice's box spans the start: 520 / (1e-9 / 40) cells would need 151 TiB, with
    # levels of the sum or with moving thresholds
    model = MDFTModel([[1.0, 3.0], [3.0, 1.0]], [0.5, 0.5], phi1=0.05, phi2=0.05, beta=10.0,
                      P0=[-500.0, -20.0])
    for theta in (1e-9, 1.0):
        with pytest.raises(ValueError, match=r"gives about \d+ lattice cells whose spreads "
                                             r"hold about [\d.e+]+ entries"):
            threshold_probabilities(model, theta, max_steps=5, fallback="raise")
    assert threshold_probabilities(model, 1.0, max_steps=5).engine == "simulation"
    levels_only(monkeypatch)
    for theta in (1e-9, 1.0):
        with pytest.raises(ValueError, match=r"gives about \d+ lattice states \(the "
                                             r"lattice's limit is 300000\)"):
            threshold_probabilities(model, theta, max_steps=5, fallback="raise")
    assert threshold_probabilities(model, 1.0, max_steps=5).engine == "simulation"


def test_small_noise_compromise_is_not_degenerate():
    # an earlier lattice returned p = [1, 0, 0] and a mean time of 1 step here
    # (theta = 17.5 there; 6 here keeps the test fast, the noise is as small)
    model = canonical(SETS["compromise"]).replace(sigma2=0.1)
    res = threshold_probabilities(model, 6.0, rt_rtol=0.05)
    assert res.probabilities.max() < 0.9 and res.mean_response_times[0] > 5
    assert_matches_simulation(res, model, 6.0, 40_000, 5)


def test_canonical_compromise_agrees_with_simulation():
    model = canonical(SETS["compromise"])
    res = threshold_probabilities(model, 12.0)
    # the feedback moves the summed preference, which the chain carries as moments
    assert res.n_levels == 1 and res.engine == "plane"
    assert_matches_simulation(res, model, 12.0, 40_000, 6)


def test_large_threshold_is_answered_or_refused_never_wrong():
    # an earlier lattice gave p_undecided = 1 at theta = 60 while every simulated trial
    # decides; now the answer is right or the call says it cannot vouch for one
    model = canonical(SETS["compromise"]).replace(sigma2=4.0)
    try:
        res = threshold_probabilities(model, 60.0, max_states=6_000, fallback="raise")
    except ValueError as exc:
        assert "cannot vouch" in str(exc)
        return
    assert res.p_undecided < 1e-3
    assert_matches_simulation(res, model, 60.0, 20_000, 7)


def test_budget_too_small_raises_a_clear_error():
    # a refusal of the chain that ran is a ThresholdToleranceError (a ValueError): looser
    # tolerances or more states may be met; a model no chain answers is another ValueError
    model = canonical(SETS["compromise"]).replace(sigma2=0.1)
    with pytest.raises(mdft.ThresholdToleranceError,
                       match=r"cannot vouch for this model within max_states=50.*mdft\.simulate"):
        threshold_probabilities(model, 17.5, max_states=50, fallback="raise")
    assert issubclass(mdft.ThresholdToleranceError, ValueError)
    with pytest.raises(ValueError, match="no noise") as info:
        threshold_probabilities(model.replace(sigma2=0.0), 17.5, fallback="raise")
    assert not isinstance(info.value, mdft.ThresholdToleranceError)


def test_tight_tolerance_refines_or_raises():
    model = canonical([A, B], w=(0.6, 0.4))
    loose = threshold_probabilities(model, 17.5, atol=0.01, rt_rtol=0.05)
    tight = threshold_probabilities(model, 17.5, atol=1e-5, rt_rtol=1e-4)
    assert tight.n_cells >= loose.n_cells
    assert tight.error_probabilities <= 1e-5 and tight.error_mean_rt <= 1e-4


def test_noise_narrower_than_the_cells_is_refined_not_trusted():
    # small noise (sigma2 = 0.106): at the first resolutions the noise is narrower than the
    # cells over sqrt(3) on both axes, where both resolutions agreed on a mean time 0.9 %
    # off; the answer now comes from a finer grid and is within its stated error
    model = MDFTModel([[1.4194, 1.9570, 0.5733], [1.4862, 1.4474, 3.7170],
                       [2.5579, 1.1213, 1.9965]], [0.374, 0.2106, 0.4154], phi1=0.093,
                      phi2=0.0598, beta=13.42, sigma2=0.1058)
    res = threshold_probabilities(model, 16.17, max_steps=3000, fallback="raise")
    assert res.engine == "plane"
    assert 1.5 * math.sqrt(model.sigma2) >= res.spacing / math.sqrt(3.0)
    assert_within_stated_error(res, model, 16.17, 200_000, 12)


def test_noise_narrower_than_the_cells_along_one_axis_is_refined_too():
    # two attributes, sigma2 = 0.11: the cells follow the attention jumps, so along one axis
    # the noise is narrower than the cell over sqrt(3) while the other axis is wide; two
    # such grids agreed on a mean time 0.55 % off (estimate 0.14 %). A finer grid answers.
    model = MDFTModel([[1.1319, 3.5942], [2.7455, 2.4939], [1.8170, 1.9383]], [0.6381, 0.3619],
                      phi1=0.02579, phi2=0.038995, beta=11.5185, sigma2=0.10974)
    res = threshold_probabilities(model, 25.47, max_steps=3000, fallback="raise")
    assert res.engine == "plane"
    assert res.resolution < 0.5
    assert_within_stated_error(res, model, 25.47, 200_000, 14)


def test_a_moving_sum_leaves_a_race_it_does_not_enter_unchanged():
    # Two identical options under strong mutual inhibition and a third that neither inhibits
    # nor is inhibited: S is block diagonal, so the race of options 0 and 1 does not depend on
    # the third option's self-feedback S[2, 2]. With the parametric S the column sums differ
    # (0.928, 0.928, 0.964), the summed preference drifts from 0 to about -10 and the chain
    # carries it as moments; with S[2, 2] = S[0, 0] + S[1, 0] they are equal and the chain is
    # exact in the sum. Where a cut cell's mass lay was taken at the state's reference sum
    # only, and the pair's mean time came out 0.8 % long (81.49 steps against 80.81; 3 x 10^6
    # simulated trials: 80.87) with an estimate of 0.26 %.
    m = [[2.668, 1.612, 1.601], [2.668, 1.612, 1.601], [0.087, 2.271, 1.294]]
    theta = 18.31
    model = MDFTModel(m, [1 / 3] * 3, phi1=0.459, phi2=0.0359, beta=39.5, sigma2=1.798)
    S = np.array(model.S)
    S[2, 2] = S[0, 0] + S[1, 0]
    constant = MDFTModel.from_matrices(m, [1 / 3] * 3, S=S, sigma2=1.798)
    ref = threshold_probabilities(constant, theta, fallback="raise")
    # the reference against the Monte Carlo engine
    sim = mdft.simulate(constant, 200_000, stopping=mdft.Threshold(theta), rng=2026)
    times = np.concatenate([sim.response_times(0), sim.response_times(1)])
    ref_time = ref.mean_response_times[:2].mean()
    assert abs(ref_time - times.mean()) <= (4 * times.std() / math.sqrt(times.size)
                                            + ref.error_mean_rt * ref_time)

    def off(res):
        assert np.abs(res.probabilities[:2] - ref.probabilities[:2]).max() <= 0.002
        return np.abs(res.mean_response_times[:2] / ref.mean_response_times[:2] - 1.0).max()

    # answered within its own stated error (a looser rt_rtol lets the chain answer)
    res = threshold_probabilities(model, theta, rt_rtol=0.006, fallback="raise")
    assert off(res) <= res.error_mean_rt + ref.error_mean_rt
    # at the default tolerances: within the 0.5 % target, or refused by the spread bound
    try:
        res = threshold_probabilities(model, theta, fallback="raise")
    except ValueError as exc:
        assert "spread of the summed preference" in str(exc)
    else:
        assert off(res) <= 0.005 + ref.error_mean_rt


def test_noise_narrower_than_the_cells_at_every_resolution_refuses_without_building(
        monkeypatch):
    # sigma2 = 1e-3 with attention spread ~1: the noise is narrower than the cells over
    # sqrt(3) even at the finest resolution, so no pass can be trusted. The chain used to
    # build (and, with method="solve", solve) every refinement up to max_states before
    # refusing: 712 s for method="solve". It now refuses before building any chain.
    model = MDFTModel(SETS["compromise"], [0.5, 0.5], **{**CANONICAL, "sigma2": 1e-3})

    def no_build(*args, **kwargs):
        raise RuntimeError("a chain was built")

    monkeypatch.setattr(_plane_passes, "build_moment_chain", no_build)
    for method in ("solve", "propagate"):
        with pytest.raises(ValueError, match=r"narrower than the cells over sqrt\(3\) even at "
                                             r"the finest resolution"):
            threshold_probabilities(model, 10.0, method=method, fallback="raise")


def test_narrow_passes_stop_where_the_first_trusted_grid_is_beyond_max_states(monkeypatch):
    # sigma2 = 0.1: the first passes are narrow along one axis (not trusted), and the first
    # resolution where they are not has about 8 times the states of resolution 1. Far beyond
    # max_states, the chain stops at the narrow pass instead of refining up to max_states
    # first, and says why.
    model = MDFTModel(SETS["compromise"], [0.5, 0.5], **{**CANONICAL, "sigma2": 0.1})
    built = []
    real_build = _plane_passes.build_moment_chain

    def counted(*args, **kwargs):
        chain = real_build(*args, **kwargs)
        built.append(chain.n_states)
        return chain

    monkeypatch.setattr(_plane_passes, "build_moment_chain", counted)
    with pytest.raises(ValueError, match=r"narrower than the cells .* the first resolution "
                                         r"where it is, [0-9.]+, would need about"):
        threshold_probabilities(model, 12.0, max_states=4000, fallback="raise")
    assert max(built) < 4000  # no pass went on to reach max_states


def test_the_states_of_the_first_trusted_grid_are_predicted_with_a_margin():
    from mdft.threshold_exact import _NARROW_STATES_MARGIN, _trusted_beyond

    def run(kappa, narrow):
        return SimpleNamespace(kappa=kappa, narrow=lambda: narrow)

    fine = SimpleNamespace(n_states=1000, resolution=1.0)
    later = [run(0.841, True), run(0.707, True), run(0.5, False), run(0.354, False)]
    # resolution 0.5 is the first trusted one: about 4,000 states
    assert _trusted_beyond(later, fine, 4000) == ""
    assert _trusted_beyond(later, fine, 4000 / _NARROW_STATES_MARGIN + 1) == ""
    why = _trusted_beyond(later, fine, 4000 / _NARROW_STATES_MARGIN - 1)
    assert "0.5, would need about 4e+03 states" in why
    # no trusted resolution left: nothing to predict (narrow_everywhere refuses earlier)
    assert _trusted_beyond(later[:2], fine, 10) == ""


@pytest.mark.parametrize("options, phi2", [(SETS["compromise"], 2.5), (SETS["compromise"], 1.0),
                                           ([A, B], 2.5)])
def test_unstable_summed_preference_is_refused(options, phi2):
    # phi1 = 0: S = I - phi2 * ones, which multiplies the summed preference by
    # 1 - n phi2 at every step. From P0 = 0 the sum stays 0 only in exact arithmetic;
    # mdft.simulate's rounding grows by |1 - n phi2| per step and drives its choices
    # (three options, phi2 = 1: p about [0.38, 0.38, 0.24] against the chain's
    # [0.42, 0.42, 0.17]), and with phi2 = 2.5 the chain refined for minutes.
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", mdft.UnstableFeedbackWarning)
        model = MDFTModel(options, [0.5, 0.5], phi1=0.0, phi2=phi2, beta=1.0)
    with pytest.raises(ValueError, match=r"multiplies the summed preference 1\^T P by -?\d"):
        threshold_probabilities(model, 20.0)


@pytest.mark.parametrize("S", [
    # upper triangular: eigenvalues 0.96 (stable), column sums 0.96, 0.96, 1.01
    [[0.96, 0.0, 0.05], [0.0, 0.96, 0.0], [0.0, 0.0, 0.96]],
    # two options: eigenvalues 0.97 and 0.9, column sums 1.02 and 0.9
    [[0.97, 0.0], [0.05, 0.9]],
])
def test_a_stable_feedback_whose_worst_case_sum_is_unbounded_is_simulated(S):
    # A column sum of S above 1 lets the chain's worst case of the summed preference (every
    # preference at theta but one) fall without bound, so no finite grid holds the states,
    # though the process is stable. The default falls back to simulation, within its stated
    # error of an independent simulation; fallback="raise" says why, naming the column sums.
    S = np.array(S)
    n = S.shape[0]
    M = [[1.0, 3.0], [3.0, 1.0], [2.0, 2.0]][:n]
    model = MDFTModel.from_matrices(M, [0.5, 0.5], S=S, sigma2=1.0)
    assert np.abs(np.linalg.eigvals(S)).max() < 1.0 and S.sum(axis=0).max() > 1.0
    res = threshold_probabilities(model, 8.0, atol=0.004, rt_rtol=0.01)
    assert res.engine == "simulation"
    assert res.error_probabilities <= 0.004 and res.error_mean_rt <= 0.01
    assert_within_stated_error(res, model, 8.0, 200_000, 12)
    sums = re.escape(str(np.round(S.sum(axis=0), 6).tolist()))
    with pytest.raises(ValueError, match=rf"column sum of S above 1 \(column sums {sums}\) "
                                         r"that worst case falls without bound.*spectral radius "
                                         r"of S is 0\.\d+: the process itself is stable.*"
                                         r"fallback='simulation'"):
        threshold_probabilities(model, 8.0, fallback="raise")


def test_bad_fallback_is_a_clear_error():
    model = canonical(SETS["compromise"])
    with pytest.raises(ValueError, match=r"fallback must be one of \('simulation', 'raise'\) "
                                         r"\(got 'mc'\)"):
        threshold_probabilities(model, 6.0, fallback="mc")


# ---------------------------------------------------------------- invariants
def test_distribution_accounts_for_all_mass():
    model = canonical(SETS["compromise"])
    res = threshold_probabilities(model, 8.0, max_steps=40, atol=0.01, rt_rtol=0.05)
    assert res.rt_pmf.shape == (40, 3)
    assert res.p_undecided > 0.01
    np.testing.assert_allclose(res.rt_pmf.sum(axis=0), res.probabilities, atol=1e-12)
    assert res.probabilities.sum() + res.p_undecided == pytest.approx(1.0, abs=1e-9)
    assert np.all(res.rt_pmf >= 0)
    longer = threshold_probabilities(model, 8.0, max_steps=400, atol=0.01, rt_rtol=0.05,
                                     resolution=res.resolution * math.sqrt(2))
    # the same chain (the same resolution) agrees step by step on the first 40 steps
    if longer.resolution == res.resolution:
        np.testing.assert_allclose(longer.rt_pmf[:40], res.rt_pmf, atol=1e-12)


def test_solve_and_propagate_agree_for_three_options():
    model = canonical(SETS["attraction"])
    loose = dict(atol=0.01, rt_rtol=0.05)  # the point is the agreement of the two solvers
    # the same tail_tol for both: the pilot passes that fit the reference sums and the
    # spread stop at the geometric tail when it is on, so it must be the same for both to
    # build the same chains
    prop = threshold_probabilities(model, 8.0, tail_tol=0.0, **loose)
    solved = threshold_probabilities(model, 8.0, method="solve", tail_tol=0.0, **loose)
    assert solved.rt_pmf is None and solved.p_undecided == 0.0
    assert solved.resolution == prop.resolution
    np.testing.assert_allclose(prop.probabilities, solved.probabilities, atol=1e-8)
    np.testing.assert_allclose(prop.mean_response_times[:2], solved.mean_response_times[:2],
                               rtol=1e-6)


@settings(deadline=None, max_examples=10)
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
        res = threshold_probabilities(model, theta, max_steps=400, n_cells=40)
        res_sw = threshold_probabilities(swapped, theta, max_steps=400, n_cells=40)
    assert np.all(res.probabilities >= 0) and 0.0 <= res.p_undecided <= 1.0
    assert res.probabilities.sum() + res.p_undecided == pytest.approx(1.0, abs=1e-9)
    np.testing.assert_allclose(res.rt_pmf.sum(axis=0), res.probabilities, atol=1e-12)
    # swapping the two options mirrors the one-dimensional lattice exactly
    np.testing.assert_allclose(res_sw.probabilities, res.probabilities[::-1], atol=1e-9)


def test_permuting_options_permutes_probabilities():
    options = SETS["compromise"]
    order = [2, 0, 1]
    res = threshold_probabilities(canonical(options), 6.0, rt_rtol=0.05)
    perm = threshold_probabilities(canonical([options[i] for i in order]), 6.0, rt_rtol=0.05)
    # the grid is laid out differently for the two orders: agreement to the stated errors
    tol = res.error_probabilities + perm.error_probabilities + 1e-3
    np.testing.assert_allclose(perm.probabilities, res.probabilities[order], atol=tol)


_SMALL_CASE = """
import json, warnings
import mdft
warnings.simplefilter("ignore")
model = mdft.MDFTModel([[1, 3], [3, 1], [2, 2]], [0.5, 0.5], phi1=0.022, phi2=0.05, beta=12.0,
                       sigma2=4.0)
res = mdft.threshold_probabilities(model, 3.0, max_steps=200, atol=0.05, rt_rtol=0.2)
print(json.dumps([res.probabilities.tolist(), res.mean_response_times.tolist()]))
"""


def test_compiled_and_interpreted_kernels_agree():
    root = Path(__file__).resolve().parents[1]
    out = []
    for disable in ("0", "1"):
        env = dict(os.environ, NUMBA_DISABLE_JIT=disable)
        run = subprocess.run([sys.executable, "-c", _SMALL_CASE], cwd=root, env=env,
                             capture_output=True, text=True, timeout=600, check=True)
        out.append(json.loads(run.stdout.strip().splitlines()[-1]))
    np.testing.assert_allclose(out[0][0], out[1][0], rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(out[0][1], out[1][1], rtol=1e-12)


# ---------------------------------------------------------------- the result object
def test_result_is_frozen_and_reports_the_grid_and_errors():
    res = threshold_probabilities(canonical([A, B]), 5.0, n_cells=20)
    assert res.n_cells == 20 and res.spacing == pytest.approx(0.25)
    assert res.theta == 5.0 and res.method == "propagate" and res.engine == "lattice"
    assert 0.0 <= res.error_probabilities <= 1e-3
    with pytest.raises(AttributeError, match="cannot assign to field 'theta'"):
        res.theta = 1.0


def test_repr_summary_and_to_dict():
    res = threshold_probabilities(canonical(SETS["attraction"]), 6.0, max_steps=300)
    text = repr(res)
    assert text.startswith("ThresholdProbabilities(probabilities=[") and len(text) < 400
    assert "engine='plane'" in text and "rt_pmf" not in text
    table = res.summary()
    lines = table.splitlines()
    assert len(lines) == 7 and "plane" in lines[0]
    for i in range(3):
        assert f"{res.probabilities[i]:.4f}" in lines[2 + i]
    d = res.to_dict()
    again = json.loads(json.dumps(d))
    assert again["probabilities"] == pytest.approx(res.probabilities.tolist())
    assert len(again["rt_pmf"]) == 300 and again["engine"] == "plane"
    assert again["error_mean_rt"] == pytest.approx(res.error_mean_rt)
    # an option never chosen has a NaN mean time, stored as None
    never = threshold_probabilities(plain([[1.0], [0.0]], [1.0]), 3.0, max_steps=2).to_dict()
    assert all(isinstance(v, (float, type(None))) for v in never["mean_response_times"])


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


def test_bad_resolution_tolerances_and_limits():
    model = canonical([A, B])
    three = canonical(SETS["compromise"])
    with pytest.raises(ValueError, match="n_cells must be an integer >= 4"):
        threshold_probabilities(model, 5.0, n_cells=2)
    with pytest.raises(TypeError, match="n_cells must be an integer"):
        threshold_probabilities(model, 5.0, n_cells=10.5)
    with pytest.raises(ValueError, match="n_cells sets the two-option lattice .* 3 options"):
        threshold_probabilities(three, 5.0, n_cells=10)
    with pytest.raises(ValueError, match="resolution sets the three-option grid .* 2 options"):
        threshold_probabilities(model, 5.0, resolution=1.0)
    with pytest.raises(ValueError, match="resolution must be >= 0.3"):
        threshold_probabilities(three, 5.0, resolution=0.1)
    with pytest.raises(ValueError, match="max_steps must be an integer >= 1"):
        threshold_probabilities(model, 5.0, max_steps=0)
    with pytest.raises(TypeError, match="max_steps must be an integer"):
        threshold_probabilities(model, 5.0, max_steps=1e3)
    # as for mdft.Threshold: a step limit beyond it would allocate rt_pmf of many gigabytes
    with pytest.raises(ValueError, match=r"max_steps must be an integer <= 10,000,000"):
        threshold_probabilities(model, 5.0, max_steps=10**9)
    with pytest.raises(ValueError, match="atol must be > 0"):
        threshold_probabilities(model, 5.0, atol=0.0)
    with pytest.raises(ValueError, match="rt_rtol must be <= 0.5"):
        threshold_probabilities(model, 5.0, rt_rtol=2.0)
    with pytest.raises(ValueError, match="tol must be > 0"):
        threshold_probabilities(model, 5.0, tol=0.0)
    with pytest.raises(ValueError, match="tail_tol must be >= 0"):
        threshold_probabilities(model, 5.0, tail_tol=-1.0)
    with pytest.raises(ValueError, match="max_iter must be an integer >= 1"):
        threshold_probabilities(model, 5.0, max_iter=0)
    with pytest.raises(ValueError, match="max_states must be an integer >= 10"):
        threshold_probabilities(model, 5.0, max_states=3)
    with pytest.raises(ValueError, match="method must be one of"):
        threshold_probabilities(model, 5.0, method="exact")


def test_four_options_are_simulated_to_the_tolerances_or_refused_when_asked():
    # no chain for four options: the default fallback simulates until three standard errors
    # meet the tolerances, and an independent simulation agrees; without it, a clear error
    model = canonical([A, B, (2.0, 2.0), (0.5, 2.5)])
    res = threshold_probabilities(model, 6.0, atol=0.004, rt_rtol=0.01)
    assert res.engine == "simulation" and res.probabilities.shape == (4,)
    assert res.rt_pmf.shape == (10_000, 4)
    assert res.error_probabilities <= 0.004 and res.error_mean_rt <= 0.01
    assert_within_stated_error(res, model, 6.0, 200_000, 13)
    with pytest.raises(ValueError, match=r"4 options; the chain handles at most 3.*fallback"):
        threshold_probabilities(model, 6.0, fallback="raise")
    with pytest.raises(ValueError, match=r"4 options; the chain handles at most 3"):
        threshold_probabilities(model, 6.0, method="solve")


def test_noise_free_model_is_simulated_or_points_to_simulation():
    # with attention switching only, nothing smooths the chain's rounding of each step: the
    # default simulates (within its stated error of an independent simulation), and
    # fallback="raise" says why and points to mdft.simulate
    model = plain([[1, 0], [0, 1]], [0.6, 0.4], sigma2=0.0)
    res = threshold_probabilities(model, 4.5, atol=0.004, rt_rtol=0.01)
    assert res.engine == "simulation"
    assert_within_stated_error(res, model, 4.5, 200_000, 14)
    with pytest.raises(ValueError, match=r"no noise \(sigma2=0\).*mdft.simulate"):
        threshold_probabilities(model, 4.5, fallback="raise")


def test_a_contrast_whose_columns_do_not_sum_to_zero_is_simulated_or_named():
    # the chain relies on valences that leave the summed preference unchanged; simulation
    # does not, so the default fallback answers and fallback="raise" says why
    C = np.array([[1.0, 0.0], [0.0, 1.0]])
    model = MDFTModel.from_matrices([[1.0, 0.2], [0.0, 0.9]], [0.5, 0.5], S=0.9 * np.eye(2),
                                    C=C)
    res = threshold_probabilities(model, 5.0, atol=0.004, rt_rtol=0.01)
    assert res.engine == "simulation"
    assert_within_stated_error(res, model, 5.0, 200_000, 16)
    with pytest.raises(ValueError, match=r"contrast C with columns summing to zero \(largest "
                                         r"column sum 1\)"):
        threshold_probabilities(model, 5.0, fallback="raise")


def test_a_long_run_too_close_to_singular_is_refused_clearly():
    # walks that almost never reach theta = 49.4 (none within 200,000 simulated steps): the
    # long run's linear system is solved to rounding, and its choices summed to 0.67 (the
    # call then refused on a change of 130 "in the probabilities" between two lattices)
    model = MDFTModel([[3.5918, 0.5899], [1.5744, 1.8035]], [0.52477, 0.47523], phi1=0.061762,
                      phi2=0.096302, beta=5.827, sigma2=1.60872)
    with pytest.raises(ValueError, match=r"the long run cannot be solved for this model: the "
                                         r"choice probabilities of the solved chain sum to "
                                         r"0\.\d+.*method='propagate'"):
        threshold_probabilities(model, 49.44, method="solve")
    res = threshold_probabilities(model, 10.0, method="solve")
    assert res.probabilities.sum() == pytest.approx(1.0, abs=1e-9)


def test_bad_model():
    with pytest.raises(TypeError, match="model must be an MDFTModel"):
        threshold_probabilities({"M": [[1, 2]]}, 5.0)
    started = canonical([A, B]).replace(P0=[6.0, -6.0])
    with pytest.raises(ValueError, match="P0 must lie below theta"):
        threshold_probabilities(started, 5.0)


def test_pilot_passes_run_one_step_coarser_than_the_counted_passes(monkeypatch):
    """The pilots (which only fit the reference sums, where the walks cannot) use the grid of
    resolution 2; the spread pass and every counted pass keep the schedule 1.41, 1, 0.71, ...
    (docs, section 2)."""
    monkeypatch.setattr(_plane_passes, "WALK_FIT", False)
    built = []
    original = _plane_passes.build_moment_chain

    def recording(model, theta, kappa, *args, **kwargs):
        built.append(kappa)
        return original(model, theta, kappa, *args, **kwargs)

    monkeypatch.setattr(_plane_passes, "build_moment_chain", recording)
    model = MDFTModel([[1.0, 3.0], [3.0, 1.0], [2.0, 2.0]], [0.5, 0.5], phi1=0.022, phi2=0.05,
                      beta=12.0)
    res = threshold_probabilities(model, 12.0, max_steps=2_000, fallback="raise")
    first = math.sqrt(2.0)
    assert built[:2] == pytest.approx([2.0, 2.0])  # the two pilots
    assert built[2:4] == pytest.approx([first, first])  # the first pass and its spread pass
    counted = sorted(set(np.round(built[2:], 9)), reverse=True)
    assert counted == pytest.approx([first / math.sqrt(2.0) ** k for k in range(len(counted))])
    assert res.resolution == pytest.approx(counted[-1])


@settings(max_examples=60, deadline=None)
@given(st.floats(-3.0, 3.0), st.floats(-3.0, 3.0), st.floats(0.2, 2.0), st.floats(0.2, 2.0),
       st.floats(0.3, 1.5), st.floats(0.3, 1.5), st.floats(-1.5, 1.5), st.floats(0.0, math.pi))
# a narrow y-spread and a line steep in x: on panels as wide as sx, the column's mass was
# off by 1e-4 of the cell's
@example(0.0, -1.0, 1.0, 0.25, 1.0, 1.0, 1.0, 1.0)
def test_cut_cell_mass_matches_a_fine_column_sum(mx, my, sx, sy, hx, hy, offset, turn):
    """The Gaussian mass of a cell cut by the three threshold lines (``_plane.cut_mass``)
    against a 200,000-column midpoint sum over the cell (exact in y), in bases where a line
    may run parallel to an axis (the integrand then jumps) or cross the cell's corners."""
    from mdft import _plane

    # an orthonormal basis of the zero-sum plane, turned by `turn`; below 0.3 the first line
    # is exactly parallel to the y axis
    E = np.c_[np.array([2.0, -1.0, -1.0]) / math.sqrt(6.0), np.array([0.0, 1.0, -1.0]) / math.sqrt(2.0)]
    if turn >= 0.3:
        E = E @ np.array([[math.cos(turn), -math.sin(turn)], [math.sin(turn), math.cos(turn)]])
    ex, ey = np.ascontiguousarray(E[:, 0]), np.ascontiguousarray(E[:, 1])
    normal = np.array([ex[0], ey[0]])
    centre = np.array([0.3, -0.2]) + offset * normal / np.linalg.norm(normal) * 0.3
    bound = float(normal @ centre) + 0.1
    xlo, xhi = centre[0] - hx / 2, centre[0] + hx / 2
    ylo, yhi = centre[1] - hy / 2, centre[1] + hy / 2
    got = _plane.cut_mass(xlo, xhi, ylo, yhi, mx, sx, my, sy, ex, ey, bound)
    n = 200_000
    xs = xlo + (np.arange(n) + 0.5) * hx / n
    a = np.full(n, ylo)
    b = np.full(n, yhi)
    for i in range(3):
        rest = bound - ex[i] * xs
        if abs(ey[i]) > 1e-14:
            lim = rest / ey[i]
            if ey[i] > 0:
                b = np.minimum(b, lim)
            else:
                a = np.maximum(a, lim)
        else:
            b = np.where(rest <= 0.0, a, b)
    col = np.where(b > a, ndtr((b - my) / sy) - ndtr((a - my) / sy), 0.0)
    dens = np.exp(-0.5 * ((xs - mx) / sx) ** 2) / (sx * math.sqrt(2.0 * math.pi))
    want = float((dens * col).sum() * hx / n)
    full = float((dens * (ndtr((yhi - my) / sy) - ndtr((ylo - my) / sy))).sum() * hx / n)
    # the column sum's own error is of the order of one column's mass where the integrand jumps;
    # cut_mass leaves out the Gaussian beyond 6.5 standard deviations (below 1e-10)
    assert abs(got - want) <= 2e-5 * full + 1e-10


# Two models of the benchmark's draws with seed 9494 (bench_threshold_exact.py): M, w, phi1,
# phi2, beta, sigma2 and theta.
SEED_9494 = {
    33: ([[2.874017742139143, 2.668734790645318, 2.1522316833901143],
          [0.8602951153455574, 1.876123503407832, 0.8506050201324691],
          [2.0211776395631773, 3.454816279337788, 2.8316879470465746]],
         [0.5384674753800045, 0.2408900751584326, 0.2206424494615628],
         0.018250502879864912, 0.015736134888981443, 10.978119209913572, 1.1889655167841526,
         40.498127632152865),
    37: ([[3.81129259018981, 3.744180174880957, 1.7281712835715515],
          [0.934485289373602, 2.683136964599837, 3.0100999212683086],
          [0.7894750094561018, 0.8376235481255265, 3.8576912705314865]],
         [0.19704958081710364, 0.35516004724266126, 0.44779037194023513],
         0.007801302776427911, 0.08288679093318242, 10.657754046404271, 1.1115908130431125,
         16.615415395407865),
}


def seed_9494_model(index):
    """``(model, theta)``: model ``index`` of :data:`SEED_9494`."""
    M, w, phi1, phi2, beta, sigma2, theta = SEED_9494[index]
    return drawn(M, w, phi1=phi1, phi2=phi2, beta=beta, sigma2=sigma2), theta


def test_a_plane_of_reference_sums_far_off_is_refused_at_once():
    """Seed 9494 model 33 of the benchmark's draws: with the plane of reference sums its
    answers at resolutions 1.41 to 0.5 give 0.879, 0.874, 0.908 and 0.905 for an option
    chosen in 85.9 % of 10^6 simulated trials. The grid answers' jumps used to refuse it
    only after the resolution-0.5 pass (the early refusal's rate rule); the closure's plane
    probe (each cell's reference sum the walks' own mean sum) changes the probabilities by
    0.037, the size of the error, and refuses it on the coarsest grid (the closure's term
    was 0.027 about the pilots' plane with the spread measured among the walks about to
    decide; about the simulated walks' own plane it is 0.0016, 0.8 % in a mean time)."""
    model, theta = seed_9494_model(33)
    with pytest.raises(ValueError, match=r"the spread of the summed preference and the plane "
                                         r"of its reference sums alone may change the "
                                         r"probabilities by 0\.00[1-9]"):
        threshold_probabilities(model, theta, fallback="raise")


@pytest.mark.parametrize("history, left, hopeless", [
    ([(0.0, 0.033), (0.0, 0.013), (0.0, 0.010)], 2, True),   # 0.010 * 0.43^2 > 0.0015
    ([(0.0, 0.033), (0.0, 0.013), (0.0, 0.005)], 2, False),  # 0.005 * 0.38^2 < 0.0015
    ([(0.0, 0.033), (0.0, 0.013), (0.0, 0.010)], 0, False),  # the last pass: refused as is
    ([(0.0, 0.013), (0.0, 0.010)], 2, False),                # too few comparisons
    ([(0.0, 0.010), (0.0, 0.020), (0.0, 0.040)], 3, True),   # growing: 0.040 * 0.5^3
    ([(0.0, 0.033), (0.0, 0.0), (0.0, 0.010)], 2, False),    # a zero ratio: no rate to hold
])
def test_out_of_reach_assumes_an_optimistic_rate(history, left, hopeless):
    """The early refusal's rule on grid terms of the mean times, with the closure's term
    taking 0.0015 of rt_rtol = 0.003: the rate is the smallest of the last two ratios and
    of 1/2."""
    from mdft.threshold_exact import _out_of_reach

    reason = _out_of_reach(history, (0.0, 0.0015), (1e-3, 3e-3), left)
    assert bool(reason) is hopeless
    if hopeless:
        assert "mean response times" in reason and f"{left} finer grids" in reason


def test_a_slow_refinement_within_reach_is_carried_on():
    """Seed 9494 model 37 of the benchmark's draws: with the pilots' spread of the sum the
    closure's term filled 97 % of rt_rtol and the grid term fell 0.0022, 0.0010, 0.0002 from
    resolution 0.71 on; the early refusal's optimistic rate let it refine, and it was answered
    at resolution 0.25. With the spread among the walks about to decide the term leaves more
    room, and it is answered at 0.5, past the first two comparisons, within the tolerances
    (the rate rule itself: test_out_of_reach_assumes_an_optimistic_rate above)."""
    model, theta = seed_9494_model(37)
    res = threshold_probabilities(model, theta, fallback="raise")
    assert res.resolution <= 0.5 + 1e-9
    assert res.error_probabilities <= 1e-3 and res.error_mean_rt <= 3e-3


# Draws of random_model (seeds of np.random.default_rng) answered at the half step 2**(-1/4)
# whose answer at tolerances three times tighter refines at least twice further (of the first
# 80 seeds, 32 are answered there, and five of them refine so: 3, 17, 18, 55 and 62)
HALF_STEP_SEEDS = [17, 18, 55]


@pytest.mark.parametrize("seed", HALF_STEP_SEEDS)
def test_a_half_step_answer_is_within_its_estimate_of_a_finer_one(seed):
    """A half step (section 4 of docs/threshold_exact.md) answers with 2.41 times its change
    from the refinement before it: on random draws answered there, the answer lies within
    that estimate (and the finer answer's own) of the answer at tolerances three times
    tighter, which refines at least twice further."""
    model, theta = random_model(np.random.default_rng(seed), 3)
    res = threshold_probabilities(model, theta, fallback="raise")
    assert res.resolution == pytest.approx(2.0**-0.25)
    assert res.error_probabilities <= 1e-3 and res.error_mean_rt <= 3e-3
    fine = threshold_probabilities(model, theta, atol=3e-4, rt_rtol=1e-3, fallback="raise")
    assert fine.resolution < res.resolution / 2.0**0.5
    err_p = res.error_probabilities + fine.error_probabilities
    assert np.max(np.abs(res.probabilities - fine.probabilities)) <= err_p
    assert abs(res.p_undecided - fine.p_undecided) <= err_p
    for i, p in enumerate(res.probabilities):
        if p >= 0.01:  # the estimate weighs rarer options' times in proportion
            change = abs(res.mean_response_times[i] / fine.mean_response_times[i] - 1.0)
            assert change <= res.error_mean_rt + fine.error_mean_rt


def test_a_mean_time_below_one_step_is_unresolved_and_its_change_counts_in_full():
    # at a probability near the chain's rounding (1e-74) the weighted time can come out 0, a
    # mean of 0 steps: reported as NaN, not as a time; and the error estimate counts a mean
    # that only one grid resolves as wrong by 100 %, weighed by p / 0.01, instead of dividing
    # by zero (an infinite estimate) or dropping it
    means = _threshold_solve.mean_rt(np.array([0.0, 0.3, 2.0, 0.0]),
                                     np.array([1e-74, 0.3, 0.5, 0.0]))
    np.testing.assert_array_equal(means, [np.nan, 1.0, 4.0, np.nan])

    def answer(p, rt):
        return SimpleNamespace(probabilities=np.array(p), p_undecided=1.0 - sum(p),
                               mean_response_times=np.array(rt, dtype=float))

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        err_p, err_rt = _threshold_solve.error_estimate(
            answer([1e-74, 0.3, 0.5], [np.nan, 10.0, 20.0]),
            answer([3e-68, 0.3, 0.5], [5e7, 10.02, 20.0]))
        assert err_p == pytest.approx(3e-68, rel=1e-6) and err_rt == pytest.approx(0.002)
        # an option that appears on the finer grid only: its mean time is unchecked
        _, err_rt = _threshold_solve.error_estimate(answer([5e-4, 0.3, 0.5], [30.0, 10.0, 20.0]),
                                                    answer([0.0, 0.3, 0.5], [np.nan, 10.0, 20.0]))
        assert err_rt == pytest.approx(0.05)


def test_binary_first_comparison_covers_a_slowly_falling_error():
    # a start away from 0 and a short step limit: the lattice's error fell by only about 1.5
    # per doubling of the cells, and the plain change from half the cells was half the error
    # of the finer answer (40 cells: 0.61208, estimate 0.00069). The reference: 0.61358 from
    # 640 cells (37 s, too slow to run here), 0.61357 from 5 x 10^6 simulated trials (se
    # 0.00022); 1e-4 allows for the reference's own error.
    model = MDFTModel([[2.6336142183248152, 2.463607615502124],
                       [2.1292178822391237, 3.2184844625651]],
                      [0.6132106154745479, 0.38678938452545225], phi1=0.0075132936742795635,
                      phi2=0.022549585985183397, beta=12.129460218834861,
                      sigma2=3.440657375503001, P0=[-3.132205413327087, 0.26586634314201274])
    res = threshold_probabilities(model, 33.61323821911933, max_steps=102)
    assert res.engine == "lattice" and res.error_probabilities <= 1e-3
    assert abs(res.p_undecided - 0.613581) <= res.error_probabilities + 1e-4
    np.testing.assert_allclose(res.probabilities, [0.188373, 0.198045],
                               atol=res.error_probabilities + 1e-4)
