"""Tests of the Monte Carlo engine: mdft.simulate, mdft.decide and their kernels.

Monte Carlo comparisons use tolerances of 3 standard errors of the difference.
The reference is the slow step-by-step NumPy code in tests/reference_numpy.py.
"""

import contextlib
import io
import json
import math
import os
import subprocess
import sys
import warnings
from pathlib import Path

import numba
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import mdft
import reference_numpy as ref
from mdft import _kernels
from mdft.simulate import (
    N_CHUNKS,
    _attention_cuts,
    _fallback_trials,
    _fixed_time_shortcut,
    _noise_factor,
    _stream_states,
)

ROOT = Path(__file__).resolve().parents[1]
CANONICAL = dict(phi1=0.022, phi2=0.05, beta=12.0)


def make_model(M, w=(0.5, 0.5), **kw):
    params = {**CANONICAL, **kw}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", mdft.UnstableFeedbackWarning)
        return mdft.MDFTModel(M, w, **params)


def from_matrices(M, w, S, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", mdft.UnstableFeedbackWarning)
        return mdft.MDFTModel.from_matrices(M, w, S=S, **kw)


COMPROMISE = [[1.0, 3.0], [3.0, 1.0], [2.0, 2.0]]


@pytest.fixture(scope="module")
def compromise():
    return make_model(COMPROMISE)


def assert_within_3se(p, q, n_p, n_q, n_se=3.0):
    """Each |p_i - q_i| within ``n_se`` standard errors of the difference of two frequencies."""
    p, q = np.asarray(p, float), np.asarray(q, float)
    pooled = (p * n_p + q * n_q) / (n_p + n_q)
    se = np.sqrt(pooled * (1 - pooled) * (1 / n_p + 1 / n_q))
    tol = n_se * np.maximum(se, 1e-12)
    assert np.all(np.abs(p - q) <= tol), (p, q, tol)


class KernelStream:
    """The kernels' xoshiro256++ stream behind the Generator methods the reference uses."""

    def __init__(self, state):
        self.state = state

    def random(self):
        return _kernels.next_double(self.state)

    def standard_normal(self, size):
        return np.array([_kernels.standard_normal(self.state) for _ in range(size)])


def one_state(seed):
    return _stream_states(np.random.default_rng(seed), 1)[0]


# ---------------------------------------------------------------- the generator
def test_xoshiro_reference_output():
    # First outputs of xoshiro256++ from the state (1, 2, 3, 4).
    state = np.array([1, 2, 3, 4], dtype=np.uint64)
    assert [int(_kernels.next_u64(state)) for _ in range(2)] == [41943041, 58720359]


def test_normal_and_uniform_draws_have_the_right_distribution():
    from scipy import stats

    @numba.njit(cache=True)
    def draws(state, n):
        z = np.empty(n)
        u = np.empty(n)
        for i in range(n):
            z[i] = _kernels.standard_normal(state)
            u[i] = _kernels.next_double(state)
        return z, u

    z, u = draws(one_state(1), 400_000)
    assert stats.kstest(z, "norm").pvalue > 1e-3
    assert stats.kstest(u, "uniform").pvalue > 1e-3
    assert abs(z.mean()) < 5 / math.sqrt(z.size)
    assert abs(z.var() - 1) < 5 * math.sqrt(2 / z.size)
    # The tail beyond the ziggurat's base (r = 3.654) is sampled separately.
    tail = np.mean(np.abs(z) > 3.6541528853610088)
    expected = 2 * stats.norm.sf(3.6541528853610088)
    assert abs(tail - expected) < 5 * math.sqrt(expected / z.size)


def test_attention_cuts_match_the_uniform_comparison():
    w = np.array([0.2, 0.0, 0.5, 0.3, 0.0])
    cuts = _attention_cuts(w)
    state = one_state(2)
    stream = KernelStream(state.copy())
    for _ in range(2000):
        assert _kernels.draw_attribute(state, cuts) == ref.attended_attribute(w, stream.random())
    # Zero-weight attributes are never attended, even the last one.
    rows = _attention_cuts(np.array([[0.5, 0.5, 0.0], [0.0, 1.0, 0.0]]))
    assert rows[0, 1] == 2**53 and rows[1, 0] == 0 and rows[1, 1] == 2**53


# ---------------------------------------------------------------- exact agreement
def dyadic_model(sigma2=0.0, P0=None, n_attributes=2):
    """A model whose arithmetic is exact in floating point (entries are multiples of 1/4)."""
    S = [[0.5, -0.25, 0.0], [-0.25, 0.5, -0.25], [0.0, -0.25, 0.75]]
    if n_attributes == 2:
        M, w = [[1.0, 3.0], [3.0, 1.0], [2.0, 2.0]], [0.25, 0.75]
    else:
        M, w = [[1.0, 3.0, 0.0], [3.0, 1.0, 1.0], [2.0, 2.0, 0.5]], [0.25, 0.25, 0.5]
    return from_matrices(M, w, S, sigma2=sigma2, P0=P0)


@pytest.mark.parametrize(
    "P0, n_attributes", [(None, 2), ([0.5, -0.25, 0.0], 2), (None, 3)], ids=str
)
def test_shortcut_equals_step_by_step_exactly_without_noise(P0, n_attributes):
    """The fixed-time shortcut is an identity: same attention draws, same choices."""
    model = dyadic_model(P0=P0, n_attributes=n_attributes)
    n_steps, n_trials = 10, 3000
    S, C = model.S, model.C
    CM = C @ model.M
    blocks, block_size, base, L = _fixed_time_shortcut(S, CM, C, model.P0, 0.0, n_steps)
    assert block_size > 1 and L.shape[1] == 0
    state = one_state(3)
    stream = KernelStream(state.copy())
    counts = np.zeros((1, 3), dtype=np.int64)
    _kernels.fixed_time_chunks(state[None].copy(), np.array([0, n_trials]), blocks, block_size,
                               n_steps, base, L, _attention_cuts(model.w), counts)
    choices = ref.simulate_fixed_time(model, n_trials, n_steps, stream)
    np.testing.assert_array_equal(counts[0], np.bincount(choices, minlength=3))


def test_step_by_step_kernel_equals_reference_draw_for_draw():
    model = make_model(COMPROMISE, P0=[0.1, -0.2, 0.0])
    n_trials, theta, max_steps = 200, 4.0, 300
    state = one_state(4)
    stream = KernelStream(state.copy())
    trajectories = np.full((n_trials, max_steps + 1, 3), np.nan)
    choices = np.empty(n_trials, dtype=np.int64)
    steps = np.empty(n_trials, dtype=np.int64)
    _kernels.plain_recorded(state, model.S, model.C @ model.M, model.C, 1.0,
                            _attention_cuts(model.w), model.P0, max_steps, theta, True,
                            trajectories, choices, steps)
    for k in range(n_trials):
        choice, step, trajectory = ref.threshold_trial(model, theta, max_steps, stream)
        assert (choices[k], steps[k]) == (choice, step)
        np.testing.assert_allclose(trajectories[k, : len(trajectory)], trajectory,
                                   rtol=1e-12, atol=1e-12)


def _scalar_kernel(n_options):
    """The kernel with the state in scalars for ``n_options`` options."""
    return _kernels.quad_trial if n_options == 4 else _kernels.small_trial


@pytest.mark.parametrize("n_options", [2, 3, 4])
def test_small_trial_equals_the_generic_kernel_to_the_bit(n_options):
    # two to four options run kernels of their own (state in scalars); on random models
    # across the documented range (with and without noise, threshold and fixed time, P0 off
    # zero, one to three attributes) each must give the generic kernel's trials exactly, and
    # leave the stream where the generic kernel leaves it
    kernel = _scalar_kernel(n_options)
    rng = np.random.default_rng(n_options)
    for draw in range(12):
        n_attributes = int(rng.integers(1, 4))
        model = make_model(rng.uniform(0.0, 4.0, (n_options, n_attributes)),
                           rng.dirichlet(np.ones(n_attributes)),
                           phi1=float(rng.uniform(0.0, 0.1)), phi2=float(rng.uniform(0.0, 0.1)),
                           beta=float(rng.uniform(1.0, 15.0)),
                           sigma2=0.0 if draw % 4 == 3 else float(rng.uniform(0.1, 4.0)),
                           P0=rng.uniform(-1.0, 1.0, n_options))
        threshold = draw % 3 != 2
        theta, n_steps = float(rng.uniform(2.0, 30.0)), int(rng.integers(1, 400))
        args = (model.S, model.C @ model.M, model.C, math.sqrt(model.sigma2),
                _attention_cuts(model.w), model.P0, n_steps, theta, threshold)
        fast, slow = one_state(draw), one_state(draw)
        P = np.empty(n_options)
        for _ in range(300):
            expected = _kernels.plain_trial(slow, *args, P.copy(), P.copy(), P.copy(),
                                            np.empty((1, n_options)), False)
            assert kernel(fast, *args, P) == expected
        np.testing.assert_array_equal(fast, slow)


def _random_threshold_model(rng, n_options, noisy=True):
    n_attributes = int(rng.integers(1, 4))
    model = make_model(rng.uniform(0.0, 4.0, (n_options, n_attributes)),
                       rng.dirichlet(np.ones(n_attributes)),
                       phi1=float(rng.uniform(0.005, 0.1)), phi2=float(rng.uniform(0.01, 0.1)),
                       beta=float(rng.uniform(0.5, 15.0)),
                       sigma2=float(np.exp(rng.uniform(np.log(0.1), np.log(4.0)))) if noisy
                       else 0.0,
                       P0=rng.uniform(-1.0, 1.0, n_options))
    return model, float(rng.uniform(2.0, 12.0))


@pytest.mark.parametrize("n_options", [2, 3])
def test_fallback_trials_have_the_distribution_of_simulate(n_options):
    # the fallback's trials draw the noise C eps from its n - 1 principal directions: on
    # random models across the documented range (sigma2 log-uniform on [0.1, 4], one to
    # three attributes, P0 off zero) their choices, undecided share and mean steps agree
    # with simulate's within 4.5 standard errors of the difference (60,000 trials each)
    rng = np.random.default_rng(40 + n_options)
    n = 60_000
    for draw in range(6):
        model, theta = _random_threshold_model(rng, n_options)
        L = _noise_factor(model.S, model.C, model.sigma2, 1)
        assert L.shape[1] == n_options - 1
        np.testing.assert_allclose(L @ L.T, model.sigma2 * model.C @ model.C.T, atol=1e-12)
        choices, steps = _fallback_trials(model, n, theta, 300, np.random.default_rng(draw))
        res = mdft.simulate(model, n, stopping=mdft.Threshold(theta, max_steps=300),
                            rng=100 + draw)
        mine = np.bincount(choices + 1, minlength=n_options + 1) / n
        theirs = np.bincount(res.choices + 1, minlength=n_options + 1) / n
        assert_within_3se(mine, theirs, n, n, n_se=4.5)
        for i in range(n_options):
            a = steps[choices == i].astype(float)
            b = res.decision_steps[res.choices == i].astype(float)
            if a.size < 100 or b.size < 100:
                continue
            se = math.hypot(a.std() / math.sqrt(a.size), b.std() / math.sqrt(b.size))
            assert abs(a.mean() - b.mean()) <= 4.5 * se + 1e-12, (draw, i)


@pytest.mark.parametrize("n_options", [2, 3, 4])
def test_fallback_trials_without_noise_are_simulates_trials(n_options):
    # with sigma2 = 0 neither kernel draws a normal, so from the same generator the trials
    # are simulate's to the bit (four options run simulate's own kernels)
    rng = np.random.default_rng(7 + n_options)
    for draw in range(3):
        model, theta = _random_threshold_model(rng, n_options, noisy=False)
        choices, steps = _fallback_trials(model, 3_000, theta, 200, np.random.default_rng(draw))
        res = mdft.simulate(model, 3_000, stopping=mdft.Threshold(theta, max_steps=200),
                            rng=np.random.default_rng(draw))
        np.testing.assert_array_equal(choices, res.choices)
        np.testing.assert_array_equal(steps, res.decision_steps)


def test_fallback_trials_are_the_same_in_parallel_and_serially(monkeypatch):
    # the same chunks and streams whether the chunks run on numba's threads or one after
    # another in the calling thread
    module = sys.modules["mdft.simulate"]
    model, theta = _random_threshold_model(np.random.default_rng(3), 3)
    runs = []
    for work in (0, 10**18):  # everything in parallel, then everything serial
        monkeypatch.setattr(module, "_PARALLEL_WORK", work)
        runs.append(_fallback_trials(model, 5_000, theta, 400, np.random.default_rng(1)))
    for a, b in zip(*runs):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("n_options", [2, 3, 4])
def test_small_trial_breaks_ties_from_where_its_stream_stands(n_options):
    # the scalar kernel holds the stream's words in local variables and writes them back
    # before a tie is broken: identical options without noise tie at every deadline, so
    # each trial draws for its tie after its attention draws, as the generic kernel does
    model = make_model(np.tile([[1.0, 2.0]], (n_options, 1)), [0.3, 0.7], phi1=0.02,
                       phi2=0.05, beta=10.0, sigma2=0.0)
    args = (model.S, model.C @ model.M, model.C, 0.0, _attention_cuts(model.w), model.P0,
            25, math.inf, False)
    fast, slow = one_state(7), one_state(7)
    P = np.empty(n_options)
    picks = []
    for _ in range(400):
        expected = _kernels.plain_trial(slow, *args, P.copy(), P.copy(), P.copy(),
                                        np.empty((1, n_options)), False)
        assert _scalar_kernel(n_options)(fast, *args, P) == expected
        picks.append(expected[0])
    np.testing.assert_array_equal(fast, slow)
    # every tied option is picked (the tie is a real draw, not a fixed index); of four
    # identical options, the rounding of S P leaves the first two tied above the others
    # (in the generic kernel too)
    assert set(picks) == (set(range(n_options)) if n_options < 4 else {0, 1})


def test_noise_factor_reproduces_the_accumulated_covariance(compromise):
    S, C = compromise.S, compromise.C
    for n_steps in (1, 2, 7, 100):
        L = _noise_factor(S, C, 2.0, n_steps)
        expected = sum(
            2.0 * np.linalg.matrix_power(S, k) @ C @ C.T @ np.linalg.matrix_power(S, k).T
            for k in range(n_steps)
        )
        np.testing.assert_allclose(L @ L.T, expected, rtol=1e-10, atol=1e-10)


# ---------------------------------------------------------------- reference, in distribution
def test_fixed_time_matches_reference(compromise):
    n_steps = 30
    res = mdft.simulate(compromise, 100_000, stopping=mdft.FixedTime(n_steps), rng=1)
    assert res.method == "shortcut"
    n_ref = 3000
    choices = ref.simulate_fixed_time(compromise, n_ref, n_steps, np.random.default_rng(2))
    assert_within_3se(res.probabilities, ref.choice_frequencies(choices, 3), res.n_samples,
                      n_ref)


def test_shortcut_matches_step_by_step_kernel(compromise):
    """Same distribution from the shortcut and from the plain kernel, with noise."""
    n_steps, n = 100, 100_000
    fast = mdft.simulate(compromise, n, stopping=mdft.FixedTime(n_steps), rng=3)
    plain = np.empty(n, dtype=np.int64)
    states = _stream_states(np.random.default_rng(4), N_CHUNKS)
    bounds = (np.arange(N_CHUNKS + 1) * n) // N_CHUNKS
    _kernels.plain_chunks(states, bounds, compromise.S, compromise.C @ compromise.M,
                          compromise.C, 1.0, _attention_cuts(compromise.w), compromise.P0,
                          n_steps, math.inf, False, plain, np.empty(n, dtype=np.int64))
    assert_within_3se(fast.probabilities, np.bincount(plain, minlength=3) / n, n, n)


def test_threshold_matches_reference(compromise):
    theta, max_steps = 6.0, 400
    res = mdft.simulate(compromise, 50_000, stopping=mdft.Threshold(theta, max_steps),
                        rng=5)
    n_ref = 2000
    choices, steps = ref.simulate_threshold(compromise, n_ref, theta, max_steps,
                                            np.random.default_rng(6))
    assert_within_3se(res.probabilities, ref.choice_frequencies(choices, 3), res.n_samples,
                      n_ref)
    # Mean response time per option within 3 standard errors.
    for i in range(3):
        a = res.response_times(i)
        b = steps[choices == i]
        se = math.sqrt(a.var() / a.size + b.var() / b.size)
        assert abs(a.mean() - res.mean_response_times[i]) < 1e-9
        assert abs(a.mean() - b.mean()) < 3 * se


def test_decide_matches_simulate():
    M = np.array([[0.9, 0.1], [0.1, 0.9], [0.5, 0.5], [0.3, 0.2]])
    params = dict(phi1=0.01, phi2=0.01, beta=2.0, sigma2=1.0)
    n = 40_000
    choices = mdft.decide(np.broadcast_to(M, (n, 4, 2)), [0.6, 0.4], n_steps=50, rng=7,
                          **params)
    model = make_model(M, [0.6, 0.4], **params)
    res = mdft.simulate(model, n, stopping=mdft.FixedTime(50), rng=8)
    assert_within_3se(np.bincount(choices, minlength=4) / n, res.probabilities, n, n)


def test_decide_with_one_weight_row_per_decision():
    M = np.broadcast_to(np.array([[1.0, 0.0], [0.0, 1.0]]), (2000, 2, 2))
    w = np.tile([[1.0, 0.0], [0.0, 1.0]], (1000, 1))
    choices = mdft.decide(M, w, phi1=0.01, phi2=0.01, beta=2.0, sigma2=0.0, n_steps=5, rng=0)
    np.testing.assert_array_equal(choices, np.tile([0, 1], 1000))
    single = mdft.decide(M[0], [1.0, 0.0], phi1=0.01, phi2=0.01, beta=2.0, sigma2=0.0,
                         n_steps=5, rng=0)
    assert isinstance(single, int) and single == 0


# ---------------------------------------------------------------- results
def test_threshold_result_fields(compromise):
    res = mdft.simulate(compromise, 3000, stopping=mdft.Threshold(10.0, 2000), rng=0,
                        n_trajectories=5)
    decided = res.choices >= 0
    assert np.all(res.decision_steps[decided] >= 1)
    assert np.all(res.decision_steps[decided] <= 2000)
    np.testing.assert_array_equal(res.counts, np.bincount(res.choices[decided], minlength=3))
    np.testing.assert_allclose(res.response_time_pmf().sum(axis=0), res.probabilities)
    np.testing.assert_allclose(
        res.standard_errors, np.sqrt(res.probabilities * (1 - res.probabilities) / 3000)
    )
    # Recorded trials are the first trials of the result.
    np.testing.assert_array_equal(res.trajectory_choices, res.choices[:5])
    for k in range(5):
        t = res.decision_steps[k]
        traj = res.trajectories[k]
        np.testing.assert_array_equal(traj[0], compromise.P0)
        assert traj[t].max() >= 10.0 and np.all(traj[:t].max(axis=1) < 10.0)
        assert np.argmax(traj[t]) == res.choices[k]
        assert np.all(np.isnan(traj[t + 1:]))
    assert res.trajectories.shape[1] == res.decision_steps[:5].max() + 1
    with pytest.raises(TypeError, match="option must be an integer"):
        res.response_times(0.5)
    with pytest.raises(ValueError, match=r"option must lie in \[0, 2\]"):
        res.response_times(3)


def test_fixed_time_trajectories(compromise):
    res = mdft.simulate(compromise, 100, stopping=mdft.FixedTime(20), rng=0,
                        n_trajectories=4)
    assert res.trajectories.shape == (4, 21, 3)
    assert not np.isnan(res.trajectories).any()
    np.testing.assert_array_equal(res.trajectories[:, -1].argmax(axis=1), res.trajectory_choices)
    assert res.counts.sum() == 100 and res.choices is None and res.decision_steps is None
    with pytest.raises(ValueError, match="response_time_pmf needs a result of threshold stopping"):
        res.response_time_pmf()
    with pytest.raises(ValueError, match="response_times needs a result of threshold stopping"):
        res.response_times(0)


def test_undecided_trials_are_counted_not_dropped(compromise):
    res = mdft.simulate(compromise, 500, stopping=mdft.Threshold(1e6, max_steps=20), rng=0)
    assert res.n_undecided == 500 and res.p_undecided == 1.0
    assert res.counts.sum() == 0 and np.all(res.choices == -1)
    assert np.all(res.decision_steps == -1) and np.isnan(res.mean_response_times).all()
    some = mdft.simulate(compromise, 4000, stopping=mdft.Threshold(12.0, max_steps=60), rng=0)
    assert 0 < some.n_undecided < 4000
    assert some.n_undecided == np.sum(some.choices == -1)
    assert math.isclose(some.probabilities.sum() + some.p_undecided, 1.0)


def test_result_is_frozen(compromise):
    res = mdft.simulate(compromise, 100, stopping=mdft.FixedTime(5), rng=0)
    with pytest.raises(AttributeError, match="cannot assign to field 'n_samples'"):
        res.n_samples = 3
    with pytest.raises(ValueError, match="read-only"):
        res.probabilities[0] = 1.0


# ---------------------------------------------------------------- reproducibility
@pytest.mark.parametrize(
    "stopping", [mdft.FixedTime(50), mdft.Threshold(8.0, max_steps=500)], ids=repr
)
def test_same_seed_same_result(compromise, stopping):
    a = mdft.simulate(compromise, 5000, stopping=stopping, rng=11, n_trajectories=2)
    b = mdft.simulate(compromise, 5000, stopping=stopping, rng=np.random.default_rng(11),
                      n_trajectories=2)
    c = mdft.simulate(compromise, 5000, stopping=stopping, rng=12, n_trajectories=2)
    np.testing.assert_array_equal(a.counts, b.counts)
    np.testing.assert_array_equal(a.trajectories, b.trajectories)
    assert not np.array_equal(a.trajectories, c.trajectories)
    if isinstance(stopping, mdft.Threshold):
        np.testing.assert_array_equal(a.decision_steps, b.decision_steps)
    gen = np.random.default_rng(0)
    first = mdft.simulate(compromise, 2000, stopping=stopping, rng=gen)
    second = mdft.simulate(compromise, 2000, stopping=stopping, rng=gen)
    assert not np.array_equal(first.counts, second.counts)  # the generator advanced


def test_same_result_with_one_and_two_threads(compromise):
    def run():
        fixed = mdft.simulate(compromise, 20_000, stopping=mdft.FixedTime(100), rng=3)
        thr = mdft.simulate(compromise, 3000, stopping=mdft.Threshold(10.0, 1000), rng=3)
        M = np.random.default_rng(0).random((3000, 8, 2))
        dec = mdft.decide(M, [0.5, 0.5], phi1=0.01, phi2=0.01, beta=2.0, n_steps=100, rng=3)
        return fixed.counts, thr.choices, thr.decision_steps, dec

    before = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        one = run()
        numba.set_num_threads(min(2, numba.config.NUMBA_NUM_THREADS))
        two = run()
    finally:
        numba.set_num_threads(before)
    for a, b in zip(one, two):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("stopping", [mdft.FixedTime(30), mdft.Threshold(6.0, 200)], ids=repr)
def test_serial_and_parallel_runs_agree(compromise, stopping, monkeypatch):
    """Small jobs run the chunks serially, large ones in parallel: same chunks, same result."""
    module = sys.modules["mdft.simulate"]
    M = np.random.default_rng(1).random((300, 5, 2))
    results = []
    for work in (0, 10**12):  # everything in parallel, then everything serial
        monkeypatch.setattr(module, "_PARALLEL_WORK", work)
        res = mdft.simulate(compromise, 3000, stopping=stopping, rng=9, n_trajectories=2)
        dec = mdft.decide(M, [0.4, 0.6], phi1=0.01, phi2=0.01, beta=2.0, n_steps=20, rng=9)
        results.append((res.counts, res.choices, res.trajectories, dec))
    for a, b in zip(*results):
        np.testing.assert_array_equal(a, b)


_NOJIT_SCRIPT = """
import json, warnings
import numpy as np
import mdft
warnings.simplefilter("ignore")
model = mdft.MDFTModel([[1, 3], [3, 1], [2, 2]], [0.5, 0.5], phi1=0.022, phi2=0.05, beta=12.0)
fixed = mdft.simulate(model, 150, stopping=mdft.FixedTime(12), rng=5, n_trajectories=2)
thr = mdft.simulate(model, 100, stopping=mdft.Threshold(3.0, max_steps=40), rng=5)
dec = mdft.decide(np.random.default_rng(0).random((6, 4, 2)), [0.3, 0.7], phi1=0.01,
                  phi2=0.01, beta=2.0, n_steps=15, rng=5)
print(json.dumps({"fixed": fixed.counts.tolist(), "traj": fixed.trajectories.tolist(),
                  "choices": thr.choices.tolist(), "steps": thr.decision_steps.tolist(),
                  "decide": dec.tolist()}))
"""


def test_compiled_and_pure_python_agree():
    env = {**os.environ, "NUMBA_DISABLE_JIT": "1", "PYTHONPATH": str(ROOT)}
    out = subprocess.run([sys.executable, "-c", _NOJIT_SCRIPT], env=env, cwd=ROOT,
                         capture_output=True, text=True, timeout=300, check=True)
    nojit = json.loads(out.stdout)
    namespace = {}
    buffer = io.StringIO()
    with contextlib.redirect_stdout(buffer):
        exec(_NOJIT_SCRIPT, namespace)
    compiled = json.loads(buffer.getvalue())
    assert compiled["fixed"] == nojit["fixed"]
    assert compiled["choices"] == nojit["choices"]
    assert compiled["steps"] == nojit["steps"]
    assert compiled["decide"] == nojit["decide"]
    np.testing.assert_allclose(compiled["traj"], nojit["traj"], rtol=1e-12)


# ---------------------------------------------------------------- properties
option_rows = st.lists(
    st.tuples(st.floats(0.0, 4.0), st.floats(0.0, 4.0)), min_size=2, max_size=4, unique=True
)


@settings(max_examples=15, deadline=None)
@given(M=option_rows, w0=st.floats(0.05, 0.95), threshold=st.booleans(),
       seed=st.integers(0, 2**32 - 1))
def test_probabilities_and_undecided_sum_to_one(M, w0, threshold, seed):
    model = make_model(M, [w0, 1 - w0])
    stopping = mdft.Threshold(5.0, max_steps=50) if threshold else mdft.FixedTime(20)
    res = mdft.simulate(model, 500, stopping=stopping, rng=seed)
    assert math.isclose(res.probabilities.sum() + res.p_undecided, 1.0)
    assert res.counts.sum() + res.n_undecided == 500


# Monte Carlo properties: the examples are derandomised (a fixed set, like the seeds), and
# the permutation test, which makes about 25 comparisons, allows 4 standard errors.
@settings(max_examples=8, deadline=None, derandomize=True)
@given(M=option_rows, perm_seed=st.integers(0, 1000), threshold=st.booleans())
def test_permuting_options_permutes_probabilities(M, perm_seed, threshold):
    M = np.array(M)
    perm = np.random.default_rng(perm_seed).permutation(len(M))
    stopping = mdft.Threshold(6.0, max_steps=300) if threshold else mdft.FixedTime(40)
    n = 20_000
    a = mdft.simulate(make_model(M), n, stopping=stopping, rng=1)
    b = mdft.simulate(make_model(M[perm]), n, stopping=stopping, rng=2)
    assert_within_3se(a.probabilities[perm], b.probabilities, n, n, n_se=4.0)


@settings(max_examples=10, deadline=None, derandomize=True)
@given(M=option_rows, worse=st.floats(2.0, 4.0), threshold=st.booleans())
def test_clearly_dominated_option_is_almost_never_chosen(M, worse, threshold):
    M = np.array(M)
    dominated = M[0] - worse  # worse than option 0 on every attribute
    model = make_model(np.vstack([M, dominated]))
    stopping = mdft.Threshold(10.0, max_steps=2000) if threshold else mdft.FixedTime(100)
    res = mdft.simulate(model, 3000, stopping=stopping, rng=0)
    assert res.probabilities[-1] < 0.01


@settings(max_examples=15, deadline=None)
@given(values=st.lists(st.integers(-30, 30), min_size=2, max_size=5, unique=True),
       n_steps=st.integers(1, 50))
def test_one_attribute_without_noise_is_deterministic(values, n_steps):
    # Evaluations on a grid of 0.1: distinct options stay numerically distinct.
    model = make_model([[v / 10] for v in values], [1.0], sigma2=0.0)
    res = mdft.simulate(model, 300, stopping=mdft.FixedTime(n_steps), rng=0)
    _, trajectory = ref.fixed_time_trial(model, n_steps, np.random.default_rng(0))
    last = trajectory[-1]
    # every trial picks the reference's best option; exact ties are shared among the tied
    best = last == last.max()
    assert res.counts[~best].sum() == 0, (last, res.counts)
    if best.sum() == 1:
        assert res.counts[np.argmax(last)] == 300


def test_real_ties_are_broken_uniformly():
    # Two identical options and no noise: P_0(t) == P_1(t) exactly at every step.
    model = make_model([[1.0, 2.0], [1.0, 2.0], [0.0, 0.0]], sigma2=0.0)
    n = 20_000
    for stopping in (mdft.FixedTime(30), mdft.Threshold(2.0, max_steps=100)):
        res = mdft.simulate(model, n, stopping=stopping, rng=0)
        assert res.counts[2] == 0
        assert abs(res.probabilities[0] - 0.5) < 3 * math.sqrt(0.25 / n)


# ---------------------------------------------------------------- bad input
def test_stopping_rules_validate():
    with pytest.raises(ValueError, match=r"n_steps must be an integer >= 1 \(got 0\)"):
        mdft.FixedTime(0)
    with pytest.raises(TypeError, match="n_steps must be an integer"):
        mdft.FixedTime(10.5)
    with pytest.raises(ValueError, match=r"theta must be > 0.0 \(got 0.0\)"):
        mdft.Threshold(0.0)
    with pytest.raises(ValueError, match=r"theta must be > 0.0 \(got -1.0\)"):
        mdft.Threshold(-1.0)
    with pytest.raises(ValueError, match="theta must be finite"):
        mdft.Threshold(float("inf"))
    with pytest.raises(ValueError, match="theta must be finite"):
        mdft.Threshold(float("nan"))
    with pytest.raises(ValueError, match=r"max_steps must be an integer >= 1 \(got 0\)"):
        mdft.Threshold(1.0, max_steps=0)
    with pytest.raises(TypeError, match="max_steps must be an integer"):
        mdft.Threshold(1.0, max_steps=2.0)


def test_simulate_validates(compromise):
    fixed = mdft.FixedTime(10)
    with pytest.raises(TypeError, match="model must be an MDFTModel"):
        mdft.simulate(np.eye(2), 10, stopping=fixed)
    with pytest.raises(ValueError, match=r"n_samples must be an integer >= 1 \(got 0\)"):
        mdft.simulate(compromise, 0, stopping=fixed)
    with pytest.raises(TypeError, match="n_samples must be an integer"):
        mdft.simulate(compromise, 10.0, stopping=fixed)
    with pytest.raises(TypeError, match=r"stopping must be mdft.FixedTime\(n_steps\)"):
        mdft.simulate(compromise, 10, stopping=100)
    with pytest.raises(ValueError, match=r"n_trajectories must be an integer >= 0 \(got -1\)"):
        mdft.simulate(compromise, 10, stopping=fixed, n_trajectories=-1)
    with pytest.raises(ValueError, match=r"n_trajectories must be <= min\(n_samples, 1000\)"):
        mdft.simulate(compromise, 10, stopping=fixed, n_trajectories=11)
    with pytest.raises(TypeError, match="n_trajectories must be an integer"):
        mdft.simulate(compromise, 10, stopping=fixed, n_trajectories=1.5)
    with pytest.raises(ValueError, match="more than 20,000,000; record fewer trajectories"):
        mdft.simulate(compromise, 1000, stopping=mdft.Threshold(5.0, max_steps=10_000),
                      n_trajectories=1000)
    # rho(S) = 1.0089 for the compromise set: 1.0089**100_000 overflows.
    with pytest.raises(ValueError, match=r"preferences overflow over n_steps=100000 steps"):
        mdft.simulate(compromise, 10, stopping=mdft.FixedTime(100_000))
    # Evaluations whose valence moments overflow are refused when the model is built.
    with pytest.raises(ValueError, match=r"M, C and sigma2 are too large for floating point: "
                                         r"the mean or covariance of the valence overflows"):
        from_matrices([[1e308, 0.0], [0.0, 1e308]], [0.5, 0.5], np.eye(2))
    high = make_model(COMPROMISE, P0=[0.0, 5.0, 0.0])
    with pytest.raises(ValueError, match="model.P0 must lie below the threshold theta=5"):
        mdft.simulate(high, 10, stopping=mdft.Threshold(5.0))


DECIDE = dict(phi1=0.01, phi2=0.01, beta=2.0, n_steps=10)


@pytest.mark.parametrize(
    "M, w, kw, error, match",
    [
        (np.zeros(3), [1.0], {}, ValueError, r"M must have shape \(n_options, n_attributes\)"),
        (np.zeros((1, 2, 3, 4)), [0.5] * 4, {}, ValueError, "M must have shape"),
        (np.zeros((0, 3, 2)), [0.5, 0.5], {}, ValueError, "M must hold at least one decision"),
        (np.zeros((1, 2)), [0.5, 0.5], {}, ValueError, "M must have at least 2 options"),
        (np.zeros((3, 0)), [], {}, ValueError, "M must have at least 1 attribute"),
        ([[1.0, np.nan], [0.0, 1.0]], [0.5, 0.5], {}, ValueError, "M must contain only finite"),
        ([[1.0, np.inf], [0.0, 1.0]], [0.5, 0.5], {}, ValueError, "M must contain only finite"),
        ([["a", "b"], ["c", "d"]], [0.5, 0.5], {}, TypeError, "M must be an array of real"),
        (np.zeros((2, 2)), [1.0], {}, ValueError, r"w must have shape \(2,\) or \(1, 2\)"),
        (np.zeros((4, 2, 2)), np.full((3, 2), 0.5), {}, ValueError,
         r"w must have shape \(2,\) or \(4, 2\)"),
        (np.zeros((2, 2)), [1.5, -0.5], {}, ValueError, "w must be non-negative"),
        (np.zeros((2, 2)), [0.5, 0.4], {}, ValueError, r"w must sum to 1 \(got 0.9\)"),
        (np.zeros((2, 2)), [0.5, np.nan], {}, ValueError, "w must contain only finite"),
        (np.zeros((2, 2)), [0.5, 0.5], {"phi1": -1.0}, ValueError, r"phi1 must be >= 0.0"),
        (np.zeros((2, 2)), [0.5, 0.5], {"phi2": np.inf}, ValueError, "phi2 must be finite"),
        (np.zeros((2, 2)), [0.5, 0.5], {"beta": [1.0, 2.0]}, TypeError,
         "beta must be a real number"),
        (np.zeros((2, 2)), [0.5, 0.5], {"sigma2": -0.1}, ValueError, r"sigma2 must be >= 0.0"),
        (np.zeros((2, 2)), [0.5, 0.5], {"sigma2": np.nan}, ValueError, "sigma2 must be finite"),
        (np.zeros((2, 2)), [0.5, 0.5], {"n_steps": 0}, ValueError,
         r"n_steps must be an integer >= 1 \(got 0\)"),
        (np.zeros((2, 2)), [0.5, 0.5], {"n_steps": 2.5}, TypeError, "n_steps must be an integer"),
    ],
)
def test_decide_validates(M, w, kw, error, match):
    with pytest.raises(error, match=match):
        mdft.decide(M, w, **{**DECIDE, **kw})


def test_decide_refuses_overflow_like_simulate():
    """rho(S) = 3.5 over 1000 steps: decide raises the error simulate raises."""
    M = np.array([[1.0, 3.0], [3.0, 1.0], [2.0, 2.0]])
    kw = dict(phi1=0.0, phi2=1.5, beta=1.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", mdft.UnstableFeedbackWarning)
        model = mdft.MDFTModel(M, [0.5, 0.5], **kw)
    assert model.spectral_radius == pytest.approx(3.5)
    match = r"preferences overflow over n_steps=1000 steps.*spectral radius 3.5 > 1"
    with pytest.raises(ValueError, match=match):
        mdft.simulate(model, 10, stopping=mdft.FixedTime(1000), rng=0)
    with pytest.raises(ValueError, match=match):
        mdft.decide(M, [0.5, 0.5], n_steps=1000, rng=0, **kw)
    # a batch is checked too
    batch = np.stack([M * 0.1] * 5 + [M])
    with pytest.raises(ValueError, match=match):
        mdft.decide(batch, [0.5, 0.5], n_steps=1000, rng=0, **kw)
    # growth that stays inside floating point is allowed, as in simulate
    assert mdft.decide(M, [0.5, 0.5], n_steps=500, rng=0, **kw) in (0, 1, 2)
    ok = dict(phi1=0.022, phi2=0.05, beta=12.0)
    assert mdft.decide(M, [0.5, 0.5], n_steps=1000, rng=0, **ok) in (0, 1, 2)


def test_decide_refuses_preferences_that_overflow_below_the_growth_check():
    # rho(S) = 2 over 900 steps stays below the growth check (900 ln 2 = 624 < 690), but M
    # spans 1e60: the preferences overflow, and a choice among them would mean nothing
    M = [[0.0, 1e60], [1e60, 0.0]]
    with pytest.raises(ValueError, match=r"preferences overflow over n_steps=900 steps in 40 "
                                         r"of 40 decisions"):
        mdft.decide([M] * 40, [0.5, 0.5], phi1=1.0, phi2=3.0, beta=1.0, n_steps=900, rng=1)


def test_complex_input_is_refused_not_cut_to_its_real_part():
    M = np.array([[1 + 5j, 3], [3, 1]])
    with pytest.raises(TypeError, match="M must be an array of real numbers"):
        mdft.MDFTModel(M, [0.5, 0.5], phi1=0.022, phi2=0.05, beta=12.0)
    with pytest.raises(TypeError, match="w must be an array of real numbers"):
        mdft.MDFTModel([[1, 3], [3, 1]], np.array([0.5 + 1j, 0.5 - 1j]), phi1=0.022,
                       phi2=0.05, beta=12.0)
    with pytest.raises(TypeError, match="must be an array of real numbers"):
        mdft.decide(M, [0.5, 0.5], phi1=0.022, phi2=0.05, beta=12.0, n_steps=5, rng=0)
    with pytest.raises(TypeError, match="phi1 must be a real number"):
        mdft.MDFTModel([[1, 3], [3, 1]], [0.5, 0.5], phi1=np.complex128(0.02), phi2=0.05,
                       beta=12.0)


def test_a_threshold_near_the_largest_float_is_refused():
    # a preference could pass theta = 1.7e308 as infinity; the threshold stops at 1e300
    with pytest.raises(ValueError, match=r"theta must be <= 1e\+300 \(got 1.7e\+308\)"):
        mdft.Threshold(1.7e308)
    model = mdft.MDFTModel([[1, 3], [3, 1]], [0.5, 0.5], phi1=0.022, phi2=0.05, beta=12.0)
    with pytest.raises(ValueError, match=r"theta must be <= 1e\+300"):
        mdft.threshold_probabilities(model, 1e301)
    assert mdft.Threshold(1e300).theta == 1e300


def test_a_noise_covariance_that_overflows_before_the_preferences_is_stepped():
    # rho(S) = 1.0089 over 50,000 steps: the preferences reach about 1e193 (finite), their
    # summed noise covariance about 1e386 (not): simulate steps instead of refusing, as
    # decide answers
    model = mdft.MDFTModel([[1, 3], [3, 1], [2, 2]], [0.5, 0.5], phi1=0.022, phi2=0.05,
                           beta=12.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", mdft.UnstableFeedbackWarning)
        res = mdft.simulate(model, 200, stopping=mdft.FixedTime(50_000), rng=0)
    assert res.method == "step-by-step" and res.counts.sum() == 200
