"""The paper's expressiveness results as properties, and the MDFT-vs-WA experiment."""

import warnings

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

import irl
import mdft
from orchestration import (
    ActionPreferences,
    GreedyOrchestrator,
    MDFTOrchestrator,
    WeightedAverageOrchestrator,
    mdft_vs_wa,
    mdft_vs_wa_instance,
)
from orchestration.expressiveness import (
    PAPER_COMPROMISE_SQ,
    PAPER_SETTINGS,
    compromise_witness,
    enumerate_fixed_time,
    greedy_preferences,
    identity_mdft,
    wa_most_likely_interval,
    wa_weights_for,
)


def random_prefs(rng, n_states, n_actions):
    qn = rng.normal(0, 2, (n_states, n_actions))
    qc = rng.normal(0, 2, (n_states, n_actions))
    sq = [np.exp(q) / np.exp(q).sum(axis=1, keepdims=True) for q in (qn, qc)]
    return ActionPreferences(q_nominal=qn, q_constrained=qc, sq_nominal=sq[0], sq_constrained=sq[1],
                             feasible=np.ones((n_states, n_actions), bool))


def quiet_model(M, w, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", mdft.UnstableFeedbackWarning)
        return mdft.MDFTModel(M, w, **kw)


# ------------------------------------------------------------------ Greedy
@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), k=st.integers(2, 8), w=st.floats(0.0, 1.0))
def test_greedy_is_expressible_by_wa_and_mdft(seed, k, w):
    greedy = GreedyOrchestrator.from_preferences(random_prefs(np.random.default_rng(seed), 4, k))
    gp = greedy_preferences(greedy)
    assert GreedyOrchestrator.from_preferences(gp).greedy_actions.tolist() == greedy.greedy_actions.tolist()
    wa = WeightedAverageOrchestrator.from_preferences(gp, (w, 1 - w))
    md = MDFTOrchestrator.from_preferences(gp, (w, 1 - w), sigma2=0.0, n_steps=1)
    for s in range(4):
        target = greedy.action_probabilities(s)
        assert wa.action_probabilities(s).tolist() == target.tolist()
        np.testing.assert_allclose(md.action_probabilities(s), target, atol=1e-12)
        # the exact law of the one-step, noiseless deliberation, by enumeration
        np.testing.assert_allclose(enumerate_fixed_time(md.model(s), 1), target, atol=1e-12)
    states = np.repeat(np.arange(4), 50)
    for orch in (wa, md):
        assert orch.decide_many(states, rng=seed).tolist() == greedy.greedy_actions[states].tolist()


# ------------------------------------------------------------------ Theorem 2
@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), k=st.integers(2, 5), action=st.integers(0, 4))
def test_wa_interval_agrees_with_a_grid_over_the_wa_segment(seed, k, action):
    rng = np.random.default_rng(seed)
    sq_n, sq_c = rng.dirichlet(np.ones(k)), rng.dirichlet(np.ones(k))
    if seed % 3 == 0:  # mirror images with a shared middle value: the compromise layout
        sq_c = sq_n[::-1].copy()
    action = action % k
    interval = wa_most_likely_interval(sq_n, sq_c, action)
    grid = np.linspace(0, 1, 4001)
    p = grid[:, None] * sq_n + (1 - grid[:, None]) * sq_c
    others = np.delete(p, action, axis=1).max(axis=1)
    strict = p[:, action] > others + 1e-9
    if interval is None:
        assert not strict.any()
    else:
        lo, hi = interval
        assert 0 <= lo <= hi <= 1
        assert strict[(grid > lo + 1e-6) & (grid < hi - 1e-6)].all()
        assert not strict[(grid < lo - 1e-6) | (grid > hi + 1e-6)].any()


def test_paper_example_no_wa_weights_favour_the_middle():
    sq_n, sq_c = PAPER_COMPROMISE_SQ
    assert wa_most_likely_interval(sq_n, sq_c, 1) is None
    assert wa_weights_for([0.25, 0.5, 0.25], sq_n, sq_c) is None
    assert wa_weights_for(0.3 * sq_n + 0.7 * sq_c, sq_n, sq_c) == (0.3, 0.7)


