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
from mdft import MDFTModel, _plane_passes, _threshold_solve, threshold_exact, threshold_probabilities

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


def drawn(M, w, **params):
    """A model of the benchmark's random draws (their feedback may warn)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", mdft.UnstableFeedbackWarning)
        return MDFTModel(M, w, **params)


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
def random_model(rng, n_options, theta_range=(5.0, 60.0), sigma2_range=(0.1, 4.0)):
    """A model drawn across the documented range (benchmarks/bench_threshold_exact.py)."""
    n_attributes = int(rng.integers(2, 4))
    M = rng.uniform(0.5, 4.0, (n_options, n_attributes))
    w = rng.dirichlet(np.full(n_attributes, 4.0))
    sigma2 = float(np.exp(rng.uniform(*np.log(sigma2_range))))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", mdft.UnstableFeedbackWarning)
        model = MDFTModel(M, w, phi1=float(np.exp(rng.uniform(np.log(0.005), np.log(0.1)))),
                          phi2=float(rng.uniform(0.01, 0.1)), beta=float(rng.uniform(1, 15)),
                          sigma2=sigma2)
    return model, float(rng.uniform(*theta_range))


def assert_matches_simulation(res, model, theta, n_trials, seed, max_steps=10_000):
    """Probabilities within 4 standard errors plus the stated error estimate and 0.002;
    mean response times of options chosen in >= 500 trials within 4 standard errors plus
    the stated relative error and 0.5 %."""
    sim = mdft.simulate(model, n_trials, stopping=mdft.Threshold(theta, max_steps=max_steps),
                        rng=seed)
    gap = np.abs(res.probabilities - sim.probabilities)
    allowed = 4 * sim.standard_errors + res.error_probabilities + 0.002
    assert np.all(gap < allowed), (res.probabilities, sim.probabilities, allowed)
    se_und = math.sqrt(max(sim.p_undecided * (1 - sim.p_undecided), 1e-12) / n_trials)
    assert abs(res.p_undecided - sim.p_undecided) < 4 * se_und + res.error_probabilities + 0.002
    for i in np.flatnonzero(sim.counts >= 500):
        rt = sim.response_times(i)
        se = rt.std(ddof=1) / math.sqrt(rt.size)
        gap = abs(res.mean_response_times[i] - rt.mean())
        limit = 4 * se + (res.error_mean_rt + 0.005) * rt.mean()
        assert gap < limit, (i, res.mean_response_times[i], rt.mean(), se)


@pytest.mark.parametrize("seed", [12, 13])
def test_random_ternary_models_agree_with_simulation(seed):
    # thresholds up to 20 keep the test fast; the benchmark covers 5-60 with 10**6 trials
    model, theta = random_model(np.random.default_rng(seed), 3, theta_range=(5.0, 20.0))
    res = threshold_probabilities(model, theta)
    assert res.engine == "plane"
    assert res.error_probabilities <= 1e-3 and res.error_mean_rt <= 3e-3
    assert_matches_simulation(res, model, theta, 50_000, seed)


def assert_within_stated_error(res, model, theta, n_trials, seed):
    """Probabilities and mean response times (options chosen in >= 2000 trials) within
    4 standard errors plus the stated error estimate, with no further slack."""
    sim = mdft.simulate(model, n_trials, stopping=mdft.Threshold(theta, max_steps=10_000),
                        rng=seed)
    gap = np.abs(res.probabilities - sim.probabilities)
    assert np.all(gap < 4 * sim.standard_errors + res.error_probabilities + 1e-4), (
        res.probabilities, sim.probabilities, res.error_probabilities)
    for i in np.flatnonzero(sim.counts >= 2000):
        rt = sim.response_times(i)
        se = rt.std(ddof=1) / math.sqrt(rt.size)
        gap = abs(res.mean_response_times[i] - rt.mean())
        assert gap < 4 * se + res.error_mean_rt * rt.mean(), (
            i, res.mean_response_times[i], rt.mean(), se, res.error_mean_rt)


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
    model = canonical(SETS["compromise"]).replace(sigma2=0.1)
    with pytest.raises(ValueError, match=r"cannot vouch for this model within max_states=50.*"
                                         r"mdft\.simulate"):
        threshold_probabilities(model, 17.5, max_states=50, fallback="raise")


def test_tight_tolerance_refines_or_raises():
    model = canonical([A, B], w=(0.6, 0.4))
    loose = threshold_probabilities(model, 17.5, atol=0.01, rt_rtol=0.05)
    tight = threshold_probabilities(model, 17.5, atol=1e-5, rt_rtol=1e-4)
    assert tight.n_cells >= loose.n_cells
    assert tight.error_probabilities <= 1e-5 and tight.error_mean_rt <= 1e-4


def test_refused_chain_falls_back_to_a_simulation_within_its_stated_error(monkeypatch):
    # max_states=10 makes the chain refuse at once; the fallback simulates until three
    # standard errors meet atol and rt_rtol, and an independent simulation agrees
    model = canonical(SETS["compromise"])
    res = threshold_probabilities(model, 6.0, max_states=10, atol=0.004, rt_rtol=0.01)
    assert res.engine == "simulation" and res.method == "simulation" and res.n_states == 0
    assert res.error_probabilities <= 0.004 and res.error_mean_rt <= 0.01
    assert res.n_iter >= 100_000 and "trials" in res.summary()
    np.testing.assert_allclose(res.rt_pmf.sum(axis=0), res.probabilities, atol=1e-12)
    assert res.probabilities.sum() + res.p_undecided == pytest.approx(1.0, abs=1e-12)
    assert_within_stated_error(res, model, 6.0, 200_000, 11)
    # repeatable by default, and a different rng gives a different (equally good) answer
    again = threshold_probabilities(model, 6.0, max_states=10, atol=0.004, rt_rtol=0.01)
    np.testing.assert_array_equal(res.probabilities, again.probabilities)
    other = threshold_probabilities(model, 6.0, max_states=10, atol=0.004, rt_rtol=0.01, rng=3)
    assert not np.array_equal(res.probabilities, other.probabilities)
    # over its work budget, the fallback raises and says why the chain refused
    from mdft import _threshold_fallback

    monkeypatch.setattr(_threshold_fallback, "MAX_WORK", 1e5)
    with pytest.raises(ValueError, match=r"the chain refused \(.*max_states.*\), and its "
                                         r"simulation fallback would need .*Raise atol"):
        threshold_probabilities(model, 6.0, max_states=10)


def test_simulation_answers_when_it_costs_less_than_a_finer_grid(monkeypatch):
    # with simulation counted as free, a chain that needs a refinement hands over to it, and
    # the reason says so; counted as dear, the chain refines instead. Both paths are
    # deterministic (counted work, not timings).
    model = canonical(SETS["compromise"])
    loose = dict(atol=0.004, rt_rtol=0.01)
    monkeypatch.setattr(threshold_exact, "_SIM_STEP_WORK", 0.0)
    monkeypatch.setattr(threshold_exact, "_FIRST_PAIR_FACTOR", 1e6)  # always refine
    res = threshold_probabilities(model, 6.0, **loose)
    assert res.engine == "simulation"
    assert_within_stated_error(res, model, 6.0, 200_000, 12)
    monkeypatch.setattr(threshold_exact, "_SIM_STEP_WORK", 1e12)
    res = threshold_probabilities(model, 6.0, **loose)
    assert res.engine == "plane" and res.resolution < 1.0


def test_fallback_far_over_its_budget_refuses_without_simulating(monkeypatch):
    # where the chain's last answer predicts more than twice the fallback's work budget, the
    # call refuses at once and says so; no trial is simulated
    from mdft import _threshold_fallback as fb

    model = canonical(SETS["compromise"])
    monkeypatch.setattr(threshold_exact, "_SIM_STEP_WORK", 0.0)  # hand over after one pair
    monkeypatch.setattr(threshold_exact, "_FIRST_PAIR_FACTOR", 1e6)

    def no_simulation(*args, **kwargs):
        raise AssertionError("the fallback simulated")

    monkeypatch.setattr(fb, "simulate", no_simulation)
    monkeypatch.setattr(fb, "MAX_WORK", 1e5)
    with pytest.raises(ValueError, match=r"the chain refused \(.*\), and its simulation "
                                         r"fallback would need .* \(predicted from the "
                                         r"chain's answer at \d+ states\).*Raise atol"):
        threshold_probabilities(model, 6.0, atol=0.004, rt_rtol=0.01)
    # near the budget the fallback's own first batch decides, as before
    exact = threshold_probabilities(model, 6.0, fallback="raise", atol=0.004, rt_rtol=0.01)
    work = fb.predicted_work(exact.max_steps, exact.probabilities, exact.p_undecided,
                             exact.rt_pmf, 0.004, 0.01)
    monkeypatch.setattr(fb, "MAX_WORK", 0.6 * work)
    with pytest.raises(AssertionError, match="simulated"):
        threshold_probabilities(model, 6.0, atol=0.004, rt_rtol=0.01)


def test_predicted_simulation_work_matches_what_the_fallback_uses():
    # the trials the fallback ends up simulating (three standard errors within the
    # tolerances) are those predicted from the answer, within the growth of its batches
    from mdft import _threshold_fallback as fb

    model = canonical(SETS["compromise"])
    exact = threshold_probabilities(model, 6.0, fallback="raise", atol=0.004, rt_rtol=0.01)
    steps = float(np.arange(1, exact.max_steps + 1) @ exact.rt_pmf.sum(axis=1))
    for atol, rt_rtol in ((0.002, 0.01), (0.01, 0.002)):
        work = fb.predicted_work(exact.max_steps, exact.probabilities, exact.p_undecided,
                                 exact.rt_pmf, atol, rt_rtol)
        sim = threshold_probabilities(model, 6.0, max_states=10, atol=atol, rt_rtol=rt_rtol)
        predicted = max(work / steps, fb.FIRST_BATCH)
        assert 0.8 * predicted <= sim.n_iter <= 1.6 * predicted, (predicted, sim.n_iter)


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


def test_geometric_tail_matches_full_propagation():
    model = canonical(SETS["similarity"])
    loose = dict(atol=0.01, rt_rtol=0.05)  # the point is the agreement of the two runs
    full = threshold_probabilities(model, 8.0, tail_tol=0.0, **loose)
    tail = threshold_probabilities(model, 8.0, **loose)
    assert tail.tail_start is not None and full.tail_start is None
    assert tail.n_iter < full.n_iter
    # the tail may change the answer by at most its share of the tolerances (which the
    # error estimate then includes)
    share = _plane_passes.TAIL_SHARE
    np.testing.assert_allclose(tail.probabilities, full.probabilities, atol=share * 0.01)
    np.testing.assert_allclose(tail.mean_response_times, full.mean_response_times,
                               rtol=share * 0.05)


@pytest.mark.parametrize("seed", [41, 42, 43, 44])
def test_extrapolated_tail_stays_within_its_own_estimate(seed):
    """On random three-option models (decided and undecided ones alike), filling the tail
    geometrically changes the answer by no more than the change it reports."""
    from mdft._plane_chain import build_moment_chain

    rng = np.random.default_rng(seed)
    model, theta = random_model(rng, 3, theta_range=(5.0, 30.0))
    ref = np.array([float(np.sum(model.P0)), 0.0, 0.0])
    chain = build_moment_chain(model, theta, 1.4, ref, 0.5, 60_000)
    tail_against_full(chain, 1500, krylov=False)


@pytest.mark.parametrize("seed", [2, 3, 5, 7])
def test_krylov_tail_stays_within_its_own_estimate(seed):
    """Random three-option models across the documented range (sigma2 0.1-4, theta 5-60)
    on a coarse grid, 6,000 steps: where the Krylov tail was filled, it changed the answer
    by no more than its estimate."""
    from mdft._plane_chain import _KRYLOV_FIRST, build_moment_chain, propagate_moments

    rng = np.random.default_rng(seed)
    budget = (1e-5, 3e-5)
    used = 0
    for _ in range(4):
        model, theta = random_model(rng, 3)
        ref = np.array([float(np.sum(model.P0)), 0.0, 0.0])
        chain = build_moment_chain(model, theta, 2.0, ref, 0.5, 60_000)
        if propagate_moments(chain, 6000, 1e-14, budget)[3] < _KRYLOV_FIRST:
            continue  # decided, or a geometric tail (the test above)
        full, tail = tail_against_full(chain, 6000, budget=budget)
        used += tail[3] < 6000
    assert used >= 1  # each seed's four models include at least one long deliberation


def test_krylov_tail_of_a_long_deliberation_saves_most_steps():
    """Seed 2026 model 5's slow next mode (section 5 of docs/threshold_exact.md): the Krylov
    tail starts at one of the first pauses and takes at most a hundred-odd steps of the
    chain, where the geometric tail alone needed thousands; both stay within their
    estimates."""
    from mdft._plane_chain import _KRYLOV_FIRST, build_moment_chain
    from mdft._plane_krylov import _DIMS

    model, theta = slow_mode_model()
    ref = np.array([float(np.sum(model.P0)), 0.0, 0.0])
    chain = build_moment_chain(model, theta, 2.0, ref, 0.5, 60_000)
    _, krylov = tail_against_full(chain, 10_000, budget=(1e-5, 3e-5))
    _, geometric = tail_against_full(chain, 10_000, budget=(1e-5, 3e-5), krylov=False)
    assert krylov[3] in (_KRYLOV_FIRST, 2 * _KRYLOV_FIRST)
    assert krylov[2] - krylov[3] <= _DIMS[-1]
    assert geometric[2] > 6 * krylov[2]


def test_krylov_start_follows_the_schedule_of_tries():
    """A finer pass's first Krylov try is where the coarser pass filled a Krylov tail (a
    point of the schedule: the first, doubled), the point after the try that failed
    before a geometric tail (filled between two points), and the schedule's first
    without a tail or with a geometric one before any try."""
    from mdft._plane_chain import _KRYLOV_FIRST, krylov_start

    first = _KRYLOV_FIRST
    assert krylov_start(None) == krylov_start(0) == krylov_start(first - 1) == first
    assert krylov_start(first) == first
    assert krylov_start(first + 1) == krylov_start(2 * first - 1) == 2 * first
    assert krylov_start(2 * first) == 2 * first
    assert krylov_start(8 * first) == 8 * first
    assert krylov_start(9 * first) == 16 * first
    # idempotent: a start passed on as krylov_from stays where it is
    for tail in (None, 0, first + 1, 9 * first):
        assert krylov_start(krylov_start(tail)) == krylov_start(tail)


def test_a_finer_pass_leaves_out_the_krylov_tries_that_failed_on_the_coarser_grid(monkeypatch):
    """A random long deliberation (seed 3 of the test draws, theta 39.7) whose coarse pass
    fills its Krylov tail only at the second try: the finer pass that starts there gives
    the very answer of the finer pass that tries from the first point on (its first try
    fails as well), without the failed try's work."""
    from mdft import _plane_chain
    from mdft._plane_chain import (_KRYLOV_FIRST, build_moment_chain, krylov_start,
                                   propagate_moments)

    tries = []
    tail = _plane_chain.krylov_tail
    monkeypatch.setattr(_plane_chain, "krylov_tail",
                        lambda *args: tries.append(args[3]) or tail(*args))
    rng = np.random.default_rng(3)
    random_model(rng, 3)
    model, theta = random_model(rng, 3)
    ref = np.array([float(np.sum(model.P0)), 0.0, 0.0])
    budget = (1e-5, 3e-5)
    coarse = propagate_moments(build_moment_chain(model, theta, 2.0, ref, 0.5, 60_000), 6000,
                               1e-14, budget)
    assert coarse[3] == 2 * _KRYLOV_FIRST
    fine = build_moment_chain(model, theta, 1.41, ref, 0.5, 60_000)
    tries.clear()
    every_try = propagate_moments(fine, 6000, 1e-14, budget)
    assert tries == [_KRYLOV_FIRST, 2 * _KRYLOV_FIRST]
    tries.clear()
    later = propagate_moments(fine, 6000, 1e-14, budget, krylov_from=krylov_start(coarse[3]))
    assert tries == [2 * _KRYLOV_FIRST]
    assert later[3] == every_try[3] == 2 * _KRYLOV_FIRST
    np.testing.assert_array_equal(later[0], every_try[0])
    assert later[1] == every_try[1]


