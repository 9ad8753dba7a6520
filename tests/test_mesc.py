"""Tests of MESC-IRL, demonstrations and saving/loading."""

import json
import warnings

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from irl import (
    MDP,
    Demonstrations,
    TransitionFeatures,
    GridWorld,
    MESCObjective,
    MESCResult,
    constraint_probability,
    generate_demonstrations,
    load_demonstrations,
    load_mdp,
    load_mesc_result,
    load_paper_demonstrations,
    load_paper_worlds,
    mesc_irl,
    sample_trajectories,
    save_demonstrations,
    save_mdp,
    soft_value_iteration,
    state_action_visitation,
)


def small_world(p_slip=0.1, discount=1.0):
    return GridWorld(
        4, 0, 15, blue=[5], green=[10], constrained_states=[6], constrained_actions=["up_right"],
        constrained_colours=["green"], p_slip=p_slip, discount=discount,
    )


@pytest.fixture(scope="module")
def figure1():
    return load_paper_worlds()[0]


# ------------------------------------------------------------- the objective
@pytest.mark.parametrize("p_slip,discount", [(0.1, 1.0), (0.2, 0.9), (0.0, 1.0)])
def test_gradient_matches_finite_differences(p_slip, discount):
    world = small_world(p_slip, discount)
    demos = generate_demonstrations(world.constrained_mdp, 30, rng=1)
    obj = MESCObjective(world.nominal_mdp, demos, horizon=12)
    w = np.random.default_rng(0).uniform(0.0, 6.0, world.n_features)
    value, grad = obj(w)
    eps = 1e-5
    fd = np.array([(obj(w + eps * e)[0] - obj(w - eps * e)[0]) / (2 * eps) for e in np.eye(w.size)])
    np.testing.assert_allclose(grad, fd, atol=1e-7 + 1e-6 * np.abs(grad).max())


@pytest.mark.parametrize("p_slip,discount", [(0.1, 1.0), (0.2, 0.9)])
def test_objective_is_the_demonstrations_log_likelihood(p_slip, discount):
    world = small_world(p_slip, discount)
    demos = generate_demonstrations(world.constrained_mdp, 25, rng=3)
    obj = MESCObjective(world.nominal_mdp, demos, horizon=10)
    w = np.random.default_rng(1).uniform(0.0, 3.0, world.n_features)
    w_copy = w.copy()
    pol = obj.policy(w)
    ref = soft_value_iteration(world.nominal_mdp.penalised(w), horizon=10).policy
    np.testing.assert_allclose(pol, ref, atol=1e-12)
    t = demos.time_steps
    keep = t < 10
    loglik = np.log(pol[t[keep], demos.states[keep], demos.actions[keep]]).sum() / len(demos)
    assert obj(w)[0] == pytest.approx(loglik, rel=1e-12)
    # evaluating elsewhere changes neither the argument nor a policy handed out before
    pol_copy = pol.copy()
    obj(2 * w)
    np.testing.assert_array_equal(w, w_copy)
    np.testing.assert_array_equal(pol, pol_copy)


def test_deterministic_gradient_is_expected_minus_empirical_counts():
    world = small_world(p_slip=0.0)
    demos = generate_demonstrations(world.constrained_mdp, 40, rng=2)
    obj = MESCObjective(world.nominal_mdp, demos)
    w = np.random.default_rng(2).uniform(0.0, 3.0, world.n_features)
    expected, empirical = obj.feature_counts(w)
    np.testing.assert_allclose(obj(w)[1], expected - empirical, atol=1e-12)
    # the expected counts are those of the forward pass from the demonstrations' starts
    d = state_action_visitation(world.nominal_mdp, obj.policy(w), start=obj.start)
    assert expected[world.feature_slices["action"]].sum() == pytest.approx(d.state_action.sum())


@pytest.mark.parametrize("p_slip,discount", [(0.0, 1.0), (0.2, 1.0), (0.1, 0.8)])
def test_expected_counts_cover_the_expected_trajectory_length(p_slip, discount):
    # backward and forward passes share the horizon and the discount: each feature block
    # (one destination, one action, one colour per step) sums to the expected discounted
    # number of steps of the soft policy, computed here by a plain NumPy forward pass
    world = small_world(p_slip, discount)
    demos = generate_demonstrations(world.constrained_mdp, 20, rng=4)
    obj = MESCObjective(world.nominal_mdp, demos, horizon=9)
    w = np.random.default_rng(4).uniform(0.0, 4.0, world.n_features)
    pol = obj.policy(w)
    assert pol.shape == (9, world.n_states, world.n_actions)
    nom = world.nominal_mdp
    P = nom.dense_transitions()
    d, length = np.array(obj.start), 0.0
    for t in range(obj.horizon):
        d = np.where(nom.terminal, 0.0, d)
        length += discount**t * d.sum()
        d = np.einsum("s,sa,sat->t", d, pol[t], P)
    expected, _ = obj.feature_counts(w)
    for block in ("state", "action", "colour"):
        assert expected[world.feature_slices[block]].sum() == pytest.approx(length, rel=1e-10), block


