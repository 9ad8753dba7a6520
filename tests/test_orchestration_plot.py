"""Orchestration figures: what is drawn is the data given."""

import matplotlib

matplotlib.use("Agg")

import numpy as np  # noqa: E402
import pytest  # noqa: E402
from matplotlib.colors import to_rgba  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402

import orchestration  # noqa: E402
from orchestration.plot import plot_action_probabilities, plot_rollouts  # noqa: E402


@pytest.fixture
def setup(small_world, small_prefs):
    return small_world, small_prefs


def test_rollout_lines_follow_the_trajectories(setup):
    world, prefs = setup
    wa = orchestration.WeightedAverageOrchestrator.from_preferences(prefs, (0.5, 0.5))
    greedy = orchestration.GreedyOrchestrator.from_preferences(prefs)
    runs = {"WA": orchestration.rollout(wa, 7, rng=0), "Greedy": orchestration.rollout(greedy, 3, rng=0)}
    ax = Figure().subplots()
    n_before = len(ax.lines)
    plot_rollouts(ax, world, runs, colors=["red", "blue"], n_shown=5, jitter=0.0)
    lines = ax.lines[n_before:]
    lines = [ln for ln in lines if ln.get_color() in ("red", "blue")]
    assert [ln.get_color() for ln in lines] == ["red"] * 5 + ["blue"] * 3
    states, _ = runs["WA"].trajectory(2)
    np.testing.assert_array_equal(lines[2].get_xdata(), np.array(states) % 4)
    np.testing.assert_array_equal(lines[2].get_ydata(), np.array(states) // 4)
    assert [t.get_text() for t in ax.get_legend().get_texts()] == ["WA", "Greedy"]
    with pytest.raises(ValueError, match=r"colors must give one colour per label \(2\) \(got 1\)"):
        plot_rollouts(Figure().subplots(), world, runs, colors=["red"])
    with pytest.raises(TypeError, match="rollouts must be a non-empty mapping"):
        plot_rollouts(Figure().subplots(), world, [])


def test_bars_are_the_action_probabilities(setup):
    _, prefs = setup
    orchs = {"WA": orchestration.WeightedAverageOrchestrator.from_preferences(prefs, (0.2, 0.8)),
             "MDFT": orchestration.MDFTOrchestrator.from_preferences(prefs, (0.2, 0.8))}
    ax = plot_action_probabilities(Figure().subplots(), orchs, 1, colors=["red", "blue"])
    heights = np.array([p.get_height() for p in ax.patches]).reshape(2, 8)
    np.testing.assert_allclose(heights[0], orchs["WA"].action_probabilities(1))
    np.testing.assert_allclose(heights[1], orchs["MDFT"].action_probabilities(1))
    assert ax.patches[0].get_facecolor() == to_rgba("red")
    with pytest.raises(TypeError, match=r"orchestrators\['x'\] must be an Orchestrator \(got int\)"):
        plot_action_probabilities(Figure().subplots(), {"x": 1}, 0)