def test_a_run_stops_on_the_size_of_the_undecided_mass_not_its_signed_sum():
    """A random model (seed 777 of the benchmark's draws) whose moment closure lets the
    probabilities of some states turn negative: their signed sum fell below the stop
    tolerance while the walks still chose 1.3e-6 more of one option. Stopping on the sum of
    |x| gives every step's answer."""
    from mdft._plane_chain import build_moment_chain, propagate_moments, reference_sums

    model = drawn([[2.455354, 3.65308], [1.585164, 1.866527], [0.530718, 2.560094]],
                  [0.674101, 0.325899], phi1=0.08985654, phi2=0.03238458, beta=2.0401195,
                  sigma2=0.50501289)
    theta = 19.778292
    ref, delta = np.array([float(np.sum(model.P0)), 0.0, 0.0]), 0.5
    for _ in range(2):  # the reference sums as the library's pilots fit them
        pilot = build_moment_chain(model, theta, 2.0, ref, delta, 30_000)
        ref, delta = reference_sums(pilot, propagate_moments(pilot, 1000, 1e-6, second=True)[4])
    chain = build_moment_chain(model, theta, 1.41, ref, delta, 30_000)
    every = propagate_moments(chain, 10_000, -np.inf)
    stopped = propagate_moments(chain, 10_000, 1e-14)
    assert stopped[2] < 10_000
    np.testing.assert_allclose(stopped[0].sum(axis=0), every[0].sum(axis=0), rtol=0,
                               atol=1e-12)


