"""Figures for gridworlds: cells, true constraints, learned values and trajectories.

Every function draws on a Matplotlib ``Axes`` given first (or, for
:func:`plot_feature_values`, a sequence of three) and returns it. This is the
only module of :mod:`irl` that imports Matplotlib, and only inside functions.

Orientation: cell ``(x, y)`` (state ``y * size + x``) is drawn at ``(x, y)``
with ``y`` growing upwards, so the action "up" points up on the page.
"""

from __future__ import annotations

import numbers
from typing import TYPE_CHECKING, Any, Sequence

import numpy as np

from ._validation import trajectory_list
from .gridworld import ACTION_MOVES, ACTIONS, COLOURS, GridWorld
from ._typing import ArrayLike, SeedLike

if TYPE_CHECKING:
    from matplotlib.axes import Axes

    from .demonstrations import Demonstrations

__all__ = [
    "plot_gridworld",
    "plot_trajectories",
    "plot_action_values",
    "plot_colour_values",
    "plot_feature_values",
]

_CELL_COLOURS = {1: "tab:blue", 2: "tab:green"}
_ARROWS = {"left": "\u2190", "right": "\u2192", "up": "\u2191", "down": "\u2193",
           "up_left": "\u2196", "up_right": "\u2197", "down_left": "\u2199", "down_right": "\u2198"}


def _check_axes(ax, name="ax"):
    if not all(hasattr(ax, m) for m in ("imshow", "plot", "add_patch")):
        raise TypeError(f"{name} must be a matplotlib Axes (got {type(ax).__name__})")


def _check_world(world):
    if not isinstance(world, GridWorld):
        raise TypeError(f"world must be a GridWorld (got {type(world).__name__})")


def _values(name, values, n, unit="cell"):
    try:
        arr = np.array(values, dtype=np.float64).ravel() if values is not None else None
    except (TypeError, ValueError) as exc:
        raise TypeError(f"{name} must be an array of numbers (got {values!r})") from exc
    if arr is None:
        return None
    if arr.size != n:
        raise ValueError(f"{name} must have {n} entries, one per {unit} (got {arr.size})")
    if np.any(np.isinf(arr)):
        raise ValueError(f"{name} must not contain infinities (NaN leaves a cell blank)")
    return arr


def _mask(name, value, n):
    if value is None:
        return None
    arr = np.asarray(value)
    if arr.dtype != bool:
        raise TypeError(f"{name} must be a boolean mask (got dtype {arr.dtype})")
    if arr.shape != (n,):
        raise ValueError(f"{name} must have shape ({n},) (got {arr.shape})")
    return arr


def _limits(values, vmin, vmax):
    finite = values[np.isfinite(values)]
    lo = float(finite.min()) if vmin is None and finite.size else vmin
    hi = float(finite.max()) if vmax is None and finite.size else vmax
    if lo is not None and hi is not None and lo == hi:
        hi = lo + 1.0
    return lo, hi


