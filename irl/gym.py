"""Turn a Gymnasium toy-text environment with a transition table into a tabular MDP.

FrozenLake, CliffWalking and Taxi (and any environment built the same way)
expose their dynamics as ``env.unwrapped.P``: ``P[s][a]`` is a list of
``(probability, next_state, reward, terminated)`` tuples. This module reads that
table into the padded sparse arrays of :class:`irl.mdp.MDP`.

Gymnasium is an optional dependency (``pip install "pymdft[gym]"``); it is
imported only by :func:`make_env`. :func:`from_gymnasium` itself works on any
object with a ``P`` table, so a hand-made environment needs no Gymnasium.
"""

from __future__ import annotations

import numbers
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.sparse as sp

from .mdp import MDP, TransitionFeatures
from ._typing import ArrayLike

__all__ = ["TransitionTable", "transition_table", "from_gymnasium", "make_env"]

_PROB_TOL = 1e-8


def _import_gymnasium():
    try:
        import gymnasium
    except ImportError as exc:  # pragma: no cover - exercised only without gymnasium
        raise ImportError(
            "the Gymnasium adapter needs the optional dependency gymnasium; "
            'install it with: pip install "pymdft[gym]"'
        ) from exc
    return gymnasium


def make_env(env_id: str, **kwargs: Any) -> Any:
    """Create a Gymnasium environment by id (a thin wrapper that explains a missing install).

    Parameters
    ----------
    env_id : str
        A registered id such as ``"FrozenLake-v1"`` or ``"CliffWalking-v1"``.
    **kwargs
        Passed to ``gymnasium.make`` (for example ``is_slippery=False``).

    Returns
    -------
    gymnasium.Env

    Raises
    ------
    ImportError
        If gymnasium is not installed, with the command that installs it.

    Examples
    --------
    >>> import importlib.util
    >>> if importlib.util.find_spec("gymnasium") is not None:  # the optional extra
    ...     mdp = from_gymnasium(make_env("FrozenLake-v1", is_slippery=False))
    ...     assert (mdp.n_states, mdp.n_actions) == (16, 4)
    """
    gymnasium = _import_gymnasium()
    return gymnasium.make(env_id, **kwargs)


@dataclass(frozen=True)
class TransitionTable:
    """A Gymnasium ``P`` table as padded sparse arrays.

    Attributes
    ----------
    next_states : ndarray of int64, shape (n_states, n_actions, max_successors)
        Distinct successors of each state-action pair; padding repeats the
        first successor with probability 0.
    probs : ndarray of float64, shape (n_states, n_actions, max_successors)
        Their probabilities (each ``probs[s, a]`` sums to 1).
    rewards : ndarray of float64, shape (n_states, n_actions, max_successors)
        Reward of each transition ``(s, a, s')``; where the table listed the
        same successor several times, the probability-weighted mean of their
        rewards (which keeps the expected reward of ``(s, a)`` unchanged).
    terminal : ndarray of bool, shape (n_states,)
        States entered by a transition flagged ``terminated``. Their rows are
        replaced by an absorbing self-loop with reward 0.
    start_distribution : ndarray of float64, shape (n_states,)
        The environment's initial state distribution.

    Examples
    --------
    >>> class Coin:
    ...     P = {0: {0: [(0.5, 0, 0.0, False), (0.5, 1, 1.0, True)]}, 1: {0: [(1.0, 1, 0.0, True)]}}
    ...     initial_state_distrib = [1.0, 0.0]
    >>> t = transition_table(Coin())
    >>> t.n_states, t.n_actions, t.probs[0, 0].tolist(), t.terminal.tolist()
    (2, 1, [0.5, 0.5], [False, True])
    """

    next_states: np.ndarray
    probs: np.ndarray
    rewards: np.ndarray
    terminal: np.ndarray
    start_distribution: np.ndarray

    @property
    def n_states(self) -> int:
        """Number of states."""
        return int(self.next_states.shape[0])

    @property
    def n_actions(self) -> int:
        """Number of actions."""
        return int(self.next_states.shape[1])


def _space_n(space, name: str):
    n = getattr(space, "n", None)
    if n is None:
        return None
    if isinstance(n, (numbers.Integral, np.integer)) and int(n) >= 1:
        return int(n)
    raise ValueError(f"env.{name}.n must be a positive integer (got {n!r})")


def _find_table(env):
    base = getattr(env, "unwrapped", env)
    table = getattr(base, "P", None)
    if table is None and base is not env:
        table = getattr(env, "P", None)
    if table is None:
        raise TypeError(
            f"env must expose a transition table P (P[s][a] = list of (prob, next_state, reward, "
            f"terminated)), as Gymnasium's toy-text environments do; got {type(env).__name__} "
            "without one"
        )
    return base, table


