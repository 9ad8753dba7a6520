"""choice_probabilities vouches for its answer: the error estimate, the fallbacks, the raises.

References: exact enumeration of attention sequences (itself checked against simulation
here), the exact mixture with an independent seed, and MDFT simulation, with Monte Carlo
tolerances in standard errors.
"""

import re
import warnings

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as hst

import mdft
from mdft import closed_form as cf
from mdft import _orthant as orthant
from mdft._edgeworth import lumpiness
from mdft.closed_form import (_LUMPY_MAX, DEFAULT_TOL, _enumerated_probabilities,
                              _fixed_time_probabilities, _normal_error, choice_probabilities,
                              mixture_choice_probabilities)

TOL = DEFAULT_TOL


def random_model(rng, n, *, sigma2=None, phi2_max=0.5, J=None):
    """A model drawn across the documented ranges (2-8 options, 1-4 attributes)."""
    J = int(rng.integers(1, 5)) if J is None else J
    M = rng.uniform(0.0, 5.0, size=(n, J))
    w = rng.dirichlet(np.ones(J))
    if sigma2 is None:
        sigma2 = float(np.exp(rng.uniform(np.log(0.01), np.log(4.0))))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", mdft.UnstableFeedbackWarning)
        return mdft.MDFTModel(M, w, phi1=rng.uniform(0.005, 0.1), phi2=rng.uniform(0, phi2_max),
                              beta=rng.uniform(0.0, 15.0), sigma2=sigma2)