def runaway_pilot_model():
    """Seed 9191 model 14 of the benchmark's draws (a long deliberation, mean times 540-590
    steps): with the pilot's first guess of the reference sums, its moment closure runs away
    after about 200 steps."""
    model = drawn([[2.0356108074080255, 2.253562468264767],
                   [0.9061297268088968, 2.1682379023887544],
                   [0.623301638882569, 2.0033458201561873]],
                  [0.4138242065397861, 0.586175793460214], phi1=0.008507515982439344,
                  phi2=0.06767721501851882, beta=10.305919742706031, sigma2=0.22853328717998567)
    return model, 50.78103007752905


def pilot_occupation(chain, max_steps, tol, budget):
    """A pilot pass's ``(occupation, steps, cut)``."""
    from mdft._plane_chain import pilot_pass

    out, cut = pilot_pass(chain, max_steps, tol, budget)
    return out[4], out[2], cut


def test_a_pilot_whose_closure_runs_away_keeps_the_steps_before(monkeypatch):
    from mdft import _plane_chain
    from mdft._plane_chain import build_moment_chain, propagate_moments

    model, theta = runaway_pilot_model()
    ref = np.array([float(np.sum(model.P0)), 0.0, 0.0])
    chain = build_moment_chain(model, theta, 2.0, ref, 0.5, 30_000)
    occ, steps, cut = pilot_occupation(chain, 1000, 1e-6, (1e-5, 3e-5))
    assert cut and 100 <= steps < 1000 and steps % _plane_chain._PILOT_CHUNK == 0
    # the occupation kept is that of a pass of that many steps
    alone = propagate_moments(chain, steps, 1e-6, (1e-5, 3e-5), second=True)
    np.testing.assert_allclose(occ, alone[4], rtol=1e-12, atol=1e-300)
    # unguarded, the pass goes on to the step limit and its answer is no distribution: its
    # negative choices (clipped, and counted) outweigh the whole
    monkeypatch.setattr(_plane_chain, "_PILOT_RUNAWAY", np.inf)
    occ_all, steps_all, cut_all = pilot_occupation(chain, 1000, 1e-6, (1e-5, 3e-5))
    assert not cut_all and steps_all == 1000
    wild = propagate_moments(chain, 1000, 1e-6, (1e-5, 3e-5), second=True)
    assert wild[5][2] > 1.0


