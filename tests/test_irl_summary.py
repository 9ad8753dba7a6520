"""irl results print a short text summary that carries their numbers."""

import numpy as np

import irl
from irl.gridworld import GridWorld


def test_planning_and_visitation_summaries():
    world = GridWorld(4, 0, 3, p_slip=0.1)
    mdp = world.nominal_mdp
    hard = irl.value_iteration(mdp)
    lines = hard.summary().splitlines()
    assert lines[0] == (f"value iteration: 16 states x 8 actions, converged after "
                        f"{hard.n_iter} iterations")
    assert lines[1] == (f"values: min {hard.values.min():.4g}, mean {hard.values.mean():.4g}, "
                        f"max {hard.values.max():.4g}")
    soft = irl.soft_value_iteration(mdp, horizon=6)
    assert "horizon 6" in soft.summary() and f"{soft.values[0].max():.4g}" in soft.summary()
    entropy = -np.sum(soft.policy[0] * np.log(soft.policy[0]), axis=1)
    assert f"max {entropy.max():.4g}" in soft.summary().splitlines()[2]
    vis = irl.state_action_visitation(mdp, soft.policy)
    lines = vis.summary().splitlines()
    assert lines[1] == f"expected transitions: {vis.state_action.sum():.4g}"
    best = int(np.argmax(vis.states))
    assert lines[2].startswith(f"most visited states: {best} ({vis.states[best]:.3g})")


def test_metric_summaries():
    scores = irl.hard_constraint_scores([True, True, False, False], [True, False, True, False])
    assert "1 true positive, 1 false positive, 1 false negative, 1 true negative" in (
        scores.summary())
    errors = irl.soft_constraint_errors([0, -50, -50], [0.2, 0.9, 0.9], [0.9, 0.1, 0.85])
    text = errors.summary()
    assert f"false negatives: {errors.n_false_negative} ({errors.false_negatives:.4f}" in text


def test_mesc_summary_lists_the_ranked_constraints_and_says_when_no_data_were_fitted():
    world = irl.GridWorld(4, 0, 15, constrained_states=[5], constrained_actions=["left"])
    res = irl.MESCResult.from_penalties(world.nominal_mdp, world.true_penalties)
    for min_zeta in (0.5, 0.95):
        text = res.summary(min_zeta=min_zeta).splitlines()
        ranked = res.ranked_constraints(min_zeta=min_zeta)
        assert text[1] == "no demonstrations (penalties given)"
        assert [line.split(None, 1)[1].rsplit(None, 2)[0] for line in text[3:]] == \
            [c.name for c in ranked]
        assert f"{len(ranked)} with zeta >= {min_zeta:g}" in text[0]
