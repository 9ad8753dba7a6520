"""Tests of irl.mdp: construction, conventions and bad input."""

import numpy as np
import pytest
import scipy.sparse as sp

from irl import MDP, TransitionFeatures
from irl.mdp import successor_patterns


def tiny(seed=0, S=4, A=2, discount=0.9):
    rng = np.random.default_rng(seed)
    P = rng.random((S, A, S)) * (rng.random((S, A, S)) < 0.7)
    P[..., 0] += 1e-3
    P /= P.sum(axis=2, keepdims=True)
    R = rng.normal(size=(S, A, S))
    return P, R


def test_from_dense_round_trip():
    P, R = tiny()
    mdp = MDP.from_dense(P, R, discount=0.9)
    np.testing.assert_allclose(mdp.dense_transitions(), P)
    # rewards sit beside their successors
    for s in range(4):
        for a in range(2):
            for k in range(mdp.n_successors):
                if mdp.probs[s, a, k] > 0:
                    assert mdp.rewards[s, a, k] == R[s, a, mdp.next_states[s, a, k]]
    np.testing.assert_allclose(mdp.expected_rewards(), (P * R).sum(axis=2))


def test_from_dense_reward_shapes():
    P, _ = tiny()
    by_dest = MDP.from_dense(P, np.arange(4.0))
    pos = by_dest.probs > 0
    np.testing.assert_allclose(by_dest.rewards[pos], by_dest.next_states[pos].astype(float))
    by_sa = MDP.from_dense(P, np.ones((4, 2)))
    assert np.all(by_sa.rewards[by_sa.probs > 0] == 1.0)
    with pytest.raises(ValueError, match="rewards must have shape"):
        MDP.from_dense(P, np.ones((3, 3)))


def test_defaults_and_readonly():
    P, R = tiny()
    mdp = MDP.from_dense(P, R)
    np.testing.assert_allclose(mdp.start, 0.25)
    assert mdp.discount == 1.0 and not mdp.terminal.any()
    with pytest.raises(ValueError, match="read-only"):
        mdp.probs[0, 0, 0] = 0.5
    for name in ("next_states", "rewards", "start", "terminal"):
        assert not getattr(mdp, name).flags.writeable, name


def test_arguments_not_mutated_and_not_aliased():
    P, R = tiny()
    mdp0 = MDP.from_dense(P, R)
    ns, pr, rw = (np.array(x) for x in (mdp0.next_states, mdp0.probs, mdp0.rewards))
    copies = [x.copy() for x in (ns, pr, rw)]
    mdp = MDP(ns, pr, rw, discount=0.5)
    for x, c in zip((ns, pr, rw), copies):
        np.testing.assert_array_equal(x, c)
    pr[0, 0, 0] = 7.0
    assert mdp.probs[0, 0, 0] == copies[1][0, 0, 0]


def test_penalised_subtracts_feature_values():
    S, A, F = 3, 2, 4
    rng = np.random.default_rng(1)
    src, act, dst = rng.random((S, F)), rng.random((A, F)), rng.random((S, F))
    feats = TransitionFeatures(src, sp.csr_array(act), dst, names=list("abcd"))
    P = np.full((S, A, S), 1 / 3)
    mdp = MDP.from_dense(P, features=feats)
    omega = rng.random(F)
    pen = mdp.penalised(omega)
    for s in range(S):
        for a in range(A):
            for k in range(mdp.n_successors):
                sn = mdp.next_states[s, a, k]
                phi = src[s] + act[a] + dst[sn]
                np.testing.assert_allclose(feats.phi(s, a, sn), phi)
                assert pen.rewards[s, a, k] == pytest.approx(-phi @ omega)
    counts = feats.counts(np.ones(S), np.ones(A), np.zeros(S))
    np.testing.assert_allclose(counts, src.sum(0) + act.sum(0))


