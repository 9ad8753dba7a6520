"""Context-effect scenarios: each canonical effect appears, measured in standard errors."""

import math
import warnings
from types import SimpleNamespace

import numpy as np
import pytest

import mdft
from mdft.effects import (
    ATTRACTION,
    COMPROMISE,
    SCENARIOS,
    SIMILARITY,
    ContextEffect,
    ContextEffects,
    _evaluate,
    _Shares,
)

N_SAMPLES = 10_000


@pytest.fixture(scope="module")
def canonical():
    """All three scenarios under the default stopping rule (threshold 17.5), seeded."""
    return mdft.context_effects(n_samples=N_SAMPLES, n_trajectories=2, rng=0)


# ----------------------------------------------------------------------------- the effects
@pytest.mark.parametrize("name", ["similarity", "attraction", "compromise"])
def test_each_canonical_effect_is_shown_at_threshold(canonical, name):
    res = canonical[name]
    assert res.shown, f"{name}: effect {res.effect_size:+.4f}, z = {res.z:.2f}"
    assert res.z > 3.0
    assert res.effect_size > 3.0 * res.standard_error


def test_binary_baseline_is_balanced(canonical):
    # A and B are equally good on their own: the binary share of A is 1/2 within 3 s.e.
    res = canonical["attraction"]
    assert abs(res.binary[0] - 0.5) < 3 * res.binary_se[0]
    np.testing.assert_allclose(res.binary.sum() + res.p_undecided_binary, 1.0)


def test_shares_and_measures_are_consistent(canonical):
    sim = canonical["similarity"]
    p3, p2 = sim.ternary, sim.binary
    assert sim.ternary_measure == pytest.approx(p3[1] / (p3[0] + p3[1]))
    assert sim.binary_measure == pytest.approx(p2[1] / (p2[0] + p2[1]))
    assert sim.effect_size == pytest.approx(sim.ternary_measure - sim.binary_measure)
    comp = canonical["compromise"]
    assert comp.effect_size == pytest.approx(comp.ternary[2] - comp.ternary[:2].max())
    assert math.isnan(comp.binary_measure)
    for res in canonical:
        np.testing.assert_allclose(res.ternary.sum() + res.p_undecided_ternary, 1.0)
        assert res.n_samples == N_SAMPLES
        # threshold stopping: a mean decision step (>= 1) for every option that was chosen
        rt = res.mean_response_times
        assert rt.shape == (3,) and np.all(rt[res.ternary > 0] >= 1)
        assert np.all(np.isnan(rt[res.ternary == 0]))


def test_scenarios_share_one_binary_baseline(canonical):
    b = [r.binary for r in canonical]
    np.testing.assert_array_equal(b[0], b[1])
    np.testing.assert_array_equal(b[0], b[2])


def test_trajectories_are_kept_for_the_ternary_set(canonical):
    traj = canonical["compromise"].trajectories
    assert traj.ndim == 3 and traj.shape[0] == 2 and traj.shape[2] == 3
    # each recorded trial starts at P0 = 0 and stops the first time a preference reaches 17.5
    theta = mdft.default_stopping().theta
    for P in traj:
        np.testing.assert_array_equal(P[0], 0.0)
        steps = np.flatnonzero(~np.isnan(P).any(axis=1))
        t = steps[-1]
        np.testing.assert_array_equal(steps, np.arange(t + 1))
        assert t >= 1 and P[t].max() >= theta and np.all(P[:t].max(axis=1) < theta)


def test_same_seed_same_result():
    a = mdft.context_effects("attraction", n_samples=2000, rng=7)["attraction"]
    b = mdft.context_effects("attraction", n_samples=2000, rng=7)["attraction"]
    np.testing.assert_array_equal(a.ternary, b.ternary)
    np.testing.assert_array_equal(a.binary, b.binary)
    assert a.effect_size == b.effect_size