# ---------------------------------------------------------------- learning
def test_recovers_figure1_constraints(figure1):
    world = figure1.replace(p_slip=0.1)
    demos = generate_demonstrations(world.constrained_mdp, 300, rng=2)
    res = mesc_irl(world.nominal_mdp, demos)
    assert res.converged
    names = res.feature_names
    zeta = dict(zip(names, res.zeta))
    # the constraints that the demonstrations reveal: the states and blue cells that a
    # nominal route would cross, and the diagonal move it would take
    for name in ("state 31", "state 39", "state 47", "action up_right", "colour blue"):
        assert zeta[name] >= 0.6, (name, zeta[name])
    false_pos = [n for n, z, t in zip(names, res.zeta, world.constraint_mask) if z >= 0.6 and not t]
    assert len(false_pos) <= 2, false_pos
    ranked = res.ranked_constraints(min_zeta=0.6)
    assert [c.penalty for c in ranked] == sorted((c.penalty for c in ranked), reverse=True)
    assert world.constraint_mask[ranked[0].feature], ranked[0].name  # the largest penalty is a true constraint


def test_fits_the_papers_own_demonstrations(figure1):
    demos = load_paper_demonstrations()[0]
    world = figure1.replace(p_slip=0.0)
    res = mesc_irl(world.nominal_mdp, demos)
    assert res.converged
    top = {c.name for c in res.ranked_constraints(min_zeta=0.75)}
    assert {"action up_right", "colour blue"} <= top


def test_same_seed_same_result_and_no_mutation():
    world = small_world()
    a = generate_demonstrations(world.constrained_mdp, 20, rng=7)
    b = generate_demonstrations(world.constrained_mdp, 20, rng=7)
    np.testing.assert_array_equal(a.states, b.states)
    np.testing.assert_array_equal(a.actions, b.actions)
    init = np.full(world.n_features, 0.5)
    init_copy = init.copy()
    states_copy = a.states.copy()
    r1 = mesc_irl(world.nominal_mdp, a, init=init)
    r2 = mesc_irl(world.nominal_mdp, b, init=init)
    np.testing.assert_array_equal(r1.penalties, r2.penalties)
    np.testing.assert_array_equal(init, init_copy)
    np.testing.assert_array_equal(a.states, states_copy)
    assert not r1.penalties.flags.writeable


def test_warm_start_transfer():
    w1 = GridWorld.random(6, rng=1, n_blue=3, n_green=3, n_constrained_states=3, min_distance=4)
    w2 = GridWorld.random(6, rng=2, n_blue=3, n_green=3, n_constrained_states=3, min_distance=4)
    r1 = mesc_irl(w1.nominal_mdp, generate_demonstrations(w1.constrained_mdp, 50, rng=0))
    d2 = generate_demonstrations(w2.constrained_mdp, 50, rng=0)
    cold = mesc_irl(w2.nominal_mdp, d2)
    warm = mesc_irl(w2.nominal_mdp, d2, init=r1)
    assert warm.converged and warm.objective >= cold.objective - 1e-2
    with pytest.raises(ValueError, match="init was learned on other features"):
        other = GridWorld(6, 0, 35)
        bad = MESCResult.from_penalties(other.nominal_mdp, np.zeros(other.n_features))
        object.__setattr__(bad, "feature_names", tuple(reversed(bad.feature_names)))
        mesc_irl(w2.nominal_mdp, d2, init=bad)
    with pytest.raises(ValueError, match=r"init must have one penalty per feature \(47\)"):
        mesc_irl(w2.nominal_mdp, d2, init=MESCResult.from_penalties(small_world().nominal_mdp, np.zeros(27)))