def test_feature_arrays_and_penalties_not_mutated():
    S, A, F = 3, 2, 4
    rng = np.random.default_rng(2)
    src, act, dst = rng.random((S, F)), rng.random((A, F)), rng.random((S, F))
    copies = [x.copy() for x in (src, act, dst)]
    feats = TransitionFeatures(src, act, dst)
    mdp = MDP.from_dense(np.full((S, A, S), 1 / 3), features=feats)
    omega = rng.random(F)
    omega_copy = omega.copy()
    pen = mdp.penalised(omega)
    mdp.penalised(2 * omega)
    for x, c in zip((src, act, dst), copies):
        np.testing.assert_array_equal(x, c)
    np.testing.assert_array_equal(omega, omega_copy)
    # nor does writing to the caller's arrays afterwards reach the MDP's features
    before = pen.rewards.copy()
    src[:] = 0.0
    np.testing.assert_array_equal(mdp.penalised(omega).rewards, before)


def test_replace_and_unknown_field():
    P, R = tiny()
    mdp = MDP.from_dense(P, R)
    assert mdp.replace(discount=0.3).discount == 0.3
    with pytest.raises(TypeError, match="unknown field"):
        mdp.replace(gamma=0.3)


# ------------------------------------------------------------------ bad input
def valid():
    P, R = tiny()
    m = MDP.from_dense(P, R)
    return np.array(m.next_states), np.array(m.probs), np.array(m.rewards)


def test_probs_must_sum_to_one():
    ns, pr, rw = valid()
    pr[1, 1, 0] += 0.1
    with pytest.raises(ValueError, match=r"probs must sum to 1 .* s=1, a=1"):
        MDP(ns, pr, rw)


def test_probs_non_negative():
    ns, pr, rw = valid()
    pr[0, 0, 0] = -0.1
    with pytest.raises(ValueError, match="probs must be non-negative"):
        MDP(ns, pr, rw)


def test_states_out_of_range():
    ns, pr, rw = valid()
    ns[2, 0, 0] = 4
    with pytest.raises(ValueError, match=r"next_states must hold states in \[0, 4\) \(got 4\)"):
        MDP(ns, pr, rw)
    ns[2, 0, 0] = -1
    with pytest.raises(ValueError, match="next_states must hold states"):
        MDP(ns, pr, rw)


def test_shapes_and_types():
    ns, pr, rw = valid()
    with pytest.raises(ValueError, match="next_states must have the shape of probs"):
        MDP(ns[:, :, :1], pr, rw)
    # probs with fewer states than next_states refers to: the shapes are named, not the range
    with pytest.raises(ValueError, match=r"next_states must have the shape of probs \(1, "):
        MDP(ns, pr[:1], rw)
    with pytest.raises(ValueError, match="rewards must have shape"):
        MDP(ns, pr, rw[:2])
    with pytest.raises(TypeError, match="next_states must hold integer"):
        MDP(ns + 0.5, pr, rw)
    with pytest.raises(ValueError, match="probs must contain only finite"):
        MDP(ns, pr * np.nan, rw)
    with pytest.raises(ValueError, match="probs must be a 3-d array"):
        MDP(ns, pr[0], rw)


def test_start_terminal_discount():
    ns, pr, rw = valid()
    with pytest.raises(ValueError, match="start must be a probability distribution"):
        MDP(ns, pr, rw, start=[0.5, 0.0, 0.0, 0.0])
    with pytest.raises(ValueError, match=r"start must have shape \(4\)"):
        MDP(ns, pr, rw, start=[1.0])
    with pytest.raises(ValueError, match=r"terminal must have shape \(4,\)"):
        MDP(ns, pr, rw, terminal=[True])
    with pytest.raises(ValueError, match=r"discount must be > 0.0 \(got 0.0\)"):
        MDP(ns, pr, rw, discount=0.0)
    with pytest.raises(ValueError, match="discount must be <= 1.0"):
        MDP(ns, pr, rw, discount=1.5)
    with pytest.raises(TypeError, match="discount must be a real number"):
        MDP(ns, pr, rw, discount="0.9")


def test_unreachable_goal():
    # state 0 loops on itself, state 1 is the goal
    P = np.zeros((2, 1, 2))
    P[0, 0, 0] = 1.0
    P[1, 0, 1] = 1.0
    with pytest.raises(ValueError, match=r"no policy reaches a terminal state from start state\(s\) \[0\]"):
        MDP.from_dense(P, terminal=[False, True], start=[1.0, 0.0])


