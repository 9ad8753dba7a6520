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
from scipy.special import logsumexp, ndtr

import mdft
from mdft import MDFTModel, threshold_probabilities
from mdft import _bound_kernels
from mdft._threshold_bound import (CHERNOFF_POINTS, CHERNOFF_SPREAD, chernoff_bound,
                                   decision_bound, theta_for_bound)
from tests.test_closed_form_auto import random_model


def numpy_steps(model, max_steps):
    """For each step ``t``, from matrix powers: ``(A, mean, gauss)``, the attention columns
    ``S^k C M`` of the earlier steps ``k < t``, the mean preferences and the noise's
    variances."""
    S, C, P0, w = (np.asarray(model.S), np.asarray(model.C), np.asarray(model.P0),
                   np.asarray(model.w))
    CM = C @ np.asarray(model.M)
    powers = [np.linalg.matrix_power(S, k) for k in range(max_steps + 1)]
    for t in range(1, max_steps + 1):
        A = [powers[k] @ CM for k in range(t)]
        mean = powers[t] @ P0 + sum(a @ w for a in A)
        gauss = model.sigma2 * sum(np.sum((powers[k] @ C) ** 2, axis=1) for k in range(t))
        yield A, mean, gauss


def numpy_bound(model, theta, max_steps):
    """The bound of ``mdft._bound_kernels.reach_bound`` from matrix powers, step by step."""
    w = np.asarray(model.w)
    live = w > 0
    total = 0.0
    for A, mean, gauss in numpy_steps(model, max_steps):
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


def test_a_noiseless_path_that_touches_theta_is_not_bounded_by_zero():
    # the kernels sum the mean path in another order than the simulation: at the peak the
    # simulation computes (and a unit in the last place below it) the path decides, and the
    # bound must say nothing rather than 0 (without a margin for rounding, 21 of these 59
    # paths were bounded by 0 at their peak)
    rng = np.random.default_rng(11)
    for _ in range(60):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", mdft.UnstableFeedbackWarning)
            model = MDFTModel(rng.uniform(0.0, 2.0, (3, 1)), [1.0], phi1=rng.uniform(0.01, 1.0),
                              phi2=rng.uniform(0.0, 0.2), beta=rng.uniform(0.0, 15.0),
                              sigma2=0.0, P0=rng.uniform(-1.5, 1.0, 3))
        steps = int(rng.integers(1, 40))
        path = mdft.simulate(model, 1, stopping=mdft.Threshold(1e300, max_steps=steps), rng=0,
                             n_trajectories=1).trajectories[0, 1:]
        peak = float(path.max())
        if peak <= max(np.max(model.P0), 0.0):  # theta must be positive
            continue
        for theta in (peak, np.nextafter(peak, -np.inf)):
            assert decision_bound(model, theta, steps) == 1.0
            assert decision_bound(model, theta, steps, target=3e-5) == 1.0
            assert mdft.simulate(model, 1, stopping=mdft.Threshold(theta, max_steps=steps),
                                 rng=0).choices[0] >= 0
        assert decision_bound(model, peak * 1.01, steps, target=3e-5) == 0.0


@pytest.mark.parametrize("seed, chernoff", [(100 + k, False) for k in range(10)]
                         + [(200 + k, True) for k in range(8)])
