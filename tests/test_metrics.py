"""Tests of irl.metrics: analytic cases, slow reference versions, properties and bad input."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from irl.metrics import (
    HardConstraintScores,
    false_discovery_rate,
    false_positive_rate,
    hard_constraint_scores,
    js_divergence,
    kl_divergence,
    precision,
    recall,
    soft_constraint_errors,
    visitation_counts,
    visitation_js_divergence,
    visitation_kl_divergence,
)

masks = st.lists(st.tuples(st.booleans(), st.booleans()), min_size=1, max_size=40)


# ----------------------------------------------------------------------------- hard


def test_hard_scores_hand_computed():
    true = np.array([1, 1, 1, 0, 0, 0, 0, 0], dtype=bool)
    pred = np.array([1, 1, 0, 1, 0, 0, 0, 0], dtype=bool)
    s = hard_constraint_scores(true, pred)
    assert isinstance(s, HardConstraintScores)
    assert (s.n_true_positive, s.n_false_positive, s.n_false_negative, s.n_true_negative) == (2, 1, 1, 4)
    assert s.precision == pytest.approx(2 / 3)
    assert s.recall == pytest.approx(2 / 3)
    assert s.false_positive_rate == pytest.approx(1 / 5)
    assert s.false_discovery_rate == pytest.approx(1 / 3)
    assert precision(true, pred) == s.precision
    assert recall(true, pred) == s.recall
    assert false_positive_rate(true, pred) == s.false_positive_rate
    assert false_discovery_rate(true, pred) == s.false_discovery_rate


def test_hard_scores_accept_zero_one_integers():
    s = hard_constraint_scores([1, 0, 1], [1, 1, 0])
    assert (s.n_true_positive, s.n_false_positive, s.n_false_negative) == (1, 1, 1)


def test_perfect_and_empty_predictions():
    true = [True, False, True]
    s = hard_constraint_scores(true, true)
    assert (s.precision, s.recall, s.false_positive_rate, s.false_discovery_rate) == (1, 1, 0, 0)
    # Predicting nothing: no false discovery (the paper's metric is a perfect 0),
    # but recall exposes it.
    e = hard_constraint_scores(true, [False] * 3)
    assert e.precision == 1.0 and e.false_discovery_rate == 0.0 and e.recall == 0.0


def test_zero_division_conventions_and_override():
    s = hard_constraint_scores([False, False], [False, False])
    assert (s.precision, s.recall, s.false_positive_rate, s.false_discovery_rate) == (1, 1, 0, 0)
    a = hard_constraint_scores([True, True], [True, True])
    assert a.false_positive_rate == 0.0
    n = hard_constraint_scores([False, False], [False, False], zero_division=float("nan"))
    assert all(math.isnan(x) for x in (n.precision, n.recall, n.false_discovery_rate))
    assert n.false_positive_rate == 0.0  # 0 / 2 is defined


@settings(deadline=None, max_examples=60)
@given(masks)
def test_hard_scores_identities(pairs):
    true = np.array([p[0] for p in pairs])
    pred = np.array([p[1] for p in pairs])
    s = hard_constraint_scores(true, pred)
    assert s.n_true_positive + s.n_false_positive + s.n_false_negative + s.n_true_negative == len(pairs)
    assert s.precision + s.false_discovery_rate == pytest.approx(1.0)
    for x in (s.precision, s.recall, s.false_positive_rate):
        assert 0.0 <= x <= 1.0
    # Slow reference, with the documented 0/0 convention (precision and recall 1, rates 0).
    tp = sum(t and p for t, p in pairs)
    fp = sum((not t) and p for t, p in pairs)
    fn = sum(t and not p for t, p in pairs)
    tn = sum((not t) and (not p) for t, p in pairs)
    assert (s.n_true_positive, s.n_false_positive, s.n_false_negative, s.n_true_negative) == (tp, fp, fn, tn)
    assert s.precision == pytest.approx(tp / (tp + fp) if tp + fp else 1.0)
    assert s.recall == pytest.approx(tp / (tp + fn) if tp + fn else 1.0)
    assert s.false_positive_rate == pytest.approx(fp / (fp + tn) if fp + tn else 0.0)
    assert s.false_discovery_rate == pytest.approx(fp / (tp + fp) if tp + fp else 0.0)


def test_hard_bad_input():
    with pytest.raises(ValueError, match=r"true and predicted must have the same shape \(got \(2,\) and \(1,\)\)"):
        hard_constraint_scores([True, False], [True])
    with pytest.raises(ValueError, match="true must hold booleans or 0/1"):
        hard_constraint_scores([0.2, 0.9], [1, 0])
    with pytest.raises(ValueError, match=r"true must be a 1-d array \(got shape \(2, 2\)\)"):
        hard_constraint_scores(np.ones((2, 2), bool), np.ones((2, 2), bool))
    with pytest.raises(ValueError, match="true must be a 1-d array of booleans .got a scalar"):
        hard_constraint_scores(True, False)
    with pytest.raises(TypeError, match="true must be an array of booleans"):
        hard_constraint_scores(["a", "b"], [True, False])
    with pytest.raises(TypeError, match="booleans"):
        hard_constraint_scores([None, True], [True, False])
    with pytest.raises(ValueError, match="true must not be empty"):
        hard_constraint_scores([], [])
    with pytest.raises(TypeError, match="zero_division"):
        hard_constraint_scores([True], [True], zero_division="warn")


# ----------------------------------------------------------------------------- soft


def test_soft_errors_hand_computed():
    cost = np.array([0, 0, 0, -50, -50])
    zt = np.array([0.1, 0.1, 0.1, 0.9, 0.9])
    zp = np.array([0.35, 0.31, 0.1, 0.6, 0.89])
    e = soft_constraint_errors(cost, zt, zp, chi=0.2)
    # fp: x0 (0.25 > 0.2); x1 0.21 > 0.2 as well; fn: x3 (0.3 > 0.2).
    assert (e.n_false_positive, e.n_false_negative) == (2, 1)
    assert e.false_positives == pytest.approx(2 / 5)
    assert e.false_negatives == pytest.approx(1 / 5)
    assert e.false_positive_share == pytest.approx(2 / 3)
    assert e.false_negative_share == pytest.approx(1 / 2)
    assert (e.n_candidates, e.n_constrained, e.n_unconstrained, e.chi) == (5, 2, 3, 0.2)


def test_soft_errors_strict_inequality_and_limits():
    cost = [0.0, 1.0]
    # A difference of exactly chi is not an error (strict >, as in the paper).
    e = soft_constraint_errors(cost, [0.0, 1.0], [0.5, 0.5], chi=0.5)
    assert (e.n_false_positive, e.n_false_negative) == (0, 0)
    # chi = 1 can never be exceeded; chi = 0 flags any overshoot.
    assert soft_constraint_errors(cost, [0.0, 1.0], [1.0, 0.0], chi=1.0).n_false_positive == 0
    e0 = soft_constraint_errors(cost, [0.0, 1.0], [1e-9, 1 - 1e-9], chi=0.0)
    assert (e0.n_false_positive, e0.n_false_negative) == (1, 1)
    # Over-estimating a real constraint is not a false positive; under-estimating a
    # non-constraint is not a false negative.
    e = soft_constraint_errors(cost, [0.5, 0.5], [0.0, 1.0], chi=0.1)
    assert (e.n_false_positive, e.n_false_negative) == (0, 0)


def test_soft_errors_boolean_cost_and_no_constraints():
    e = soft_constraint_errors([False, False], [0.1, 0.1], [0.9, 0.1], chi=0.2)
    assert e.n_constrained == 0 and e.false_negative_share == 0.0 and e.false_positives == 0.5


def test_soft_bad_input():
    with pytest.raises(ValueError, match=r"true_cost and zeta_true must have the same shape \(got \(2,\) and \(3,\)\)"):
        soft_constraint_errors([0, 1], [0.1, 0.2, 0.3], [0.1, 0.2, 0.3])
    with pytest.raises(ValueError, match="same shape"):
        soft_constraint_errors([0, 1], [0.1, 0.2], [0.1])
    with pytest.raises(ValueError, match=r"zeta_pred must lie in \[0, 1\]"):
        soft_constraint_errors([0, 1], [0.1, 0.2], [0.1, 1.2])
    with pytest.raises(ValueError, match="zeta_true must be finite"):
        soft_constraint_errors([0, 1], [np.nan, 0.2], [0.1, 0.2])
    with pytest.raises(ValueError, match="chi must be <= 1"):
        soft_constraint_errors([0, 1], [0.1, 0.2], [0.1, 0.2], chi=1.5)
    with pytest.raises(TypeError, match="chi must be a real number"):
        soft_constraint_errors([0, 1], [0.1, 0.2], [0.1, 0.2], chi="0.2")
    with pytest.raises(ValueError, match="not be empty"):
        soft_constraint_errors([], [], [])
    with pytest.raises(ValueError, match="true_cost must be a 1-d"):
        soft_constraint_errors(np.zeros((2, 2)), [0.1, 0.2], [0.1, 0.2])
    with pytest.raises(ValueError, match="true_cost must be finite"):
        soft_constraint_errors([np.inf, 0], [0.1, 0.2], [0.1, 0.2])
    with pytest.raises(TypeError, match="true_cost"):
        soft_constraint_errors(["x", 0], [0.1, 0.2], [0.1, 0.2])


# ----------------------------------------------------------------------------- divergences


def slow_kl(p, q):
    p = np.asarray(p, float) / np.sum(p)
    q = np.asarray(q, float) / np.sum(q)
    total = 0.0
    for pi, qi in zip(p.ravel(), q.ravel()):
        if pi > 0:
            if qi == 0:
                return math.inf
            total += pi * math.log(pi / qi)
    return total


def test_kl_analytic_bernoulli():
    p, q = 0.3, 0.6
    expected = p * math.log(p / q) + (1 - p) * math.log((1 - p) / (1 - q))
    assert kl_divergence([p, 1 - p], [q, 1 - q]) == pytest.approx(expected)
    assert kl_divergence([3, 7], [6, 4]) == pytest.approx(expected)  # counts are normalised


def test_kl_zero_cases_never_nan():
    assert kl_divergence([0.5, 0.5], [0.5, 0.5]) == 0.0
    assert kl_divergence([1, 0], [0.5, 0.5]) == pytest.approx(math.log(2))  # 0 log 0 = 0
    assert kl_divergence([0.5, 0.5], [1, 0]) == math.inf


def test_js_analytic_cases():
    assert js_divergence([1, 0], [0, 1]) == pytest.approx(math.log(2))
    assert js_divergence([0.2, 0.8], [0.2, 0.8]) == pytest.approx(0.0, abs=1e-15)
    p, q = np.array([0.3, 0.7]), np.array([0.6, 0.4])
    m = (p + q) / 2
    assert js_divergence(p, q) == pytest.approx(0.5 * slow_kl(p, m) + 0.5 * slow_kl(q, m))


@settings(deadline=None, max_examples=60)
@given(
    st.lists(st.floats(0, 10), min_size=2, max_size=12).filter(lambda x: sum(x) > 1e-3),
    st.data(),
)
def test_divergence_properties(p, data):
    q = data.draw(st.lists(st.floats(0.01, 10), min_size=len(p), max_size=len(p)))
    kl = kl_divergence(p, q)
    assert kl >= 0 and not math.isnan(kl)
    assert kl == pytest.approx(slow_kl(p, q), rel=1e-9, abs=1e-12)
    js = js_divergence(p, q)
    assert 0 <= js <= math.log(2) + 1e-12
    m = np.asarray(p) / np.sum(p) + np.asarray(q) / np.sum(q)
    assert js == pytest.approx(0.5 * slow_kl(p, m) + 0.5 * slow_kl(q, m), rel=1e-9, abs=1e-12)
    assert js == pytest.approx(js_divergence(q, p), abs=1e-12)


def test_inputs_not_mutated():
    p, q = np.array([3.0, 1.0, 0.0]), np.array([1.0, 1.0, 2.0])
    true, pred = np.array([True, False, True]), np.array([True, True, False])
    cost, zt, zp = np.array([0.0, -50.0]), np.array([0.2, 0.9]), np.array([0.5, 0.5])
    args = (p, q, true, pred, cost, zt, zp)
    copies = [x.copy() for x in args]
    kl_divergence(p, q)
    js_divergence(p, q)
    hard_constraint_scores(true, pred)
    soft_constraint_errors(cost, zt, zp, chi=0.1)
    for x, c in zip(args, copies):
        np.testing.assert_array_equal(x, c)


def test_divergence_bad_input():
    with pytest.raises(ValueError, match=r"p and q must have the same shape \(got \(2,\) and \(1,\)\)"):
        kl_divergence([0.5, 0.5], [1.0])
    with pytest.raises(ValueError, match=r"p must be non-negative \(got -0.5\)"):
        kl_divergence([-0.5, 1.5], [0.5, 0.5])
    with pytest.raises(ValueError, match="positive total mass"):
        kl_divergence([0, 0], [0.5, 0.5])
    with pytest.raises(ValueError, match="q must have positive total mass"):
        js_divergence([1, 0], [0, 0])
    with pytest.raises(ValueError, match="p must be finite"):
        js_divergence([np.nan, 1], [0.5, 0.5])
    with pytest.raises(ValueError, match="must not be empty"):
        kl_divergence([], [])
    with pytest.raises(TypeError, match="non-negative numbers"):
        kl_divergence(["a"], [1.0])


# ----------------------------------------------------------------------------- visitation


def test_visitation_counts_formats_agree():
    class Demo:
        def __init__(self, states, actions):
            self.states = np.asarray(states)
            self.actions = np.asarray(actions)

    as_pairs = [([0, 1, 2], [1, 0]), ([2, 2], [1, 1])]
    as_arrays = [np.array([[0, 1], [1, 0]]), np.array([[2, 1], [2, 1]])]
    as_objects = [Demo([0, 1, 2], [1, 0]), Demo([2, 2, 0], [1, 1])]
    expected = np.array([[0, 1], [1, 0], [0, 2]])
    for trajs in (as_pairs, as_arrays, as_objects):
        np.testing.assert_array_equal(visitation_counts(trajs, n_states=3, n_actions=2), expected)


def test_visitation_kl_matches_hand_smoothing():
    p = [([0, 1], [0]), ([0, 1], [0]), ([1, 0], [1])]
    q = [([0, 1], [1])]
    alpha = 0.5
    cp = np.array([2, 0, 0, 1]) + alpha
    cq = np.array([0, 1, 0, 0]) + alpha
    expected = slow_kl(cp, cq)
    assert visitation_kl_divergence(p, q, n_states=2, n_actions=2, pseudocount=alpha) == pytest.approx(expected)
    # Without smoothing the divergence is infinite here, reported as inf, not NaN.
    assert visitation_kl_divergence(p, q, n_states=2, n_actions=2, pseudocount=0) == math.inf
    assert visitation_kl_divergence(p, p, n_states=2, n_actions=2) == 0.0
    js = visitation_js_divergence(p, q, n_states=2, n_actions=2)
    assert js == pytest.approx(js_divergence([2, 0, 0, 1], [0, 1, 0, 0]))


def test_visitation_bad_input():
    ok = [([0, 1], [0])]
    with pytest.raises(ValueError, match="at least one trajectory"):
        visitation_counts([], n_states=2, n_actions=2)
    with pytest.raises(ValueError, match="at least one trajectory"):
        visitation_kl_divergence(ok, [], n_states=2, n_actions=2)
    with pytest.raises(ValueError, match="state outside"):
        visitation_counts([([0, 5], [0])], n_states=2, n_actions=2)
    with pytest.raises(ValueError, match="action outside"):
        visitation_counts([([0, 1], [3])], n_states=2, n_actions=2)
    with pytest.raises(ValueError, match="action outside"):
        visitation_counts([([0, 1], [-1])], n_states=2, n_actions=2)
    with pytest.raises(ValueError, match="3 states and 1 actions"):
        visitation_counts([([0, 1, 1], [0])], n_states=2, n_actions=2)
    with pytest.raises(ValueError, match="no state-action pair"):
        visitation_counts([([0], [])], n_states=2, n_actions=2)
    with pytest.raises(TypeError, match="trajectory 0"):
        visitation_counts(["abc"], n_states=2, n_actions=2)
    with pytest.raises(TypeError, match="integer array"):
        visitation_counts([([0.5, 1.0], [0])], n_states=2, n_actions=2)
    with pytest.raises(TypeError, match="sequence of trajectories"):
        visitation_counts(3, n_states=2, n_actions=2)
    with pytest.raises(ValueError, match="n_states must be >= 1"):
        visitation_counts(ok, n_states=0, n_actions=2)
    with pytest.raises(TypeError, match="n_actions must be an integer"):
        visitation_counts(ok, n_states=2, n_actions=2.0)
    with pytest.raises(ValueError, match="pseudocount must be >= 0"):
        visitation_kl_divergence(ok, ok, n_states=2, n_actions=2, pseudocount=-1)


def test_visitation_counts_of_a_demonstrations_set():
    from irl.demonstrations import Demonstrations

    states, actions = [[0, 1, 2], [2, 2]], [[1, 0], [1]]
    demos = Demonstrations.from_sequences(states, actions)
    np.testing.assert_array_equal(
        visitation_counts(demos, n_states=3, n_actions=2),
        visitation_counts(list(zip(states, actions)), n_states=3, n_actions=2),
    )
    assert visitation_kl_divergence(demos, demos, n_states=3, n_actions=2) == 0.0
    with pytest.raises(ValueError, match="state outside"):
        visitation_counts(demos, n_states=2, n_actions=2)
    with pytest.raises(ValueError, match="action outside"):
        visitation_counts(demos, n_states=3, n_actions=1)
