"""Checks of trajectory input shared by the public functions of :mod:`irl` that take trajectories.

A set of trajectories is a :class:`~irl.demonstrations.Demonstrations` or any
object stored flat like it, or a sequence of trajectories. One trajectory is an
object with ``.states`` and ``.actions``, a ``(states, actions)`` pair and,
where the caller accepts them, a dict with ``state_seq`` and ``action_seq``
(the paper's JSON files) or an ``(n, 2)`` array of ``(state, action)`` rows.
Each caller names the things it checks in its own words (``noun``) and keeps
its own rule on the number of states per action.
"""

from __future__ import annotations

import numpy as np


def is_flat_set(obj) -> bool:
    """A set of trajectories stored flat, like :class:`irl.demonstrations.Demonstrations`."""
    return all(hasattr(obj, k) for k in ("offsets", "trajectory", "__len__"))


def trajectory_list(value, name) -> list:
    """The trajectories of ``value`` (a flat set is split into ``(states, actions)`` pairs) as a list.

    Raises TypeError if ``value`` is not iterable and ValueError if it is empty.
    """
    if is_flat_set(value):
        value = [value.trajectory(i) for i in range(len(value))]
    try:
        items = list(value)
    except TypeError as exc:
        raise TypeError(f"{name} must be a sequence of trajectories (got {type(value).__name__})") from exc
    if not items:
        raise ValueError(f"{name} must hold at least one trajectory (got an empty set)")
    return items


def split_trajectory(traj, index, *, noun, rows=False, dicts=False):
    """``(states, actions)`` of one trajectory as 1-d integer arrays.

    Parameters
    ----------
    traj : object
        The trajectory.
    index : int
        Its position in the set (for the messages).
    noun : str
        What the caller calls it in its messages ("trajectory", "demonstration").
    rows : bool
        Accept an ``(n, 2)`` array of ``(state, action)`` rows. A pair must
        then be a tuple: a two-element list is read as two rows.
    dicts : bool
        Accept a dict with ``state_seq`` and ``action_seq``.
    """
    states = actions = None
    if hasattr(traj, "states") and hasattr(traj, "actions"):
        states, actions = traj.states, traj.actions
    elif dicts and isinstance(traj, dict) and "state_seq" in traj:
        states, actions = traj["state_seq"], traj["action_seq"]
    elif isinstance(traj, tuple if rows else (tuple, list)) and len(traj) == 2:
        states, actions = traj
    elif rows:
        arr = np.asarray(traj)
        if arr.ndim == 2 and arr.shape[1] == 2:
            states, actions = arr[:, 0], arr[:, 1]
    if states is None:
        forms = ["a (states, actions) pair"]
        if rows:
            forms.append("an (n, 2) array of state-action pairs")
        if dicts:
            forms.append("a dict with state_seq and action_seq")
        raise TypeError(
            f"{noun} {index} must be {', '.join(forms)} or an object with .states and .actions "
            f"(got {type(traj).__name__})"
        )
    s = np.asarray(states)
    a = np.asarray(actions)
    for name, arr in (("states", s), ("actions", a)):
        if arr.ndim != 1 or (arr.size and not np.issubdtype(arr.dtype, np.integer)):
            raise TypeError(f"{noun} {index}: {name} must be a 1-d integer array (got {arr.dtype}, shape {arr.shape})")
    return s, a


def check_indices(states, actions, index, *, noun, n_states, n_actions):
    """Raise ValueError if a state is outside ``[0, n_states)`` or an action outside ``[0, n_actions)``."""
    for what, arr, high in (("a state", states, n_states), ("an action", actions, n_actions)):
        if arr.size and (arr.min() < 0 or arr.max() >= high):
            bad = int(arr.min() if arr.min() < 0 else arr.max())
            raise ValueError(f"{noun} {index} has {what} outside [0, {high}) (got {bad})")