def test_the_bound_lies_above_the_simulated_share_of_decisions(seed, chernoff):
    # random models across the documented range (2-4 options, 1-3 attributes, 2-3 where
    # the Chernoff bound is tried, sigma2 from 0.1 to 4, up to 300 steps), at a threshold
    # where the bound is about 0.05 (with the Chernoff bound tried: the smaller on 6 of the
    # 8): the simulated share of decided trials never exceeds it (one-sided, 5 standard
    # errors)
    rng = np.random.default_rng(seed)
    model = random_model(rng, int(rng.integers(2, 5)), J=int(rng.integers(1 + chernoff, 4)),
                         sigma2=float(np.exp(rng.uniform(np.log(0.1), np.log(4.0)))))
    max_steps = int(rng.choice([5, 30, 100, 300]))
    theta = theta_for_bound(model, max_steps, 0.05, chernoff=chernoff)
    bound = decision_bound(model, theta, max_steps, target=0.05 if chernoff else None)
    assert bound <= 0.05
    n = 40_000
    res = mdft.simulate(model, n, stopping=mdft.Threshold(theta, max_steps=max_steps),
                        rng=seed % 100)
    decided = float(np.mean(res.choices >= 0))
    assert decided <= bound + 5.0 * math.sqrt(bound * (1.0 - bound) / n)
    # and it is an informative bound: somewhat lower thresholds decide
    lower = mdft.simulate(model, 2_000, stopping=mdft.Threshold(0.5 * theta,
                                                                max_steps=max_steps),
                          rng=seed % 100)
    assert np.mean(lower.choices >= 0) > 0.0


def bound_args(model, theta, max_steps):
    """``decision_bound``'s arguments of the kernels."""
    return (np.asarray(model.S, dtype=float), np.asarray(model.C, dtype=float),
            np.asarray(model.C) @ np.asarray(model.M), np.asarray(model.w, dtype=float),
            np.asarray(model.P0, dtype=float), float(model.sigma2), float(theta), max_steps)


def numpy_chernoff(model, theta, max_steps, grid):
    """The Chernoff bound of ``mdft._bound_kernels.chernoff_bound`` from matrix powers: at
    each step and for each option, the smallest over its row of ``grid`` of
    ``exp(K(lambda) - lambda z)``, with the attention terms' log moment generating
    function summed over the earlier steps and the noise's ``lambda^2 V / 2``."""
    w = np.asarray(model.w)
    live = w > 0
    total = 0.0
    for A, mean, gauss in numpy_steps(model, max_steps):
        z = theta - mean
        if np.any(z <= 0):
            return 1.0
        for i, lams in enumerate(grid):
            K = 0.5 * lams**2 * gauss[i]
            for a in A:
                dev = a[i, live] - a[i] @ w
                K += np.maximum(logsumexp(np.outer(lams, dev), b=w[live], axis=1), 0.0)
            total += float(np.exp(np.min(K - lams * z[i])))
    return min(total, 1.0)


@pytest.mark.parametrize("seed", range(4))
def test_the_chernoff_kernel_computes_the_bound_it_states(seed):
    rng = np.random.default_rng(30 + seed)
    model = random_model(rng, int(rng.integers(2, 5)), J=int(rng.integers(1, 4)),
                         sigma2=float(np.exp(rng.uniform(np.log(0.1), np.log(4.0)))))
    if seed % 2:  # a start away from zero
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", mdft.UnstableFeedbackWarning)
            model = model.replace(P0=rng.uniform(-2.0, 2.0, model.n_options))
    max_steps = int(rng.integers(1, 30))
    theta = theta_for_bound(model, max_steps, 0.05, chernoff=True)
    for th in (theta, 1.3 * theta, 2.0 * theta):
        args = bound_args(model, th, max_steps)
        grid = _bound_kernels.chernoff_grid(*args, CHERNOFF_POINTS, CHERNOFF_SPREAD)
        # the grid: the Gaussian optimum z / V at the last step, spread 30 times each way
        A = [np.linalg.matrix_power(np.asarray(model.S), k) for k in range(max_steps + 1)]
        CM, w = args[2], args[3]
        z = th - (A[max_steps] @ args[4] + sum(a @ CM @ w for a in A[:max_steps]))
        V = sum(((a @ CM - (a @ CM @ w)[:, None]) ** 2) @ w
                + model.sigma2 * np.sum((a @ args[1]) ** 2, axis=1) for a in A[:max_steps])
        np.testing.assert_allclose(grid[:, 0], z / V / CHERNOFF_SPREAD, rtol=1e-9)
        np.testing.assert_allclose(grid[:, -1], z / V * CHERNOFF_SPREAD, rtol=1e-9)
        assert _bound_kernels.chernoff_bound(*args, grid, 1.0) == pytest.approx(
            numpy_chernoff(model, th, max_steps, grid), rel=1e-9, abs=1e-300)


