"""Reference tests of irl.planning against brute-force NumPy computations on tiny MDPs."""

import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from irl import GridWorld, MDP, soft_value_iteration, state_action_visitation, value_iteration


def random_mdp(seed, S=4, A=2, discount=0.8, terminal=True):
    rng = np.random.default_rng(seed)
    P = rng.random((S, A, S)) * (rng.random((S, A, S)) < 0.6)
    P[:, :, S - 1] += 0.05  # the last state (terminal) is reachable from everywhere
    P /= P.sum(axis=2, keepdims=True)
    R = rng.normal(size=(S, A, S))
    term = np.zeros(S, dtype=bool)
    term[S - 1] = terminal
    start = np.zeros(S)
    start[0] = 1.0
    return MDP.from_dense(P, R, terminal=term, start=start, discount=discount), P, R, term


def brute_force_optimal_values(P, R, term, discount):
    """Best value over all deterministic stationary policies, each solved exactly."""
    S, A, _ = P.shape
    best = np.full(S, -np.inf)
    live = ~term
    for pol in itertools.product(range(A), repeat=S):
        Pp = np.array([P[s, pol[s]] for s in range(S)])
        rp = np.array([P[s, pol[s]] @ R[s, pol[s]] for s in range(S)])
        Pp[:, term] = 0.0
        Pp[term] = 0.0
        rp[term] = 0.0
        v = np.linalg.solve(np.eye(S) - discount * Pp, rp)
        best = np.maximum(best, v)
    best[~live] = 0.0
    return best


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_value_iteration_matches_policy_enumeration(seed):
    mdp, P, R, term = random_mdp(seed)
    res = value_iteration(mdp, tol=1e-12)
    assert res.converged
    np.testing.assert_allclose(res.values, brute_force_optimal_values(P, R, term, 0.8), atol=1e-9)
    # Q is consistent with V, the greedy policy picks argmax Q
    Pm = P.copy()
    Pm[:, :, term] = 0.0
    q = (P * R).sum(2) + 0.8 * Pm @ res.values
    q[term] = 0.0
    np.testing.assert_allclose(res.q_values, q, atol=1e-9)
    np.testing.assert_allclose(res.policy.sum(1), 1.0)
    best = res.q_values >= res.q_values.max(axis=1, keepdims=True) - 1e-9
    live = ~term
    assert np.all(res.policy[live][~best[live]] == 0.0)
    np.testing.assert_allclose((res.policy * q).sum(1)[live], res.values[live], atol=1e-9)


def enumerate_soft(P, R, term, discount, pol, s0, H):
    """Sum over all (state, action) paths of length <= H: discounted visitation and entropy-regularised return."""
    S, A, _ = P.shape
    sa = np.zeros((S, A))
    value = 0.0

    def walk(s, t, prob):
        nonlocal value
        if t == H or term[s]:
            return
        for a in range(A):
            pa = pol[t, s, a]
            sa[s, a] += discount**t * prob * pa
            for sn in range(S):
                p = P[s, a, sn]
                if p == 0.0:
                    continue
                value += discount**t * prob * pa * p * (R[s, a, sn] - np.log(pa))
                walk(sn, t + 1, prob * pa * p)

    walk(s0, 0, 1.0)
    return sa, value


@pytest.mark.parametrize("seed,discount", [(0, 1.0), (3, 0.7)])
def test_soft_backward_and_forward_match_trajectory_enumeration(seed, discount):
    mdp, P, R, term = random_mdp(seed, S=3, A=2, discount=discount)
    H = 4
    soft = soft_value_iteration(mdp, horizon=H)
    assert soft.policy.shape == (H, 3, 2) and soft.values.shape == (H + 1, 3)
    sa, value = enumerate_soft(P, R, term, discount, soft.policy, 0, H)
    # V_0(s0) is the expected discounted reward plus causal entropy of the soft policy
    assert soft.values[0, 0] == pytest.approx(value, abs=1e-10)
    vis = state_action_visitation(mdp, soft.policy)
    np.testing.assert_allclose(vis.state_action, sa, atol=1e-12)
    np.testing.assert_allclose(vis.states, sa.sum(1), atol=1e-12)


