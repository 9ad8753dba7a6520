"""Fuzzing the public API of ``irl``: bad and edge inputs get a ValueError or TypeError that
names the parameter (or, for a damaged file, the file), never another exception.

Each test replaces one argument of a cheap, valid call by a drawn value; valid draws run.
"""

import json

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import irl
from fuzzing import FUZZ, odd, run, scalars
from irl import GridWorld, io

WORLD = GridWorld(3, 0, 8, p_slip=0.0)
MDP = WORLD.nominal_mdp
SOFT = irl.soft_value_iteration(MDP, horizon=5)
DEMOS = [([0, 3, 4, 5, 8], [2, 1, 1, 2])]
counts = st.one_of(odd, st.integers(-5, 30), st.integers(10**9 + 1, 2**80))
arrays = st.one_of(
    odd,
    st.lists(st.floats(allow_nan=True, allow_infinity=True), max_size=10),
    st.lists(st.integers(-(10**400), 10**400), min_size=1, max_size=3),
    st.sampled_from([np.zeros((2, 0)), np.zeros(0), np.ones((9, 8)), np.ones((9, 8)) / 8,
                     np.ones((2, 9, 8)) / 8, [[1.0, 2.0]], np.full(9, 1 / 9), [[]]]),
)
json_values = st.recursive(
    st.one_of(st.none(), st.booleans(), st.floats(allow_nan=False), st.integers(),
              st.text(max_size=6)),
    lambda x: st.lists(x, max_size=3) | st.dictionaries(
        st.sampled_from(["state_seq", "action_seq", "trajs", "format", "feature_names",
                         "size", "start", "goal", "blue", "reached_terminal", "x"]),
        x, max_size=4),
    max_leaves=10,
)


@FUZZ
@given(content=st.one_of(st.binary(max_size=300), json_values.map(lambda v: json.dumps(v).encode()),
                         st.sampled_from([b"null", b"[" * 50_000 + b"]" * 50_000, b"\xff\xfe",
                                          b"PK\x03\x04junk", b"\x1f\x8b\x08\x00"])))
def test_loaders_name_the_file(content, tmp_path_factory):
    folder = tmp_path_factory.mktemp("files")
    loaders = [
        ("d.json", io.load_demonstrations),
        ("p.json", lambda p: io.load_paper_demonstrations(path=p)),
        ("w.json", lambda p: io.load_paper_worlds(path=p)),
        ("m.npz", io.load_mdp),
        ("r.json", lambda p: io.load_mesc_result(p, MDP)),
    ]
    for name, load in loaders:
        path = folder / name
        path.write_bytes(content)
        run(lambda: load(path), name)


