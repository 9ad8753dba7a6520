"""Orchestrators: preferences, Greedy and WA exact, MDFT against simulation, validation."""

import warnings

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

import irl
import mdft
import orchestration
from orchestration import (
    ActionPreferences,
    GreedyOrchestrator,
    MDFTOrchestrator,
    WeightedAverageOrchestrator,
    action_preferences,
)


def random_prefs(rng, n_states, n_actions, scale=3.0):
    """Preferences from random Q-values (an independent construction of sq)."""
    qn = rng.normal(0, scale, (n_states, n_actions))
    qc = rng.normal(0, scale, (n_states, n_actions))
    sq = [np.exp(q) / np.exp(q).sum(axis=1, keepdims=True) for q in (qn, qc)]
    return ActionPreferences(q_nominal=qn, q_constrained=qc, sq_nominal=sq[0], sq_constrained=sq[1],
                             feasible=np.ones((n_states, n_actions), bool))


# ------------------------------------------------------------------ preferences
def test_preferences_are_softmax_of_value_iteration(small_world, small_prefs):
    qn = irl.value_iteration(small_world.nominal_mdp).q_values
    qc = irl.value_iteration(small_world.constrained_mdp).q_values
    np.testing.assert_allclose(small_prefs.q_nominal, qn)
    np.testing.assert_allclose(small_prefs.q_constrained, qc)
    for q, sq in ((qn, small_prefs.sq_nominal), (qc, small_prefs.sq_constrained)):
        ref = np.array([[np.exp(v) / np.exp(row).sum() for v in row] for row in q])
        np.testing.assert_allclose(sq, ref, rtol=1e-12, atol=1e-15)
    assert small_prefs.terminal.tolist() == small_world.nominal_mdp.terminal.tolist()
    assert small_prefs.nominal is small_world.nominal_mdp


def test_temperature_and_feasibility(small_world):
    feasible = np.ones((16, 8), bool)
    feasible[:, 4:] = False
    p = action_preferences(small_world.nominal_mdp, small_world.constrained_mdp, temperature=2.0,
                           feasible=feasible)
    q = p.q_constrained[3, :4] / 2.0
    np.testing.assert_allclose(p.sq_constrained[3, :4], np.exp(q) / np.exp(q).sum())
    assert (p.sq_nominal[:, 4:] == 0).all()
    orch = MDFTOrchestrator.from_preferences(p, (0.5, 0.5))
    assert orch.action_probabilities(3)[4:].sum() == 0
    assert set(orch.decide_many([3] * 200, rng=0).tolist()) <= {0, 1, 2, 3}


def test_preferences_reject_bad_input(small_world):
    other = irl.GridWorld(3, 0, 8)
    with pytest.raises(TypeError, match=r"nominal must be an irl.MDP \(got str\)"):
        action_preferences("small_world", small_world.constrained_mdp)
    with pytest.raises(ValueError, match=r"share states and actions \(got 16 states x 8 actions and 9 states"):
        action_preferences(small_world.nominal_mdp, other.constrained_mdp)
    slippier = irl.GridWorld(4, 0, 15, p_slip=0.3).nominal_mdp
    with pytest.raises(ValueError, match="must share transitions and terminal states"):
        action_preferences(small_world.nominal_mdp, slippier)
    with pytest.raises(ValueError, match=r"temperature must be finite and > 0 \(got 0.0\)"):
        action_preferences(small_world.nominal_mdp, small_world.constrained_mdp, temperature=0.0)
    bad = np.ones((16, 8), bool)
    bad[2] = False
    with pytest.raises(ValueError, match=r"at least one action in every state \(state 2 has none\)"):
        action_preferences(small_world.nominal_mdp, small_world.constrained_mdp, feasible=bad)
    with pytest.raises(ValueError, match=r"feasible must have shape \(16, 8\) \(got \(16, 4\)\)"):
        action_preferences(small_world.nominal_mdp, small_world.constrained_mdp, feasible=np.ones((16, 4), bool))


