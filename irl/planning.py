"""Planning in tabular MDPs: value iteration, soft value iteration and visitation.

All functions take an :class:`irl.mdp.MDP` (conventions in :mod:`irl.mdp`):
``policy[s, a]`` for stationary policies, ``policy[t, s, a]`` for time-indexed
ones, values are zero at terminal states.

Equations
---------
With ``r(s, a) = sum_s' P(s'|s, a) R(s, a, s')`` and discount gamma:

- value iteration: ``Q(s, a) = r(s, a) + gamma sum_s' P(s'|s, a) V(s')``,
  ``V(s) = max_a Q(s, a)``;
- soft value iteration (maximum causal entropy backward pass):
  ``V(s) = log sum_a exp Q(s, a)`` and ``pi(a|s) = exp(Q(s, a) - V(s))``;
  with a finite ``horizon`` H the recursion runs from ``V_H = 0`` back to
  ``V_0`` and gives a time-indexed policy ``pi_t``;
- visitation (forward pass): ``D(s, a) = sum_t gamma**t Pr(s_t = s, a_t = a)``
  for a start distribution, with the same horizon and discount as the
  backward pass; mass that enters a terminal state stops.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from . import _kernels
from .mdp import MDP, _as_float, _as_int, _as_real, _check_size
from ._repr import compact_repr, iterations, spread
from ._typing import ArrayLike

__all__ = [
    "PlanningResult",
    "SoftPlanningResult",
    "VisitationResult",
    "value_iteration",
    "soft_value_iteration",
    "state_action_visitation",
    "greedy_policy",
]


def _check_mdp(mdp):
    if not isinstance(mdp, MDP):
        raise TypeError(f"mdp must be an irl.MDP (got {type(mdp).__name__})")


def _check_iter(max_iter, tol):
    return _as_int("max_iter", max_iter, low=1), _as_real("tol", tol, low=0.0, low_open=True)


@dataclass(frozen=True, eq=False)
class PlanningResult:
    """Optimal values of an MDP.

    Attributes
    ----------
    values : ndarray, shape (n_states,)
    q_values : ndarray, shape (n_states, n_actions)
    policy : ndarray, shape (n_states, n_actions)
        Greedy policy, uniform over the actions within 1e-9 of the best.
    n_iter : int
    converged : bool
    """

    __repr__ = compact_repr

    values: np.ndarray
    q_values: np.ndarray
    policy: np.ndarray
    n_iter: int
    converged: bool

    def summary(self) -> str:
        """Size, convergence and the range of the values, as text.

        Examples
        --------
        >>> import irl
        >>> world = irl.GridWorld(3, 0, 2, p_slip=0.0)
        >>> print(irl.value_iteration(world.nominal_mdp).summary())  # doctest: +ELLIPSIS
        value iteration: 9 states x 8 actions, converged after ... iterations
        values: min ..., mean ..., max ...
        """
        n_states, n_actions = self.q_values.shape
        return (f"value iteration: {n_states} states x {n_actions} actions, "
                f"{iterations(self.n_iter, self.converged)}\nvalues: {spread(self.values)}")


@dataclass(frozen=True, eq=False)
class SoftPlanningResult:
    """Soft (maximum causal entropy) values and policy.

    Attributes
    ----------
    values : ndarray, shape (n_states,) or (horizon + 1, n_states)
        Soft values ``V``; time-indexed when a horizon was given (``values[H] = 0``).
    q_values : ndarray, shape (n_states, n_actions) or (horizon, n_states, n_actions)
    policy : ndarray, shape (n_states, n_actions) or (horizon, n_states, n_actions)
        ``exp(Q - V)``; uniform at terminal states.
    horizon : int or None
    n_iter : int
        Backups done (``horizon`` for the finite-horizon recursion).
    converged : bool
        Always True for a finite horizon.
    """

    __repr__ = compact_repr

    values: np.ndarray
    q_values: np.ndarray
    policy: np.ndarray
    horizon: int | None
    n_iter: int
    converged: bool

    def summary(self) -> str:
        """Size, horizon, convergence, the range of the values and the policy's entropy.

        Examples
        --------
        >>> import irl
        >>> world = irl.GridWorld(3, 0, 2, p_slip=0.0)
        >>> print(irl.soft_value_iteration(world.nominal_mdp, horizon=4).summary())
        ... # doctest: +ELLIPSIS
        soft value iteration: 9 states x 8 actions, horizon 4, converged after 4 iterations
        values at the start: min ..., mean ..., max ...
        policy entropy (nats): min ..., mean ..., max ...
        """
        n_states, n_actions = self.q_values.shape[-2:]
        horizon = "infinite horizon" if self.horizon is None else f"horizon {self.horizon}"
        start = self.values if self.values.ndim == 1 else self.values[0]
        first = self.policy if self.policy.ndim == 2 else self.policy[0]
        with np.errstate(divide="ignore", invalid="ignore"):
            entropy = -np.sum(np.where(first > 0, first * np.log(first), 0.0), axis=1)
        return "\n".join([
            f"soft value iteration: {n_states} states x {n_actions} actions, {horizon}, "
            f"{iterations(self.n_iter, self.converged)}",
            f"values at the start: {spread(start)}",
            f"policy entropy (nats): {spread(entropy)}",
        ])


@dataclass(frozen=True, eq=False)
class VisitationResult:
    """Expected discounted visitation of a policy.

    Attributes
    ----------
    state_action : ndarray, shape (n_states, n_actions)
        ``D(s, a) = sum_t gamma**t Pr(s_t = s, a_t = a)``.
    states : ndarray, shape (n_states,)
        ``sum_a D(s, a)`` (visits of non-terminal states).
    destinations : ndarray, shape (n_states,)
        ``sum_t gamma**t Pr(s_{t+1} = s')`` over transitions taken at step t
        (includes entries into terminal states).
    n_iter : int
    converged : bool
    """

    __repr__ = compact_repr

    state_action: np.ndarray
    states: np.ndarray
    destinations: np.ndarray
    n_iter: int
    converged: bool

    def summary(self) -> str:
        """Total expected visits, the most visited states, and convergence, as text.

        Examples
        --------
        >>> import irl
        >>> world = irl.GridWorld(3, 0, 2, p_slip=0.0)
        >>> soft = irl.soft_value_iteration(world.nominal_mdp, horizon=4)
        >>> print(irl.state_action_visitation(world.nominal_mdp, soft.policy).summary())
        ... # doctest: +ELLIPSIS
        visitation: 9 states x 8 actions, converged after ... iterations
        expected transitions: ...
        most visited states: ...
        """
        n_states, n_actions = self.state_action.shape
        top = np.argsort(-self.states, kind="stable")[:5]
        visited = ", ".join(f"{int(s)} ({self.states[s]:.3g})" for s in top if self.states[s] > 0)
        return "\n".join([
            f"visitation: {n_states} states x {n_actions} actions, "
            f"{iterations(self.n_iter, self.converged)}",
            f"expected transitions: {self.state_action.sum():.4g}",
            f"most visited states: {visited or 'none'}",
        ])


def _warn(name, n_iter, tol):
    warnings.warn(
        f"{name} did not converge in max_iter={n_iter} iterations (tol={tol}); "
        "raise max_iter, or check that the discount is < 1 or a terminal state is reachable",
        RuntimeWarning,
        stacklevel=3,
    )


def greedy_policy(q_values: ArrayLike, *, atol: float = 1e-9) -> np.ndarray:
    """Uniform distribution over the maximising actions of each row of ``q_values``.

    Parameters
    ----------
    q_values : array_like, shape (..., n_actions)
    atol : float, default 1e-9
        Actions within ``atol`` (>= 0) of the best count as maximising.

    Returns
    -------
    ndarray, same shape as ``q_values``

    Examples
    --------
    >>> greedy_policy([[1.0, 1.0, 0.0]]).tolist()
    [[0.5, 0.5, 0.0]]
    """
    q = _as_float("q_values", q_values)
    atol = _as_real("atol", atol, low=0.0)
    if q.ndim < 1 or q.shape[-1] < 1:
        raise ValueError(f"q_values must have at least one action on its last axis (got shape "
                         f"{q.shape})")
    best = q.max(axis=-1, keepdims=True)
    mask = (q >= best - atol).astype(np.float64)
    return mask / mask.sum(axis=-1, keepdims=True)


def value_iteration(mdp: MDP, *, max_iter: int = 10_000, tol: float = 1e-8) -> PlanningResult:
    """Optimal values and Q-values by value iteration.

    Parameters
    ----------
    mdp : MDP
    max_iter : int
        Maximum number of Bellman backups.
    tol : float
        Stop when the largest change of V in one backup is <= tol.

    Returns
    -------
    PlanningResult

    Warns
    -----
    RuntimeWarning
        If V did not converge within ``max_iter`` backups.

    Examples
    --------
    >>> from irl import GridWorld
    >>> res = value_iteration(GridWorld(3, 0, 8, p_slip=0.0, discount=1.0).nominal_mdp)
    >>> res.converged, round(float(res.values[0]), 3)
    (True, -1.314)
    """
    _check_mdp(mdp)
    max_iter, tol = _check_iter(max_iter, tol)
    r_bar = mdp.expected_rewards()
    v, q, n_iter, converged = _kernels.value_iteration(
        mdp.next_states, mdp.probs, r_bar, mdp.terminal, mdp.discount, max_iter, tol
    )
    if not converged:
        _warn("value_iteration", max_iter, tol)
    return PlanningResult(v, q, greedy_policy(q), int(n_iter), bool(converged))


def soft_value_iteration(mdp: MDP, *, horizon: int | None = None, max_iter: int = 10_000,
                         tol: float = 1e-8) -> SoftPlanningResult:
    """Soft value iteration: the backward pass of maximum causal entropy IRL.

    Parameters
    ----------
    mdp : MDP
    horizon : int or None
        ``None``: the stationary infinite-horizon fixed point, iterated to
        ``tol``. An int H: the exact H-step recursion from ``V_H = 0``,
        giving a time-indexed policy ``policy[t, s, a]``.
    max_iter, tol : int, float
        Iteration limit and tolerance (largest change of V) for ``horizon=None``.

    Returns
    -------
    SoftPlanningResult

    Warns
    -----
    RuntimeWarning
        If the stationary iteration did not converge.

    Examples
    --------
    >>> from irl import GridWorld
    >>> mdp = GridWorld(3, 0, 8).nominal_mdp
    >>> res = soft_value_iteration(mdp)
    >>> res.policy.shape, bool(abs(res.policy.sum(1) - 1).max() < 1e-12)
    ((9, 8), True)
    >>> soft_value_iteration(mdp, horizon=5).policy.shape
    (5, 9, 8)
    """
    _check_mdp(mdp)
    r_bar = mdp.expected_rewards()
    if horizon is not None:
        horizon = _as_int("horizon", horizon)
        _check_size(f"horizon={horizon} (x {mdp.n_states} states x {mdp.n_actions} actions)",
                    horizon * mdp.n_states * mdp.n_actions)
        v, q, pol = _kernels.soft_value_iteration_finite(
            mdp.next_states, mdp.probs, r_bar, mdp.terminal, mdp.discount, horizon
        )
        return SoftPlanningResult(v, q, pol, horizon, horizon, True)
    max_iter, tol = _check_iter(max_iter, tol)
    v, q, pol, n_iter, converged = _kernels.soft_value_iteration(
        mdp.next_states, mdp.probs, r_bar, mdp.terminal, mdp.discount, max_iter, tol
    )
    if not converged:
        _warn("soft_value_iteration", max_iter, tol)
    return SoftPlanningResult(v, q, pol, None, int(n_iter), bool(converged))


def check_policy(mdp, policy, name="policy"):
    """Return ``policy`` as a new float array (S, A) or (H, S, A) whose rows are distributions, or raise.

    Examples
    --------
    >>> from irl import GridWorld
    >>> check_policy(GridWorld(2, 0, 3).nominal_mdp, [[0.125] * 8] * 4).shape
    (4, 8)
    """
    pol = _as_float(name, policy)
    S, A = mdp.n_states, mdp.n_actions
    if pol.ndim not in (2, 3) or pol.shape[-2:] != (S, A):
        raise ValueError(f"{name} must have shape ({S}, {A}) or (horizon, {S}, {A}) (got {pol.shape})")
    if pol.min() < 0 or np.abs(pol.sum(axis=-1) - 1.0).max() > 1e-8:
        raise ValueError(f"{name} rows must be probability distributions over actions (non-negative, summing to 1)")
    return pol


def state_action_visitation(mdp: MDP, policy: ArrayLike, *, start: ArrayLike | None = None,
                            max_iter: int = 100_000, tol: float = 1e-10) -> VisitationResult:
    """Expected discounted state-action visitation of a policy (the forward pass).

    Parameters
    ----------
    mdp : MDP
    policy : array_like, shape (S, A) or (H, S, A)
        Stationary or time-indexed policy. A time-indexed policy is followed
        for exactly H steps (the horizon of the backward pass that made it).
    start : array_like, shape (S,), optional
        Start distribution (default ``mdp.start``); any non-negative vector is
        accepted (visitation is linear in it).
    max_iter, tol : int, float
        For a stationary policy: steps are summed until the discounted mass
        left in non-terminal states is <= tol.

    Returns
    -------
    VisitationResult

    Examples
    --------
    >>> from irl import GridWorld
    >>> mdp = GridWorld(3, 0, 8, p_slip=0.0).nominal_mdp
    >>> pol = soft_value_iteration(mdp, horizon=20).policy
    >>> d = state_action_visitation(mdp, pol)
    >>> d.state_action.shape, round(float(d.states[0]), 3)
    ((9, 8), 1.0)
    """
    _check_mdp(mdp)
    pol = check_policy(mdp, policy)
    d0 = mdp.start if start is None else _as_float("start", start, ndim=1, shape=(mdp.n_states,))
    if np.any(d0 < 0):
        raise ValueError("start must be non-negative")
    d0 = np.ascontiguousarray(d0, dtype=np.float64)
    if pol.ndim == 3:
        sa, dst = _kernels.visitation_finite(mdp.next_states, mdp.probs, mdp.terminal, mdp.discount, pol, d0)
        n_iter, converged = pol.shape[0], True
    else:
        max_iter, tol = _check_iter(max_iter, tol)
        sa, dst, n_iter, converged = _kernels.visitation_stationary(
            mdp.next_states, mdp.probs, mdp.terminal, mdp.discount, pol, d0, max_iter, tol
        )
        if not converged:
            _warn("state_action_visitation", max_iter, tol)
    return VisitationResult(sa, sa.sum(axis=1), dst, int(n_iter), bool(converged))