def test_analytic_fixed_time_shows_the_time_dependence():
    # Closed form, no sampling error: at T = 100 the similarity effect reverses while
    # attraction and compromise appear; at T = 15 similarity appears and compromise does not.
    long = mdft.context_effects(stopping=mdft.FixedTime(100), method="analytic")
    assert not long["similarity"].shown and long["similarity"].effect_size < -0.05
    assert long["attraction"].shown and long["compromise"].shown
    short = mdft.context_effects(stopping=mdft.FixedTime(15), method="analytic")
    assert short["similarity"].shown and not short["compromise"].shown
    assert long["attraction"].standard_error == 0.0 and long["attraction"].n_samples == 0


def test_direction_minus_one_detects_a_reversal():
    reversed_similarity = SIMILARITY.with_parameters(name="similarity reversed", direction=-1)
    res = mdft.context_effects(
        reversed_similarity, stopping=mdft.FixedTime(100), method="analytic"
    )[0]
    assert res.shown and res.z == math.inf


def test_monte_carlo_fixed_time_agrees_with_analytic():
    mc = mdft.context_effects("compromise", stopping=mdft.FixedTime(60), n_samples=20_000, rng=1)
    an = mdft.context_effects("compromise", stopping=mdft.FixedTime(60), method="analytic")
    se = mc[0].ternary_se
    assert np.all(np.abs(mc[0].ternary - an[0].ternary) < 4 * se + 1e-3)


def test_analytic_threshold_goes_through_threshold_probabilities(monkeypatch):
    # Plumbing only: the lattice computation itself is tested with mdft.threshold_exact.
    exact = pytest.importorskip("mdft.threshold_exact")
    calls = []

    def fake(model, theta, *, max_steps, fallback):
        assert fallback == "raise"  # an analytic effect has no sampling error
        calls.append((model.n_options, theta, max_steps))
        p = np.array([0.6, 0.35, 0.0]) if model.n_options == 3 else np.array([0.5, 0.48])
        return SimpleNamespace(probabilities=p, p_undecided=1.0 - p.sum(),
                               mean_response_times=np.full(model.n_options, 80.0))

    monkeypatch.setattr(exact, "threshold_probabilities", fake)
    res = mdft.context_effects("attraction", method="analytic")["attraction"]
    assert calls == [(3, 17.5, 10_000), (2, 17.5, 10_000)]
    assert res.effect_size == pytest.approx(0.6 / 0.95 - 0.5 / 0.98)
    assert res.shown and res.standard_error == 0.0
    assert res.p_undecided_ternary == pytest.approx(0.05)
    np.testing.assert_array_equal(res.mean_response_times, [80.0, 80.0, 80.0])


# ----------------------------------------------------------------------------- standard errors
def test_standard_errors_follow_the_binomial_and_multinomial_formulas():
    n = 1000
    tern = _Shares(np.array([0.3, 0.4, 0.3]), np.zeros(3), None, n, 0.0)
    bina = _Shares(np.array([0.5, 0.5]), np.zeros(2), None, n, 0.0)
    r = _evaluate(SIMILARITY, tern, bina, None, "monte_carlo", n, 3.0)
    r3 = 0.4 / 0.7
    se3 = math.sqrt(r3 * (1 - r3) / (0.7 * n))
    se2 = math.sqrt(0.25 / n)
    assert r.effect_size == pytest.approx(r3 - 0.5)
    assert r.standard_error == pytest.approx(math.hypot(se3, se2))
    c = _evaluate(COMPROMISE, _Shares(np.array([0.25, 0.3, 0.45]), np.zeros(3), None, n, 0.0),
                  bina, None, "monte_carlo", n, 3.0)
    assert c.effect_size == pytest.approx(0.15)
    assert c.standard_error == pytest.approx(math.sqrt((0.75 - 0.15**2) / n))


def test_no_choice_of_target_or_rival_is_an_error_not_a_nan():
    n = 100
    tern = _Shares(np.array([0.0, 0.0, 1.0]), np.zeros(3), None, n, 0.0)
    bina = _Shares(np.array([0.5, 0.5]), np.zeros(2), None, n, 0.0)
    with pytest.raises(ValueError, match="the relative share is undefined: neither the target "
                                         "nor its rival was chosen in 100 trials; raise n_samples"):
        _evaluate(ATTRACTION, tern, bina, None, "monte_carlo", n, 3.0)


