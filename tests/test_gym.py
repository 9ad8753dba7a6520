"""Tests of irl.gym: the transition-table adapter, on hand-made tables and on Gymnasium."""

import sys

import numpy as np
import pytest

from irl.gym import from_gymnasium, make_env, transition_table
from irl.mdp import MDP, TransitionFeatures


class FakeEnv:
    """Three states: 0 -> {0 twice, 1}, 1 -> terminal 2; a state-action listed with duplicates."""

    def __init__(self, table=None, isd=(1.0, 0.0, 0.0)):
        self.P = table if table is not None else {
            0: {
                0: [(0.25, 0, -1.0, False), (0.25, 0, -3.0, False), (0.5, 1, -1.0, False)],
                1: [(1.0, 1, -2.0, False)],
            },
            1: {
                0: [(1.0, 2, 10.0, True)],
                1: [(0.5, 0, -1.0, False), (0.5, 2, 10.0, True)],
            },
            2: {0: [(1.0, 2, 0.0, True)], 1: [(1.0, 1, 5.0, False)]},
        }
        if isd is not None:
            self.initial_state_distrib = np.array(isd)


class Wrapper:
    """Mimics a Gymnasium wrapper: the table lives on .unwrapped."""

    def __init__(self, inner):
        self.unwrapped = inner


def test_merges_duplicates_and_averages_rewards():
    t = transition_table(FakeEnv())
    k0 = list(t.next_states[0, 0]).index(0)
    k1 = list(t.next_states[0, 0]).index(1)
    assert t.probs[0, 0, k0] == pytest.approx(0.5)
    assert t.rewards[0, 0, k0] == pytest.approx(-2.0)  # (0.25 * -1 + 0.25 * -3) / 0.5
    assert t.probs[0, 0, k1] == pytest.approx(0.5)
    # The expected reward of every (s, a) is unchanged by merging.
    assert np.sum(t.probs[0, 0] * t.rewards[0, 0]) == pytest.approx(0.25 * -1 + 0.25 * -3 + 0.5 * -1)
    np.testing.assert_allclose(t.probs.sum(axis=2), 1.0)
    assert t.next_states.shape == (3, 2, 2)


def test_terminal_states_become_absorbing():
    t = transition_table(FakeEnv())
    assert t.terminal.tolist() == [False, False, True]
    # State 2's own row (a move back to 1 with reward 5) is replaced by a free self-loop.
    for a in range(2):
        assert t.probs[2, a, 0] == 1.0 and t.next_states[2, a, 0] == 2
        assert np.all(t.rewards[2, a] == 0.0)


def test_from_gymnasium_builds_an_mdp_with_default_features():
    mdp = from_gymnasium(Wrapper(FakeEnv()), discount=0.9)
    assert isinstance(mdp, MDP)
    assert (mdp.n_states, mdp.n_actions, mdp.n_features, mdp.discount) == (3, 2, 5, 0.9)
    np.testing.assert_array_equal(mdp.start, [1.0, 0.0, 0.0])
    np.testing.assert_array_equal(mdp.terminal, [False, False, True])
    # Feature layout: one-hot destination, then one-hot action.
    np.testing.assert_array_equal(mdp.features.phi(0, 1, 1), [0, 1, 0, 0, 1])
    assert mdp.features.names[3] == "action 0"
    # Dense view agrees with the table.
    P = mdp.dense_transitions()
    assert P[1, 1, 0] == pytest.approx(0.5) and P[1, 1, 2] == pytest.approx(0.5)


def test_features_options():
    assert from_gymnasium(FakeEnv(), features=None).features is None
    custom = TransitionFeatures(action=np.eye(2), n_states=3)
    assert from_gymnasium(FakeEnv(), features=custom).features is custom
    with pytest.raises(ValueError, match='features must be "default"'):
        from_gymnasium(FakeEnv(), features="onehot")
    with pytest.raises(TypeError, match="features must be"):
        from_gymnasium(FakeEnv(), features=np.eye(2))


