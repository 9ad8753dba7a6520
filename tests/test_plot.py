"""Figures: each function returns its Axes/Figure and draws the expected artists."""

import matplotlib

matplotlib.use("Agg")

import numpy as np  # noqa: E402
import pytest  # noqa: E402
from matplotlib.axes import Axes  # noqa: E402
from matplotlib.container import BarContainer, ErrorbarContainer  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402

import mdft  # noqa: E402
from mdft.plot import plot_choice_shares, plot_context_effects, plot_trajectories  # noqa: E402


@pytest.fixture(scope="module")
def results():
    return mdft.context_effects(n_samples=500, n_trajectories=2, rng=0)


def new_axes():
    return Figure().subplots()


def test_choice_shares_draws_one_bar_per_share_with_error_bars(results):
    res = results["compromise"]
    ax = new_axes()
    out = plot_choice_shares(ax, res)
    assert out is ax
    assert len(ax.patches) == 3 + 2
    bars = [c for c in ax.containers if isinstance(c, BarContainer)]
    assert [len(b) for b in bars] == [3, 2]
    assert sum(isinstance(c, ErrorbarContainer) for c in ax.containers) == 2
    heights = [p.get_height() for p in bars[0]]
    np.testing.assert_allclose(heights, res.ternary)
    np.testing.assert_allclose([p.get_height() for p in bars[1]], res.binary)
    assert "compromise" in ax.get_title()
    assert [t.get_text().split("\n")[0] for t in ax.get_xticklabels()] == ["A", "B", "C"]


def test_choice_shares_rejects_negative_n_se(results):
    with pytest.raises(ValueError, match=r"n_se must be >= 0.0 \(got -1.0\)"):
        plot_choice_shares(new_axes(), results["attraction"], n_se=-1)


def test_trajectories_one_line_per_trial_and_option_plus_threshold():
    P = np.random.default_rng(0).normal(size=(4, 30, 3))
    P[1, 10:] = np.nan  # a trial that decided at step 9
    ax = new_axes()
    assert plot_trajectories(ax, P, labels=["A", "B", "C"], threshold=17.5) is ax
    assert len(ax.lines) == 4 * 3 + 1
    # each trial's preference for each option is drawn once, against the step number, in
    # one colour per option
    curves = ax.lines[:-1]
    colours = {}
    for k in range(4):
        for i in range(3):
            drawn = [ln for ln in curves
                     if np.array_equal(ln.get_ydata(), P[k, :, i], equal_nan=True)]
            assert len(drawn) == 1, (k, i)
            np.testing.assert_array_equal(drawn[0].get_xdata(), np.arange(30))
            colours.setdefault(i, set()).add(drawn[0].get_color())
    assert all(len(c) == 1 for c in colours.values()) and len(set.union(*colours.values())) == 3
    assert list(ax.lines[-1].get_ydata()) == [17.5, 17.5]
    legend = [t.get_text() for t in ax.get_legend().get_texts()]
    assert legend[:3] == ["A", "B", "C"]
    ax2 = plot_trajectories(new_axes(), P)
    assert len(ax2.lines) == 4 * 3


def test_trajectories_from_a_simulation_result():
    model = mdft.MDFTModel([[1, 3], [3, 1]], [0.5, 0.5], phi1=0.022, phi2=0.05, beta=12.0)
    res = mdft.simulate(model, 50, stopping=mdft.FixedTime(20), rng=0, n_trajectories=3)
    ax = plot_trajectories(new_axes(), res.trajectories, labels="AB")
    assert len(ax.lines) == 3 * 2
    thr = mdft.simulate(model, 50, stopping=mdft.Threshold(5.0), rng=0, n_trajectories=2)
    ax = plot_trajectories(new_axes(), thr)  # the result itself: threshold drawn too
    assert len(ax.lines) == 2 * 2 + 1
    assert ax.lines[-1].get_ydata()[0] == 5.0
    with pytest.raises(ValueError, match="trajectories is None"):
        plot_trajectories(new_axes(), mdft.simulate(model, 10, stopping=mdft.FixedTime(5), rng=0))


@pytest.mark.parametrize(
    "traj, kwargs, match",
    [
        (None, {}, "trajectories is None"),
        (np.zeros((5, 3)), {}, r"trajectories must have shape \(n_trials, n_steps \+ 1, n_options\)"),
        (np.zeros((1, 5, 3)), dict(labels=["A", "B"]), "labels must have 3 entries"),
    ],
)
def test_trajectories_rejects_bad_input(traj, kwargs, match):
    with pytest.raises(ValueError, match=match):
        plot_trajectories(new_axes(), traj, **kwargs)


def test_context_effects_figure_has_shares_and_trajectories(results):
    fig = Figure()
    out = plot_context_effects(results, fig=fig)
    assert out is fig
    assert len(fig.axes) == 6
    assert all(isinstance(ax, Axes) for ax in fig.axes)
    top, bottom = fig.axes[:3], fig.axes[3:]
    assert [len(ax.patches) for ax in top] == [5, 5, 5]
    for ax, res in zip(top, results):  # the bars are each scenario's own shares
        np.testing.assert_allclose([p.get_height() for p in ax.patches],
                                   np.concatenate([res.ternary, res.binary]))
    # 2 trials x 3 options + the threshold line
    assert [len(ax.lines) for ax in bottom] == [7, 7, 7]


def test_context_effects_figure_without_trajectories_has_one_row():
    res = mdft.context_effects(stopping=mdft.FixedTime(50), method="analytic")
    fig = plot_context_effects(res, fig=Figure())
    assert len(fig.axes) == 3
    assert all(len(ax.patches) == 5 for ax in fig.axes)


def test_context_effects_figure_defaults_to_a_pyplot_figure(results):
    import matplotlib.pyplot as plt

    fig = plot_context_effects([results["similarity"]])
    try:
        assert isinstance(fig, Figure) and len(fig.axes) == 2
    finally:
        plt.close(fig)


def test_context_effects_figure_rejects_empty_results():
    with pytest.raises(ValueError, match="results must hold at least one EffectResult"):
        plot_context_effects([], fig=Figure())