def plot_gridworld(
    ax: Axes,
    world: GridWorld,
    *,
    values: ArrayLike | None = None,
    cmap: Any = "Reds",
    vmin: float | None = None,
    vmax: float | None = None,
    colorbar: bool = False,
    label: str | None = None,
    show_colours: bool = True,
    show_constraints: bool = True,
    annotate: bool = False,
    fmt: str = "{:.2g}",
) -> Axes:
    """Draw a gridworld: coloured cells, start and goal, true constraints and an optional heat map.

    Parameters
    ----------
    ax : matplotlib.axes.Axes
        Where to draw.
    world : GridWorld
        The world.
    values : array_like, shape (n_states,), optional
        One number per cell drawn as a heat map, e.g. the learned penalty of
        each state feature (``penalties[world.feature_slices["state"]]``) or
        its probability ``zeta``. NaN leaves a cell blank.
    cmap : str or Colormap, optional
        Colour map of the heat map (default ``"Reds"``).
    vmin, vmax : float, optional
        Limits of the colour scale (default: the range of ``values``).
    colorbar : bool, optional
        Add a colour bar for ``values`` (default False).
    label : str, optional
        Label of the colour bar.
    show_colours : bool, optional
        Outline blue and green cells in their colour (default True).
    show_constraints : bool, optional
        Hatch the truly constrained states with black crosses (default True).
    annotate : bool, optional
        Write each value in its cell (default False).
    fmt : str, optional
        Format of the annotations.

    Returns
    -------
    ax : matplotlib.axes.Axes

    Examples
    --------
    >>> from matplotlib.figure import Figure
    >>> from irl.gridworld import GridWorld
    >>> w = GridWorld(4, 0, 3, blue=[5], constrained_states=[6])
    >>> ax = plot_gridworld(Figure().subplots(), w, values=range(16), colorbar=True)
    >>> len(ax.images), [float(x) for x in ax.get_xlim()]
    (1, [-0.5, 3.5])
    """
    _check_axes(ax)
    _check_world(world)
    from matplotlib.patches import Rectangle

    n = world.size
    vals = _values("values", values, world.n_states)
    extent = (-0.5, n - 0.5, -0.5, n - 0.5)
    if vals is not None:
        lo, hi = _limits(vals, vmin, vmax)
        image = ax.imshow(
            vals.reshape(n, n), origin="lower", extent=extent, cmap=cmap, vmin=lo, vmax=hi,
            interpolation="nearest",
        )
        if colorbar:
            cb = ax.figure.colorbar(image, ax=ax, fraction=0.046, pad=0.04)
            if label:
                cb.set_label(label)
        if annotate:
            for s in range(world.n_states):
                if np.isfinite(vals[s]):
                    x, y = world.coords(s)
                    ax.text(x, y, fmt.format(vals[s]), ha="center", va="center", fontsize=7,
                            color=_text_colour(vals[s], lo, hi))
    if show_colours:
        for s, c in enumerate(world.colours):
            if c in _CELL_COLOURS:
                x, y = world.coords(s)
                ax.add_patch(Rectangle((x - 0.42, y - 0.42), 0.84, 0.84, fill=False,
                                       edgecolor=_CELL_COLOURS[int(c)], linewidth=2.5))
    if show_constraints:
        for s in world.constrained_states:
            _hatch_cell(ax, *world.coords(s))
    for s, text in ((world.start, "S"), (world.goal, "G")):
        x, y = world.coords(s)
        ax.text(x, y, text, ha="center", va="center", fontsize=11, fontweight="bold",
                bbox={"boxstyle": "circle,pad=0.2", "facecolor": "white", "edgecolor": "black"})
    ax.set_xticks(np.arange(-0.5, n, 1), minor=True)
    ax.set_yticks(np.arange(-0.5, n, 1), minor=True)
    ax.grid(which="minor", color="0.75", linewidth=0.5)
    ax.tick_params(which="both", length=0)
    ax.set_xticks(range(n))
    ax.set_yticks(range(n))
    ax.set_xlim(extent[:2])
    ax.set_ylim(extent[2:])
    ax.set_aspect("equal")
    return ax


def _states_of(traj, index):
    if hasattr(traj, "states"):
        states = traj.states
    elif isinstance(traj, tuple) and len(traj) == 2:
        states = traj[0]
    else:
        states = traj
    arr = np.asarray(states)
    if arr.ndim == 2 and arr.shape[1] == 2:
        arr = arr[:, 0]
    if arr.ndim != 1 or (arr.size and not np.issubdtype(arr.dtype, np.integer)):
        raise TypeError(
            f"trajectory {index} must be a sequence of integer states, a (states, actions) pair "
            f"or an object with .states (got {type(traj).__name__})"
        )
    return arr


