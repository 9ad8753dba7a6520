"""Figures of the experiments. Each function draws on the Matplotlib Axes it is given and returns it.

The experiment modules build their figures from these; nothing here computes results.
"""

from __future__ import annotations

import numpy as np

__all__ = ["new_figure", "plot_curves", "plot_histograms", "plot_scatter", "plot_weight_sweep"]


def new_figure(n_panels: int, *, width=4.0, height=3.2, ncols=None):
    """A Matplotlib Figure (no pyplot state) with ``n_panels`` Axes in a grid.

    Examples
    --------
    >>> fig, axes = new_figure(4, ncols=2)
    >>> len(axes)
    4
    """
    from matplotlib.figure import Figure

    ncols = ncols or n_panels
    nrows = -(-n_panels // ncols)
    fig = Figure(figsize=(width * ncols, height * nrows), layout="constrained")
    axes = fig.subplots(nrows, ncols, squeeze=False).ravel()
    for ax in axes[n_panels:]:
        ax.set_visible(False)
    return fig, list(axes[:n_panels])


def plot_curves(ax, x, curves, *, xlabel="", ylabel="", title="", logx=False, markers=True,
                legend=True):
    """Lines with standard-error bands: one per entry of ``curves``.

    Parameters
    ----------
    ax : matplotlib.axes.Axes
    x : array_like, shape (n,)
    curves : dict
        ``label -> (means, standard_errors)``, each of shape (n,); NaN
        standard errors draw no band.

    Returns
    -------
    matplotlib.axes.Axes

    Examples
    --------
    >>> fig, (ax,) = new_figure(1)
    >>> ax = plot_curves(ax, [1, 2], {"a": ([0.1, 0.2], [0.01, 0.02])})
    >>> len(ax.lines)
    1
    """
    x = np.asarray(x, dtype=float)
    for label, (mean, se) in curves.items():
        mean = np.asarray(mean, dtype=float)
        se = np.nan_to_num(np.asarray(se, dtype=float), nan=0.0)
        (line,) = ax.plot(x, mean, marker="o" if markers else None, markersize=3, label=label)
        if np.any(se > 0):
            ax.fill_between(x, mean - se, mean + se, color=line.get_color(), alpha=0.2, linewidth=0)
    if logx:
        from matplotlib.ticker import NullLocator, ScalarFormatter

        ax.set_xscale("log")
        ax.set_xticks(x)
        ax.xaxis.set_major_formatter(ScalarFormatter())
        ax.xaxis.set_minor_locator(NullLocator())
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    if title:
        ax.set_title(title)
    ax.grid(alpha=0.3)
    if legend and len(curves) > 1:
        ax.legend(fontsize="x-small")
    return ax


def plot_weight_sweep(ax, w_c, curves, *, baselines=None, ylabel="", title=""):
    """A metric against the constraint weight w_c, with horizontal lines for fixed policies.

    Parameters
    ----------
    ax : matplotlib.axes.Axes
    w_c : array_like, shape (n,)
        Weight of the constrained policy (w_n = 1 - w_c).
    curves : dict
        ``label -> (means, standard_errors)`` over the weights (WA, MDFT).
    baselines : dict, optional
        ``label -> value`` drawn as dashed horizontal lines (Nominal,
        Constrained, Greedy).

    Returns
    -------
    matplotlib.axes.Axes

    Examples
    --------
    >>> fig, (ax,) = new_figure(1)
    >>> ax = plot_weight_sweep(ax, [0, 1], {"WA": ([1, 2], [0, 0])}, baselines={"Greedy": 1.5})
    >>> len(ax.lines)
    2
    """
    plot_curves(ax, w_c, curves, xlabel="weight of the constraints $w_c$", ylabel=ylabel,
                title=title)
    styles = iter(["--", ":", "-."] * 3)
    for label, value in (baselines or {}).items():
        if value is not None and np.isfinite(value):
            ax.axhline(value, color="grey", linestyle=next(styles), linewidth=1, label=label)
    ax.legend(fontsize="small")
    return ax


def plot_histograms(ax, samples, *, xlabel="", bins=20):
    """Overlaid histograms, one per entry of ``samples`` (``label -> values``), on shared bins.

    Examples
    --------
    >>> fig, (ax,) = new_figure(1)
    >>> ax = plot_histograms(ax, {"a": [0.1, 0.2, 0.2], "b": [0.3]})
    >>> len(ax.patches) > 0
    True
    """
    values = [np.asarray(v, dtype=float) for v in samples.values()]
    edges = np.histogram_bin_edges(np.concatenate(values), bins=bins)
    for label, v in zip(samples, values):
        ax.hist(v, bins=edges, alpha=0.5, label=label)
    ax.set_xlabel(xlabel)
    ax.set_ylabel("count")
    ax.legend(fontsize="x-small")
    return ax


def plot_scatter(ax, x, y, *, xlabel="", ylabel="", diagonal=False):
    """A scatter plot of ``y`` against ``x``, with the line y = x if ``diagonal``.

    Examples
    --------
    >>> fig, (ax,) = new_figure(1)
    >>> ax = plot_scatter(ax, [0, 1], [0, 1], diagonal=True)
    >>> len(ax.lines)
    1
    """
    ax.scatter(x, y, s=10)
    if diagonal:
        ax.plot([0, 1], [0, 1], color="grey", linewidth=1, linestyle="--")
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.grid(alpha=0.3)
    return ax