def test_start_distribution_sources():
    env = FakeEnv(isd=None)
    env.isd = [0.0, 1.0, 0.0]  # the older Gym name
    np.testing.assert_array_equal(transition_table(env).start_distribution, [0, 1, 0])
    t = transition_table(FakeEnv(), start_distribution=[0.5, 0.5, 0.0])
    np.testing.assert_array_equal(t.start_distribution, [0.5, 0.5, 0.0])
    with pytest.raises(ValueError, match="pass start_distribution"):
        transition_table(FakeEnv(isd=None))
    with pytest.raises(ValueError, match="start_distribution must have 3 entries"):
        transition_table(FakeEnv(), start_distribution=[1.0, 0.0])
    with pytest.raises(ValueError, match="sum to 1"):
        transition_table(FakeEnv(), start_distribution=[0.5, 0.0, 0.0])
    with pytest.raises(TypeError, match="start_distribution must be an array"):
        transition_table(FakeEnv(), start_distribution=["a", "b", "c"])


def test_input_is_not_modified():
    env = FakeEnv()
    before = repr(env.P)
    from_gymnasium(env)
    assert repr(env.P) == before


def table_with(s, a, outcomes):
    env = FakeEnv()
    env.P[s][a] = outcomes
    return env


def test_bad_tables():
    with pytest.raises(TypeError, match="transition table P"):
        transition_table(object())
    with pytest.raises(TypeError, match="transition table P"):
        from_gymnasium(Wrapper(object()))
    with pytest.raises(ValueError, match=r"sum to 0\.9.*must sum to 1"):
        transition_table(table_with(0, 1, [(0.9, 1, 0.0, False)]))
    with pytest.raises(ValueError, match="next state 7 outside"):
        transition_table(table_with(0, 1, [(1.0, 7, 0.0, False)]))
    with pytest.raises(ValueError, match="invalid probability"):
        transition_table(table_with(0, 1, [(-0.5, 1, 0.0, False), (1.5, 0, 0.0, False)]))
    with pytest.raises(ValueError, match="non-finite reward"):
        transition_table(table_with(0, 1, [(1.0, 1, float("nan"), False)]))
    with pytest.raises(TypeError, match=r"\(prob, next_state, reward, terminated\)"):
        transition_table(table_with(0, 1, [(1.0, 1)]))
    with pytest.raises(TypeError, match="not an integer"):
        transition_table(table_with(0, 1, [(1.0, 1.5, 0.0, False)]))
    env = FakeEnv()
    del env.P[1][1]
    with pytest.raises(ValueError, match=r"env.P\[1\] has no entry for action 1"):
        transition_table(env)
    env = FakeEnv()
    env.observation_space = type("Space", (), {"n": 4})()
    with pytest.raises(ValueError, match="no entry for state 3"):
        transition_table(env)
    env = FakeEnv()
    env.P = 5
    with pytest.raises(TypeError, match="indexable by state"):
        transition_table(env)
    with pytest.raises(ValueError, match="at least one state"):
        transition_table(FakeEnv(table={}))


def test_unreachable_goal_is_reported():
    # State 0 can only loop on itself, yet a terminal state exists.
    env = FakeEnv()
    env.P[0] = {0: [(1.0, 0, -1.0, False)], 1: [(1.0, 0, -1.0, False)]}
    with pytest.raises(ValueError, match=r"no policy reaches a terminal state from start state\(s\) \[0\]"):
        from_gymnasium(env)


def test_missing_gymnasium_gives_install_hint(monkeypatch):
    monkeypatch.setitem(sys.modules, "gymnasium", None)
    with pytest.raises(ImportError, match=r'pip install "pymdft\[gym\]"'):
        make_env("FrozenLake-v1")


# ----------------------------------------------------------------- real Gymnasium