# ------------------------------------------------------------------ Greedy, WA
@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1))
def test_greedy_takes_the_best_q_of_either_mdp(seed):
    rng = np.random.default_rng(seed)
    p = random_prefs(rng, 5, 6)
    greedy = GreedyOrchestrator.from_preferences(p)
    for s in range(5):
        best = max(range(6), key=lambda a: (max(p.q_nominal[s, a], p.q_constrained[s, a]), -a))
        assert greedy.act(s) == best
        probs = greedy.action_probabilities(s)
        assert probs[best] == 1.0 and probs.sum() == 1.0
    assert greedy.decide_many([0, 1, 2, 3, 4], rng=1).tolist() == greedy.greedy_actions.tolist()


def test_greedy_ties_go_to_the_lowest_action():
    q = np.array([[0.0, 1.0, 1.0, 1.0 - 1e-12]])
    sq = np.exp(q) / np.exp(q).sum()
    p = ActionPreferences(q_nominal=q, q_constrained=q[:, ::-1].copy(), sq_nominal=sq,
                          sq_constrained=sq[:, ::-1].copy(), feasible=np.ones((1, 4), bool))
    assert GreedyOrchestrator.from_preferences(p).act(0) == 0  # q_c[0] = 1 - 1e-12 ties q_n max


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), w=st.floats(0.0, 1.0))
def test_wa_is_the_weighted_average(seed, w):
    rng = np.random.default_rng(seed)
    p = random_prefs(rng, 4, 5)
    wa = WeightedAverageOrchestrator.from_preferences(p, (w, 1 - w))
    for s in range(4):
        expected = w * p.sq_nominal[s] + (1 - w) * p.sq_constrained[s]
        np.testing.assert_allclose(wa.action_probabilities(s), expected, rtol=1e-12, atol=1e-15)


def test_wa_decisions_follow_its_distribution(small_prefs):
    wa = WeightedAverageOrchestrator.from_preferences(small_prefs, (0.3, 0.7))
    n = 40_000
    choices = wa.decide_many(np.full(n, 1), rng=3)
    freq = np.bincount(choices, minlength=8) / n
    p = wa.action_probabilities(1)
    se = np.sqrt(p * (1 - p) / n)
    assert np.all(np.abs(freq - p) <= 4.5 * se + 1e-12)
    assert np.all(freq[p == 0] == 0)


# ------------------------------------------------------------------ MDFT
@settings(max_examples=8, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), k=st.integers(2, 8), w=st.floats(0.0, 1.0),
       conc=st.floats(0.1, 10.0))