def test_negative_choices_are_clipped_scaled_and_counted():
    from mdft._plane_chain import _clip_negative

    rt_pmf = np.array([[0.5, -0.1, 0.0], [0.45, 0.2, -0.05]])
    mass, clipped = _clip_negative(rt_pmf, 0.0)
    assert clipped == pytest.approx(0.15) and mass == 0.0
    assert rt_pmf.min() == 0.0 and rt_pmf.sum() == pytest.approx(1.0)
    np.testing.assert_allclose(rt_pmf, np.array([[0.5, 0, 0], [0.45, 0.2, 0]]) / 1.15)
    untouched = np.array([[0.25, 0.25, 0.0]])
    assert _clip_negative(untouched, 0.5) == (0.5, 0.0)
    assert untouched.sum() == 0.5


def test_a_closure_whose_choices_turn_negative_answers_a_distribution_and_says_so():
    # seed 8282 model 14 of the benchmark's draws: option 1 is chosen in every one of 10**6
    # simulated trials (mean time 46.28 steps), but the linearised choices of the other two
    # turn negative by 0.0008 in all. Clipped and left out, they made p_1 = 1.0008 with an
    # estimate of 5e-5; clipped, scaled back and counted, p_1 = 1 and the estimate covers them.
    # The closure's plane probe (each cell's reference sum the walks' own mean sum) turns
    # negative by 0.0017, beyond the default atol: refused as unstable there; at atol = 2e-3
    # its term also covers the mean time's error (0.16 %, the plane's alone said 0.015 %)
    model = drawn([[1.66396564, 1.14790297, 0.64966856], [3.98162207, 2.97665791, 2.54034374],
                   [1.72459506, 0.66875495, 1.71616334]], [0.2046643, 0.50472451, 0.29061119],
                  phi1=0.010131737724362024, phi2=0.03996832951331772, beta=11.772343811026468,
                  sigma2=0.17304052523857907)
    with pytest.raises(ValueError, match=r"closure of the summed preference is unstable.*"
                                         r"turn negative by 0\.0017"):
        threshold_probabilities(model, 40.354331093471934, fallback="raise")
    res = threshold_probabilities(model, 40.354331093471934, fallback="raise", atol=2e-3)
    assert res.probabilities.min() >= 0.0
    assert res.probabilities.sum() + res.p_undecided == pytest.approx(1.0, abs=1e-12)
    assert abs(res.probabilities[1] - 1.0) <= 1e-4
    assert 5e-4 <= res.error_probabilities <= 1e-3
    assert res.mean_response_times[1] == pytest.approx(46.28, rel=3e-3)
    assert res.error_mean_rt >= abs(res.mean_response_times[1] / 46.28 - 1.0)


