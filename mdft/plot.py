"""Figures for MDFT: choice shares and preference trajectories.

Every function draws on a Matplotlib ``Axes`` given first and returns it;
:func:`plot_context_effects` composes a whole figure and returns the
``Figure``. This is the only module of :mod:`mdft` that imports Matplotlib.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Sequence

import numpy as np

from ._typing import ArrayLike
from ._validation import as_scalar

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

    from .effects import ContextEffects, EffectResult
    from .simulation_result import SimulationResult

__all__ = ["plot_choice_shares", "plot_context_effects", "plot_trajectories"]

_TERNARY_COLOR = "tab:blue"
_BINARY_COLOR = "tab:gray"


def plot_choice_shares(ax: Axes, result: EffectResult, *, n_se: float = 2.0,
                       title: bool = True) -> Axes:
    """Bar chart of ternary against binary choice shares for one scenario.

    Parameters
    ----------
    ax : matplotlib.axes.Axes
        Where to draw.
    result : EffectResult
        One result of :func:`mdft.context_effects`.
    n_se : float, default 2.0
        Half-length of the error bars in standard errors.
    title : bool, default True
        Set the axes title to the scenario name and effect size.

    Returns
    -------
    ax : matplotlib.axes.Axes
        One bar per option of the ternary set (``n_options`` patches) and one
        per option of the binary baseline (2 patches), with error bars.

    Examples
    --------
    >>> import matplotlib
    >>> matplotlib.use("Agg")
    >>> from matplotlib.figure import Figure
    >>> import mdft
    >>> res = mdft.context_effects("attraction", n_samples=2000, rng=0)["attraction"]
    >>> ax = plot_choice_shares(Figure().subplots(), res)
    >>> len(ax.patches)
    5
    """
    from .effects import EffectResult

    _check_axes(ax)
    if not isinstance(result, EffectResult):
        raise TypeError(f"result must be an mdft.EffectResult (got {type(result).__name__})")
    n_se = as_scalar("n_se", n_se, low=0.0)
    scenario = result.scenario
    n = scenario.n_options
    x = np.arange(n)
    width = 0.38
    ax.bar(
        x - width / 2, result.ternary, width, yerr=n_se * result.ternary_se, capsize=3,
        color=_TERNARY_COLOR, label=f"with {scenario.labels[_third(scenario)]}",
    )
    xb = np.asarray(scenario.baseline)
    ax.bar(
        xb + width / 2, result.binary, width, yerr=n_se * result.binary_se, capsize=3,
        color=_BINARY_COLOR, label="binary baseline",
    )
    ax.set_xticks(x)
    ax.set_xticklabels(
        [f"{lab}\n({', '.join(f'{v:g}' for v in row)})"
         for lab, row in zip(scenario.labels, scenario.M)]
    )
    ax.set_ylabel("choice share")
    top = max(float(np.max(result.ternary)), float(np.max(result.binary)))
    ax.set_ylim(0, min(1.05, top + 0.2))
    ax.axhline(0.5, color="0.7", lw=0.8, ls=":", zorder=0)
    if title:
        mark = "shown" if result.shown else "not shown"
        ax.set_title(f"{scenario.name}: effect {result.effect_size:+.3f} ({mark})")
    ax.legend(loc="upper right", ncols=2, fontsize="small", frameon=False)
    return ax


def plot_trajectories(ax: Axes, trajectories: ArrayLike | SimulationResult, *,
                      labels: Sequence[str] | None = None, threshold: float | None = None,
                      alpha: float = 0.6) -> Axes:
    """Preference trajectories ``P(t)`` of a few trials over time.

    Parameters
    ----------
    ax : matplotlib.axes.Axes
        Where to draw.
    trajectories : array_like, shape (n_trials, n_steps + 1, n_options), or SimulationResult
        Preferences from ``SimulationResult.trajectories`` (or
        ``EffectResult.trajectories``); steps after a trial decided may be NaN
        and are not drawn. A :class:`mdft.SimulationResult` may be passed
        itself: its trajectories are drawn, with its threshold if it used
        threshold stopping and ``threshold`` is not given.
    labels : sequence of str, optional
        One label per option, used in the legend.
    threshold : float, optional
        Draw the preference threshold ``theta`` as a dashed line.
    alpha : float, default 0.6
        Line opacity.

    Returns
    -------
    ax : matplotlib.axes.Axes
        One line per trial and option (``n_trials * n_options`` lines, one
        colour per option), plus one line for the threshold if given.

    Examples
    --------
    >>> import matplotlib
    >>> matplotlib.use("Agg")
    >>> from matplotlib.figure import Figure
    >>> import numpy as np
    >>> P = np.cumsum(np.random.default_rng(0).normal(size=(2, 50, 3)), axis=1)
    >>> ax = plot_trajectories(Figure().subplots(), P, labels="ABC", threshold=5.0)
    >>> len(ax.lines)
    7
    """
    if hasattr(trajectories, "trajectories") and hasattr(trajectories, "stopping"):
        if threshold is None:
            threshold = getattr(trajectories.stopping, "theta", None)
        trajectories = trajectories.trajectories  # type: ignore[assignment]
    _check_axes(ax)
    if trajectories is None:
        raise ValueError(
            "trajectories is None; run the simulation with n_trajectories >= 1 to record some"
        )
    try:
        P = np.asarray(trajectories, dtype=float)
    except (TypeError, ValueError, OverflowError):
        raise TypeError("trajectories must be an array of real numbers, shape (n_trials, "
                        f"n_steps + 1, n_options) (got {type(trajectories).__name__})") from None
    if P.ndim != 3 or P.shape[2] < 1:
        raise ValueError(
            "trajectories must have shape (n_trials, n_steps + 1, n_options) "
            f"(got shape {P.shape})"
        )
    n_trials, n_times, n_options = P.shape
    alpha = as_scalar("alpha", alpha, low=0.0, high=1.0)
    if threshold is not None:
        threshold = as_scalar("threshold", threshold)
    if labels is None:
        labels = [f"option {i}" for i in range(n_options)]
    if isinstance(labels, (int, float)) or not hasattr(labels, "__iter__"):
        raise TypeError(f"labels must be a sequence of {n_options} strings (got {labels!r})")
    labels = [str(s) for s in labels]
    if len(labels) != n_options:
        raise ValueError(f"labels must have {n_options} entries, one per option (got {len(labels)})")
    colors = [f"C{i % 10}" for i in range(n_options)]
    steps = np.arange(n_times)
    for k in range(n_trials):
        for i in range(n_options):
            ax.plot(
                steps, P[k, :, i], color=colors[i], lw=0.9, alpha=alpha,
                label=labels[i] if k == 0 else None,
            )
    finite = P[np.isfinite(P)]
    low = float(finite.min()) if finite.size else -1.0
    high = float(finite.max()) if finite.size else 1.0
    if threshold is not None:
        ax.axhline(float(threshold), color="k", ls="--", lw=0.8, label=r"threshold $\theta$")
        high = max(high, float(threshold))
    span = high - low if high > low else 1.0
    # head room for a one-row legend above the curves
    ax.set_ylim(low - 0.05 * span, high + 0.3 * span)
    ax.set_xlabel("step t")
    ax.set_ylabel("preference P(t)")
    ax.legend(loc="upper left", ncols=n_options + (threshold is not None), fontsize="small",
              frameon=False)
    return ax


def plot_context_effects(results: ContextEffects | Sequence[EffectResult], *,
                         fig: Figure | None = None, n_se: float = 2.0) -> Figure:
    """The context-effects figure: shares (top row) and trajectories (bottom row).

    Parameters
    ----------
    results : ContextEffects or sequence of EffectResult
        From :func:`mdft.context_effects`; run it with ``n_trajectories >= 1``
        to fill the bottom row.
    fig : matplotlib.figure.Figure, optional
        Figure to draw on; a new ``matplotlib.pyplot`` figure by default.
    n_se : float, default 2.0
        Half-length of the error bars in standard errors.

    Returns
    -------
    fig : matplotlib.figure.Figure
        Two rows of axes, one column per scenario (one row when no scenario
        carries trajectories).

    Examples
    --------
    >>> import matplotlib
    >>> matplotlib.use("Agg")
    >>> from matplotlib.figure import Figure
    >>> import mdft
    >>> res = mdft.context_effects(n_samples=2000, n_trajectories=3, rng=0)
    >>> fig = plot_context_effects(res, fig=Figure())
    >>> len(fig.axes)
    6
    """
    from .effects import EffectResult

    try:
        results = list(results)
    except TypeError:
        raise TypeError("results must be an mdft.ContextEffects or a sequence of EffectResult "
                        f"(got {type(results).__name__})") from None
    if not results:
        raise ValueError("results must hold at least one EffectResult (got none)")
    if not all(isinstance(r, EffectResult) for r in results):
        bad = next(r for r in results if not isinstance(r, EffectResult))
        raise TypeError(f"results must hold EffectResult objects (got {type(bad).__name__})")
    with_traj = any(r.trajectories is not None for r in results)
    n_rows = 2 if with_traj else 1
    if fig is None:
        import matplotlib.pyplot as plt

        fig = plt.figure()
    fig.set_size_inches(4.2 * len(results), 3.6 * n_rows)
    axes = np.atleast_2d(fig.subplots(n_rows, len(results), squeeze=False))
    for j, res in enumerate(results):
        plot_choice_shares(axes[0, j], res, n_se=n_se)
        if with_traj:
            ax = axes[1, j]
            if res.trajectories is None:
                ax.set_axis_off()
                continue
            theta = getattr(res.stopping, "theta", None)
            plot_trajectories(ax, res.trajectories, labels=res.scenario.labels, threshold=theta)
            ax.set_title(f"{res.scenario.name}: preference over time", fontsize="medium")
    fig.tight_layout()
    return fig


def _check_axes(ax) -> None:
    if not (hasattr(ax, "plot") and hasattr(ax, "bar") and hasattr(ax, "set_ylim")):
        raise TypeError(f"ax must be a matplotlib Axes (got {type(ax).__name__})")


def _third(scenario) -> int:
    """Index of the option added to the binary baseline (the first one outside it)."""
    outside = [i for i in range(scenario.n_options) if i not in scenario.baseline]
    return outside[0] if outside else scenario.target