def test_a_warm_start_is_used_or_refused():
    # init used to be dropped without a word by the default call (the evidence selection starts
    # its path from zero) and by the paper's optimiser: a "warm start" gave the cold result
    w1 = GridWorld.random(6, rng=1, n_blue=3, n_green=3, n_constrained_states=3, min_distance=4)
    w2 = GridWorld.random(6, rng=2, n_blue=3, n_green=3, n_constrained_states=3, min_distance=4)
    r1 = mesc_irl(w1.nominal_mdp, generate_demonstrations(w1.constrained_mdp, 50, rng=0))
    d2 = generate_demonstrations(w2.constrained_mdp, 10, rng=0)
    warm = mesc_irl(w2.nominal_mdp, d2, init=r1)
    assert warm.selection == "none"
    explicit = mesc_irl(w2.nominal_mdp, d2, init=r1, selection="none")
    np.testing.assert_array_equal(warm.penalties, explicit.penalties)
    cold = mesc_irl(w2.nominal_mdp, d2, selection="none")
    # the start matters where the demonstrations leave penalties free (features they never approach)
    assert not np.allclose(warm.penalties, cold.penalties, atol=1e-2)
    assert warm.objective == pytest.approx(cold.objective, abs=0.05)  # both maximise L (to the slack tol leaves)
    with pytest.raises(ValueError, match="init applies to selection='l1' or 'none'"):
        mesc_irl(w2.nominal_mdp, d2, init=r1, selection="evidence")
    with pytest.raises(ValueError, match="paper's optimiser starts every penalty at eg_options"):
        mesc_irl(w2.nominal_mdp, d2, init=r1, optimizer="eg")


def test_demonstration_subsets_by_mask_or_integers_only():
    d = Demonstrations.from_sequences([[0, 1], [1, 2], [2, 0]], [[0], [0], [1]])
    # a boolean mask selects where it is True (it used to be read as the indices 1, 0, 1)
    picked = d.subset(np.array([True, False, True]))
    assert [picked.trajectory(i) for i in range(len(picked))] == [d.trajectory(0), d.trajectory(2)]
    assert d.subset([-1]).trajectory(0) == d.trajectory(2)
    with pytest.raises(ValueError, match=r"boolean indices mask must have one entry per trajectory \(3\)"):
        d.subset(np.array([True, False]))
    with pytest.raises(TypeError, match="indices must be integers or a boolean mask"):
        d.subset([0.0, 1.7])
    with pytest.raises(ValueError, match=r"indices must lie in \[-3, 3\)"):
        d.subset([3])