def test_a_healthy_pilot_is_not_cut(monkeypatch):
    # the canonical compromise set: the pilot's closure stays sound, and running it in
    # chunks gives the occupation of one run
    from mdft import _plane_chain
    from mdft._plane_chain import build_moment_chain

    model = MDFTModel(SETS["compromise"], [0.5, 0.5], phi1=0.022, phi2=0.05, beta=12.0,
                      sigma2=1.0)
    ref = np.array([float(np.sum(model.P0)), 0.0, 0.0])
    chain = build_moment_chain(model, 17.5, 2.0, ref, 0.5, 30_000)
    occ, steps, cut = pilot_occupation(chain, 1000, 1e-6, (1e-5, 3e-5))
    assert not cut and steps > 2 * _plane_chain._PILOT_CHUNK
    monkeypatch.setattr(_plane_chain, "_PILOT_CHUNK", 10_000)
    occ_one, steps_one, _ = pilot_occupation(chain, 1000, 1e-6, (1e-5, 3e-5))
    assert steps_one == steps
    np.testing.assert_allclose(occ, occ_one, rtol=1e-12, atol=1e-300)


def test_a_model_whose_first_pilot_runs_away_is_answered():
    """Before the guard, the reference sums fitted from the runaway pilot made every pass's
    closure unstable, and the call simulated (40 s). Reference: 10**6 simulated trials
    (benchmarks/bench_threshold_exact.py, seed 9191, max_steps 10,000): p = 2.1e-5,
    0.50616, 0.493819 (standard errors 0.0005) and mean times 582 (21 trials), 538.78,
    587.04 steps."""
    model, theta = runaway_pilot_model()
    res = threshold_probabilities(model, theta, fallback="raise")
    assert res.engine == "plane"
    np.testing.assert_allclose(res.probabilities, [2.1e-5, 0.50616, 0.493819], atol=0.002)
    np.testing.assert_allclose(res.mean_response_times[1:], [538.78, 587.04], rtol=0.005)