def test_the_chernoff_bound_stops_past_its_limit_and_says_nothing_there():
    model = random_model(np.random.default_rng(5), 3, J=3, sigma2=0.3)
    theta = theta_for_bound(model, 300, 1e-3, chernoff=True)
    args = bound_args(model, theta, 300)
    full = chernoff_bound(args)
    assert 1e-4 < full <= 1e-3
    assert chernoff_bound(args, limit=2.0 * full) == full
    assert chernoff_bound(args, limit=0.5 * full) == 1.0
    # decision_bound tries it only where Hoeffding's and Bernstein's bound misses the target
    plain = decision_bound(model, theta, 300)
    assert plain > full
    assert decision_bound(model, theta, 300, target=plain) == plain
    assert decision_bound(model, theta, 300, target=2.0 * full) == full
    assert decision_bound(model, theta, 300, target=0.5 * full) == plain


def test_one_step_of_a_skewed_attention_is_bounded_above_its_exact_tail_and_below_hoeffding():
    # one step: P_i(1) is a mixture of two Gaussians (attention 0.9 / 0.1); the Chernoff
    # bound lies above the exact tail and, where the rare attribute carries the option up,
    # far below the bounds that know only the attention term's range
    model = MDFTModel([[0.0, 6.0], [1.0, 1.0], [0.5, 0.5]], [0.9, 0.1], phi1=0.05, phi2=0.05,
                      beta=10.0, sigma2=0.2)
    C, M = np.asarray(model.C), np.asarray(model.M)
    base = np.asarray(model.S) @ np.asarray(model.P0)
    sd = np.sqrt(0.2 * np.sum(C**2, axis=1))
    # option 1 moves by 5.25 where the rare attribute is attended, by -0.75 elsewhere
    for theta, factor in ((6.0, 0.5), (7.0, 0.02), (8.0, 1e-4)):
        exact = sum(wj * float(ndtr(-(theta - base - C @ M[:, j]) / sd).sum())
                    for j, wj in enumerate([0.9, 0.1]))
        bound = chernoff_bound(bound_args(model, theta, 1))
        # above the tail by less than the factor 20 of a Gaussian tail at 5 sd; below the
        # other bound by more and more as theta rises (0.30, 0.0095, 1.4e-5 of it)
        assert exact < bound < 20.0 * exact
        assert bound < factor * decision_bound(model, theta, 1)


def test_the_chernoff_bound_answers_where_hoeffding_and_bernstein_cannot():
    # a random model of the benchmark's draws (seed 5150, model 1): its attention terms
    # dominate the spread and are skewed; Hoeffding's and Bernstein's bound is 0.06 over
    # 2,000 steps, the chain ran 1.3 s to answer 1e-7, the Chernoff bound says 6e-7
    model = MDFTModel([[0.694, 1.741, 3.627], [0.887, 3.885, 0.78], [1.268, 3.21, 3.784]],
                      [0.276, 0.526, 0.198], phi1=0.0705, phi2=0.0648, beta=1.822,
                      sigma2=0.14)
    theta = 29.01
    assert decision_bound(model, theta, 2_000) > 0.05
    res = threshold_probabilities(model, theta, max_steps=2_000, fallback="raise")
    assert res.engine == "bound" and res.error_probabilities < 1e-6
    sim = mdft.simulate(model, 20_000, stopping=mdft.Threshold(theta, max_steps=2_000), rng=3)
    assert np.all(sim.choices < 0)
    # and it is an informative bound: a threshold 20 % lower decides
    lower = mdft.simulate(model, 20_000, stopping=mdft.Threshold(0.8 * theta, max_steps=2_000),
                          rng=3)
    assert np.any(lower.choices >= 0)


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
    theta = theta_for_bound(model, 200, 1e-4, chernoff=True)
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