def test_demonstrations_of_a_soft_policy_that_does_not_exist_are_refused():
    # with discount 1 and a step cost of 1 < log 8, wandering forever has infinite soft value: the
    # stationary soft iteration diverges (V grows by about log 8 - 1 per sweep). The demonstrations
    # used to come from the unconverged policy with only a warning (1000-step trajectories).
    world = GridWorld(5, 0, 24, step_cost=1.0, p_slip=0.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        v100 = soft_value_iteration(world.nominal_mdp, max_iter=100).values.max()
        v200 = soft_value_iteration(world.nominal_mdp, max_iter=200).values.max()
    assert v200 - v100 > 50  # diverging, the premise of the test
    with pytest.raises(ValueError, match=r"soft value iteration of mdp did not converge in max_iter=10000"):
        generate_demonstrations(world.nominal_mdp, 5, rng=0)
    # a discount below 1 or a finite horizon makes the soft policy exist again
    assert len(generate_demonstrations(world.replace(discount=0.9).nominal_mdp, 5, rng=0)) == 5
    assert len(generate_demonstrations(world.nominal_mdp, 5, rng=0, horizon=30)) == 5
    assert len(generate_demonstrations(GridWorld(5, 0, 24, p_slip=0.0).nominal_mdp, 5, rng=0)) == 5


def test_objective_refuses_no_features_and_an_oversized_horizon():
    world = small_world()
    demos = generate_demonstrations(world.constrained_mdp, 5, rng=0)
    empty = world.nominal_mdp.replace(features=TransitionFeatures(destination=np.zeros((16, 0)), n_actions=8))
    for kw in ({}, {"optimizer": "eg"}, {"selection": "l1"}):
        with pytest.raises(ValueError, match="nominal must have at least one feature"):
            mesc_irl(empty, demos, **kw)
    # the (H, S, A) policy buffer is checked before it is allocated (it used to be a MemoryError)
    with pytest.raises(ValueError, match=r"horizon=1000000000 x 16 states x 8 actions \(the policy buffer\)"):
        MESCObjective(world.nominal_mdp, demos, horizon=10**9)


def test_bounds_and_ridge():
    world = small_world()
    demos = generate_demonstrations(world.constrained_mdp, 30, rng=0)
    capped = mesc_irl(world.nominal_mdp, demos, max_penalty=5.0, selection="none")
    assert capped.penalties.max() <= 5.0
    ridge = mesc_irl(world.nominal_mdp, demos, l2=1.0)
    free = mesc_irl(world.nominal_mdp, demos, selection="none")
    # the cap binds: the free fit goes above it, so the capped fit is a worse fit
    assert free.penalties.max() > 5.0 and capped.penalties.max() == pytest.approx(5.0)
    assert capped.objective < free.objective
    assert np.linalg.norm(ridge.penalties) < np.linalg.norm(free.penalties)
    assert free.objective >= ridge.objective
    scaled = mesc_irl(world.nominal_mdp, demos, precondition=True, selection="none")
    assert scaled.converged and scaled.objective == pytest.approx(free.objective, abs=5e-3)


def test_non_convergence_warns():
    world = small_world()
    demos = generate_demonstrations(world.constrained_mdp, 30, rng=0)
    with pytest.warns(RuntimeWarning, match="L-BFGS-B did not converge"):
        res = mesc_irl(world.nominal_mdp, demos, max_iter=1)
    assert not res.converged


# -------------------------------------------------------------------- zeta
def test_zeta_and_pooled_sd():
    world = small_world()
    w = np.zeros(world.n_features)
    w[6] = 30.0
    w[world.feature_slices["colour"].start + 2] = 5.0
    res = MESCResult.from_penalties(world.nominal_mdp, w)
    n, c = world.nominal_mdp, res.constrained
    feasible = (n.probs > 0) & ~n.terminal[:, None, None]
    s_n, s_c = np.std(n.rewards[feasible]), np.std(c.rewards[feasible])
    assert res.sigma_nominal == pytest.approx(s_n) and res.sigma_constrained == pytest.approx(s_c)
    s = np.sqrt((s_n**2 + s_c**2) / 2)
    np.testing.assert_allclose(res.zeta, 1 / (1 + np.exp(-(w - s) / s)))
    np.testing.assert_allclose(res.feature_zeta([6]), constraint_probability([30.0], s))
    tz = res.transition_zeta(world.feature_slices["state"])
    k = n.successor_index(2, 2, 6)
    assert tz[2, 2, k] == pytest.approx(float(constraint_probability(30.0, s)))
    assert res.ranked_constraints(min_zeta=0.5)[0].name == "state 6"


# ---------------------------------------------------------- demonstrations
def test_sampled_visitation_matches_forward_pass():
    world = small_world(p_slip=0.2)
    mdp = world.constrained_mdp
    pol = soft_value_iteration(mdp).policy
    n = 4000
    demos = sample_trajectories(mdp, pol, n, rng=0)
    counts = np.zeros((mdp.n_states, mdp.n_actions))
    np.add.at(counts, (demos.states, demos.actions), 1.0)
    expected = state_action_visitation(mdp, pol).state_action
    # per-trajectory counts: the mean is within 5 standard errors of the expectation
    per = np.zeros((n, mdp.n_states, mdp.n_actions))
    idx = np.repeat(np.arange(n), demos.lengths)
    np.add.at(per, (idx, demos.states, demos.actions), 1.0)
    se = per.std(axis=0) / np.sqrt(n) + 1e-3
    assert np.all(np.abs(counts / n - expected) <= 5 * se)


def test_time_indexed_sampling_and_truncation():
    world = small_world()
    mdp = world.nominal_mdp
    pol = soft_value_iteration(mdp, horizon=3).policy
    with pytest.warns(RuntimeWarning, match=r"did not reach a terminal state within max_steps=3"):
        demos = sample_trajectories(mdp, pol, 10, rng=0)
    assert demos.lengths.max() <= 3 and not demos.reached_terminal.all()


def test_demonstrations_views_and_round_trip(tmp_path):
    d = Demonstrations.from_sequences([[0, 1, 5], [0, 4]], [[1, 5], [2]])
    assert d.time_steps.tolist() == [0, 1, 0] and d.start_states.tolist() == [0, 0]
    save_demonstrations(d, tmp_path / "d.json")
    back = load_demonstrations(tmp_path / "d.json")
    assert back.to_dict() == d.to_dict()


def test_paper_demonstrations_fit_the_paper_world(figure1):
    sets = load_paper_demonstrations()
    assert len(sets) == 10 and all(len(s) == 100 for s in sets)
    sets[0].check(figure1.replace(p_slip=0.0).nominal_mdp)


def test_save_and_load(tmp_path, figure1):
    world = small_world()
    demos = generate_demonstrations(world.constrained_mdp, 20, rng=0)
    res = mesc_irl(world.nominal_mdp, demos)
    res.save(tmp_path / "r.json")
    doc = json.loads((tmp_path / "r.json").read_text())
    assert doc["format"] == "pymdft.mesc_result"
    back = load_mesc_result(tmp_path / "r.json", world.nominal_mdp)
    np.testing.assert_array_equal(back.penalties, res.penalties)
    np.testing.assert_allclose(back.zeta, res.zeta)
    assert back.objective == res.objective and back.converged == res.converged
    with pytest.raises(ValueError, match="do not match"):
        load_mesc_result(tmp_path / "r.json", figure1.nominal_mdp)
    save_mdp(res.constrained, tmp_path / "m.npz")
    m = load_mdp(tmp_path / "m.npz")
    np.testing.assert_array_equal(m.rewards, res.constrained.rewards)
    assert m.features.names == world.feature_names
    with np.load(tmp_path / "m.npz", allow_pickle=False) as z:
        assert all(z[k].dtype != object for k in z.files)
    with pytest.raises(FileNotFoundError, match="result file not found"):
        load_mesc_result(tmp_path / "nope.json", world.nominal_mdp)


# --------------------------------------------------------------- bad input
def test_bad_demonstrations():
    with pytest.raises(ValueError, match="at least one trajectory"):
        Demonstrations.from_sequences([], [])
    with pytest.raises(ValueError, match=r"at least one transition \(trajectory 1 is empty\)"):
        Demonstrations.from_sequences([[0, 1], [3]], [[0], []])
    with pytest.raises(ValueError, match="trajectory 0 must have one more state than actions"):
        Demonstrations.from_sequences([[0, 1]], [[0, 1]])
    with pytest.raises(ValueError, match="trajectory 0 is not contiguous"):
        Demonstrations([0, 2], [0, 5], [1, 1], [1, 6])
    with pytest.raises(TypeError, match="states must hold integers"):
        Demonstrations([0, 1], [0.5], [1], [1])
    world = small_world()
    mdp = world.nominal_mdp
    with pytest.raises(ValueError, match=r"demonstrations states must be < 16 for this MDP \(trajectory 0, step 1 has 20\)"):
        Demonstrations.from_sequences([[0, 20, 1]], [[1, 1]]).check(mdp)
    with pytest.raises(ValueError, match=r"demonstrations actions must be < 8"):
        Demonstrations.from_sequences([[0, 1]], [[9]]).check(mdp)
    with pytest.raises(ValueError, match=r"the transition \(0, 1, 10\) has probability zero"):
        Demonstrations.from_sequences([[0, 10]], [[1]]).check(mdp)
    with pytest.raises(ValueError, match="acts from the terminal state 15"):
        Demonstrations.from_sequences([[14, 15, 14]], [[1, 0]]).check(mdp)


def test_bad_mesc_input():
    world = small_world()
    demos = generate_demonstrations(world.constrained_mdp, 5, rng=0)
    with pytest.raises(TypeError, match="demonstrations must be an irl.Demonstrations"):
        mesc_irl(world.nominal_mdp, [[0, 1]])
    with pytest.raises(ValueError, match="nominal must have features"):
        mesc_irl(world.nominal_mdp.replace(features=None), demos)
    with pytest.raises(TypeError, match="nominal must be an irl.MDP"):
        mesc_irl("world", demos)
    with pytest.raises(ValueError, match=r"init must have shape \(27\)"):
        mesc_irl(world.nominal_mdp, demos, init=np.zeros(3))
    with pytest.raises(ValueError, match="init must be non-negative"):
        mesc_irl(world.nominal_mdp, demos, init=-np.ones(27))
    with pytest.raises(ValueError, match="horizon must be an integer >= 1"):
        mesc_irl(world.nominal_mdp, demos, horizon=0)
    with pytest.raises(ValueError, match="l2 must be >= 0"):
        mesc_irl(world.nominal_mdp, demos, l2=-1.0)
    with pytest.raises(ValueError, match=r"penalties must have shape \(27\)"):
        MESCObjective(world.nominal_mdp, demos)(np.zeros(26))
    with pytest.raises(ValueError, match="penalties must be non-negative"):
        MESCResult.from_penalties(world.nominal_mdp, -np.ones(27))


@settings(deadline=None, max_examples=10)
@given(seed=st.integers(0, 10_000), discount=st.sampled_from([1.0, 0.8]))
def test_gradient_on_random_mdps_with_dense_features(seed, discount):
    # generic MDPs: successors differ between actions, features on all three blocks
    rng = np.random.default_rng(seed)
    S, A, F = 5, 3, 4
    P = rng.random((S, A, S)) * (rng.random((S, A, S)) < 0.5)
    P[:, :, S - 1] += 0.1
    P /= P.sum(axis=2, keepdims=True)
    feats = TransitionFeatures(rng.random((S, F)), rng.random((A, F)), rng.random((S, F)))
    term = np.zeros(S, dtype=bool)
    term[S - 1] = True
    start = np.zeros(S)
    start[0] = 1.0
    mdp = MDP.from_dense(P, rng.normal(size=(S, A, S)), terminal=term, start=start, discount=discount,
                         features=feats)
    pol = np.full((S, A), 1.0 / A)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # some trajectories are cut at max_steps
        demos = sample_trajectories(mdp, pol, 6, rng=seed, max_steps=8)
    obj = MESCObjective(mdp, demos, horizon=7)
    w = rng.uniform(0.0, 2.0, F)
    _, grad = obj(w)
    eps = 1e-6
    fd = np.array([(obj(w + eps * e)[0] - obj(w - eps * e)[0]) / (2 * eps) for e in np.eye(F)])
    np.testing.assert_allclose(grad, fd, rtol=1e-5, atol=1e-7)


@settings(deadline=None, max_examples=10)
@given(seed=st.integers(0, 10_000))
def test_objective_on_mdps_mixing_shared_and_own_successors(seed):
    # some states list the same successors for every action (read through the pattern table),
    # the others their own; two shared states repeat one probability matrix
    rng = np.random.default_rng(seed)
    S, A, F = 6, 3, 5
    P = rng.random((S, A, S)) * (rng.random((S, A, S)) < 0.5)
    shared = rng.random(S) < 0.5
    P[shared] = rng.random((int(shared.sum()), A, S)) * (rng.random((int(shared.sum()), 1, S)) < 0.6)
    P[:, :, S - 1] += 0.1
    P /= P.sum(axis=2, keepdims=True)
    P[1] = P[0]
    feats = TransitionFeatures(rng.random((S, F)), rng.random((A, F)), rng.random((S, F)))
    term = np.zeros(S, dtype=bool)
    term[S - 1] = True
    mdp = MDP.from_dense(P, rng.normal(size=(S, A, S)), terminal=term, start=np.eye(S)[0], features=feats)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # some trajectories are cut at max_steps
        demos = sample_trajectories(mdp, np.full((S, A), 1.0 / A), 8, rng=seed, max_steps=8)
    obj = MESCObjective(mdp, demos, horizon=7)
    w = rng.uniform(0.0, 2.0, F)
    value, grad = obj(w)
    pol = soft_value_iteration(mdp.penalised(w), horizon=7).policy
    t = demos.time_steps
    keep = t < 7
    assert value == pytest.approx(np.log(pol[t[keep], demos.states[keep], demos.actions[keep]]).sum() / len(demos),
                                  rel=1e-12)
    eps = 1e-6
    fd = np.array([(obj(w + eps * e)[0] - obj(w - eps * e)[0]) / (2 * eps) for e in np.eye(F)])
    np.testing.assert_allclose(grad, fd, rtol=1e-5, atol=1e-7)


@pytest.mark.parametrize("p_slip,discount", [(0.1, 1.0), (0.0, 0.9)])
def test_passes_skip_only_states_the_likelihood_cannot_see(p_slip, discount):
    # 20 x 20 (several blocks of states): blocks far from the start are skipped at early steps,
    # and L, its gradient and the value alone are those of passes over every state at every step
    world = GridWorld(20, 0, 399, constrained_states=[21, 42, 63], p_slip=p_slip, discount=discount)
    demos = generate_demonstrations(world.constrained_mdp, 15, rng=4)
    obj = MESCObjective(world.nominal_mdp, demos)
    assert obj._block_first.max() > 0 and obj._block_first.min() == 0
    full = MESCObjective(world.nominal_mdp, demos)
    full._block_first = full._block_all
    rng = np.random.default_rng(2)
    for _ in range(3):
        w = rng.uniform(0.0, 4.0, world.n_features) * (rng.random(world.n_features) < 0.3)
        value, grad = obj(w)
        ref_value, ref_grad = full(w)
        assert value == ref_value
        np.testing.assert_array_equal(grad, ref_grad)
        assert obj._value(w + 0.5) == full._value(w + 0.5)
    # and the full passes are the independent recursion's
    pol = soft_value_iteration(world.nominal_mdp.penalised(w), horizon=obj.horizon).policy
    t = demos.time_steps
    keep = t < obj.horizon
    assert value == pytest.approx(np.log(pol[t[keep], demos.states[keep], demos.actions[keep]]).sum() / len(demos),
                                  rel=1e-12)
    np.testing.assert_allclose(obj.policy(w), pol, atol=1e-12)
    d = rng.normal(size=world.n_features)
    eps = 1e-6
    fd = (obj(w + eps * d)[0] - obj(w - eps * d)[0]) / (2 * eps)
    assert fd == pytest.approx(grad @ d, rel=1e-5)


def test_fast_exp_matches_numpy_exp_within_two_ulp():
    # the backward pass's exp of q - max(q) <= 0, drawn over its whole range, and the edges
    from irl._kernels import _exp_nonpositive
    from numba import njit

    @njit
    def apply(x):
        out = np.empty_like(x)
        for i in range(x.size):
            out[i] = _exp_nonpositive(x[i])
        return out

    rng = np.random.default_rng(5)
    x = np.concatenate([-rng.exponential(10.0, 20000), -rng.uniform(0, 708, 20000), -rng.uniform(0, 1e-6, 2000),
                        [0.0, -0.0, -5e-324, -np.log(2) / 2, -np.log(2), -700.0, -708.0]])
    got, want = apply(x), np.exp(x)
    assert np.all(np.abs(got - want) <= 2 * np.spacing(want))
    # below exp(-708) the result is 0 (against at most 3e-308); -inf gives 0, nan stays nan
    tail = apply(np.array([-708.5, -745.0, -1e5, -np.inf, np.nan]))
    assert tail[:4].tolist() == [0.0, 0.0, 0.0, 0.0] and np.isnan(tail[4])


@pytest.mark.parametrize("seed", range(3))
def test_expected_features_per_state_action_against_brute_force(seed):
    # psi(s, a) = sum_k P(s_k | s, a) phi(s, a, s_k) from TransitionFeatures.phi, zero at terminal states;
    # r0 - psi . omega is the expected penalised reward of the kernel that sums per transition
    from irl import _kernels
    from irl.mesc import _expected_features, _pass_tables

    rng = np.random.default_rng(seed)
    S, A, F = 9, 3, 5
    P = rng.random((S, A, S)) * (rng.random((S, A, S)) < 0.4)
    P[:, :, S - 1] += 0.05
    P /= P.sum(axis=2, keepdims=True)
    feats = TransitionFeatures(rng.random((S, F)) * (rng.random((S, F)) < 0.5), rng.random((A, F)),
                               rng.random((S, F)) * (rng.random((S, F)) < 0.5))
    term = np.zeros(S, dtype=bool)
    term[S - 1] = True
    mdp = MDP.from_dense(P, rng.normal(size=(S, A, S)), terminal=term, start=np.eye(S)[0], features=feats)
    want = np.zeros((S * A, F))
    for s in range(S - 1):
        for a in range(A):
            for k in range(mdp.n_successors):
                want[s * A + a] += mdp.probs[s, a, k] * feats.phi(s, a, mdp.next_states[s, a, k])
    np.testing.assert_allclose(_expected_features(mdp).toarray(), want, rtol=1e-12, atol=1e-15)
    w = rng.uniform(0, 3, F)
    r0, psi = _pass_tables(mdp)[:2]
    got = np.empty((S, A))
    _kernels.affine_rewards(r0, *psi, w, got)
    ref = _kernels.penalised_expected_rewards(mdp.next_states, mdp.probs, mdp.rewards, mdp.terminal,
                                              *feats.projections(w))
    np.testing.assert_allclose(got, ref, rtol=1e-12, atol=1e-12)
    assert _pass_tables(mdp)[1] is psi  # made once per MDP


@pytest.mark.parametrize("size, p_slip, seed", [(4, 0.1, 0), (6, 0.3, 1), (9, 0.1, 2), (5, 0.05, 3)])
def test_split_patterns_passes_match_the_general_passes(size, p_slip, seed):
    # with slip every pattern is a common part plus one successor of its own per action: those passes
    # (K + A multiply-adds per state) give L, its gradient and the policy of the passes reading probs
    from irl.mesc import _split_patterns

    world = GridWorld.random(size, rng=seed, n_blue=2, n_green=2, n_constrained_states=2, n_constrained_actions=1,
                             min_distance=size / 2, p_slip=p_slip)
    demos = generate_demonstrations(world.constrained_mdp, 20, rng=seed)
    obj = MESCObjective(world.nominal_mdp, demos)
    base, res_k, res_p, simple = obj._split
    assert simple.all()
    patterns = obj._compact[3]
    rebuilt = np.repeat(base[:, :, None], patterns.shape[2], axis=2)
    np.put_along_axis(rebuilt, res_k[:, None, :], rebuilt[np.arange(len(base))[:, None], res_k, np.arange(8)][:, None, :]
                      + res_p[:, None, :], axis=1)
    np.testing.assert_allclose(rebuilt, patterns, rtol=1e-15, atol=0)  # up to the rounding of the split
    general = MESCObjective(world.nominal_mdp, demos)
    shared, succ, pattern_of, pats = general._compact
    general._compact = (np.zeros_like(shared), succ, pattern_of, pats)
    w = np.random.default_rng(seed).uniform(0.0, 5.0, world.n_features)
    value, grad = obj(w)
    ref_value, ref_grad = general(w)
    assert value == pytest.approx(ref_value, rel=1e-13)
    np.testing.assert_allclose(grad, ref_grad, rtol=1e-10, atol=1e-13)
    np.testing.assert_allclose(obj.policy(w), general.policy(w), rtol=0, atol=1e-13)
    assert obj._value(w * 0.5) == pytest.approx(general._value(w * 0.5), rel=1e-13)
    # a pattern with two successors of its own for some action is not split
    two = patterns[:1].copy()
    two[0, :2, 0] += [0.2, 0.1]
    assert not _split_patterns(two)[3][0]


def test_fused_multiply_add_rounds_once():
    # compiled: one rounding of the exact a * b + c (against exact rational arithmetic); the
    # uncompiled fallback is that rational arithmetic itself, and differs from a * b + c where it should
    from fractions import Fraction

    from irl._kernels import _fma
    from numba import njit

    @njit
    def apply(a, b, c):
        out = np.empty_like(a)
        for i in range(a.size):
            out[i] = _fma(a[i], b[i], c[i])
        return out

    rng = np.random.default_rng(3)
    a, b = rng.normal(size=500) * 10.0 ** rng.integers(-5, 5, 500), rng.normal(size=500)
    c = -a * b * (1 + rng.normal(size=500) * 1e-12)  # cancellation: the single rounding shows
    exact = np.array([float(Fraction(x) * Fraction(y) + Fraction(z)) for x, y, z in zip(a, b, c)])
    np.testing.assert_array_equal(apply(a, b, c), exact)
    assert _fma(a[0], b[0], c[0]) == exact[0]
    assert np.count_nonzero(a * b + c != exact) > 100


@settings(deadline=None, max_examples=15)
@given(seed=st.integers(0, 10_000), n_actions=st.integers(1, 9), n_succ=st.integers(1, 9))
def test_shared_successor_passes_match_the_general_passes(seed, n_actions, n_succ):
    # every state lists the same successors for all its actions (the pattern-table passes, which
    # work on four actions or successors at a time plus a remainder); they must give the policy of
    # the plain recursion, and L (bit for bit, unless a pattern in use is split into a common part
    # and one successor per action: then to rounding) and its gradient of the passes reading probs
    rng = np.random.default_rng(seed)
    S, F = 7, 4
    P = np.zeros((S, n_actions, S))
    for s in range(S):
        succ = np.append(rng.choice(S - 1, size=min(n_succ, S) - 1, replace=False), S - 1)  # the goal reachable
        P[s][:, succ] = rng.random((n_actions, succ.size)) + 0.05
    P /= P.sum(axis=2, keepdims=True)
    feats = TransitionFeatures(rng.random((S, F)), rng.random((n_actions, F)), rng.random((S, F)))
    term = np.zeros(S, dtype=bool)
    term[S - 1] = True
    mdp = MDP.from_dense(P, rng.normal(size=(S, n_actions, S)), terminal=term, start=np.eye(S)[0],
                         discount=float(rng.choice([1.0, 0.9])), features=feats)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # some trajectories are cut at max_steps
        demos = sample_trajectories(mdp, np.full((S, n_actions), 1.0 / n_actions), 8, rng=seed, max_steps=8)
    obj = MESCObjective(mdp, demos, horizon=7)
    assert obj._compact[0][~mdp.terminal].all()
    general = MESCObjective(mdp, demos, horizon=7)
    shared, succ, pattern_of, patterns = general._compact
    general._compact = (np.zeros_like(shared), succ, pattern_of, patterns)
    w = rng.uniform(0.0, 2.0, F)
    value, grad = obj(w)
    ref_value, ref_grad = general(w)
    split = obj._split[3][np.unique(pattern_of[~mdp.terminal])].any()
    same = (lambda x, y: x == pytest.approx(y, rel=1e-13, abs=1e-13)) if split else (lambda x, y: x == y)
    assert same(value, ref_value)
    np.testing.assert_allclose(grad, ref_grad, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(obj.policy(w), soft_value_iteration(mdp.penalised(w), horizon=7).policy, atol=1e-12)
    assert same(obj._value(w + 0.25), general._value(w + 0.25))
