"""Tests of irl.plot: what gets drawn where, and bad input."""

import matplotlib

matplotlib.use("Agg")

import numpy as np
import pytest
from matplotlib.figure import Figure

from irl.gridworld import GridWorld
from irl.plot import (
    plot_action_values,
    plot_colour_values,
    plot_feature_values,
    plot_gridworld,
    plot_trajectories,
)


@pytest.fixture
def world():
    return GridWorld(4, 0, 15, blue=[1, 2], green=[9], constrained_states=[5, 6],
                     constrained_actions=[4], constrained_colours=["green"])


def new_ax():
    return Figure().subplots()


def test_gridworld_heat_map_orientation(world):
    values = np.arange(16, dtype=float)
    ax = plot_gridworld(new_ax(), world, values=values)
    (image,) = ax.images
    data = np.asarray(image.get_array())
    # Row y holds states y * size .. y * size + size - 1, drawn with y upwards.
    np.testing.assert_array_equal(data[1], [4, 5, 6, 7])
    assert image.origin == "lower"
    # Two blue outlines, one green outline, two hatched constraints.
    assert len(ax.patches) == 3 + 2
    texts = [t.get_text() for t in ax.texts]
    assert "S" in texts and "G" in texts


def test_gridworld_without_values_and_options(world):
    ax = plot_gridworld(new_ax(), world, show_colours=False, show_constraints=False)
    assert len(ax.images) == 0 and len(ax.patches) == 0
    ax = plot_gridworld(new_ax(), world, values=np.full(16, np.nan), annotate=True)
    assert len(ax.images) == 1  # all-NaN values draw blank cells without failing
    ax = plot_gridworld(new_ax(), world, values=np.ones(16), annotate=True, vmin=0, vmax=2)
    assert sum(t.get_text() == "1" for t in ax.texts) == 16


def test_gridworld_colorbar_and_label(world):
    fig = Figure()
    ax = fig.subplots()
    plot_gridworld(ax, world, values=np.arange(16.0), colorbar=True, label="zeta")
    assert len(fig.axes) == 2
    assert fig.axes[1].get_ylabel() == "zeta"


def test_trajectories_follow_cell_centres(world):
    ax = plot_trajectories(new_ax(), world, [[0, 5, 10, 15], ([0, 1, 2], [1, 1])])
    assert len(ax.lines) == 2
    x, y = ax.lines[0].get_data()
    np.testing.assert_array_equal(x, [0, 1, 2, 3])
    np.testing.assert_array_equal(y, [0, 1, 2, 3])
    assert ax.lines[0].get_alpha() == 1.0

    class Demo:
        states = np.array([0, 4, 8])

    many = plot_trajectories(new_ax(), world, [Demo()] * 8, label="demos")
    assert many.lines[0].get_alpha() == pytest.approx(0.25)
    assert many.lines[0].get_label() == "demos"
    jittered = plot_trajectories(new_ax(), world, [[0, 5]], jitter=0.1, rng=0)
    again = plot_trajectories(new_ax(), world, [[0, 5]], jitter=0.1, rng=0)
    np.testing.assert_array_equal(jittered.lines[0].get_xdata(), again.lines[0].get_xdata())
    assert not np.array_equal(jittered.lines[0].get_xdata(), [0, 1])
    # one offset per trajectory: the path is shifted, not distorted
    x, y = (np.asarray(v, float) for v in jittered.lines[0].get_data())
    dx, dy = x - [0, 1], y - [0, 1]  # cells 0 -> 5 on a 4 x 4 grid: (0, 0) -> (1, 1)
    assert dx[0] == pytest.approx(dx[1]) and dy[0] == pytest.approx(dy[1])
    assert max(abs(dx[0]), abs(dy[0])) < 0.5  # normal with sd 0.1: beyond 5 sd never happens at rng=0


