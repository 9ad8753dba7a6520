"""Action preferences: the Q-values of a nominal and a constrained MDP and their softmax.

For every state ``s`` the orchestrators deliberate over the vectors

    sq_n(s, a) = softmax_a(q_n(s, a) / temperature),   sq_c(s, a) = softmax_a(q_c(s, a) / temperature)

taken over the feasible actions of ``s`` (the paper's Section 4, with temperature 1). The
Q-values come from value iteration (:func:`irl.value_iteration`) on each MDP.
"""

from __future__ import annotations

import numbers
from dataclasses import dataclass

import numpy as np

import irl

__all__ = ["ActionPreferences", "action_preferences"]


def _readonly(a: np.ndarray) -> np.ndarray:
    a = np.array(a, copy=True)
    a.flags.writeable = False
    return a


def _as_temperature(temperature) -> float:
    if isinstance(temperature, bool) or not isinstance(temperature, (numbers.Real, np.floating)):
        raise TypeError(f"temperature must be a real number (got {temperature!r})")
    t = float(temperature)
    if not np.isfinite(t) or t <= 0:
        raise ValueError(f"temperature must be finite and > 0 (got {t})")
    return t


def _check_feasible(feasible, shape) -> np.ndarray:
    """``feasible`` as a boolean mask of ``shape`` allowing an action in every state, or raise."""
    mask = np.asarray(feasible)
    if mask.dtype != bool:
        raise TypeError(f"feasible must be a boolean mask (got dtype {mask.dtype})")
    if mask.shape != shape:
        raise ValueError(f"feasible must have shape {shape} (got {mask.shape})")
    if not mask.any(axis=1).all():
        s = int(np.flatnonzero(~mask.any(axis=1))[0])
        raise ValueError(f"feasible must allow at least one action in every state (state {s} has none)")
    return mask


def masked_softmax(q: np.ndarray, feasible: np.ndarray, temperature: float) -> np.ndarray:
    """Row-wise softmax of ``q / temperature`` over the ``feasible`` entries (zero elsewhere)."""
    z = np.where(feasible, q / temperature, -np.inf)
    z = z - z.max(axis=-1, keepdims=True)
    e = np.where(feasible, np.exp(z), 0.0)
    return e / e.sum(axis=-1, keepdims=True)