def test_features_of_wrong_size():
    P, R = tiny()
    with pytest.raises(ValueError, match="features must be defined for 4 states and 2 actions"):
        MDP.from_dense(P, R, features=TransitionFeatures(destination=np.eye(3), n_actions=2))
    with pytest.raises(ValueError, match="destination must have 2 feature columns"):
        TransitionFeatures(destination=np.eye(5), action=np.eye(2))
    with pytest.raises(ValueError, match=r"names must have one entry per feature \(3\)"):
        TransitionFeatures(destination=np.eye(3), n_actions=1, names=["a"])
    with pytest.raises(TypeError, match="features must be a TransitionFeatures"):
        MDP.from_dense(P, R, features=np.eye(4))
    f = TransitionFeatures(destination=np.eye(4), n_actions=2)
    mdp = MDP.from_dense(P, R, features=f)
    with pytest.raises(ValueError, match=r"penalties must have shape \(4\)"):
        mdp.penalised(np.ones(5))
    with pytest.raises(ValueError, match="penalised needs an MDP with features"):
        MDP.from_dense(P, R).penalised(np.ones(4))


@pytest.mark.parametrize("n_states,n_features", [(30, 20), (600, 500)])  # dense copies below the size limit, CSR above
def test_feature_products_match_dense_algebra(n_states, n_features):
    rng = np.random.default_rng(n_states)
    src = sp.random(n_states, n_features, density=0.05, random_state=1)
    act = sp.random(4, n_features, density=0.3, random_state=2)
    feats = TransitionFeatures(source=src, action=act)
    w = rng.normal(size=n_features)
    u_src, u_act, u_dst = feats.projections(w)
    np.testing.assert_allclose(u_src, src.toarray() @ w, atol=1e-12)
    np.testing.assert_allclose(u_act, act.toarray() @ w, atol=1e-12)
    np.testing.assert_array_equal(u_dst, np.zeros(n_states))
    d_src, d_act, d_dst = rng.normal(size=n_states), rng.normal(size=4), rng.normal(size=n_states)
    np.testing.assert_allclose(feats.counts(d_src, d_act, d_dst), src.toarray().T @ d_src + act.toarray().T @ d_act,
                               atol=1e-12)


@pytest.mark.parametrize("seed", range(5))
def test_successor_patterns_rebuild_the_transitions(seed):
    rng = np.random.default_rng(seed)
    S, A = 7, 3
    P = rng.random((S, A, S)) * (rng.random((S, A, S)) < 0.5)
    shared = rng.random(S) < 0.6
    P[shared] = rng.random((int(shared.sum()), A, S)) * (rng.random((int(shared.sum()), 1, S)) < 0.6)
    P[..., 0] += 0.1
    P /= P.sum(axis=2, keepdims=True)
    P[2] = P[1]
    mdp = MDP.from_dense(P)
    is_shared, succ, pattern_of, patterns = successor_patterns(mdp.next_states, mdp.probs)
    same = np.all(mdp.next_states == mdp.next_states[:, :1], axis=(1, 2))
    np.testing.assert_array_equal(is_shared, same)
    assert succ.dtype == np.int32 and pattern_of.dtype == np.int32
    for s in np.flatnonzero(same):
        np.testing.assert_array_equal(succ[s], mdp.next_states[s, 0])
        np.testing.assert_array_equal(patterns[pattern_of[s]].T, mdp.probs[s])
    distinct = {mdp.probs[s].tobytes() for s in np.flatnonzero(same)}
    assert len(patterns) == max(len(distinct), 1)


def test_gridworld_with_slip_has_nine_successor_patterns():
    from irl import GridWorld

    mdp = GridWorld(12, 0, 143, p_slip=0.1).nominal_mdp
    is_shared, _, _, patterns = successor_patterns(mdp.next_states, mdp.probs)
    assert is_shared.all() and len(patterns) == 9