def test_reference_sums_refitted_after_a_cut_pilot_are_checked():
    """Seed 5150 model 3 of the benchmark's draws: its pilot's closure runs away within 50
    steps, and the pilot cut at 150 steps fits reference sums that leave the chain stable but
    biased (0.0067 and 0.9933, mean time 226 steps for the second option). Refitted to the
    walks of the first pass that counts, the answer is within the tolerances of
    5 * 10**6 simulated trials (1 and 4 million with seeds 1 and 7 of mdft.simulate, pooled:
    p = 0.00826, 0.99174, mean times 143.6 and 217.2 steps)."""
    model = drawn([[1.8138094066077708, 3.9686312912630735],
                   [2.579267199608471, 2.9609474427885942],
                   [0.9511985461332478, 1.3554338688020402]],
                  [0.5606021609462761, 0.4393978390537239], phi1=0.0076642266530194715,
                  phi2=0.03956108946247433, beta=2.745171083240042, sigma2=0.18106185763880178)
    res = threshold_probabilities(model, 31.51853929122604, fallback="raise")
    np.testing.assert_allclose(res.probabilities, [0.00826, 0.99174, 0.0], atol=0.001)
    np.testing.assert_allclose(res.mean_response_times[:2], [143.6, 217.2], rtol=0.005)


def test_krylov_powers_match_matrix_powers():
    from mdft._plane_moment import krylov_powers

    rng = np.random.default_rng(0)
    H = np.triu(rng.normal(size=(6, 6)) * 0.3, -1)
    out, n = krylov_powers(H, 2.0, 12, 0.0)
    assert n == 12
    for k in (0, 1, 5, 11):
        np.testing.assert_allclose(out[k], 2.0 * np.linalg.matrix_power(H, k)[:, 0],
                                   rtol=1e-12, atol=1e-15)
    # rows after the first below the negligible norm are zero
    out, n = krylov_powers(0.1 * np.eye(3), 1.0, 20, 1e-6)
    assert n == 8 and np.all(out[8:] == 0.0) and out[7, 0] == pytest.approx(1e-7)


