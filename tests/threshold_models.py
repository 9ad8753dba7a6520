"""Models shared by the threshold-stopping tests: the canonical context-effect sets and
random models drawn across the documented range (as ``benchmarks/bench_threshold_exact.py``
draws them)."""

import math
import warnings

import numpy as np

import mdft
from mdft import MDFTModel

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
