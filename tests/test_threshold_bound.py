"""Tests of the bound on deciding at all (mdft._threshold_bound) and of the answer
"undecided" that mdft.threshold_probabilities gives under it.

References: the bound written again with NumPy matrix powers (the same formula, an
independent implementation), the exact Gaussian tail of a single step, and the Monte
Carlo engine on random models across the documented range, where the bound must lie
above the simulated share of decided trials.
"""

import math
import warnings

import numpy as np
import pytest
from scipy.special import ndtr

import mdft
from mdft import MDFTModel, threshold_probabilities
from mdft._threshold_bound import decision_bound, theta_for_bound
from tests.test_closed_form_auto import random_model


def numpy_bound(model, theta, max_steps):
    """The bound of ``mdft._kernels.reach_bound`` from matrix powers, step by step."""
    S, C, P0, w = (np.asarray(model.S), np.asarray(model.C), np.asarray(model.P0),
                   np.asarray(model.w))
    CM = C @ np.asarray(model.M)
    live = w > 0
    powers = [np.linalg.matrix_power(S, k) for k in range(max_steps + 1)]
    total = 0.0
    for t in range(1, max_steps + 1):
        A = [powers[k] @ CM for k in range(t)]
        mean = powers[t] @ P0 + sum(a @ w for a in A)
        gauss = model.sigma2 * sum(np.sum((powers[k] @ C) ** 2, axis=1) for k in range(t))
        rng_sq = sum((a[:, live].max(axis=1) - a[:, live].min(axis=1)) ** 2 for a in A)
        var = sum(((a - (a @ w)[:, None]) ** 2) @ w for a in A)
        top = np.max([a[:, live].max(axis=1) - a @ w for a in A], axis=0)
        z = theta - mean
        if np.any(z <= 0):
            return 1.0
        hoeffding = z**2 / (0.25 * rng_sq + gauss)
        bernstein = z**2 / (var + gauss + top * z / 3.0)
        total += float(np.exp(-0.5 * np.maximum(hoeffding, bernstein)).sum())
    return min(total, 1.0)


@pytest.mark.parametrize("seed", range(4))
def test_the_kernel_computes_the_bound_it_states(seed):
    rng = np.random.default_rng(seed)
    model = random_model(rng, int(rng.integers(2, 5)), J=int(rng.integers(1, 4)),
                         sigma2=float(np.exp(rng.uniform(np.log(0.1), np.log(4.0)))))
    max_steps = int(rng.integers(1, 40))
    theta = theta_for_bound(model, max_steps, 0.05)
    for th in (theta, 1.3 * theta, 2.0 * theta):
        assert decision_bound(model, th, max_steps) == pytest.approx(
            numpy_bound(model, th, max_steps), rel=1e-9, abs=1e-300)


def test_one_step_without_attention_switches_is_a_sum_of_gaussian_tails():
    # one attribute, one step: P_i(1) = (S P0 + C M)_i + (C eps)_i, Gaussian; the bound is
    # sum_i exp(-z_i^2 / (2 v_i)), above the exact sum_i P(P_i(1) >= theta)
    model = MDFTModel([[1.0], [2.5], [0.5]], [1.0], phi1=0.05, phi2=0.05, beta=10.0,
                      sigma2=1.3)
    C = np.asarray(model.C)
    mean = np.asarray(model.S) @ np.asarray(model.P0) + C @ np.asarray(model.M)[:, 0]
    sd = np.sqrt(1.3 * np.sum(C**2, axis=1))
    for theta in (4.0, 6.0, 9.0):
        z = theta - mean
        assert decision_bound(model, theta, 1) == pytest.approx(
            float(np.exp(-0.5 * (z / sd) ** 2).sum()), rel=1e-12)
        exact = float(ndtr(-z / sd).sum())
        assert exact < decision_bound(model, theta, 1)


def test_a_deterministic_path_below_theta_is_bounded_by_zero_and_one_reaching_it_by_one():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", mdft.UnstableFeedbackWarning)
        model = MDFTModel([[1.0], [3.0], [2.0]], [1.0], phi1=0.05, phi2=0.1, beta=10.0,
                          sigma2=0.0)
    S, drive = np.asarray(model.S), np.asarray(model.C) @ np.asarray(model.M)[:, 0]
    P, highest = np.asarray(model.P0, dtype=float), -math.inf
    for _ in range(200):
        P = S @ P + drive
        highest = max(highest, float(P.max()))
    assert decision_bound(model, 1.01 * highest, 200) == 0.0
    assert decision_bound(model, 0.99 * highest, 200) == 1.0