def tail_against_full(chain, steps, budget=(5e-5, 1.5e-4), krylov=True):
    """Propagate ``chain`` for ``steps`` with and without the tail; assert that filling the
    tail changed the answer by no more than the change it reported (within ``budget``).
    The full run's own error (the mass of the states it left out as holding less than
    1e-15 of the undecided mass) counts on its side."""
    from mdft._plane_chain import propagate_moments

    # every step (no stop at a small undecided mass: where the moment closure lets x change
    # sign, the mass can pass below it while the walks still choose)
    full = propagate_moments(chain, steps, -np.inf)
    tail = propagate_moments(chain, steps, 1e-14, budget, krylov=krylov)
    times = np.arange(1, steps + 1)
    if full[5][2] > 1e-3:
        # an unstable moment closure (docs/threshold_exact.md, section 8): no distribution,
        # which threshold_probabilities refuses by its negative choices; so it must with the
        # tail
        assert tail[5][2] > 1e-3
        return full, tail
    err_p, err_rt, _ = tail[5]
    if tail[3] < steps:  # the tail was filled
        assert err_p <= budget[0] and err_rt <= budget[1]
    assert tail[2] <= full[2]
    p_full, p_tail = full[0].sum(axis=0), tail[0].sum(axis=0)
    assert np.abs(p_tail - p_full).max() <= err_p + full[5][0] + 1e-12
    assert abs(tail[1] - full[1]) <= err_p + full[5][0] + 1e-12
    for i in range(3):
        if p_full[i] > 1e-6:
            rt_full = times @ full[0][:, i] / p_full[i]
            rt_tail = times @ tail[0][:, i] / p_tail[i]
            weight = min(1.0, p_full[i] / 0.01)
            assert weight * abs(rt_tail / rt_full - 1.0) <= err_rt + 1e-9
    return full, tail


def test_hazard_drift_of_a_slow_mode_is_measured_over_longer_windows():
    """A hazard approaching its limit by a factor 0.998 per step shrinks by 0.951 per 25-step
    window, too slowly to count as geometric there; over doubled windows it does, and the
    distance estimated still to go covers the true one."""
    from mdft import _plane_tail

    t = np.arange(3000)
    hazard = 1e-3 - 1e-4 * 0.998**t
    hazard[0] = 0.0
    u = 1200
    w = _plane_tail.WINDOW
    assert _plane_tail.drift(hazard[u - 3 * w], hazard[u - 2 * w], hazard[u - w],
                             hazard[u]) == -1.0
    rest = 1e-4 * 0.998**u
    assert rest <= _plane_tail._hazard_drift(hazard, u) <= 2.5 * rest
    # a hazard still at 0 at the start of the longest window is not a geometric approach
    assert _plane_tail._hazard_drift(np.r_[np.zeros(200), hazard[200:]], 230) == -1.0


def slow_mode_model():
    """Seed 2026 model 5 of the benchmark: a long deliberation whose hazard settles by about
    0.998 per step."""
    model = MDFTModel([[3.257, 2.737, 2.809], [2.411, 3.710, 1.316], [2.598, 3.350, 0.972]],
                      [0.5958, 0.2729, 0.1313], phi1=0.03285, phi2=0.03892, beta=10.18,
                      sigma2=0.3481)
    return model, 41.77


def test_tail_of_a_slow_next_mode_is_filled_within_its_estimate():
    """A long deliberation whose hazard settles by about 0.998 per step (seed 2026, model 5
    of the benchmark, on a coarse grid): the tail is filled before the step limit, where a
    25-step window alone never sees a geometric drift, and within its own estimate."""
    from mdft._plane_chain import build_moment_chain

    model, theta = slow_mode_model()
    ref = np.array([float(np.sum(model.P0)), 0.0, 0.0])
    chain = build_moment_chain(model, theta, 2.0, ref, 0.5, 60_000)
    steps = 10_000
    full, tail = tail_against_full(chain, steps, krylov=False)
    assert tail[3] < 0.7 * steps  # filled well before the limit
    # where it was filled, the drift over 25 steps is not (yet) geometric
    from mdft import _plane_tail

    chosen = full[0].sum(axis=1)
    hazard = chosen / np.r_[1.0, 1.0 - np.cumsum(chosen)[:-1]]
    u, w = tail[3] - 1, _plane_tail.WINDOW
    assert _plane_tail.drift(hazard[u - 3 * w], hazard[u - 2 * w], hazard[u - w],
                             hazard[u]) == -1.0


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