def quiet(fn, *args, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", mdft.UnstableFeedbackWarning)
        return fn(*args, **kw)


def estimate(model, T):
    mean, cov = quiet(mdft.preference_moments, model, T)
    p = quiet(choice_probabilities, model, T, method="normal")
    return p, _normal_error(model, T, mean, cov, p)


def lumpy(model, T):
    _, cov = quiet(mdft.preference_moments, model, T)
    return lumpiness(cov, np.asarray(model.C) @ np.asarray(model.M), np.asarray(model.w))


def max_enumerable_steps(model):
    J = int(np.count_nonzero(np.asarray(model.w) > 0))
    return 12 if J <= 1 else int(np.floor(np.log(4096) / np.log(J) + 1e-9))


# ------------------------------------------------------------------ exact references
@settings(max_examples=15, deadline=None)
@given(seed=hst.integers(0, 2**32 - 1), n=hst.integers(2, 6), noisy=hst.booleans())
def test_enumeration_matches_simulation(seed, n, noisy):
    rng = np.random.default_rng(seed)
    noisy = noisy and n <= 3  # with noise, enumeration handles 2 or 3 options
    model = random_model(rng, n, sigma2=None if noisy else 0.0)
    T = int(rng.integers(1, max_enumerable_steps(model) + 1))
    p = quiet(_enumerated_probabilities, model, T)
    assert abs(p.sum() - 1) < 1e-12 and np.all(p >= 0)
    n_trials = 40_000
    sim = quiet(mdft.simulate, model, n_trials, stopping=mdft.FixedTime(T), rng=seed)
    se = np.sqrt(np.maximum(p * (1 - p), 1e-12) / n_trials)
    assert np.all(np.abs(sim.probabilities - p) <= 4.5 * se + 1e-9), (p, sim.probabilities)


# ------------------------------------------------------------------ the contract
@settings(max_examples=40, deadline=None)
@given(seed=hst.integers(0, 2**32 - 1), n=hst.integers(2, 3))
def test_estimate_tracks_the_error_where_it_takes_over(seed, n):
    """Random 2-3 option models at the longest T that can still be enumerated (beyond it
    ``method="auto"`` relies on the estimate): the exact law is known there."""
    rng = np.random.default_rng(seed)
    model = random_model(rng, n, J=int(rng.integers(2, 5)))
    T = max_enumerable_steps(model)
    exact = quiet(_enumerated_probabilities, model, T)
    p, est = estimate(model, T)
    err = np.abs(p - exact).max()
    if lumpy(model, T) > _LUMPY_MAX:
        return  # the estimate is not used (test_lumpy_models_are_not_trusted)
    # accepted by the estimate -> within tol; and it never under-reports badly
    assert est.max() > TOL / 2 or err <= TOL, (err, est)
    assert est.max() >= err / 4 or err < 5e-4, (err, est)


@settings(max_examples=20, deadline=None)
@given(seed=hst.integers(0, 2**32 - 1), n=hst.integers(2, 6))
def test_auto_enumerates_short_deliberations(seed, n):
    rng = np.random.default_rng(seed)
    model = random_model(rng, n, sigma2=None if n <= 3 else 0.0)
    T = int(rng.integers(1, max_enumerable_steps(model) + 1))
    np.testing.assert_array_equal(quiet(choice_probabilities, model, T, tol=0.5),
                                  quiet(_enumerated_probabilities, model, T))


@settings(max_examples=8, deadline=None)
@given(seed=hst.integers(0, 2**32 - 1), n=hst.integers(2, 3))
def test_auto_is_within_tol_of_the_mixture_long_deliberations(seed, n):
    rng = np.random.default_rng(seed)
    model = random_model(rng, n, J=int(rng.integers(2, 5)))
    T = int(np.exp(rng.uniform(np.log(20), np.log(300))))
    try:
        auto = quiet(choice_probabilities, model, T)
    except ValueError as exc:  # only where the exact mixture would cost too much
        assert re.search(r"the exact mixture (would need|cannot reach)", str(exc)), exc
        return
    mix = quiet(mixture_choice_probabilities, model, T, n_sequences=40_000, rng=seed)
    assert np.all(np.abs(auto - mix.probabilities) <= TOL + 3 * mix.standard_errors)


@settings(max_examples=8, deadline=None)
@given(seed=hst.integers(0, 2**32 - 1), n=hst.integers(4, 8))
@example(seed=10007, n=4)  # an attribute of weight 0: nearly collinear control variates
def test_auto_many_options_is_within_tol_of_simulation(seed, n):
    # four or more options: the normal answer where the estimate vouches for it, else the
    # exact mixture (randomised separation of variables per sequence); it raises only
    # where the mixture would cost more than its limit
    rng = np.random.default_rng(seed)
    model = random_model(rng, n, sigma2=float(rng.uniform(0.2, 4.0)), phi2_max=0.2)
    T = int(rng.integers(5, 150))
    try:
        p = quiet(choice_probabilities, model, T)
    except ValueError as exc:
        assert re.search(r"the exact mixture (would need|cannot reach)", str(exc)), exc
        return
    n_trials = 100_000
    sim = quiet(mdft.simulate, model, n_trials, stopping=mdft.FixedTime(T), rng=seed)
    se = np.sqrt(np.maximum(p * (1 - p), 1e-12) / n_trials)
    assert np.all(np.abs(sim.probabilities - p) <= TOL + 4 * se), (p, sim.probabilities)


def test_control_variates_that_are_nearly_collinear_do_not_move_the_mean():
    # two control variates that differ by a tiny spread and a rounding-sized offset of
    # their known mean (unrelated to f): a regression that kept that direction would turn
    # the offset into an adjustment of about a hundred standard errors
    rng = np.random.default_rng(5)
    N = 4000
    f = rng.random((N, 3))
    z = rng.standard_normal(N)
    z -= z.mean()
    X = np.column_stack([z, z + 1e-9 * rng.standard_normal(N) + 1e-7, rng.standard_normal(N)])
    est, se = cf._control_variate_mean(f, X / X.std(axis=0))
    plain_se = f.std(axis=0, ddof=1) / np.sqrt(N)
    assert np.all(np.abs(est - f.mean(axis=0)) <= 5 * plain_se)
    assert np.all(se > 0.5 * plain_se)


def test_too_few_sequences_for_the_control_variates_use_the_plain_mean():
    rng = np.random.default_rng(6)
    f = rng.random((100, 4))
    X = rng.standard_normal((100, 14))
    est, se = cf._control_variate_mean(f, X)
    np.testing.assert_array_equal(est, f.mean(axis=0))
    np.testing.assert_allclose(se, f.std(axis=0, ddof=1) / 10.0)


@settings(max_examples=6, deadline=None)
@given(seed=hst.integers(0, 2**32 - 1), n=hst.integers(4, 7))
def test_many_option_mixture_is_unbiased_against_simulation(seed, n):
    # the mixture's own standard errors, not tol: the comparison can see a bias of a few 1e-3
    rng = np.random.default_rng(seed)
    model = random_model(rng, n, sigma2=float(np.exp(rng.uniform(np.log(0.05), np.log(4.0)))),
                         phi2_max=0.2)
    T = int(rng.integers(2, 80))
    mix = quiet(mixture_choice_probabilities, model, T, n_sequences=20_000, rng=seed)
    assert abs(mix.probabilities.sum() - 1) < 1e-12
    n_trials = 200_000
    sim = quiet(mdft.simulate, model, n_trials, stopping=mdft.FixedTime(T), rng=seed + 1)
    q = sim.probabilities
    se = np.sqrt(np.maximum(q * (1 - q), 1.0 / n_trials) / n_trials + mix.standard_errors**2)
    assert np.all(np.abs(mix.probabilities - q) <= 4.5 * se), (mix.probabilities, q, se)


# ------------------------------------------------------------------ where it switches
SIMILARITY = [[1.0, 3.0], [3.0, 1.0], [0.9, 3.1]]


def canonical(M=SIMILARITY, **kw):
    params = dict(phi1=0.022, phi2=0.05, beta=12.0, sigma2=1.0)
    params.update(kw)
    return quiet(mdft.MDFTModel, M, [0.5, 0.5], **params)


@pytest.mark.parametrize("T", [13, 40])
def test_switch_happens_exactly_where_the_estimate_says(T):
    model = canonical(phi2=0.12, sigma2=0.5)
    p, est = estimate(model, T)
    e = float(est.max())
    assert e > 0
    below = choice_probabilities(model, T, tol=2 * e * 1.001)
    np.testing.assert_array_equal(below, p)  # estimate within tol/2: the normal answer
    above = choice_probabilities(model, T, tol=2 * e * 0.999)
    assert not np.array_equal(above, p)
    # the exact mixture with the fixed seed: deterministic, and within tol of an
    # independent run
    np.testing.assert_array_equal(above, choice_probabilities(model, T, tol=2 * e * 0.999))
    mix = mixture_choice_probabilities(model, T, n_sequences=50_000, rng=1)
    assert np.all(np.abs(above - mix.probabilities) <= 2 * e + 3 * mix.standard_errors)


def test_common_cases_stay_on_the_normal_approximation():
    # the canonical sets at T = 100 and the orchestrator's 8-action models (paper settings)
    for M in (SIMILARITY, [[1, 3], [3, 1], [2, 2]], [[1, 3], [3, 1], [0.5, 2.5]]):
        m = canonical(M)
        np.testing.assert_array_equal(choice_probabilities(m, 100),
                                      choice_probabilities(m, 100, method="normal"))
    rng = np.random.default_rng(0)
    for _ in range(3):
        sq = rng.dirichlet(np.ones(8), size=2).T
        m = quiet(mdft.MDFTModel, sq, [0.55, 0.45], phi1=0.01, phi2=0.01, beta=2.0, sigma2=1.0)
        _, est = estimate(m, 100)
        assert est.max() < 1e-3
        np.testing.assert_array_equal(choice_probabilities(m, 100),
                                      choice_probabilities(m, 100, method="normal"))


def test_exact_gaussian_cases_have_zero_estimate():
    # one attribute: no attention randomness, P(T) is exactly normal
    m = quiet(mdft.MDFTModel, [[1.0], [3.0], [2.0]], [1.0], phi1=0.02, phi2=0.3, beta=2.0,
              sigma2=0.05)
    _, est = estimate(m, 30)
    assert np.all(est == 0)
    # mirror-image binary set: the error terms vanish by symmetry, as the error does
    _, est = estimate(canonical([[1.0, 3.0], [3.0, 1.0]]), 30)
    np.testing.assert_allclose(est, 0.0, atol=1e-12)


def test_raises_where_no_exact_method_applies():
    rng = np.random.default_rng(5)
    M = rng.uniform(0, 5, size=(5, 2))
    m = quiet(mdft.MDFTModel, M, [0.3, 0.7], phi1=0.02, phi2=0.4, beta=5.0, sigma2=0.05)
    # the normal approximation is off here (estimate above tol / 2): the exact mixture answers
    _, est = estimate(m, 60)
    assert est.max() > TOL / 2
    p = choice_probabilities(m, 60)
    sim = quiet(mdft.simulate, m, 100_000, stopping=mdft.FixedTime(60), rng=5)
    se = np.sqrt(np.maximum(p * (1 - p), 1e-12) / 100_000)
    assert np.all(np.abs(sim.probabilities - p) <= TOL + 4 * se), (p, sim.probabilities)
    p = choice_probabilities(m, 60, method="normal")  # the deliberate choice still works
    assert abs(p.sum() - 1) < 1e-9
    m0 = canonical([[1, 3], [3, 1], [0.5, 2.5]], sigma2=0.0, phi2=0.2)  # attraction set
    with pytest.raises(ValueError, match=r"without noise the exact mixture does not exist"):
        choice_probabilities(m0, 30)
    # short enough to enumerate: exact; twins with sigma2 = 0 tie exactly (concepts.md)
    np.testing.assert_array_equal(choice_probabilities(m0, 5), _enumerated_probabilities(m0, 5))
    twins = canonical([[1, 3], [1, 3], [3, 1]], sigma2=0.0)
    np.testing.assert_allclose(choice_probabilities(twins, 1), [0.25, 0.25, 0.5], atol=1e-12)


def test_lumpy_models_are_not_trusted(monkeypatch):
    # little noise, strong decay: the last attention draw splits P(T) into modes
    m = canonical([[1, 3], [3, 1], [0.5, 2.5]], sigma2=0.01, phi2=0.45)
    d = lumpy(m, 40)
    assert d > _LUMPY_MAX
    exact = choice_probabilities(m, 40)  # exact mixture, not the normal answer
    mix = mixture_choice_probabilities(m, 40, n_sequences=40_000, rng=3)
    assert np.all(np.abs(exact - mix.probabilities) <= TOL + 3 * mix.standard_errors)
    assert not np.array_equal(exact, choice_probabilities(m, 40, method="normal"))
    # one step, four options: P(1) is two narrow normals; the exact mixture answers
    m4 = canonical([[1, 3], [3, 1], [0.5, 2.5], [2, 2]], sigma2=0.01)
    assert lumpy(m4, 1) > _LUMPY_MAX
    p = choice_probabilities(m4, 1, tol=0.5)
    sim = quiet(mdft.simulate, m4, 100_000, stopping=mdft.FixedTime(1), rng=2)
    se = np.sqrt(np.maximum(p * (1 - p), 1e-12) / 100_000)
    assert np.all(np.abs(sim.probabilities - p) <= 0.002 + 4 * se), (p, sim.probabilities)
    # and where that mixture would cost too much, the reason is given
    with monkeypatch.context() as mp:
        mp.setattr(cf, "_MIXTURE_WORK", 10)
        with pytest.raises(ValueError, match=r"P\(T\) is far from normal: the last attention "
                                             r"draw alone moves a comparison by [\d.]+ standard "
                                             r"deviations"):
            choice_probabilities(m4, 1, tol=0.5)


def test_too_expensive_mixture_raises(monkeypatch):
    monkeypatch.setattr(cf, "_MIXTURE_WORK", 1000)
    m = canonical(phi2=0.12, sigma2=0.5)
    with pytest.raises(ValueError, match=r"the exact mixture would need 20,000 sequences of 40 "
                                         r"steps"):
        choice_probabilities(m, 40, tol=1e-4)


# ------------------------------------------------------------------ sum to one
def test_orthants_that_do_not_sum_to_one_raise_or_fall_back(monkeypatch):
    m = canonical()
    good = choice_probabilities(m, 40)
    m5 = canonical([[1, 3], [3, 1], [2, 2], [0.5, 2.5], [2.5, 1.2]])
    good5 = choice_probabilities(m5, 40)
    monkeypatch.setattr(orthant, "_small_regular", lambda *a: None)
    monkeypatch.setattr(orthant, "_orthant", lambda *a: (0.5, 0.0))
    with pytest.raises(ValueError, match=r"sum to 1.5 instead of 1 .*use mdft.simulate"):
        choice_probabilities(m, 3, method="normal")
    # too long to enumerate: the exact mixture (its own orthants are unaffected)
    assert np.abs(choice_probabilities(m, 40) - good).max() <= TOL
    # five options: the exact mixture too (its randomised orthants are unaffected)
    assert np.abs(choice_probabilities(m5, 40) - good5).max() <= TOL
    with monkeypatch.context() as mp:
        mp.setattr(cf, "_MIXTURE_WORK", 10)
        with pytest.raises(ValueError, match=r"cannot vouch for its answer: the closed-form "
                                             r"choice probabilities sum to 2.5.*exact mixture "
                                             r"would need"):
            choice_probabilities(m5, 40)
    # the fitting path marks the point infeasible instead of raising
    assert _fixed_time_probabilities(np.asarray(m.M), np.asarray(m.w), 0.022, 0.05, 12.0,
                                     1.0, 3) is None


# ------------------------------------------------------------------ bad input
def test_bad_method_and_tol():
    m = canonical()
    with pytest.raises(ValueError, match=r"method must be 'auto' or 'normal' \(got 'exact'\)"):
        choice_probabilities(m, 10, method="exact")
    with pytest.raises(ValueError, match=r"method must be 'auto' or 'normal' \(got None\)"):
        choice_probabilities(m, 10, method=None)
    for bad in (0.0, -0.1, 0.6, float("nan")):
        with pytest.raises(ValueError, match="tol must be"):
            choice_probabilities(m, 10, tol=bad)
    with pytest.raises(TypeError, match="tol must be a real number"):
        choice_probabilities(m, 10, tol="0.01")


def test_exact_mixture_refuses_a_numerically_singular_noise():
    # rho(S) = 3.8: after 20 steps the noise of P_1 - P_2 is lost to rounding
    # (each call first warns that S is unstable, then refuses)
    def unstable():
        return pytest.warns(mdft.UnstableFeedbackWarning, match="spectral radius")

    m = canonical([[1, 3], [3, 1], [2, 2]], phi2=2.0)
    with unstable(), pytest.raises(ValueError, match=r"numerically singular .*use mdft.simulate"):
        mixture_choice_probabilities(m, 20, n_sequences=2000, rng=0)
    with unstable(), pytest.raises(ValueError, match=r"numerically singular .*n_steps"):
        choice_probabilities(m, 20)
    m4 = canonical([[1, 3], [3, 1], [2, 2], [0.5, 2.5]], phi2=2.0)  # four options too
    with unstable(), pytest.raises(ValueError, match=r"numerically singular .*use mdft.simulate"):
        mixture_choice_probabilities(m4, 20, n_sequences=2000, rng=0)