@dataclass(frozen=True, eq=False)
class ActionPreferences:
    """Q-values of a nominal and a constrained MDP and their softmax over feasible actions.

    Attributes
    ----------
    q_nominal, q_constrained : ndarray, shape (n_states, n_actions)
        Optimal Q-values ``q_n(s, a)`` and ``q_c(s, a)`` (zero at terminal states).
    sq_nominal, sq_constrained : ndarray, shape (n_states, n_actions)
        ``softmax(q / temperature)`` over the feasible actions of each state; zero on
        infeasible actions, every row sums to one.
    feasible : ndarray of bool, shape (n_states, n_actions)
        The actions the orchestrators may choose in each state (at least one per state).
    temperature : float
        Softmax temperature (1 in the paper).
    terminal : ndarray of bool, shape (n_states,)
        Terminal states of the MDPs: no decision is taken there (default: none, or the
        terminal states of ``nominal``).
    nominal : irl.MDP or None
        The nominal MDP, whose transitions are the world's dynamics in
        :func:`orchestration.rollout`.

    Examples
    --------
    >>> import irl, orchestration
    >>> world = irl.GridWorld(3, 0, 8, p_slip=0.0, constrained_states=(4,))
    >>> prefs = orchestration.action_preferences(world.nominal_mdp, world.constrained_mdp)
    >>> prefs
    ActionPreferences(n_states=9, n_actions=8, temperature=1, n_terminal=1, nominal=MDP)
    >>> bool(abs(prefs.sq_constrained.sum(axis=1) - 1).max() < 1e-12)
    True
    """

    q_nominal: np.ndarray
    q_constrained: np.ndarray
    sq_nominal: np.ndarray
    sq_constrained: np.ndarray
    feasible: np.ndarray
    temperature: float = 1.0
    terminal: np.ndarray | None = None
    nominal: object = None

    def __post_init__(self):
        for key in ("q_nominal", "q_constrained", "sq_nominal", "sq_constrained"):
            arr = np.asarray(getattr(self, key), dtype=np.float64)
            if arr.ndim != 2:
                raise ValueError(f"{key} must be a 2-d array (n_states, n_actions) (got shape {arr.shape})")
            if not np.all(np.isfinite(arr)):
                raise ValueError(f"{key} must contain only finite values (got NaN or infinity)")
            object.__setattr__(self, key, _readonly(arr))
        shape = self.q_nominal.shape
        for key in ("q_constrained", "sq_nominal", "sq_constrained"):
            if getattr(self, key).shape != shape:
                raise ValueError(f"{key} must have the shape of q_nominal {shape} (got {getattr(self, key).shape})")
        feasible = _check_feasible(self.feasible, shape)
        if self.nominal is not None:
            if not isinstance(self.nominal, irl.MDP):
                raise TypeError(f"nominal must be an irl.MDP or None (got {type(self.nominal).__name__})")
            if (self.nominal.n_states, self.nominal.n_actions) != shape:
                raise ValueError(
                    f"nominal must have {shape[0]} states and {shape[1]} actions like the Q-values "
                    f"(got {self.nominal.n_states} and {self.nominal.n_actions})"
                )
        if self.terminal is None:
            terminal = (np.zeros(shape[0], dtype=bool) if self.nominal is None
                        else np.asarray(self.nominal.terminal, dtype=bool))
        else:
            terminal = np.asarray(self.terminal)
        if terminal.shape != (shape[0],) or terminal.dtype != bool:
            raise ValueError(f"terminal must be a boolean mask of shape ({shape[0]},) (got {terminal.dtype} {terminal.shape})")
        for key in ("sq_nominal", "sq_constrained"):
            sq = getattr(self, key)
            if sq.min() < 0 or np.abs(sq.sum(axis=1) - 1.0).max() > 1e-9 or np.any(sq[~feasible] != 0):
                raise ValueError(
                    f"{key} rows must be probability distributions over the feasible actions "
                    "(non-negative, zero on infeasible actions, summing to 1)"
                )
        object.__setattr__(self, "feasible", _readonly(feasible))
        object.__setattr__(self, "terminal", _readonly(terminal))
        object.__setattr__(self, "temperature", _as_temperature(self.temperature))

    def __repr__(self):
        return (f"ActionPreferences(n_states={self.n_states}, n_actions={self.n_actions}, "
                f"temperature={self.temperature:g}, n_terminal={int(self.terminal.sum())}, "
                f"nominal={'MDP' if self.nominal is not None else None})")

    @property
    def n_states(self) -> int:
        """Number of states."""
        return self.q_nominal.shape[0]

    @property
    def n_actions(self) -> int:
        """Number of actions."""
        return self.q_nominal.shape[1]

    def attributes(self, state: int) -> tuple[np.ndarray, np.ndarray]:
        """``(actions, M)``: the feasible actions of ``state`` and ``M = [sq_n, sq_c]`` on them.

        ``M`` has shape (n_feasible, 2): row ``i`` holds ``sq_n`` and ``sq_c`` of
        ``actions[i]``, the MDFT orchestrator's evaluation matrix.

        Examples
        --------
        >>> import irl, orchestration
        >>> world = irl.GridWorld(3, 0, 8, p_slip=0.0)
        >>> prefs = orchestration.action_preferences(world.nominal_mdp, world.constrained_mdp)
        >>> actions, M = prefs.attributes(0)
        >>> actions.tolist(), M.shape
        ([0, 1, 2, 3, 4, 5, 6, 7], (8, 2))
        """
        state = check_state(state, self.n_states)
        actions = np.flatnonzero(self.feasible[state])
        M = np.stack([self.sq_nominal[state, actions], self.sq_constrained[state, actions]], axis=1)
        return actions, M


def check_state(state, n_states: int) -> int:
    """``state`` as a Python int in ``[0, n_states)``, or a clear error."""
    if isinstance(state, bool) or not isinstance(state, (numbers.Integral, np.integer)):
        raise TypeError(f"state must be an integer state index (got {state!r})")
    s = int(state)
    if not 0 <= s < n_states:
        raise ValueError(f"state must lie in [0, {n_states}) (got {s})")
    return s