def transition_table(env: Any, *, start_distribution: ArrayLike | None = None) -> TransitionTable:
    """Read the transition table ``P`` of a toy-text environment into padded arrays.

    Parameters
    ----------
    env : object
        A Gymnasium environment (wrappers are looked through via
        ``env.unwrapped``) or any object with a table ``P``: a mapping or
        sequence indexed by state, then by action, of lists of
        ``(probability, next_state, reward, terminated)``.
    start_distribution : array_like, shape (n_states,), optional
        Start-state distribution. By default the environment's
        ``initial_state_distrib`` (or ``isd``); required where it has neither.

    Returns
    -------
    TransitionTable

    Raises
    ------
    TypeError
        If ``env`` has no ``P`` table or an entry is not a 4-tuple.
    ValueError
        If a state or action is missing, a successor is out of range, a
        probability is negative or a row does not sum to 1.

    Notes
    -----
    * Duplicate successors of one ``(s, a)`` are merged: probabilities add,
      rewards are averaged with the probabilities as weights.
    * A state is terminal if some transition entering it is flagged
      ``terminated``. Gymnasium ends the episode there, so the MDP makes it
      absorbing: every action loops on it with probability 1 and reward 0.
      Its own row in ``P`` (often a self-loop already) is ignored.
    * The numbers of states and actions come from ``observation_space.n`` and
      ``action_space.n`` where present, else from the table.

    Examples
    --------
    >>> class Chain:
    ...     P = {0: {0: [(1.0, 1, -1.0, False)], 1: [(0.5, 0, 0.0, False), (0.5, 0, 2.0, False)]},
    ...          1: {0: [(1.0, 1, 0.0, True)], 1: [(1.0, 1, 0.0, True)]}}
    ...     initial_state_distrib = [1.0, 0.0]
    >>> t = transition_table(Chain())
    >>> t.next_states[0, 1], t.probs[0, 1], t.rewards[0, 1], t.terminal
    (array([0]), array([1.]), array([1.]), array([False,  True]))
    """
    base, table = _find_table(env)
    n_states = _space_n(getattr(base, "observation_space", None), "observation_space")
    n_actions = _space_n(getattr(base, "action_space", None), "action_space")
    try:
        n_listed = len(table)
    except TypeError as exc:
        raise TypeError(f"env.P must be indexable by state (got {type(table).__name__})") from exc
    if n_states is None:
        n_states = n_listed
    if n_states < 1:
        raise ValueError("env.P must list at least one state (got an empty table)")

    def row(s):
        try:
            return table[s]
        except (KeyError, IndexError):
            raise ValueError(f"env.P has no entry for state {s} (the environment has {n_states} states)") from None

    if n_actions is None:
        n_actions = len(row(0))
        if n_actions < 1:
            raise ValueError("env.P[0] lists no action; cannot infer the number of actions")

    merged: list[list[dict]] = []
    terminal = np.zeros(n_states, dtype=bool)
    for s in range(n_states):
        actions = row(s)
        per_action = []
        for a in range(n_actions):
            try:
                outcomes = actions[a]
            except (KeyError, IndexError):
                raise ValueError(f"env.P[{s}] has no entry for action {a} (the environment has {n_actions} actions)") from None
            succ: dict[int, list[float]] = {}
            total = 0.0
            for entry in outcomes:
                if not isinstance(entry, (tuple, list)) or len(entry) != 4:
                    raise TypeError(
                        f"env.P[{s}][{a}] entries must be (prob, next_state, reward, terminated) "
                        f"tuples (got {entry!r})"
                    )
                p, s2, r, done = entry
                p, r = float(p), float(r)
                if not np.isfinite(p) or p < 0:
                    raise ValueError(f"env.P[{s}][{a}] has an invalid probability {p}; probabilities must be >= 0")
                if not np.isfinite(r):
                    raise ValueError(f"env.P[{s}][{a}] has a non-finite reward {r}")
                if isinstance(s2, bool) or not isinstance(s2, (numbers.Integral, np.integer)):
                    raise TypeError(f"env.P[{s}][{a}] has a next state {s2!r} that is not an integer")
                s2 = int(s2)
                if not 0 <= s2 < n_states:
                    raise ValueError(f"env.P[{s}][{a}] has next state {s2} outside [0, {n_states})")
                total += p
                if p == 0:
                    continue
                acc = succ.setdefault(s2, [0.0, 0.0])
                acc[0] += p
                acc[1] += p * r
                if done:
                    terminal[s2] = True
            if abs(total - 1.0) > _PROB_TOL:
                raise ValueError(
                    f"the probabilities of env.P[{s}][{a}] sum to {total:.12g}; they must sum to 1"
                )
            per_action.append(succ)
        merged.append(per_action)

    width = max(1, max(len(succ) for per_action in merged for succ in per_action))
    next_states = np.zeros((n_states, n_actions, width), dtype=np.int64)
    probs = np.zeros((n_states, n_actions, width), dtype=np.float64)
    rewards = np.zeros((n_states, n_actions, width), dtype=np.float64)
    for s in range(n_states):
        for a in range(n_actions):
            if terminal[s]:
                next_states[s, a, :] = s
                probs[s, a, 0] = 1.0
                continue
            items = sorted(merged[s][a].items())
            for k, (s2, (p, pr)) in enumerate(items):
                next_states[s, a, k] = s2
                probs[s, a, k] = p
                rewards[s, a, k] = pr / p
            next_states[s, a, len(items):] = items[0][0]
            probs[s, a] /= probs[s, a].sum()

    if start_distribution is None:
        start_distribution = getattr(base, "initial_state_distrib", None)
        if start_distribution is None:
            start_distribution = getattr(base, "isd", None)
        if start_distribution is None:
            raise ValueError(
                "env has no initial_state_distrib (or isd); pass start_distribution, "
                f"an array of {n_states} probabilities"
            )
        name = "the environment's initial state distribution"
    else:
        name = "start_distribution"
    try:
        start = np.array(start_distribution, dtype=np.float64).ravel()
    except (TypeError, ValueError, OverflowError) as exc:
        text = repr(start_distribution)
        text = text if len(text) <= 80 else text[:77] + "..."
        raise TypeError(f"{name} must be an array of probabilities (got {text})") from exc
    if start.shape != (n_states,):
        raise ValueError(f"{name} must have {n_states} entries (got {start.size})")
    if not np.all(np.isfinite(start)) or np.any(start < 0) or abs(start.sum() - 1.0) > 1e-6:
        raise ValueError(f"{name} must be non-negative and sum to 1 (got sum {start.sum():.6g})")
    start = start / start.sum()
    return TransitionTable(next_states, probs, rewards, terminal, start)


