"""Rollouts and the agent loop: frequencies against action_probabilities, dynamics, determinism."""

import numpy as np
import pytest

import irl
from orchestration import (
    GreedyOrchestrator,
    MDFTOrchestrator,
    OrchestratorAgent,
    WeightedAverageOrchestrator,
    rollout,
    run_episode,
)


def test_rollouts_are_valid_trajectories_of_the_world(small_world, small_prefs):
    for orch in (GreedyOrchestrator.from_preferences(small_prefs),
                 WeightedAverageOrchestrator.from_preferences(small_prefs, (0.5, 0.5)),
                 MDFTOrchestrator.from_preferences(small_prefs, (0.5, 0.5))):
        demos = rollout(orch, 100, rng=0)
        assert len(demos) == 100
        demos.check(small_world.nominal_mdp)  # every transition has positive probability
        assert demos.reached_terminal.all()
        assert (demos.start_states == 0).all()
        ends = demos.next_states[demos.offsets[1:] - 1]
        assert (ends == 15).all()
        inner = np.ones(demos.n_transitions, bool)
        inner[demos.offsets[1:] - 1] = False
        assert not small_world.nominal_mdp.terminal[demos.next_states[inner]].any()


def test_rollout_is_deterministic_per_seed(small_prefs):
    orch = MDFTOrchestrator.from_preferences(small_prefs, (0.3, 0.7))
    a, b, c = rollout(orch, 60, rng=4), rollout(orch, 60, rng=4), rollout(orch, 60, rng=5)
    for key in ("offsets", "states", "actions", "next_states"):
        assert getattr(a, key).tolist() == getattr(b, key).tolist()
    assert a.actions.tolist() != c.actions.tolist()


@pytest.mark.parametrize("kind", ["wa", "mdft"])
def test_action_frequencies_match_action_probabilities(small_prefs, kind):
    if kind == "wa":
        orch = WeightedAverageOrchestrator.from_preferences(small_prefs, (0.6, 0.4))
    else:
        orch = MDFTOrchestrator.from_preferences(small_prefs, (0.6, 0.4))
    demos = rollout(orch, 6000, rng=1)
    visits = np.bincount(demos.states, minlength=16)
    for s in np.argsort(-visits)[:3]:  # the start and the two most visited other states
        acts = demos.actions[demos.states == s]
        n = acts.size
        assert n > 1000
        freq = np.bincount(acts, minlength=8) / n
        p = orch.action_probabilities(s)
        se = np.sqrt(p * (1 - p) / n)
        assert np.all(np.abs(freq - p) <= 4.5 * se + 2e-5), (s, freq, p)


def test_successor_frequencies_follow_the_transitions(small_world, small_prefs):
    greedy = GreedyOrchestrator.from_preferences(small_prefs)
    with pytest.warns(RuntimeWarning, match="20000 of 20000 trajectories did not reach"):
        demos = rollout(greedy, 20_000, rng=2, max_length=1)
    a = greedy.act(0)
    P = small_world.nominal_mdp.dense_transitions()[0, a]
    freq = np.bincount(demos.next_states, minlength=16) / 20_000
    se = np.sqrt(P * (1 - P) / 20_000)
    assert np.all(np.abs(freq - P) <= 4.5 * se + 1e-12)


def test_max_length_cuts_and_warns(small_prefs):
    orch = WeightedAverageOrchestrator.from_preferences(small_prefs, (0.5, 0.5))
    with pytest.warns(RuntimeWarning, match=r"of 50 trajectories did not reach a terminal state within max_length=2"):
        demos = rollout(orch, 50, rng=0, max_length=2)
    assert demos.lengths.max() <= 2
    assert not demos.reached_terminal[demos.lengths == 2].all() or demos.reached_terminal.all()


def test_start_state_and_distribution(small_prefs):
    orch = WeightedAverageOrchestrator.from_preferences(small_prefs, (0.5, 0.5))
    assert (rollout(orch, 20, rng=0, start=5).start_states == 5).all()
    p0 = np.zeros(16)
    p0[[1, 2]] = 0.5
    starts = rollout(orch, 400, rng=0, start=p0).start_states
    assert set(starts.tolist()) == {1, 2}
    assert abs((starts == 1).mean() - 0.5) <= 4.5 * np.sqrt(0.25 / 400)