def test_compromise_witness_checked_by_simulation():
    wit = compromise_witness()
    p = wit.probabilities
    assert p[1] > max(p[0], p[2]) and wit.wa_interval is None
    assert wa_weights_for(p, wit.sq_nominal, wit.sq_constrained, atol=1e-3) is None
    cfg = dict(wit.settings)
    n_steps = cfg.pop("n_steps")
    model = quiet_model(np.stack([wit.sq_nominal, wit.sq_constrained], 1), wit.weights, **cfg)
    n = 100_000
    sim = mdft.simulate(model, n, stopping=mdft.FixedTime(n_steps), rng=0)
    se = sim.standard_errors
    # the middle action beats both others in the simulation by far more than 5 SE
    assert sim.probabilities[1] - sim.probabilities.max(initial=0, where=[True, False, True]) > 5 * se.max()
    mix = mdft.mixture_choice_probabilities(model, n_steps, n_sequences=4000, rng=0)
    assert mix.probabilities[1] > max(mix.probabilities[0], mix.probabilities[2])
    # the orchestrator built from the witness deliberates to the same distribution
    orch = wit.orchestrator()
    freq = np.bincount(orch.decide_many(np.zeros(20_000, int), rng=1), minlength=3) / 20_000
    assert np.all(np.abs(freq - p) <= 4.5 * np.sqrt(p * (1 - p) / 20_000) + 2e-3)


@settings(max_examples=10, deadline=None)
@given(a=st.floats(0.1, 0.22), w=st.floats(0.45, 0.55))
def test_compromise_holds_across_mirror_sets_and_weights(a, w):
    sq_n = np.array([a, 1 / 3, 2 / 3 - a])
    wit = compromise_witness(sq_n, sq_n[::-1], weights=(w, 1 - w))
    assert wit.probabilities[1] > max(wit.probabilities[0], wit.probabilities[2])
    assert wa_most_likely_interval(sq_n, sq_n[::-1], 1) is None


def test_paper_settings_do_not_favour_the_middle():
    """Measured, not assumed: under the paper's own settings the third action wins."""
    with pytest.raises(ValueError, match="not a witness: under these settings MDFT gives"):
        compromise_witness(settings=dict(PAPER_SETTINGS, n_steps=100))
    sq_n, sq_c = PAPER_COMPROMISE_SQ
    model = quiet_model(np.stack([sq_n, sq_c], 1), [0.55, 0.45], **PAPER_SETTINGS)
    n = 100_000
    sim = mdft.simulate(model, n, stopping=mdft.FixedTime(100), rng=3)
    assert sim.probabilities[2] - sim.probabilities[1] > 5 * sim.standard_errors.max()
    closed = mdft.choice_probabilities(model, 100)
    assert np.all(np.abs(closed - sim.probabilities) <= 4.5 * sim.standard_errors + 1e-4)


def test_witness_rejects_bad_input():
    with pytest.raises(ValueError, match=r"sq_nominal must be shape \(3,\) \(got shape \(2,\)\)"):
        compromise_witness([0.5, 0.5], [0.5, 0.25, 0.25])
    with pytest.raises(ValueError, match=r"settings has unknown keys \['theta'\]"):
        compromise_witness(settings=dict(theta=1.0))
    with pytest.raises(ValueError, match=r"action must be an index in \[0, 3\) \(got 3\)"):
        wa_most_likely_interval([0.2, 0.3, 0.5], [0.2, 0.3, 0.5], 3)
    with pytest.raises(ValueError, match=r"sq_n must be a probability distribution"):
        wa_most_likely_interval([0.2, 0.3, 0.6], [0.2, 0.3, 0.5], 0)