def _default_features(n_states: int, n_actions: int) -> TransitionFeatures:
    n_f = n_states + n_actions
    destination = sp.csr_array(
        (np.ones(n_states), (np.arange(n_states), np.arange(n_states))), shape=(n_states, n_f)
    )
    action = sp.csr_array(
        (np.ones(n_actions), (np.arange(n_actions), n_states + np.arange(n_actions))), shape=(n_actions, n_f)
    )
    names = [f"state {s}" for s in range(n_states)] + [f"action {a}" for a in range(n_actions)]
    return TransitionFeatures(action=action, destination=destination, names=tuple(names))


def from_gymnasium(env: Any, *, discount: float = 1.0,
                   features: str | TransitionFeatures | None = "default",
                   start_distribution: ArrayLike | None = None) -> MDP:
    """Build an :class:`~irl.mdp.MDP` from a toy-text environment's transition table.

    Parameters
    ----------
    env : object
        A Gymnasium environment with ``env.unwrapped.P`` (FrozenLake,
        CliffWalking, Taxi, ...) or any object with a ``P`` table; see
        :func:`transition_table` for the format.
    discount : float, optional
        Discount factor in (0, 1] (default 1: Gymnasium itself has none).
    features : {"default"}, TransitionFeatures or None, optional
        Transition features for constraint learning. ``"default"`` gives the
        gridworld's kind of features: a one-hot of the destination state
        (features ``0 .. n_states - 1``) followed by a one-hot of the action.
    start_distribution : array_like, shape (n_states,), optional
        Overrides the environment's initial state distribution.

    Returns
    -------
    MDP
        Transitions, per-transition rewards, absorbing terminal states and the
        start distribution of the environment.

    Raises
    ------
    TypeError, ValueError
        As :func:`transition_table`; ``ValueError`` also where no terminal
        state can be reached from a start state (see :class:`~irl.mdp.MDP`).

    Notes
    -----
    Only the table is read: the environment is never reset or stepped, and its
    random state is not touched. Gymnasium's episode truncation (a time
    limit) is not part of the MDP.

    Examples
    --------
    >>> class Corridor:  # three cells, walk right to the goal
    ...     P = {s: {0: [(1.0, max(s - 1, 0), -1.0, False)],
    ...              1: [(1.0, s + 1, -1.0, s + 1 == 2)]} for s in range(2)}
    ...     P[2] = {0: [(1.0, 2, 0.0, True)], 1: [(1.0, 2, 0.0, True)]}
    ...     initial_state_distrib = [1.0, 0.0, 0.0]
    >>> mdp = from_gymnasium(Corridor())
    >>> mdp.n_states, mdp.n_actions, mdp.terminal.tolist(), mdp.n_features
    (3, 2, [False, False, True], 5)
    """
    table = transition_table(env, start_distribution=start_distribution)
    if isinstance(features, str):
        if features != "default":
            raise ValueError(f'features must be "default", a TransitionFeatures or None (got {features!r})')
        features = _default_features(table.n_states, table.n_actions)
    elif features is not None and not isinstance(features, TransitionFeatures):
        raise TypeError(
            f'features must be "default", a TransitionFeatures or None (got {type(features).__name__})'
        )
    return MDP(
        table.next_states,
        table.probs,
        table.rewards,
        terminal=table.terminal,
        start=table.start_distribution,
        discount=discount,
        features=features,
    )