def test_frozen_lake():
    pytest.importorskip("gymnasium")
    env = make_env("FrozenLake-v1")  # slippery: each action has three outcomes
    mdp = from_gymnasium(env)
    assert (mdp.n_states, mdp.n_actions) == (16, 4)
    desc = env.unwrapped.desc.astype(str).ravel()
    np.testing.assert_array_equal(mdp.terminal, np.isin(desc, ["H", "G"]))
    # Left from the corner: slips keep the agent at 0 with probability 2/3.
    P = mdp.dense_transitions()
    assert P[0, 0, 0] == pytest.approx(2 / 3) and P[0, 0, 4] == pytest.approx(1 / 3)
    # Reward 1 only on entering the goal.
    goal = int(np.flatnonzero(desc == "G")[0])
    entering = mdp.next_states == goal
    live = (mdp.probs > 0) & ~mdp.terminal[:, None, None]
    assert (entering & live).sum() == 3  # from 14, down, right and up can each end in 15
    assert np.all(mdp.rewards[entering & live] == 1.0)
    assert np.all(mdp.rewards[~entering & live] == 0.0)
    assert mdp.start[0] == 1.0


def test_cliff_walking_and_taxi():
    pytest.importorskip("gymnasium")
    cliff = from_gymnasium(_make_first("CliffWalking-v1", "CliffWalking-v0"))
    assert (cliff.n_states, cliff.n_actions, int(cliff.terminal.sum())) == (48, 4, 1)
    assert cliff.terminal[47] and cliff.start[36] == 1.0
    # Stepping right from the start falls off the cliff: -100 and back to the start.
    assert cliff.next_states[36, 1, 0] == 36 and cliff.rewards[36, 1, 0] == -100.0
    taxi = from_gymnasium(_make_first("Taxi-v4", "Taxi-v3"))
    assert (taxi.n_states, taxi.n_actions) == (500, 6)
    assert taxi.terminal.sum() == 4  # passenger delivered at each of the four stands


def _make_first(*ids):
    """The first of several versions of an environment that this Gymnasium provides."""
    import warnings

    import gymnasium

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for env_id in ids:
            try:
                return make_env(env_id)
            except gymnasium.error.Error:
                continue
    pytest.skip(f"none of {ids} in this Gymnasium")


def test_planning_on_adapted_worlds():
    from irl.planning import value_iteration

    # Fake corridor: two steps of -1 to the goal.
    class Corridor:
        P = {s: {0: [(1.0, max(s - 1, 0), -1.0, False)], 1: [(1.0, s + 1, -1.0, s + 1 == 2)]} for s in range(2)}
        P[2] = {0: [(1.0, 2, 0.0, True)], 1: [(1.0, 2, 0.0, True)]}
        initial_state_distrib = [1.0, 0.0, 0.0]

    res = value_iteration(from_gymnasium(Corridor()))
    np.testing.assert_allclose(res.values, [-2.0, -1.0, 0.0])
    pytest.importorskip("gymnasium")
    # CliffWalking: the optimal path hugs the cliff, 13 steps of -1.
    cliff = from_gymnasium(_make_first("CliffWalking-v1", "CliffWalking-v0"))
    assert value_iteration(cliff).values[36] == pytest.approx(-13.0)


def test_round_trip_of_a_gridworld_through_a_p_table():
    """An MDP written out as a Gymnasium table and read back is the same MDP."""
    from irl.gridworld import GridWorld
    from irl.planning import soft_value_iteration

    world = GridWorld(3, 0, 8, constrained_states=[4], p_slip=0.2)
    mdp = world.constrained_mdp

    class TableEnv:
        P = {
            s: {
                a: [
                    (float(p), int(s2), float(r), bool(mdp.terminal[s2]))
                    for p, s2, r in zip(mdp.probs[s, a], mdp.next_states[s, a], mdp.rewards[s, a])
                ]
                for a in range(mdp.n_actions)
            }
            for s in range(mdp.n_states)
        }
        initial_state_distrib = np.array(mdp.start)

    back = from_gymnasium(TableEnv(), features=world.features)
    live = ~mdp.terminal
    np.testing.assert_allclose(back.dense_transitions()[live], mdp.dense_transitions()[live], atol=1e-12)
    np.testing.assert_allclose(back.expected_rewards()[live], mdp.expected_rewards()[live], atol=1e-12)
    np.testing.assert_array_equal(back.terminal, mdp.terminal)
    np.testing.assert_allclose(
        soft_value_iteration(back, horizon=10).values, soft_value_iteration(mdp, horizon=10).values, atol=1e-10
    )