@pytest.mark.parametrize("seed", range(10))
def test_the_bound_lies_above_the_simulated_share_of_decisions(seed):
    # random models across the documented range (2-4 options, 1-3 attributes, sigma2 from
    # 0.1 to 4, up to 300 steps), at a threshold where the bound is about 0.05: the
    # simulated share of decided trials never exceeds it (one-sided, 5 standard errors)
    rng = np.random.default_rng(100 + seed)
    model = random_model(rng, int(rng.integers(2, 5)), J=int(rng.integers(1, 4)),
                         sigma2=float(np.exp(rng.uniform(np.log(0.1), np.log(4.0)))))
    max_steps = int(rng.choice([5, 30, 100, 300]))
    theta = theta_for_bound(model, max_steps, 0.05)
    bound = decision_bound(model, theta, max_steps)
    n = 40_000
    res = mdft.simulate(model, n, stopping=mdft.Threshold(theta, max_steps=max_steps),
                        rng=seed)
    decided = float(np.mean(res.choices >= 0))
    assert decided <= bound + 5.0 * math.sqrt(bound * (1.0 - bound) / n)
    # and it is an informative bound: somewhat lower thresholds decide
    lower = mdft.simulate(model, 2_000, stopping=mdft.Threshold(0.5 * theta,
                                                                max_steps=max_steps), rng=seed)
    assert np.mean(lower.choices >= 0) > 0.0


@pytest.mark.parametrize("n_options", [2, 3, 4])
def test_an_unreachable_threshold_is_answered_undecided_without_a_chain(n_options):
    rng = np.random.default_rng(7 + n_options)
    model = random_model(rng, n_options, J=2, sigma2=0.5)
    theta = theta_for_bound(model, 2_000, 1e-6)
    res = threshold_probabilities(model, theta, max_steps=2_000, fallback="raise")
    assert res.engine == "bound" and res.method == "bound" and res.n_states == 0
    np.testing.assert_array_equal(res.probabilities, np.zeros(n_options))
    assert res.p_undecided == 1.0 and res.rt_pmf.shape == (2_000, n_options)
    assert not np.any(res.rt_pmf) and np.all(np.isnan(res.mean_response_times))
    assert res.error_probabilities == pytest.approx(decision_bound(model, theta, 2_000))
    assert res.error_probabilities <= 1e-6 and res.error_mean_rt <= 1e-4
    assert "no decision within 2000 steps" in res.summary()
    # the simulation agrees: no trial of 20,000 decides
    sim = mdft.simulate(model, 20_000, stopping=mdft.Threshold(theta, max_steps=2_000), rng=1)
    assert np.all(sim.choices < 0)


def test_the_bound_answers_only_within_the_tolerances():
    model = random_model(np.random.default_rng(21), 3, J=2, sigma2=2.0)
    # a bound of 1e-4 is within atol but, weighed as a rare option's mean time (1e-4 / 0.01),
    # not within the default rt_rtol of 3e-3: the chain answers
    theta = theta_for_bound(model, 200, 1e-4)
    assert threshold_probabilities(model, theta, max_steps=200).engine == "plane"
    res = threshold_probabilities(model, theta, max_steps=200, rt_rtol=0.02)
    assert res.engine == "bound" and res.error_mean_rt <= 0.02
    # the long run (method="solve") has no step limit to bound
    binary = random_model(np.random.default_rng(23), 2, J=2, sigma2=2.0)
    theta = theta_for_bound(binary, 200, 1e-9)
    assert threshold_probabilities(binary, theta, max_steps=200).engine == "bound"
    long_run = threshold_probabilities(binary, theta, method="solve")
    assert long_run.engine == "lattice"
    # its walks take so long to decide that the solved choices miss 9e-5 of summing to one,
    # which counts in the error estimate (test_threshold_exact.py: beyond 0.01 it refuses)
    missing = abs(long_run.probabilities.sum() - 1.0)
    assert missing > 5e-5 and long_run.error_probabilities >= missing