def test_damaged_npz_names_the_file(tmp_path):
    good = tmp_path / "good.npz"
    io.save_mdp(MDP, good)
    raw = good.read_bytes()
    for k, cut in enumerate([raw[: len(raw) // 2], raw[:40], raw[:-20] + b"\x00" * 20]):
        path = tmp_path / f"cut{k}.npz"
        path.write_bytes(cut)
        with pytest.raises(ValueError, match=f"cut{k}.npz' does not hold a valid MDP"):
            io.load_mdp(path)


@FUZZ
@given(value=odd)
def test_loader_paths(value):
    for load in (io.load_demonstrations, io.load_mdp, lambda p: io.load_paper_worlds(path=p)):
        run(lambda: load(value), "path", "file", errors=(ValueError, TypeError,
                                                          FileNotFoundError))
    run(lambda: io.load_paper_worlds(value), "name")


@FUZZ
@given(name=st.sampled_from(["size", "start", "goal", "p_slip", "penalty", "step_cost",
                             "goal_reward", "discount", "blue", "constrained_states",
                             "constrained_actions", "boundary"]),
       value=st.one_of(scalars, arrays))
def test_gridworld(name, value):
    kwargs = dict(size=3, start=0, goal=8)
    kwargs[name] = value
    size, start, goal = kwargs.pop("size"), kwargs.pop("start"), kwargs.pop("goal")
    run(lambda: GridWorld(size, start, goal, **kwargs).nominal_mdp, name, "goal", "start",
        "size", "cells", "constrained")


@FUZZ
@given(name=st.sampled_from(["n_blue", "n_green", "n_constrained_states", "min_distance",
                             "max_tries", "rng"]), value=counts)
def test_random_gridworld(name, value):
    run(lambda: GridWorld.random(4, **{name: value}), name, "too few", "seed", "no layout",
        "Generator", "SeedSequence", "expected", "diagonal")


@FUZZ
@given(name=st.sampled_from(["next_states", "probs", "rewards", "terminal", "start",
                             "discount"]), value=st.one_of(scalars, arrays))
def test_mdp(name, value):
    kwargs = dict(next_states=MDP.next_states, probs=MDP.probs, rewards=MDP.rewards,
                  terminal=MDP.terminal, start=MDP.start, discount=1.0)
    kwargs[name] = value
    ns, pr = kwargs.pop("next_states"), kwargs.pop("probs")
    run(lambda: irl.MDP(ns, pr, **kwargs), name, "terminal")


@FUZZ
@given(value=st.one_of(scalars, counts))
def test_planning_options(value):
    run(lambda: irl.greedy_policy([[1.0, 2.0]], atol=value), "atol")
    run(lambda: irl.value_iteration(MDP, max_iter=value), "max_iter")
    run(lambda: irl.value_iteration(MDP, tol=value), "tol")
    run(lambda: irl.soft_value_iteration(MDP, horizon=value), "horizon")
    run(lambda: irl.state_action_visitation(MDP, SOFT.policy, max_iter=value), "max_iter")
    run(lambda: irl.value_iteration(value), "mdp")


@FUZZ
@given(value=arrays)
def test_planning_arrays(value):
    run(lambda: irl.greedy_policy(value), "q_values")
    run(lambda: irl.state_action_visitation(MDP, value), "policy")
    run(lambda: irl.state_action_visitation(MDP, SOFT.policy, start=value), "start")
    run(lambda: irl.sample_trajectories(MDP, value, 2, rng=0), "policy")
    run(lambda: irl.sample_trajectories(MDP, SOFT.policy, 2, rng=0, start=value), "start")


@FUZZ
@given(value=counts)
def test_demonstration_counts(value):
    run(lambda: irl.sample_trajectories(MDP, SOFT.policy, value, rng=0), "n")
    run(lambda: irl.sample_trajectories(MDP, SOFT.policy, 2, max_steps=value, rng=0),
        "max_steps")
    run(lambda: irl.generate_demonstrations(MDP, 2, horizon=value, rng=0), "horizon")
    run(lambda: irl.visitation_counts(DEMOS, n_states=value, n_actions=8), "n_states",
        "a state outside")


@FUZZ
@given(states=arrays, actions=arrays)
def test_trajectories(states, actions):
    run(lambda: irl.Demonstrations.from_sequences([states], [actions]), "state", "action")
    run(lambda: irl.visitation_counts([(states, actions)], n_states=9, n_actions=8),
        "trajector", "state", "action")
    run(lambda: irl.infer_hard_constraints(MDP, [(states, actions)]), "demonstration",
        "trajector", "state", "action")


@FUZZ
@given(p=arrays, q=arrays, value=scalars)
def test_metrics(p, q, value):
    run(lambda: irl.kl_divergence(p, q), "p", "q")
    run(lambda: irl.js_divergence(p, q), "p", "q")
    run(lambda: irl.hard_constraint_scores(p, q), "true", "predicted")
    run(lambda: irl.hard_constraint_scores([True], [False], zero_division=value),
        "zero_division")
    run(lambda: irl.soft_constraint_errors(p, [0.5] * 2, [0.5] * 2), "true_cost", "zeta")
    run(lambda: irl.soft_constraint_errors([0, -50], [0.2, 0.9], [0.9, 0.1], chi=value), "chi")
    run(lambda: irl.visitation_kl_divergence(DEMOS, DEMOS, n_states=9, n_actions=8,
                                             pseudocount=value), "pseudocount")


@FUZZ
@given(name=st.sampled_from(["candidates", "max_constraints", "min_kl_decrease",
                             "kl_threshold", "horizon"]), value=st.one_of(scalars, arrays))
def test_hard_constraint_inference(name, value):
    run(lambda: irl.infer_hard_constraints(MDP, DEMOS, **{name: value}), name)


@FUZZ
@given(value=st.one_of(scalars, arrays))
def test_gymnasium(value):
    pytest.importorskip("gymnasium")
    env = irl.gym.make_env("FrozenLake-v1", map_name="4x4")
    run(lambda: irl.from_gymnasium(value), "env")
    run(lambda: irl.from_gymnasium(env, discount=value), "discount")
    run(lambda: irl.from_gymnasium(env, start_distribution=value), "start_distribution")
    run(lambda: irl.from_gymnasium(env, features=value), "features")


def test_known_cases():
    """The inputs reported as crashing, each answered by its parameter's name."""
    cases = [
        (lambda: irl.greedy_policy([[1.0, 2.0]], atol="abc"), TypeError, "atol must be a real"),
        (lambda: irl.greedy_policy([[1.0, 2.0]], atol=-1), ValueError, r"atol must be >= 0.0"),
        (lambda: irl.infer_hard_constraints(MDP, DEMOS, candidates=[]), ValueError,
         "candidates must name at least one feature"),
        (lambda: irl.soft_value_iteration(MDP, horizon=10**7), ValueError,
         "horizon=10000000 .* asks for 720,000,000 values"),
    ]
    for call, error, match in cases:
        with pytest.raises(error, match=match):
            call()