def plot_trajectories(ax: Axes, world: GridWorld, trajectories: Demonstrations | Sequence[Any], *,
                      color: Any = "tab:red", alpha: float | None = None,
                      linewidth: float = 2.0, jitter: float = 0.0, rng: SeedLike = None,
                      label: str | None = None) -> Axes:
    """Overlay trajectories on a gridworld drawn by :func:`plot_gridworld`.

    Parameters
    ----------
    ax : matplotlib.axes.Axes
        Where to draw.
    world : GridWorld
        The world the trajectories live in.
    trajectories : Demonstrations or sequence
        A :class:`~irl.demonstrations.Demonstrations` set, or a sequence of
        trajectories, each an object with ``.states``, a ``(states, actions)``
        pair or a sequence of states.
    color : color, optional
        Line colour (default ``"tab:red"``).
    alpha : float, optional
        Opacity; default ``min(1, 2 / n_trajectories)`` so that frequent
        paths stand out.
    linewidth : float, optional
        Line width.
    jitter : float, optional
        Standard deviation of a random offset (in cells) added to each
        trajectory so that overlapping ones stay apart (default 0).
    rng : None, int or numpy.random.Generator, optional
        Source of the jitter.
    label : str, optional
        Legend label (given to the first line only).

    Returns
    -------
    ax : matplotlib.axes.Axes
        With one line per trajectory.

    Examples
    --------
    >>> from matplotlib.figure import Figure
    >>> from irl.gridworld import GridWorld
    >>> w = GridWorld(3, 0, 8)
    >>> ax = plot_trajectories(Figure().subplots(), w, [[0, 4, 8], [0, 1, 2, 5, 8]], rng=0)
    >>> len(ax.lines)
    2
    """
    _check_axes(ax)
    _check_world(world)
    if isinstance(trajectories, np.ndarray) and trajectories.ndim == 1:
        trajectories = [trajectories]
    items = trajectory_list(trajectories, "trajectories")
    if alpha is None:
        alpha = min(1.0, 2.0 / len(items))
    if isinstance(jitter, bool) or not isinstance(jitter, numbers.Real) or not jitter >= 0:
        raise ValueError(f"jitter must be a number >= 0 (got {jitter!r})")
    gen = np.random.default_rng(rng)
    for i, traj in enumerate(items):
        states = _states_of(traj, i)
        if states.size and (states.min() < 0 or states.max() >= world.n_states):
            raise ValueError(f"trajectory {i} has a state outside [0, {world.n_states})")
        xy = np.column_stack([states % world.size, states // world.size]).astype(float)
        if jitter:
            xy = xy + gen.normal(0.0, jitter, size=2)
        ax.plot(xy[:, 0], xy[:, 1], color=color, alpha=alpha, linewidth=linewidth,
                solid_capstyle="round", label=label if i == 0 else None)
    return ax


def _text_colour(value, lo, hi):
    """Black on light cells, white on dark ones."""
    if not np.isfinite(value) or lo is None or hi is None or hi <= lo:
        return "black"
    return "white" if (value - lo) / (hi - lo) > 0.6 else "black"


def _hatch_cell(ax, x, y):
    """Cross-hatch the unit cell centred on ``(x, y)`` (a true constraint)."""
    from matplotlib.patches import Rectangle

    ax.add_patch(Rectangle((x - 0.5, y - 0.5), 1, 1, fill=False, hatch="xx", edgecolor="0.15", linewidth=0))


def _small_heat(ax, grid, cmap, vmin, vmax):
    lo, hi = _limits(grid[np.isfinite(grid)], vmin, vmax)
    ax.imshow(grid, origin="lower", cmap=cmap, vmin=lo, vmax=hi, interpolation="nearest")
    return lo, hi


def _label_cells(ax, cells, texts, vals, lo, hi, mask):
    """Write ``texts[i]`` (if ``texts`` is given) and hatch where ``mask[i]`` in the cell ``cells[i]``."""
    for i, (x, y) in enumerate(cells):
        if texts is not None:
            ax.text(x, y, texts[i], ha="center", va="center", fontsize=8, color=_text_colour(vals[i], lo, hi))
        if mask is not None and mask[i]:
            _hatch_cell(ax, x, y)


def plot_action_values(ax: Axes, values: ArrayLike, *, true: ArrayLike | None = None,
                       cmap: Any = "Reds", vmin: float | None = None, vmax: float | None = None,
                       annotate: bool = True, fmt: str = "{:.2g}") -> Axes:
    """Draw one value per action as a 3 x 3 compass (each action in the direction it moves).

    Parameters
    ----------
    ax : matplotlib.axes.Axes
        Where to draw.
    values : array_like, shape (8,)
        One number per action (order of :data:`irl.gridworld.ACTIONS`), e.g.
        ``penalties[world.feature_slices["action"]]``.
    true : array_like of bool, shape (8,), optional
        Truly constrained actions, hatched.
    cmap, vmin, vmax : optional
        Colour scale, as in :func:`plot_gridworld`.
    annotate : bool, optional
        Write the arrow and the value in each cell (default True).
    fmt : str, optional
        Format of the values.

    Returns
    -------
    ax : matplotlib.axes.Axes

    Examples
    --------
    >>> from matplotlib.figure import Figure
    >>> ax = plot_action_values(Figure().subplots(), range(8), true=[False] * 4 + [True] * 2 + [False] * 2)
    >>> len(ax.images), len(ax.patches)
    (1, 2)
    """
    _check_axes(ax)
    vals = _values("values", values, len(ACTIONS), "action")
    mask = _mask("true", true, len(ACTIONS))
    cells = [(1 + dx, 1 + dy) for dx, dy in ACTION_MOVES]
    grid = np.full((3, 3), np.nan)
    for a, (x, y) in enumerate(cells):
        grid[y, x] = vals[a]
    lo, hi = _small_heat(ax, grid, cmap, vmin, vmax)
    texts = [f"{_ARROWS[name]}\n{fmt.format(v)}" for name, v in zip(ACTIONS, vals)] if annotate else None
    _label_cells(ax, cells, texts, vals, lo, hi, mask)
    ax.set_xticks([])
    ax.set_yticks([])
    ax.set_title("actions", fontsize=9)
    return ax


def plot_colour_values(ax: Axes, values: ArrayLike, *, true: ArrayLike | None = None,
                       cmap: Any = "Reds", vmin: float | None = None, vmax: float | None = None,
                       annotate: bool = True, fmt: str = "{:.2g}") -> Axes:
    """Draw one value per cell colour (none, blue, green) as a row of three cells.

    Parameters
    ----------
    ax : matplotlib.axes.Axes
        Where to draw.
    values : array_like, shape (3,)
        One number per colour (order of :data:`irl.gridworld.COLOURS`).
    true : array_like of bool, shape (3,), optional
        Truly constrained colours, hatched.
    cmap, vmin, vmax, annotate, fmt : optional
        As in :func:`plot_action_values`.

    Returns
    -------
    ax : matplotlib.axes.Axes

    Examples
    --------
    >>> from matplotlib.figure import Figure
    >>> ax = plot_colour_values(Figure().subplots(), [0.0, 40.0, 55.0])
    >>> [t.get_text() for t in ax.get_xticklabels()]
    ['none', 'blue', 'green']
    """
    _check_axes(ax)
    vals = _values("values", values, len(COLOURS), "colour")
    mask = _mask("true", true, len(COLOURS))
    lo, hi = _small_heat(ax, vals[None, :], cmap, vmin, vmax)
    texts = [fmt.format(v) for v in vals] if annotate else None
    _label_cells(ax, [(c, 0) for c in range(len(COLOURS))], texts, vals, lo, hi, mask)
    ax.set_xticks(range(len(COLOURS)), list(COLOURS))
    for tick, c in zip(ax.get_xticklabels(), ("black", "tab:blue", "tab:green")):
        tick.set_color(c)
    ax.set_yticks([])
    ax.set_title("colours", fontsize=9)
    return ax


def plot_feature_values(axes: Sequence[Axes], world: GridWorld, values: ArrayLike, *,
                        trajectories: Demonstrations | Sequence[Any] | None = None,
                        cmap: Any = "Reds", vmin: float | None = None, vmax: float | None = None,
                        label: str | None = None, show_truth: bool = True,
                        trajectory_color: Any = "tab:blue") -> Sequence[Axes]:
    """Draw a value per feature of a gridworld on three axes: states, actions and colours.

    Parameters
    ----------
    axes : sequence of three matplotlib.axes.Axes
        Where to draw the states (a large one), the actions and the colours.
    world : GridWorld
        The world whose features ``values`` describes.
    values : array_like, shape (n_features,)
        One number per feature, e.g. learned penalties ``omega`` or the
        constraint probabilities ``zeta``. One colour scale is shared by all
        three panels.
    trajectories : sequence, optional
        Overlaid on the state panel (see :func:`plot_trajectories`).
    cmap, vmin, vmax : optional
        Colour scale.
    label : str, optional
        Label of the colour bar (drawn next to the state panel).
    show_truth : bool, optional
        Hatch the true constraints in every panel (default True).
    trajectory_color : color, optional
        Colour of the trajectories.

    Returns
    -------
    axes : tuple of three matplotlib.axes.Axes

    Examples
    --------
    >>> import numpy as np
    >>> from matplotlib.figure import Figure
    >>> from irl.gridworld import GridWorld
    >>> w = GridWorld(3, 0, 8, constrained_actions=[5])
    >>> fig = Figure()
    >>> axes = [fig.add_subplot(1, 3, i + 1) for i in range(3)]
    >>> out = plot_feature_values(axes, w, np.arange(w.n_features, dtype=float), label="penalty")
    >>> len(out)
    3
    """
    try:
        axs = tuple(axes)
    except TypeError:
        raise TypeError(f"axes must be a sequence of three Axes (got {type(axes).__name__})") from None
    if len(axs) != 3:
        raise ValueError(f"axes must hold three Axes: states, actions, colours (got {len(axs)})")
    for i, ax in enumerate(axs):
        _check_axes(ax, f"axes[{i}]")
    _check_world(world)
    vals = _values("values", values, world.n_features, "feature")
    lo, hi = _limits(vals, vmin, vmax)
    sl = world.feature_slices
    truth = world.constraint_mask
    plot_gridworld(axs[0], world, values=vals[sl["state"]], cmap=cmap, vmin=lo, vmax=hi,
                   colorbar=True, label=label, show_constraints=show_truth)
    if trajectories is not None:
        plot_trajectories(axs[0], world, trajectories, color=trajectory_color)
    plot_action_values(axs[1], vals[sl["action"]], true=truth[sl["action"]] if show_truth else None,
                       cmap=cmap, vmin=lo, vmax=hi)
    plot_colour_values(axs[2], vals[sl["colour"]], true=truth[sl["colour"]] if show_truth else None,
                       cmap=cmap, vmin=lo, vmax=hi)
    return axs