# ----------------------------------------------------------------------------- scenarios
def test_canonical_scenarios_match_the_design():
    assert SCENARIOS == {"similarity": SIMILARITY, "attraction": ATTRACTION, "compromise": COMPROMISE}
    for s in SCENARIOS.values():
        assert s.M[:2] == ((1.0, 3.0), (3.0, 1.0))
        assert (s.phi1, s.phi2, s.beta, s.sigma2, s.w) == (0.022, 0.05, 12.0, 1.0, (0.5, 0.5))
        assert s.baseline == (0, 1)
    assert SIMILARITY.M[2] == (0.9, 3.1)
    assert ATTRACTION.M[2] == (0.5, 2.5)
    assert COMPROMISE.M[2] == (2.0, 2.0)
    assert mdft.default_stopping() == mdft.Threshold(17.5, max_steps=10_000)


def test_compromise_model_is_slightly_expansive():
    assert COMPROMISE.model().spectral_radius == pytest.approx(1.0089, abs=1e-4)
    # 1.0089 ** 100 = 2.4: not the meaningful growth that the warning is for
    with warnings.catch_warnings():
        warnings.simplefilter("error", mdft.UnstableFeedbackWarning)
        mdft.MDFTModel(COMPROMISE.M, COMPROMISE.w, **COMPROMISE.parameters)
        mdft.simulate(COMPROMISE.model(), 10, stopping=mdft.FixedTime(100), rng=0)
    with pytest.warns(mdft.UnstableFeedbackWarning, match="n_steps=300 steps"):
        mdft.simulate(COMPROMISE.model(), 10, stopping=mdft.FixedTime(300), rng=0)


def test_scenario_is_frozen_and_hashable():
    with pytest.raises(AttributeError, match="cannot assign to field 'phi1'"):
        SIMILARITY.phi1 = 0.1
    assert hash(SIMILARITY) == hash(SIMILARITY.with_parameters())


def _kw(**changes):
    base = dict(
        name="x", labels=("A", "B", "C"), M=[[1, 3], [3, 1], [2, 2]], target=2,
        rivals=(0, 1), measure="margin", expected="C wins",
    )
    base.update(changes)
    return base


def test_scenario_accepts_lists_and_normalises_to_tuples():
    s = ContextEffect(**_kw())
    assert s.M == ((1.0, 3.0), (3.0, 1.0), (2.0, 2.0)) and s.rivals == (0, 1)


@pytest.mark.parametrize(
    "changes, error, match",
    [
        (dict(name=""), TypeError, "name must be a non-empty string"),
        (dict(M=[[1, 3]], labels=("A",)), ValueError, "at least 2 options"),
        (dict(M=[1, 2, 3]), ValueError, "M must be a 2-d array"),
        (dict(labels=("A", "B")), ValueError, r"labels must have one entry per option \(row of M\), 3"),
        (dict(target=3), ValueError, r"target must hold option indices in \[0, 2\]"),
        (dict(target=1.0), TypeError, "target must hold integer option indices"),
        (dict(rivals=(2,)), ValueError, "rivals must be distinct options other than the target"),
        (dict(rivals=()), ValueError, "rivals must be distinct options"),
        (dict(rivals=None), TypeError, "rivals must be a sequence of option indices"),
        (dict(measure="ratio"), ValueError, "measure must be one of"),
        (dict(baseline=(0, 0)), ValueError, "baseline must hold two distinct options"),
        (dict(measure="relative_share"), ValueError, "rivals must hold exactly one option"),
        (dict(measure="relative_share", rivals=(0,), target=1, baseline=(0, 2)), ValueError,
         "baseline must be the target and its rival"),
        (dict(direction=0), ValueError, "direction must be 1 or -1"),
        (dict(w=(0.5, 0.5, 0.0)), ValueError, r"w must have shape \(2\)"),
        (dict(w=(0.7, 0.7)), ValueError, "w must sum to 1"),
        (dict(phi1=-1.0), ValueError, "phi1 must be >= 0"),
        (dict(sigma2=float("nan")), ValueError, "sigma2 must be finite"),
    ],
)
def test_scenario_rejects_bad_fields(changes, error, match):
    with pytest.raises(error, match=match):
        ContextEffect(**_kw(**changes))