def check_states(states, n_states: int) -> np.ndarray:
    """``states`` as a 1-d int64 array of indices in ``[0, n_states)``, or a clear error."""
    arr = np.asarray(states)
    if arr.dtype == bool or not (np.issubdtype(arr.dtype, np.integer) or arr.size == 0):
        raise TypeError(f"states must hold integer state indices (got dtype {arr.dtype})")
    arr = np.array(arr, dtype=np.int64, copy=True).ravel()
    if arr.size and (arr.min() < 0 or arr.max() >= n_states):
        bad = arr[(arr < 0) | (arr >= n_states)][0]
        raise ValueError(f"states must lie in [0, {n_states}) (got {bad})")
    return arr


def _check_pair(nominal, constrained) -> None:
    for name, mdp in (("nominal", nominal), ("constrained", constrained)):
        if not isinstance(mdp, irl.MDP):
            raise TypeError(f"{name} must be an irl.MDP (got {type(mdp).__name__})")
    if (nominal.n_states, nominal.n_actions) != (constrained.n_states, constrained.n_actions):
        raise ValueError(
            "nominal and constrained must share states and actions (got "
            f"{nominal.n_states} states x {nominal.n_actions} actions and "
            f"{constrained.n_states} states x {constrained.n_actions} actions)"
        )
    same = (
        np.array_equal(nominal.terminal, constrained.terminal)
        and np.allclose(nominal.dense_transitions(), constrained.dense_transitions(), rtol=0, atol=1e-12)
        if nominal.n_states * nominal.n_actions * nominal.n_states <= 4_000_000
        else np.array_equal(nominal.terminal, constrained.terminal)
        and np.array_equal(nominal.next_states, constrained.next_states)
        and np.allclose(nominal.probs, constrained.probs, rtol=0, atol=1e-12)
    )
    if not same:
        raise ValueError(
            "nominal and constrained must share transitions and terminal states (they differ); "
            "the constrained MDP is the nominal one with other rewards, e.g. nominal.penalised(...)"
        )


def action_preferences(nominal, constrained, *, temperature=1.0, feasible=None,
                       max_iter=10_000, tol=1e-8) -> ActionPreferences:
    """Q-values of both MDPs by value iteration and their softmax over feasible actions.

    Parameters
    ----------
    nominal : irl.MDP
        The nominal MDP (the agent's own goal).
    constrained : irl.MDP
        The constrained MDP, true or learned (e.g. ``irl.mesc_irl(...).mdp``); it must share
        the nominal MDP's states, actions, transitions and terminal states.
    temperature : float, default 1.0
        Softmax temperature: ``sq = softmax(q / temperature)``; the paper uses 1.
    feasible : array_like of bool, shape (n_states, n_actions), optional
        Actions available in each state (default: every action everywhere, as in the
        paper's gridworlds, where a move off the grid is clipped).
    max_iter, tol
        Passed to :func:`irl.value_iteration`.

    Returns
    -------
    ActionPreferences

    Raises
    ------
    TypeError, ValueError
        MDPs of the wrong type or not sharing states, actions and transitions; a bad
        temperature or feasibility mask.

    Notes
    -----
    ``q(s, a) = r(s, a) + gamma sum_s' P(s'|s, a) max_a' q(s', a')`` for each MDP
    (:func:`irl.value_iteration`); ``sq(s, a) = exp(q(s, a)/T) / sum_{a' feasible}
    exp(q(s, a')/T)``. The rows of terminal states (where no decision is taken) are
    uniform over the feasible actions, as their Q-values are zero.

    Examples
    --------
    >>> import irl, orchestration
    >>> world = irl.GridWorld(3, 0, 8, p_slip=0.0, constrained_states=(4,))
    >>> prefs = orchestration.action_preferences(world.nominal_mdp, world.constrained_mdp)
    >>> int(prefs.sq_nominal[0].argmax()), int(prefs.sq_constrained[0].argmax())  # diagonal; around the centre
    (5, 1)
    """
    _check_pair(nominal, constrained)
    temperature = _as_temperature(temperature)
    shape = (nominal.n_states, nominal.n_actions)
    mask = np.ones(shape, dtype=bool) if feasible is None else _check_feasible(feasible, shape)
    qn = irl.value_iteration(nominal, max_iter=max_iter, tol=tol).q_values
    qc = irl.value_iteration(constrained, max_iter=max_iter, tol=tol).q_values
    return ActionPreferences(
        q_nominal=qn,
        q_constrained=qc,
        sq_nominal=masked_softmax(qn, mask, temperature),
        sq_constrained=masked_softmax(qc, mask, temperature),
        feasible=mask,
        temperature=temperature,
        nominal=nominal,
    )