def test_mdft_probabilities_match_a_large_simulation(seed, k, w, conc):
    """The closed form against the engine's Monte Carlo (an independent computation)."""
    rng = np.random.default_rng(seed)
    sq_n, sq_c = rng.dirichlet(np.full(k, conc)), rng.dirichlet(np.full(k, conc))
    p = ActionPreferences(q_nominal=np.log(sq_n)[None], q_constrained=np.log(sq_c)[None],
                          sq_nominal=sq_n[None], sq_constrained=sq_c[None],
                          feasible=np.ones((1, k), bool))
    orch = MDFTOrchestrator.from_preferences(p, (w, 1 - w))
    exact = orch.action_probabilities(0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", mdft.UnstableFeedbackWarning)
        model = mdft.MDFTModel(np.stack([sq_n, sq_c], 1), [w, 1 - w], phi1=0.01, phi2=0.01,
                               beta=2.0, sigma2=1.0)
    n = 200_000
    sim = mdft.simulate(model, n, stopping=mdft.FixedTime(100), rng=seed).probabilities
    se = np.sqrt(exact * (1 - exact) / n)
    # 4.5 SE per option; 2e-5 covers the quasi-Monte Carlo error of the closed form (k >= 4)
    assert np.all(np.abs(sim - exact) <= 4.5 * se + 2e-5), (sim, exact)
    assert abs(exact.sum() - 1) < 1e-9


def test_mdft_act_and_decide_many_follow_action_probabilities(small_prefs):
    orch = MDFTOrchestrator.from_preferences(small_prefs, (0.4, 0.6))
    n = 30_000
    p = orch.action_probabilities(0)
    freq = np.bincount(orch.decide_many(np.zeros(n, int), rng=11), minlength=8) / n
    se = np.sqrt(p * (1 - p) / n)
    assert np.all(np.abs(freq - p) <= 4.5 * se + 2e-5)
    acts = [orch.act(0, rng=np.random.default_rng(i)) for i in range(300)]
    assert orch.act(0, rng=5) == orch.act(0, rng=5)
    freq1 = np.bincount(acts, minlength=8) / 300
    assert np.all(np.abs(freq1 - p) <= 4.5 * np.sqrt(p * (1 - p) / 300) + 1e-3)


def test_mdft_matches_the_engine_model(small_prefs):
    orch = MDFTOrchestrator.from_preferences(small_prefs, (0.7, 0.3), phi1=0.02, beta=3.0, n_steps=40)
    actions, M = small_prefs.attributes(2)
    model = orch.model(2)
    np.testing.assert_array_equal(model.M, M)
    assert model.w.tolist() == [0.7, 0.3] and model.phi1 == 0.02 and model.beta == 3.0
    np.testing.assert_allclose(orch.action_probabilities(2)[actions],
                               mdft.choice_probabilities(model, 40), atol=1e-12)


def test_single_feasible_action_is_chosen_without_deliberation(small_prefs):
    feasible = np.ones((16, 8), bool)
    feasible[4] = False
    feasible[4, 6] = True
    p = ActionPreferences(q_nominal=small_prefs.q_nominal, q_constrained=small_prefs.q_constrained,
                          sq_nominal=np.where(feasible, small_prefs.sq_nominal, 0) / np.where(feasible, small_prefs.sq_nominal, 0).sum(1, keepdims=True),
                          sq_constrained=np.where(feasible, small_prefs.sq_constrained, 0) / np.where(feasible, small_prefs.sq_constrained, 0).sum(1, keepdims=True),
                          feasible=feasible)
    orch = MDFTOrchestrator.from_preferences(p, (0.5, 0.5))
    assert orch.action_probabilities(4)[6] == 1.0
    assert set(orch.decide_many([4, 4, 0], rng=0)[:2].tolist()) == {6}
    with pytest.raises(ValueError, match="state 4 has a single feasible action"):
        orch.model(4)


def test_mdft_threshold_stopping():
    sq_n, sq_c = np.array([0.2, 0.3, 0.5]), np.array([0.6, 0.3, 0.1])
    p = ActionPreferences(q_nominal=np.log(sq_n)[None], q_constrained=np.log(sq_c)[None],
                          sq_nominal=sq_n[None], sq_constrained=sq_c[None],
                          feasible=np.ones((1, 3), bool))
    orch = MDFTOrchestrator.from_preferences(p, (0.5, 0.5), threshold=3.0, n_steps=2000)
    exact = orch.action_probabilities(0)
    n = 20_000
    freq = np.bincount(orch.decide_many(np.zeros(n, int), rng=2), minlength=3) / n
    se = np.sqrt(exact * (1 - exact) / n)
    # the lattice method's own error is about 2e-3 for three options (docs/threshold_exact.md)
    assert np.all(np.abs(freq - exact) <= 4.5 * se + 3e-3), (freq, exact)
    hopeless = MDFTOrchestrator.from_preferences(p, (0.5, 0.5), threshold=1e6, n_steps=5)
    with pytest.raises(RuntimeError, match="did not reach threshold=1e\\+06 within n_steps=5"):
        hopeless.act(0, rng=0)


def test_mdft_threshold_stopping_with_more_than_three_actions_is_simulated_to_the_tolerances():
    # no chain beyond three options: mdft.threshold_probabilities simulates (seeded), and
    # the orchestrator's own deliberations (another stream) agree with it
    rng = np.random.default_rng(3)
    sq_n, sq_c = rng.dirichlet(np.ones(6), size=1), rng.dirichlet(np.ones(6), size=1)
    six = ActionPreferences(q_nominal=np.log(sq_n), q_constrained=np.log(sq_c),
                            sq_nominal=sq_n, sq_constrained=sq_c, feasible=np.ones((1, 6), bool))
    orch = MDFTOrchestrator.from_preferences(six, (0.4, 0.6), threshold=2.0, n_steps=500)
    exact = orch.action_probabilities(0)
    assert exact.shape == (6,) and abs(exact.sum() - 1.0) < 1e-12
    np.testing.assert_array_equal(exact, MDFTOrchestrator.from_preferences(
        six, (0.4, 0.6), threshold=2.0, n_steps=500).action_probabilities(0))   # repeatable
    n = 50_000
    freq = np.bincount(orch.decide_many(np.zeros(n, int), rng=5), minlength=6) / n
    se = np.sqrt(exact * (1 - exact) / n)
    assert np.all(np.abs(freq - exact) <= 4 * se + 1e-3), (freq, exact)


def test_mdft_threshold_stopping_asks_again_when_many_deliberations_do_not_decide(monkeypatch):
    # conditional on deciding within n_steps: the error is divided by the probability d of
    # deciding, so below d = 0.99 the chain is asked again with atol scaled by d
    sq_n, sq_c = np.array([0.2, 0.3, 0.5]), np.array([0.6, 0.3, 0.1])
    p = ActionPreferences(q_nominal=np.log(sq_n)[None], q_constrained=np.log(sq_c)[None],
                          sq_nominal=sq_n[None], sq_constrained=sq_c[None],
                          feasible=np.ones((1, 3), bool))
    calls = []
    real = mdft.threshold_probabilities

    def spy(model, theta, **kwargs):
        res = real(model, theta, **kwargs)
        calls.append((kwargs["atol"], 1.0 - res.p_undecided))
        return res

    monkeypatch.setattr(mdft, "threshold_probabilities", spy)
    orch = MDFTOrchestrator.from_preferences(p, (0.5, 0.5), threshold=3.0, n_steps=8)
    exact = orch.action_probabilities(0)
    assert len(calls) == 2 and calls[0][0] == 1e-3
    decided = calls[0][1]
    assert 0.5 < decided < 0.99 and calls[1][0] == pytest.approx(1e-3 * decided)
    n = 50_000
    freq = np.bincount(orch.decide_many(np.zeros(n, int), rng=4), minlength=3) / n
    se = np.sqrt(exact * (1 - exact) / n)
    assert np.all(np.abs(freq - exact) <= 4 * se + 1e-3), (freq, exact)
    calls.clear()
    MDFTOrchestrator.from_preferences(p, (0.5, 0.5), threshold=3.0,
                                      n_steps=2000).action_probabilities(0)
    assert len(calls) == 1    # nearly every deliberation decides: one call


# ------------------------------------------------------------------ validation
def test_orchestrators_reject_bad_input(small_world, small_prefs):
    nom, con = small_world.nominal_mdp, small_world.constrained_mdp
    with pytest.raises(ValueError, match=r"weights must sum to 1 \(got \[0.5, 0.6\], sum 1.1\)"):
        WeightedAverageOrchestrator(nom, con, weights=(0.5, 0.6))
    with pytest.raises(ValueError, match=r"weights must be finite and non-negative \(got \[-0.5, 1.5\]\)"):
        MDFTOrchestrator(nom, con, weights=(-0.5, 1.5))
    with pytest.raises(ValueError, match=r"weights must be a pair \(w_n, w_c\) \(got shape \(3,\)"):
        MDFTOrchestrator.from_preferences(small_prefs, (0.2, 0.3, 0.5))
    with pytest.raises(TypeError, match=r"weights must be a pair of real numbers"):
        MDFTOrchestrator.from_preferences(small_prefs, "ab")
    with pytest.raises(ValueError, match=r"phi1 must be finite and >= 0 \(got -1.0\)"):
        MDFTOrchestrator.from_preferences(small_prefs, (0.5, 0.5), phi1=-1.0)
    with pytest.raises(ValueError, match=r"n_steps must be an integer >= 1 \(got 0\)"):
        MDFTOrchestrator.from_preferences(small_prefs, (0.5, 0.5), n_steps=0)
    with pytest.raises(ValueError, match=r"threshold must be finite and > 0, or None \(got -2\)"):
        MDFTOrchestrator.from_preferences(small_prefs, (0.5, 0.5), threshold=-2)
    with pytest.raises(TypeError, match=r"prefs must be an orchestration.ActionPreferences \(got MDP\)"):
        GreedyOrchestrator.from_preferences(nom)
    with pytest.raises(ValueError, match=r"temperature=2.0 differs from the temperature of prefs \(1.0\)"):
        WeightedAverageOrchestrator.from_preferences(small_prefs, (0.5, 0.5), temperature=2.0)
    with pytest.raises(ValueError, match="must share states and actions"):
        GreedyOrchestrator(nom, irl.GridWorld(3, 0, 8).nominal_mdp)
    orch = MDFTOrchestrator.from_preferences(small_prefs, (0.5, 0.5))
    for o in (orch, GreedyOrchestrator.from_preferences(small_prefs),
              WeightedAverageOrchestrator.from_preferences(small_prefs, (1.0, 0.0))):
        with pytest.raises(ValueError, match=r"state must lie in \[0, 16\) \(got 16\)"):
            o.act(16)
        with pytest.raises(TypeError, match=r"state must be an integer state index \(got 1.5\)"):
            o.action_probabilities(1.5)
        with pytest.raises(ValueError, match="state 15 is terminal: no action is taken there"):
            o.act(15)
        with pytest.raises(ValueError, match=r"states must not be terminal \(got terminal state 15\)"):
            o.decide_many([0, 15])
        with pytest.raises(ValueError, match=r"states must lie in \[0, 16\) \(got -1\)"):
            o.decide_many([0, -1])


def test_same_seed_same_decisions_and_no_mutation(small_prefs):
    before = small_prefs.sq_nominal.copy()
    states = np.array([0, 1, 2, 3] * 50)
    keep = states.copy()
    for orch in (MDFTOrchestrator.from_preferences(small_prefs, (0.5, 0.5)),
                 WeightedAverageOrchestrator.from_preferences(small_prefs, (0.5, 0.5))):
        a = orch.decide_many(states, rng=7)
        b = orch.decide_many(states, rng=7)
        assert a.tolist() == b.tolist()
        assert orch.decide_many(states, rng=8).tolist() != a.tolist()
    np.testing.assert_array_equal(states, keep)
    np.testing.assert_array_equal(small_prefs.sq_nominal, before)
    with pytest.raises(ValueError, match="read-only"):
        small_prefs.sq_nominal[0, 0] = 1.0


def test_policy_stacks_action_probabilities(small_prefs):
    wa = WeightedAverageOrchestrator.from_preferences(small_prefs, (0.5, 0.5))
    pol = wa.policy()
    assert pol.shape == (16, 8)
    np.testing.assert_allclose(pol[3], wa.action_probabilities(3))
    np.testing.assert_allclose(pol.sum(axis=1), 1.0)


def test_public_names():
    for name in ("ActionPreferences", "action_preferences", "Orchestrator", "GreedyOrchestrator",
                 "WeightedAverageOrchestrator", "MDFTOrchestrator", "rollout", "OrchestratorAgent",
                 "run_episode", "mdft_vs_wa_instance", "mdft_vs_wa", "MDFTvsWAInstance"):
        assert name in orchestration.__all__ and hasattr(orchestration, name)


def test_orchestrators_pickle_for_process_executors(small_prefs):
    import pickle

    for orch in (GreedyOrchestrator.from_preferences(small_prefs),
                 WeightedAverageOrchestrator.from_preferences(small_prefs, (0.5, 0.5)),
                 MDFTOrchestrator.from_preferences(small_prefs, (0.5, 0.5))):
        copy = pickle.loads(pickle.dumps(orch))
        assert copy.decide_many([0, 1, 2] * 10, rng=3).tolist() == orch.decide_many([0, 1, 2] * 10, rng=3).tolist()
        np.testing.assert_array_equal(copy.action_probabilities(1), orch.action_probabilities(1))


def test_mdft_action_probabilities_raise_where_the_closed_form_cannot_vouch(small_prefs):
    # strong decay and no noise: eight actions, 2**40 attention sequences, no exact method,
    # a clear error (with a little noise the exact mixture answers instead)
    orch = MDFTOrchestrator.from_preferences(small_prefs, (0.7, 0.3), phi2=0.2, sigma2=0.0,
                                             n_steps=40)
    with pytest.raises(ValueError, match=r"^state 2: choice_probabilities cannot vouch for its "
                                         r"answer.*8 options"):
        orch.action_probabilities(2)