# ----------------------------------------------------------------------------- the runner
def test_context_effects_selects_scenarios():
    res = mdft.context_effects(["compromise", SIMILARITY], n_samples=200, rng=0)
    assert isinstance(res, ContextEffects)
    assert res.names == ("compromise", "similarity")
    assert len(res) == 2 and res[1] is res["similarity"]
    with pytest.raises(KeyError, match="no scenario named 'attraction'"):
        res["attraction"]


@pytest.mark.parametrize(
    "kwargs, error, match",
    [
        (dict(scenarios="decoy"), ValueError, "unknown scenario 'decoy'"),
        (dict(scenarios=[]), TypeError, "non-empty sequence"),
        (dict(scenarios=[3]), TypeError, "scenarios must hold names or ContextEffect"),
        (dict(scenarios=5), TypeError, "scenarios must be a scenario name"),
        (dict(stopping=100), TypeError, "stopping must be mdft.FixedTime or mdft.Threshold"),
        (dict(method="exact"), ValueError, "method must be one of"),
        (dict(n_samples=0), ValueError, "n_samples must be an integer >= 100"),
        (dict(n_samples=99), ValueError, r"n_samples must be an integer >= 100 \(got 99\)"),
        (dict(n_samples=2**63), ValueError, "n_samples must be an integer <= 100,000,000"),
        (dict(n_samples=2.5), TypeError, "n_samples must be an integer"),
        (dict(n_trajectories=-1), ValueError, "n_trajectories must be an integer >= 0"),
        (dict(criterion=-1.0), ValueError, "criterion must be >= 0"),
        (dict(method="analytic", stopping=mdft.FixedTime(5), n_trajectories=2), ValueError,
         "n_trajectories must be 0 for method='analytic'"),
    ],
)
def test_context_effects_rejects_bad_arguments(kwargs, error, match):
    with pytest.raises(error, match=match):
        mdft.context_effects(**kwargs)


# ----------------------------------------------------------------------------- properties
from hypothesis import given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402


@settings(deadline=None, max_examples=60)
@given(
    k3=st.lists(st.integers(0, 500), min_size=3, max_size=3),
    k2=st.lists(st.integers(0, 500), min_size=2, max_size=2),
    scenario=st.sampled_from([SIMILARITY, ATTRACTION, COMPROMISE]),
)
def test_effect_statistics_are_consistent(k3, k2, scenario):
    n3, n2 = max(sum(k3), 1), max(sum(k2), 1)
    tern = _Shares(np.array(k3) / n3, np.zeros(3), np.array(k3), n3, 1 - sum(k3) / n3)
    bina = _Shares(np.array(k2) / n2, np.zeros(2), np.array(k2), n2, 1 - sum(k2) / n2)
    if scenario.measure == "relative_share":
        t, (rival,) = scenario.target, scenario.rivals
        if k3[t] + k3[rival] == 0 or k2[0] + k2[1] == 0:  # the share is undefined
            with pytest.raises(ValueError, match="the relative share is undefined"):
                _evaluate(scenario, tern, bina, None, "monte_carlo", n3, 3.0)
            return
    r = _evaluate(scenario, tern, bina, None, "monte_carlo", n3, 3.0)
    flipped = _evaluate(scenario.with_parameters(direction=-1), tern, bina, None,
                        "monte_carlo", n3, 3.0)
    assert not math.isnan(r.effect_size)
    assert -1.0 <= r.effect_size <= 1.0
    assert r.standard_error >= 0.0
    if r.standard_error > 0:
        assert r.shown == (r.effect_size > 3.0 * r.standard_error)
        assert flipped.z == pytest.approx(-r.z)
    else:  # a Monte Carlo estimate without spread is never called significant
        assert not r.shown
    assert not (r.shown and flipped.shown)