def test_rollout_rejects_bad_input(small_world, small_prefs):
    orch = WeightedAverageOrchestrator.from_preferences(small_prefs, (0.5, 0.5))
    with pytest.raises(TypeError, match=r"orchestrator must be an orchestration.Orchestrator .* \(got str\)"):
        rollout("wa", 10)
    with pytest.raises(ValueError, match=r"n_trajectories must be an integer >= 1 \(got 0\)"):
        rollout(orch, 0)
    with pytest.raises(ValueError, match=r"max_length must be an integer >= 1 \(got 0\)"):
        rollout(orch, 1, max_length=0)
    with pytest.raises(ValueError, match="start must put no mass on terminal states"):
        rollout(orch, 1, start=15)
    with pytest.raises(ValueError, match=r"start must be a state index or a probability distribution of shape \(16,\)"):
        rollout(orch, 1, start=[0.5, 0.5])
    with pytest.raises(ValueError, match=r"mdp must have the orchestrator's 16 states and 8 actions \(got 9 and 8\)"):
        rollout(orch, 1, mdp=irl.GridWorld(3, 0, 8).nominal_mdp)
    no_goal = small_world.nominal_mdp.replace(terminal=np.zeros(16, bool), start=None)
    with pytest.raises(ValueError, match="mdp must have the terminal states of the orchestrator's MDPs"):
        rollout(orch, 1, mdp=no_goal)
    bare = type(small_prefs)(q_nominal=small_prefs.q_nominal, q_constrained=small_prefs.q_constrained,
                       sq_nominal=small_prefs.sq_nominal, sq_constrained=small_prefs.sq_constrained,
                       feasible=small_prefs.feasible, terminal=small_prefs.terminal)
    with pytest.raises(ValueError, match="mdp is required: the orchestrator's preferences hold no nominal MDP"):
        rollout(WeightedAverageOrchestrator.from_preferences(bare, (0.5, 0.5)), 1)
    assert len(rollout(WeightedAverageOrchestrator.from_preferences(bare, (0.5, 0.5)), 3,
                       mdp=small_world.nominal_mdp, rng=0)) == 3


# ------------------------------------------------------------------ agent loop
@pytest.fixture(scope="module")
def frozen_lake():
    gymnasium = pytest.importorskip("gymnasium")
    return gymnasium.make("FrozenLake-v1", is_slippery=True)


def test_agent_in_frozen_lake(frozen_lake):
    mdp = irl.from_gymnasium(frozen_lake, discount=0.95)
    holes = np.zeros(mdp.n_features)
    holes[:16] = [10.0 if c == b"H" else 0.0 for c in frozen_lake.unwrapped.desc.ravel()]
    constrained = mdp.penalised(holes)  # falling into a hole is penalised
    orch = MDFTOrchestrator(mdp, constrained, weights=(0.3, 0.7))
    ep = run_episode(frozen_lake, orch, rng=0, max_steps=200)
    assert ep.n_steps == ep.actions.size == ep.rewards.size == ep.states.size - 1
    assert ep.terminated or ep.truncated
    demos = ep.to_demonstrations()
    demos.check(mdp)  # every step the environment took is a transition of the MDP
    again = run_episode(frozen_lake, orch, rng=0, max_steps=200)
    assert again.states.tolist() == ep.states.tolist() and again.actions.tolist() == ep.actions.tolist()
    # the episode's reward is the environment's: 1 exactly when the goal (state 15) is entered
    assert ep.total_reward == float(ep.states[-1] == 15 and ep.terminated)


def test_agent_reaches_the_goal_of_a_deterministic_lake():
    gymnasium = pytest.importorskip("gymnasium")
    env = gymnasium.make("FrozenLake-v1", is_slippery=False)
    mdp = irl.from_gymnasium(env, discount=0.95)
    greedy = GreedyOrchestrator(mdp, mdp)
    ep = run_episode(env, greedy, rng=0)
    assert ep.terminated and ep.total_reward == 1.0 and ep.n_steps == 6


def test_agent_rejects_bad_input(frozen_lake):
    mdp = irl.from_gymnasium(frozen_lake)
    orch = GreedyOrchestrator(mdp, mdp)
    with pytest.raises(TypeError, match=r"orchestrator must be an orchestration.Orchestrator \(got int\)"):
        OrchestratorAgent(3)
    with pytest.raises(TypeError, match="observation_to_state must be callable or None"):
        OrchestratorAgent(orch, observation_to_state=5)
    agent = OrchestratorAgent(orch, observation_to_state=lambda obs: obs + 100)
    with pytest.raises(ValueError, match=r"the observation maps to state 100, outside \[0, 16\)"):
        agent.act(0)
    with pytest.raises(TypeError, match=r"the observation must map to an integer state index \(got 'a'"):
        OrchestratorAgent(orch, observation_to_state=lambda obs: "a").act(0)
    with pytest.raises(ValueError, match=r"max_steps must be an integer >= 1 \(got 0\)"):
        run_episode(frozen_lake, orch, max_steps=0)
    with pytest.raises(TypeError, match=r"env must have a reset\(\) method in the Gymnasium API \(got object\)"):
        run_episode(object(), orch)
