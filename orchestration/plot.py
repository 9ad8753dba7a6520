"""Figures for orchestrators: trajectories on a gridworld and action distributions.

Every function draws on a Matplotlib ``Axes`` given first and returns it. Matplotlib is
imported only by the drawing functions of :mod:`irl.plot` that these call.
"""

from __future__ import annotations

import numbers

import numpy as np

from irl.plot import plot_gridworld, plot_trajectories

from .orchestrators import Orchestrator

__all__ = ["plot_rollouts", "plot_action_probabilities"]

_DEFAULT_COLOURS = ("tab:red", "tab:blue", "tab:purple", "tab:orange", "tab:brown", "tab:olive",
                    "tab:cyan", "tab:pink")


def _check_axes(ax):
    if not hasattr(ax, "plot") or not hasattr(ax, "bar"):
        raise TypeError(f"ax must be a matplotlib Axes (got {type(ax).__name__})")


def _check_mapping(name, value):
    if not hasattr(value, "items") or len(value) == 0:
        raise TypeError(f"{name} must be a non-empty mapping of labels to items (got {type(value).__name__})")
    return list(value.items())


def plot_rollouts(ax, world, rollouts, *, colors=None, n_shown=20, jitter=0.08, rng=None,
                  values=None, label=None):
    """Draw a gridworld and, on top, trajectories of several orchestrators.

    Parameters
    ----------
    ax : matplotlib.axes.Axes
    world : irl.GridWorld
        The world (coloured cells, start, goal and true constraints are drawn).
    rollouts : mapping of str to irl.Demonstrations
        Trajectories per label, e.g. ``{"WA (0.5, 0.5)": demos, ...}``.
    colors : sequence of colours, optional
        One per label (default: a qualitative palette).
    n_shown : int, default 20
        Trajectories drawn per label (the first ones).
    jitter : float, default 0.08
        Offset (cells) that keeps overlapping trajectories apart.
    rng : None, int or numpy.random.Generator
        Source of the jitter.
    values, label
        An optional heat map of one value per cell and its colour-bar label, as in
        :func:`irl.plot.plot_gridworld`.

    Returns
    -------
    ax : matplotlib.axes.Axes

    Examples
    --------
    >>> import irl, orchestration
    >>> from matplotlib.figure import Figure
    >>> from orchestration.plot import plot_rollouts
    >>> world = irl.GridWorld(3, 0, 8)
    >>> wa = orchestration.WeightedAverageOrchestrator(
    ...     world.nominal_mdp, world.constrained_mdp, weights=(0.5, 0.5))
    >>> ax = plot_rollouts(Figure().subplots(), world, {"WA": orchestration.rollout(wa, 5, rng=0)})
    >>> ax.get_legend().get_texts()[0].get_text()
    'WA'
    """
    _check_axes(ax)
    items = _check_mapping("rollouts", rollouts)
    if isinstance(n_shown, bool) or not isinstance(n_shown, (numbers.Integral, np.integer)) or n_shown < 1:
        raise ValueError(f"n_shown must be an integer >= 1 (got {n_shown!r})")
    colors = list(colors) if colors is not None else list(_DEFAULT_COLOURS)
    if len(colors) < len(items):
        raise ValueError(f"colors must give one colour per label ({len(items)}) (got {len(colors)})")
    gen = np.random.default_rng(rng)
    plot_gridworld(ax, world, values=values, colorbar=values is not None, label=label)
    for (name, demos), colour in zip(items, colors):
        shown = demos.subset(range(min(int(n_shown), len(demos))))
        plot_trajectories(ax, world, shown, color=colour, jitter=jitter, rng=gen, label=str(name),
                          alpha=min(1.0, 3.0 / len(shown)))
    legend = ax.legend(loc="upper left", bbox_to_anchor=(1.02, 1.0), fontsize="small")
    for handle in legend.legend_handles:
        handle.set_alpha(1.0)
    return ax


def plot_action_probabilities(ax, orchestrators, state, *, action_names=None, colors=None):
    """Grouped bars: the action distribution of several orchestrators in one state.

    Parameters
    ----------
    ax : matplotlib.axes.Axes
    orchestrators : mapping of str to Orchestrator
    state : int
        A non-terminal state.
    action_names : sequence of str, optional
        Tick labels (default the action indices).
    colors : sequence of colours, optional

    Returns
    -------
    ax : matplotlib.axes.Axes

    Examples
    --------
    >>> import irl, orchestration
    >>> from matplotlib.figure import Figure
    >>> from orchestration.plot import plot_action_probabilities
    >>> world = irl.GridWorld(3, 0, 8)
    >>> prefs = orchestration.action_preferences(world.nominal_mdp, world.constrained_mdp)
    >>> orchs = {"Greedy": orchestration.GreedyOrchestrator.from_preferences(prefs),
    ...          "WA": orchestration.WeightedAverageOrchestrator.from_preferences(prefs, (0.5, 0.5))}
    >>> ax = plot_action_probabilities(Figure().subplots(), orchs, 0)
    >>> len(ax.patches)  # 2 orchestrators x 8 actions
    16
    """
    _check_axes(ax)
    items = _check_mapping("orchestrators", orchestrators)
    for name, orch in items:
        if not isinstance(orch, Orchestrator):
            raise TypeError(f"orchestrators[{name!r}] must be an Orchestrator (got {type(orch).__name__})")
    n_actions = items[0][1].n_actions
    colors = list(colors) if colors is not None else list(_DEFAULT_COLOURS)
    width = 0.8 / len(items)
    x = np.arange(n_actions)
    for i, ((name, orch), colour) in enumerate(zip(items, colors)):
        ax.bar(x + (i - (len(items) - 1) / 2) * width, orch.action_probabilities(state), width,
               label=str(name), color=colour)
    ax.set_xticks(x)
    ax.set_xticklabels(list(action_names) if action_names is not None else [str(a) for a in x],
                       rotation=45 if action_names is not None else 0, ha="right" if action_names is not None else "center")
    ax.set_ylabel("probability")
    ax.set_title(f"action distribution in state {state}")
    ax.legend(fontsize="small")
    return ax