def test_soft_values_are_log_sum_exp_over_paths_when_deterministic():
    # deterministic chain-with-choices: V_0(s) = log sum_paths exp(return)
    S, A, H = 3, 2, 3
    rng = np.random.default_rng(5)
    nxt = rng.integers(S, size=(S, A))
    P = np.zeros((S, A, S))
    P[np.arange(S)[:, None], np.arange(A)[None, :], nxt] = 1.0
    R = rng.normal(size=(S, A, S))
    mdp = MDP.from_dense(P, R)
    soft = soft_value_iteration(mdp, horizon=H)
    for s0 in range(S):
        total = []
        for acts in itertools.product(range(A), repeat=H):
            s, ret = s0, 0.0
            for a in acts:
                ret += R[s, a, nxt[s, a]]
                s = nxt[s, a]
            total.append(ret)
        assert soft.values[0, s0] == pytest.approx(np.log(np.sum(np.exp(total))), abs=1e-10)


def test_stationary_soft_is_the_fixed_point_and_long_horizon_limit():
    mdp, P, R, term = random_mdp(1, discount=0.8)
    st_ = soft_value_iteration(mdp, tol=1e-13)
    assert st_.converged
    q = (P * R).sum(2) + 0.8 * np.where(term[None, None, :], 0.0, P) @ st_.values
    q[term] = 0.0
    v = np.log(np.exp(q).sum(1))
    v[term] = 0.0
    np.testing.assert_allclose(st_.values, v, atol=1e-10)
    fin = soft_value_iteration(mdp, horizon=400)
    np.testing.assert_allclose(fin.values[0], st_.values, atol=1e-9)
    # stationary visitation = long finite-horizon visitation
    d_st = state_action_visitation(mdp, st_.policy, tol=1e-14)
    d_fin = state_action_visitation(mdp, np.broadcast_to(st_.policy, (400, 4, 2)))
    np.testing.assert_allclose(d_st.state_action, d_fin.state_action, atol=1e-9)


def test_visitation_matches_linear_solve():
    mdp, P, R, term = random_mdp(2, discount=0.9)
    pol = np.random.default_rng(0).dirichlet(np.ones(2), size=4)
    res = state_action_visitation(mdp, pol, tol=1e-14)
    Pp = np.einsum("sa,sat->st", pol, P)
    Pp[term] = 0.0
    d = np.linalg.solve(np.eye(4) - 0.9 * Pp.T, mdp.start)
    d[term] = 0.0
    np.testing.assert_allclose(res.states, d, atol=1e-10)


def expected_discounted_length(P, term, discount, pol, start):
    """sum_t discount**t P(the trajectory is still running at step t), by a NumPy forward pass."""
    d = np.array(start, dtype=float)
    total = 0.0
    for t in range(pol.shape[0]):
        d = np.where(term, 0.0, d)
        total += discount**t * d.sum()
        d = np.einsum("s,sa,sat->t", d, pol[t], P)
    return total


@settings(deadline=None, max_examples=15)
@given(seed=st.integers(0, 10_000), horizon=st.integers(1, 6), discount=st.sampled_from([1.0, 0.8]),
       terminal=st.booleans())
def test_policies_are_distributions_and_visitation_is_the_expected_length(seed, horizon, discount, terminal):
    mdp, P, _, term = random_mdp(seed, discount=discount, terminal=terminal)
    soft = soft_value_iteration(mdp, horizon=horizon)
    np.testing.assert_allclose(soft.policy.sum(-1), 1.0, atol=1e-12)
    assert np.all(soft.policy >= 0)
    vis = state_action_visitation(mdp, soft.policy)
    np.testing.assert_allclose(vis.state_action.sum(1), vis.states, atol=1e-12)
    # the forward pass runs over the backward pass's horizon: its total mass is the
    # expected (discounted) number of steps taken before the horizon or a terminal state
    length = expected_discounted_length(P, term, discount, soft.policy, mdp.start)
    assert vis.states.sum() == pytest.approx(length, rel=1e-12, abs=1e-12)
    if not terminal and discount == 1.0:
        assert vis.states.sum() == pytest.approx(horizon, rel=1e-12)
    assert np.all(vis.states[term] == 0.0)