# ------------------------------------------------------------------ Theorem 3
@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), k=st.integers(2, 8), sparse=st.booleans())
def test_any_distribution_by_identity_mdft_in_one_step(seed, k, sparse):
    rng = np.random.default_rng(seed)
    p = rng.dirichlet(np.ones(k))
    if sparse:
        p[rng.random(k) < 0.4] = 0.0
        if p.sum() == 0:
            p[0] = 1.0
        p /= p.sum()
    model = identity_mdft(p)
    np.testing.assert_allclose(enumerate_fixed_time(model, 1), p, atol=1e-12)
    n = 20_000
    sim = mdft.simulate(model, n, stopping=mdft.FixedTime(1), rng=seed).probabilities
    assert np.all(np.abs(sim - p) <= 4.5 * np.sqrt(p * (1 - p) / n) + 1e-12)
    # the compiled per-decision deliberation agrees too
    choices = mdft.decide(np.stack([np.eye(k)] * n), p, phi1=0.01, phi2=0.01, beta=2.0,
                          sigma2=0.0, n_steps=1, rng=seed)
    freq = np.bincount(choices, minlength=k) / n
    assert np.all(np.abs(freq - p) <= 4.5 * np.sqrt(p * (1 - p) / n) + 1e-12)


def test_theorem_3_needs_a_noiseless_deliberation():
    p = np.array([0.9, 0.1])
    noisy = quiet_model(np.eye(2), p, phi1=0.01, phi2=0.01, beta=2.0, sigma2=1.0)
    assert abs(mdft.choice_probabilities(noisy, 1)[0] - 0.9) > 0.1
    with pytest.raises(ValueError, match=r"needs a noiseless model, sigma2 = 0 \(got 1.0\)"):
        enumerate_fixed_time(noisy, 1)
    with pytest.raises(ValueError, match=r"sequences exceed 1,000,000"):
        enumerate_fixed_time(identity_mdft([0.5, 0.5]), 30)


# ------------------------------------------------------------------ MDFT vs WA
def test_mdft_vs_wa_instance_is_a_pure_function_of_its_seed():
    a = mdft_vs_wa_instance(7, n_actions=3, n_choices=60, n_steps=10)
    b = mdft_vs_wa_instance(7, n_actions=3, n_choices=60, n_steps=10)
    assert a.fitted_weights == b.fitted_weights and a.counts.tolist() == b.counts.tolist()
    w = a.wa_weights[0]
    np.testing.assert_allclose(a.wa_probabilities, w * a.sq_nominal + (1 - w) * a.sq_constrained)
    assert a.counts.sum() == 60
    assert a.js_divergence == pytest.approx(irl.js_divergence(a.wa_probabilities, a.mdft_probabilities))
    assert a.exact_fit_js_divergence <= a.js_divergence + 1e-12
    M = np.stack([a.sq_nominal, a.sq_constrained], 1)
    settings_ = dict(phi1=0.01, phi2=0.01, beta=2.0, sigma2=1.0)

    def probs(wn):
        return mdft.choice_probabilities(quiet_model(M, [wn, 1 - wn], **settings_), 10,
                                         method="normal")

    np.testing.assert_allclose(a.mdft_probabilities, probs(a.fitted_weights[0]), atol=1e-12)
    grid = np.linspace(0, 1, 51)
    # maximum likelihood: no weight on a grid fits the counts better
    loglik = [float(a.counts @ np.log(np.maximum(probs(g), 1e-300))) for g in grid]
    best = float(a.counts @ np.log(a.mdft_probabilities))
    assert best >= max(loglik) - 1e-6
    # the exact fit: no weight on the grid comes closer to the WA distribution
    assert a.exact_fit_js_divergence <= min(irl.js_divergence(a.wa_probabilities, probs(g))
                                            for g in grid) + 1e-9


def test_mdft_vs_wa_aggregates_and_validates():
    res = mdft_vs_wa(3, rng=1, n_actions=3, n_choices=40, n_steps=10)
    js = [x.js_divergence for x in res.instances]
    assert res.mean_js == pytest.approx(np.mean(js))
    assert res.se_js == pytest.approx(np.std(js, ddof=1) / np.sqrt(3))
    seeds = np.random.default_rng(1).integers(0, 2**63 - 1, size=3)
    assert [x.seed for x in res.instances] == seeds.tolist()
    with pytest.raises(ValueError, match=r"seed must be a non-negative integer \(got -1\)"):
        mdft_vs_wa_instance(-1)
    with pytest.raises(ValueError, match=r"n_actions must be an integer >= 2 \(got 1\)"):
        mdft_vs_wa_instance(0, n_actions=1)
    with pytest.raises(ValueError, match=r"n_instances must be an integer >= 1 \(got 0\)"):
        mdft_vs_wa(0)