def test_action_compass_places_each_action_by_its_move():
    values = np.arange(8, dtype=float)
    ax = plot_action_values(new_ax(), values, true=np.array([0, 0, 0, 0, 1, 0, 0, 0], bool))
    grid = np.asarray(ax.images[0].get_array())
    # left (dx=-1, dy=0) -> row 1, col 0; up_right (1, 1) -> row 2, col 2; centre blank.
    assert grid[1, 0] == 0 and grid[2, 2] == 5 and grid[0, 2] == 7
    assert np.ma.is_masked(grid[1, 1]) or np.isnan(grid[1, 1])
    assert len(ax.patches) == 1


def test_colour_values(world):
    ax = plot_colour_values(new_ax(), [0, 1, 2], true=np.array([False, True, True]))
    assert len(ax.patches) == 2
    np.testing.assert_array_equal(np.asarray(ax.images[0].get_array())[0], [0, 1, 2])


def test_feature_values_shares_one_scale(world):
    fig = Figure()
    axes = [fig.add_subplot(1, 3, i + 1) for i in range(3)]
    values = world.true_penalties.copy()
    values[:16] = 10.0
    out = plot_feature_values(axes, world, values, trajectories=[[0, 5, 15]], label="penalty")
    assert len(out) == 3
    clims = [ax.images[0].get_clim() for ax in out]
    assert all(c == clims[0] for c in clims)
    assert len(out[0].lines) == 1
    # The true constrained action and colour are hatched.
    assert len(out[1].patches) == 1 and len(out[2].patches) == 1


def test_bad_input(world):
    ax = new_ax()
    with pytest.raises(TypeError, match="ax must be a matplotlib Axes"):
        plot_gridworld("axes", world)
    with pytest.raises(TypeError, match="world must be a GridWorld"):
        plot_gridworld(ax, "world")
    with pytest.raises(ValueError, match="values must have 16 entries"):
        plot_gridworld(ax, world, values=np.zeros(15))
    with pytest.raises(ValueError, match="infinities"):
        plot_gridworld(ax, world, values=np.full(16, np.inf))
    with pytest.raises(TypeError, match="values must be an array of numbers"):
        plot_gridworld(ax, world, values=["a"] * 16)
    with pytest.raises(ValueError, match="at least one trajectory"):
        plot_trajectories(ax, world, [])
    with pytest.raises(ValueError, match="state outside"):
        plot_trajectories(ax, world, [[0, 16]])
    with pytest.raises(TypeError, match="integer states"):
        plot_trajectories(ax, world, [[0.5, 1.5]])
    with pytest.raises(ValueError, match=r"jitter must be a number >= 0 \(got -1\)"):
        plot_trajectories(ax, world, [[0, 1]], jitter=-1)
    with pytest.raises(ValueError, match="values must have 8 entries"):
        plot_action_values(ax, np.zeros(4))
    with pytest.raises(TypeError, match="true must be a boolean mask"):
        plot_action_values(ax, np.zeros(8), true=np.zeros(8))
    with pytest.raises(ValueError, match=r"true must have shape \(3,\)"):
        plot_colour_values(ax, np.zeros(3), true=np.zeros(2, bool))
    with pytest.raises(ValueError, match="three Axes"):
        plot_feature_values([ax, ax], world, np.zeros(world.n_features))
    with pytest.raises(TypeError, match=r"axes\[2\] must be a matplotlib Axes"):
        plot_feature_values([ax, ax, None], world, np.zeros(world.n_features))
    with pytest.raises(TypeError, match="sequence of three Axes"):
        plot_feature_values(ax, world, np.zeros(world.n_features))
    with pytest.raises(ValueError, match=f"values must have {world.n_features} entries"):
        plot_feature_values([ax, ax, ax], world, np.zeros(3))


def test_trajectories_from_a_demonstrations_set(world):
    from irl.demonstrations import Demonstrations

    demos = Demonstrations.from_sequences([[0, 5, 10], [0, 1]], [[5, 5], [1]])
    ax = plot_trajectories(new_ax(), world, demos)
    assert len(ax.lines) == 2
    np.testing.assert_array_equal(ax.lines[0].get_xdata(), [0, 1, 2])