@pytest.mark.parametrize("in_parts", [False, True])
def test_moment_step_carries_the_covariance_of_the_sum_and_the_transition(in_parts):
    # One step of the moment chain from a state whose sum is spread around its reference
    # s_ref with variance delta**2 (no mean deviation): the staying probability is linear
    # in the sum, T(s) = t0 + t1 (s - s_ref), and the next sum is s' = s_next + b (s - s_ref),
    # so the first moment reaching the next state is E[s' T(s)] = s_next t0 + b t1 delta**2.
    # The same, serially and in parallel parts.
    from mdft import _plane_moment
    from mdft._plane_chain import tail_track

    t0, t1, s_ref, s_next, b, delta = 0.6, 0.05, 10.0, 9.0, 0.9, 1.5
    x = np.array([1.0, 0.0])
    m = np.array([s_ref, 0.0])
    q = np.zeros(2)
    rt_pmf = np.zeros((2, 3))
    _plane_moment.propagate(
        np.array([0, 1, 1]), np.array([1], dtype=np.int32), np.array([t0]), np.array([t1]),
        np.zeros((2, 3)), np.zeros((2, 3)), np.array([s_ref, s_ref]), np.array([s_next, s_next]),
        b, delta**2, x, m, q, rt_pmf, np.zeros((2, 3)), 0.0, False, 0.0, 0.0, 0.01, np.zeros(3),
        in_parts, np.zeros(2, dtype=bool), 2, 1, *tail_track(2, 2), np.inf)
    assert x[1] == pytest.approx(t0)
    assert m[1] == pytest.approx(s_next * t0 + b * t1 * delta**2)


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


def test_noise_free_model_points_to_simulation():
    model = plain([[1, 0], [0, 1]], [0.6, 0.4], sigma2=0.0)
    with pytest.raises(ValueError, match=r"no noise \(sigma2=0\).*mdft.simulate"):
        threshold_probabilities(model, 4.5)


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


def test_slow_start_is_not_mistaken_for_the_geometric_tail():
    # A two-option walk that needs hundreds of steps to reach a distant threshold: while the
    # mass is on its way, the per-step choices are tiny and steady, which an earlier tail
    # detector took for the slowest mode, returning p_undecided = 1 with a zero error estimate.
    M = [[3.2911181, 2.62348387, 1.70785203], [3.81386927, 2.47182081, 2.01466959]]
    w = [0.23881413, 0.40882123, 0.35236464]
    model = MDFTModel(M, w, phi1=0.02, phi2=0.0533, beta=1.0, sigma2=0.2)
    res = threshold_probabilities(model, 30.0, max_steps=3000)
    assert res.p_undecided < 1e-3
    assert_matches_simulation(res, model, 30.0, 20_000, 8, max_steps=3000)


def test_pilot_passes_run_one_step_coarser_than_the_counted_passes(monkeypatch):
    """The pilots (which only fit the reference sums) use the grid of resolution 2; the spread
    pass and every counted pass keep the schedule 1.41, 1, 0.71, ... (docs, section 2)."""
    built = []
    original = _plane_passes.build_moment_chain

    def recording(model, theta, kappa, *args):
        built.append(kappa)
        return original(model, theta, kappa, *args)

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
    0.037, the size of the error, and refuses it on the coarsest grid."""
    model, theta = seed_9494_model(33)
    with pytest.raises(ValueError, match=r"the spread of the summed preference and the plane "
                                         r"of its reference sums alone may change the "
                                         r"probabilities by 0\.03"):
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


def test_a_slow_refinement_within_reach_is_carried_to_the_end():
    """Seed 9494 model 37 of the benchmark's draws: the closure's term fills 97 % of
    rt_rtol and the grid term falls 0.0022, 0.0010, 0.0002 from resolution 0.71 on; the
    early refusal's optimistic rate lets it refine, and it is answered at resolution 0.25
    within the tolerances."""
    model, theta = seed_9494_model(37)
    res = threshold_probabilities(model, theta, fallback="raise")
    assert res.resolution == pytest.approx(0.25)
    assert res.error_probabilities <= 1e-3 and res.error_mean_rt <= 3e-3



# Draws of random_model (seeds of np.random.default_rng) answered at the half step 2**(-1/4)
# whose answer at tolerances three times tighter refines at least twice further (of the first
# 80 seeds, 23 are answered there; at tighter tolerances most are refused by their closure)
HALF_STEP_SEEDS = [17, 19, 54]


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


def test_an_unstable_moment_closure_is_refused_with_its_reason():
    """Two near-identical options, almost no leakage and a long deliberation: the first-order
    closure in the summed preference grows without bound on this model (a pass's
    probabilities summed to 1e34). The call refuses and says why, instead of reporting an
    error estimate of that size."""
    model = MDFTModel([[4.72, 9.53], [0.32, 0.41], [4.31, 9.96]], [0.462, 0.538],
                      phi1=0.0584, phi2=0.0694, beta=21.85, sigma2=0.3006)
    with pytest.raises(ValueError, match="moment closure of the summed preference is "
                                         "unstable for this model"):
        threshold_probabilities(model, 41.98, max_steps=3000, fallback="raise")


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