def test_gridworld_value_iteration_deterministic_shortest_path():
    world = GridWorld(5, 0, 24, p_slip=0.0, discount=1.0)
    res = value_iteration(world.nominal_mdp)
    # four diagonal moves: -4 * 4 * sqrt(2) + 10
    assert res.values[0] == pytest.approx(10 - 16 * np.sqrt(2))
    assert res.policy[0, 5] == 1.0  # up_right


def test_non_convergence_warns():
    mdp, *_ = random_mdp(0, discount=0.99)
    with pytest.warns(RuntimeWarning, match="value_iteration did not converge in max_iter=2"):
        res = value_iteration(mdp, max_iter=2)
    assert not res.converged and res.n_iter == 2
    with pytest.warns(RuntimeWarning, match="soft_value_iteration did not converge"):
        assert not soft_value_iteration(mdp, max_iter=2).converged
    with pytest.warns(RuntimeWarning, match="state_action_visitation did not converge"):
        state_action_visitation(mdp, np.full((4, 2), 0.5), max_iter=1)


def test_bad_input():
    mdp, *_ = random_mdp(0)
    with pytest.raises(TypeError, match="mdp must be an irl.MDP"):
        value_iteration("mdp")
    with pytest.raises(ValueError, match="max_iter must be an integer >= 1"):
        value_iteration(mdp, max_iter=0)
    with pytest.raises(ValueError, match="tol must be > 0"):
        soft_value_iteration(mdp, tol=0.0)
    with pytest.raises(ValueError, match="horizon must be an integer >= 1"):
        soft_value_iteration(mdp, horizon=0)
    with pytest.raises(ValueError, match=r"policy must have shape \(4, 2\)"):
        state_action_visitation(mdp, np.full((3, 2), 0.5))
    with pytest.raises(ValueError, match="policy rows must be probability distributions"):
        state_action_visitation(mdp, np.full((4, 2), 0.6))


def test_inputs_not_mutated():
    mdp, *_ = random_mdp(0)
    pol = np.full((4, 2), 0.5)
    before = pol.copy()
    state_action_visitation(mdp, pol)
    np.testing.assert_array_equal(pol, before)


_JIT_SCRIPT = r"""
import json, numpy as np
from irl import GridWorld, generate_demonstrations, MESCObjective, soft_value_iteration, value_iteration
w = GridWorld(3, 0, 8, blue=[4], constrained_states=[5], p_slip=0.2)
d = generate_demonstrations(w.constrained_mdp, 5, rng=0)
obj = MESCObjective(w.nominal_mdp, d, horizon=6)
val, grad = obj(np.linspace(0.0, 2.0, w.n_features))
print(json.dumps({
    "v": value_iteration(w.constrained_mdp).values.tolist(),
    "soft": soft_value_iteration(w.constrained_mdp, horizon=4).values.tolist(),
    "states": d.states.tolist(), "val": val, "grad": grad.tolist(),
}))
"""


def test_compiled_and_pure_python_agree():
    import json
    import os
    import subprocess
    import sys
    from pathlib import Path

    root = str(Path(__file__).resolve().parents[1])
    out = {}
    for flag in ("0", "1"):
        env = dict(os.environ, NUMBA_DISABLE_JIT=flag, PYTHONPATH=root)
        run = subprocess.run([sys.executable, "-c", _JIT_SCRIPT], env=env, capture_output=True, text=True, timeout=300)
        assert run.returncode == 0, run.stderr
        out[flag] = json.loads(run.stdout)
    assert out["0"]["states"] == out["1"]["states"]
    for key in ("v", "soft", "grad"):
        np.testing.assert_allclose(out["0"][key], out["1"][key], rtol=1e-12, atol=1e-12)
    assert out["0"]["val"] == pytest.approx(out["1"]["val"], rel=1e-12)
