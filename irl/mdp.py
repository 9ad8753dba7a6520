"""Tabular MDPs with sparse transitions and factorised transition features.

Array conventions (used throughout :mod:`irl`)
----------------------------------------------
- States are ``0 .. n_states - 1``, actions ``0 .. n_actions - 1``.
- Transitions are padded sparse arrays of shape ``(n_states, n_actions, K)``:
  taking action ``a`` in state ``s`` leads to ``next_states[s, a, k]`` with
  probability ``probs[s, a, k]``. ``K`` is the largest number of successors of
  any (s, a); unused slots have probability 0 (their state index is still a
  valid state). ``probs[s, a, :]`` sums to one for every (s, a).
- ``rewards[s, a, k]`` is the reward R(s, a, s') of the transition to
  ``s' = next_states[s, a, k]``.
- ``terminal[s]`` marks absorbing terminal states: entering one ends the
  episode. No action is taken, no reward is received and no feature is counted
  from a terminal state; its value is zero. The rows of terminal states in the
  transition arrays are ignored by every algorithm.
- ``start[s]`` is the start distribution, ``discount`` the discount factor.
- Policies are ``policy[s, a]`` (stationary) or ``policy[t, s, a]`` (time-indexed).
- Features of a transition are factorised,
  ``phi(s, a, s') = source[s] + action[a] + destination[s']`` (see
  :class:`TransitionFeatures`), so ``omega . phi`` costs three sparse products.
"""

from __future__ import annotations

import numbers
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any

import numpy as np
import scipy.sparse as sp

from . import _kernels
from ._repr import compact_repr
from ._typing import ArrayLike

__all__ = ["MDP", "TransitionFeatures"]

_PROB_ATOL = 1e-8


# ------------------------------------------------------------------ validation
def _as_float(name, value, *, ndim=None, shape=None):
    try:
        arr = np.array(value, dtype=np.float64, order="C", copy=True)
    except OverflowError:
        raise ValueError(f"{name} must contain only finite values (got a number too large for "
                         "a float)") from None
    except (TypeError, ValueError) as exc:
        raise TypeError(f"{name} must be an array of real numbers (got {type(value).__name__})") from exc
    if ndim is not None and arr.ndim != ndim:
        raise ValueError(f"{name} must be a {ndim}-d array (got {arr.ndim}-d with shape {arr.shape})")
    if shape is not None and (
        arr.ndim != len(shape) or any(w is not None and g != w for g, w in zip(arr.shape, shape))
    ):
        want = "(" + ", ".join("any" if w is None else str(w) for w in shape) + ")"
        raise ValueError(f"{name} must have shape {want} (got {arr.shape})")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must contain only finite values (got NaN or infinity)")
    return arr


def _as_index(name, value, *, ndim=None, high=None):
    arr = np.asarray(value)
    if arr.dtype == bool or not (np.issubdtype(arr.dtype, np.integer) or arr.size == 0):
        if arr.size and np.issubdtype(arr.dtype, np.floating) and np.all(arr == np.round(arr)):
            arr = arr.astype(np.int64)
        else:
            raise TypeError(f"{name} must hold integer indices (got dtype {arr.dtype})")
    arr = np.array(arr, dtype=np.int64, order="C", copy=True)
    if ndim is not None and arr.ndim != ndim:
        raise ValueError(f"{name} must be a {ndim}-d array (got {arr.ndim}-d with shape {arr.shape})")
    if high is not None and arr.size and (arr.min() < 0 or arr.max() >= high):
        bad = arr[(arr < 0) | (arr >= high)].ravel()[0]
        raise ValueError(f"{name} must hold states in [0, {high}) (got {bad})")
    return arr


def _as_real(name, value, *, low=None, high=None, low_open=False):
    if isinstance(value, bool) or not isinstance(value, (numbers.Real, np.integer, np.floating)):
        raise TypeError(f"{name} must be a real number (got {value!r})")
    try:
        x = float(value)
    except OverflowError:
        raise ValueError(f"{name} must be finite (got an integer too large for a float)") from None
    if not np.isfinite(x):
        raise ValueError(f"{name} must be finite (got {x})")
    if low is not None and (x <= low if low_open else x < low):
        raise ValueError(f"{name} must be {'>' if low_open else '>='} {low} (got {x})")
    if high is not None and x > high:
        raise ValueError(f"{name} must be <= {high} (got {x})")
    return x


#: Largest count accepted by the public API (iterations, horizons, trajectories, sizes).
MAX_COUNT = 1_000_000_000
#: Largest array (in values) that a horizon, a number of trajectories or a table may ask
#: for: 100 million values, 800 MB of float64 (``docs/decisions.md``).
MAX_VALUES = 100_000_000


def _as_int(name, value, *, low=1, high=MAX_COUNT):
    if isinstance(value, bool) or not isinstance(value, (numbers.Integral, np.integer)):
        raise TypeError(f"{name} must be an integer (got {value!r})")
    n = int(value)
    if n < low:
        raise ValueError(f"{name} must be an integer >= {low} (got {n})")
    if n > high:
        shown = f"{n:,}" if n < 10**30 else f"an integer of {n.bit_length()} bits"
        raise ValueError(f"{name} must be an integer <= {high:,} (got {shown})")
    return n


def _check_size(what, n_values):
    """Refuse a request for more than :data:`MAX_VALUES` values, naming what asked for it."""
    if n_values > MAX_VALUES:
        raise ValueError(
            f"{what} asks for {n_values:,} values, more than the limit of {MAX_VALUES:,} "
            "(800 MB of float64); ask for less"
        )


def _readonly(arr):
    arr.flags.writeable = False
    return arr


DENSE_OPERATOR_MAX = 200_000  # entries: below, repeated feature products use a dense copy


def _fast_operator(m):
    """None for an empty block, a dense float array when small, CSR otherwise (repeated products)."""
    if m.nnz == 0:
        return None
    if m.shape[0] * m.shape[1] <= DENSE_OPERATOR_MAX:
        return np.ascontiguousarray(m.toarray(), dtype=np.float64)
    return sp.csr_array(m, dtype=np.float64)


def _as_sparse(name, value, n_rows, n_features):
    if value is None:
        return sp.csr_array((n_rows, n_features))
    if sp.issparse(value):
        mat = sp.csr_array(value, dtype=np.float64, copy=True)
        if mat.shape[0] != n_rows or (n_features is not None and mat.shape[1] != n_features):
            want = f"({n_rows}, {'F' if n_features is None else n_features})"
            raise ValueError(f"{name} must have shape {want} (got {mat.shape})")
        if not np.all(np.isfinite(mat.data)):
            raise ValueError(f"{name} must contain only finite values (got NaN or infinity)")
        return mat
    arr = _as_float(name, value, ndim=2, shape=(n_rows, n_features))
    return sp.csr_array(arr)


def successor_patterns(next_states, probs):
    """Compact transitions for the passes of MESC-IRL.

    Parameters
    ----------
    next_states : ndarray of int, shape (S, A, K)
    probs : ndarray, shape (S, A, K)
        The padded arrays of an :class:`MDP`.

    Returns
    -------
    shared : ndarray of bool, shape (S,)
        Every action of s lists the same successors in the same order (as with slip).
    succ : ndarray of int32, shape (S, K)
        ``next_states[:, 0, :]``.
    pattern_of : ndarray of int32, shape (S,)
        The pattern of each shared state (0 for the others).
    patterns : ndarray, shape (P, K, A)
        The distinct matrices ``probs[s].T`` of the shared states, compared bit
        for bit (nothing is rounded); one zero matrix when no state is shared.

    Notes
    -----
    A gridworld with slip has nine patterns (the interior, four edges, four
    corners), so a pass reads a pattern number and K successors per state
    instead of ``A K`` probabilities.

    Examples
    --------
    >>> from irl import GridWorld
    >>> mdp = GridWorld(6, 0, 35, p_slip=0.1).nominal_mdp
    >>> shared, succ, pattern_of, patterns = successor_patterns(mdp.next_states, mdp.probs)
    >>> bool(shared.all()), patterns.shape
    (True, (9, 8, 8))
    """
    shared = _kernels.shared_successors(next_states)
    n_states, n_actions, n_succ = probs.shape
    succ = np.ascontiguousarray(next_states[:, 0, :], dtype=np.int32)
    bits = np.ascontiguousarray(probs.transpose(0, 2, 1)).reshape(n_states, -1).view(np.int64)
    pattern_of = np.zeros(n_states, dtype=np.int32)
    idx = np.flatnonzero(shared)
    if idx.size:
        table, inverse = np.unique(bits[idx], axis=0, return_inverse=True)
        pattern_of[idx] = inverse.reshape(-1)
        patterns = np.ascontiguousarray(table.view(np.float64).reshape(-1, n_succ, n_actions))
    else:
        patterns = np.zeros((1, n_succ, n_actions))
    return shared, succ, pattern_of, patterns


# -------------------------------------------------------------------- features
@dataclass(frozen=True, eq=False)
class TransitionFeatures:
    """Factorised transition features phi(s, a, s') = source[s] + action[a] + destination[s'].

    Parameters
    ----------
    source : array_like or scipy.sparse matrix, shape (n_states, n_features), optional
        Features of the state a transition leaves. ``None`` means all zero.
    action : array_like or scipy.sparse matrix, shape (n_actions, n_features), optional
        Features of the action taken (the chosen action, not the executed one).
    destination : array_like or scipy.sparse matrix, shape (n_states, n_features), optional
        Features of the state a transition enters.
    names : sequence of str, optional
        One name per feature.
    n_states, n_actions, n_features : int, optional
        Sizes, needed only where a block is ``None``.

    Notes
    -----
    The paper's gridworld features (one-hot destination state, one-hot action,
    one-hot destination colour) are all of this form. Expected feature counts
    follow as ``source.T @ d_src + action.T @ d_act + destination.T @ d_dst``
    for visitation vectors of sources, actions and destinations, and
    ``omega . phi(s, a, s') = u_src[s] + u_act[a] + u_dst[s']`` with
    ``u_src = source @ omega`` and so on. All blocks are stored as CSR arrays.

    Examples
    --------
    >>> import numpy as np
    >>> f = TransitionFeatures(action=np.eye(2), destination=np.zeros((3, 2)))
    >>> f.n_features, f.n_states, f.n_actions
    (2, 3, 2)
    >>> f.phi(0, 1, 2).tolist()
    [0.0, 1.0]
    """

    __repr__ = compact_repr

    source: object = None
    action: object = None
    destination: object = None
    names: tuple | None = None
    n_states: int | None = None
    n_actions: int | None = None
    n_features: int | None = None

    def __post_init__(self):
        dims = {}
        for key, val in (("source", self.source), ("action", self.action), ("destination", self.destination)):
            if val is not None:
                shape = val.shape if sp.issparse(val) else np.shape(val)
                if len(shape) != 2:
                    raise ValueError(f"{key} must be a 2-d array of shape (rows, n_features) (got shape {shape})")
                dims[key] = shape
        n_f = self.n_features
        for key, shape in dims.items():
            if n_f is None:
                n_f = shape[1]
            elif shape[1] != n_f:
                raise ValueError(
                    f"{key} must have {n_f} feature columns like the other blocks (got {shape[1]})"
                )
        if n_f is None:
            raise ValueError("n_features is required when source, action and destination are all None")
        n_f = _as_int("n_features", n_f, low=0)
        n_s = self.n_states
        for key in ("source", "destination"):
            if key in dims:
                if n_s is None:
                    n_s = dims[key][0]
                elif dims[key][0] != n_s:
                    raise ValueError(f"{key} must have {n_s} rows, one per state (got {dims[key][0]})")
        n_a = self.n_actions
        if "action" in dims:
            if n_a is None:
                n_a = dims["action"][0]
            elif dims["action"][0] != n_a:
                raise ValueError(f"action must have {n_a} rows, one per action (got {dims['action'][0]})")
        if n_s is None or n_a is None:
            raise ValueError("n_states and n_actions are required where the blocks do not fix them")
        object.__setattr__(self, "n_states", _as_int("n_states", n_s))
        object.__setattr__(self, "n_actions", _as_int("n_actions", n_a))
        object.__setattr__(self, "n_features", n_f)
        object.__setattr__(self, "source", _as_sparse("source", self.source, n_s, n_f))
        object.__setattr__(self, "action", _as_sparse("action", self.action, n_a, n_f))
        object.__setattr__(self, "destination", _as_sparse("destination", self.destination, n_s, n_f))
        if self.names is not None:
            names = tuple(str(x) for x in self.names)
            if len(names) != n_f:
                raise ValueError(f"names must have one entry per feature ({n_f}) (got {len(names)})")
            object.__setattr__(self, "names", names)
        else:
            object.__setattr__(self, "names", tuple(f"f{i}" for i in range(n_f)))

    def check_weights(self, omega: ArrayLike, name: str = "omega") -> np.ndarray:
        """Return ``omega`` as a new float array of shape (n_features,), or raise ValueError."""
        return _as_float(name, omega, ndim=1, shape=(self.n_features,))

    def projections(self, omega: ArrayLike) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Per-block weights ``(source @ omega, action @ omega, destination @ omega)``.

        Parameters
        ----------
        omega : array_like, shape (n_features,)

        Returns
        -------
        u_src : ndarray, shape (n_states,)
        u_act : ndarray, shape (n_actions,)
        u_dst : ndarray, shape (n_states,)
        """
        w = self.check_weights(omega)
        return self._projections(w)

    def _projections(self, w):
        return tuple(np.zeros(n) if m is None else m @ w for m, n in zip(self._operators, self._block_rows))

    @cached_property
    def _block_rows(self):
        return tuple(m.shape[0] for m in (self.source, self.action, self.destination))

    @cached_property
    def _operators(self):
        # the non-empty blocks for repeated products: dense when small (a dense product of a few
        # thousand entries is far cheaper than a sparse product's call overhead), CSR otherwise
        return tuple(_fast_operator(m) for m in (self.source, self.action, self.destination))

    def counts(self, d_src: ArrayLike, d_act: ArrayLike, d_dst: ArrayLike) -> np.ndarray:
        """Feature counts ``source.T d_src + action.T d_act + destination.T d_dst``, shape (n_features,)."""
        out = np.zeros(self.n_features)
        for mat_t, d in zip(self._transposed, (d_src, d_act, d_dst)):
            if mat_t is not None:
                out += mat_t @ d
        return out

    @cached_property
    def _transposed(self):
        # CSR copies of the transposed non-empty blocks: fast repeated counts
        return tuple(_fast_operator(m.T) for m in (self.source, self.action, self.destination))

    def phi(self, s: int, a: int, s_next: int) -> np.ndarray:
        """Dense feature vector phi(s, a, s') of one transition, shape (n_features,)."""
        return (
            self.source[[int(s)], :].toarray()[0]
            + self.action[[int(a)], :].toarray()[0]
            + self.destination[[int(s_next)], :].toarray()[0]
        )

    def transition_values(self, omega: ArrayLike, next_states: ArrayLike) -> np.ndarray:
        """``omega . phi(s, a, next_states[s, a, k])`` for every padded transition, shape (S, A, K)."""
        u_src, u_act, u_dst = self.projections(omega)
        ns = np.asarray(next_states)
        return u_src[:, None, None] + u_act[None, :, None] + u_dst[ns]


# ------------------------------------------------------------------------- MDP
@dataclass(frozen=True, eq=False)
class MDP:
    """A tabular MDP with padded sparse transitions (see the module docstring for conventions).

    Parameters
    ----------
    next_states : array_like of int, shape (n_states, n_actions, K)
        Successor states; ``next_states[s, a, k]`` must lie in ``[0, n_states)``.
    probs : array_like, shape (n_states, n_actions, K)
        Transition probabilities, non-negative, summing to one over ``k`` (to 1e-8).
    rewards : array_like, shape (n_states, n_actions, K), or None
        R(s, a, s') of each padded transition; ``None`` means zero.
    terminal : array_like of bool, shape (n_states,), or None
        Absorbing terminal states (default none). When there are terminal
        states, one must be reachable from every start state.
    start : array_like, shape (n_states,), or None
        Start distribution (non-negative, sums to one). Default uniform over the
        non-terminal states.
    discount : float
        Discount factor in (0, 1].
    features : TransitionFeatures or None
        Transition features used by :mod:`irl.mesc`.

    Notes
    -----
    Arrays are copied on construction and stored read-only, so an ``MDP`` never
    changes and never aliases its caller's arrays. New MDPs with other rewards
    come from :meth:`replace`, :meth:`penalised`.

    Examples
    --------
    >>> import numpy as np
    >>> P = np.zeros((2, 1, 2)); P[0, 0, 1] = 1.0; P[1, 0, 1] = 1.0
    >>> mdp = MDP.from_dense(P, rewards=-np.ones((2, 1, 2)), terminal=[False, True], start=[1, 0])
    >>> mdp.n_states, mdp.n_actions, mdp.n_successors
    (2, 1, 1)
    """

    __repr__ = compact_repr

    next_states: np.ndarray
    probs: np.ndarray
    rewards: np.ndarray | None = None
    terminal: np.ndarray | None = None
    start: np.ndarray | None = None
    discount: float = 1.0
    features: TransitionFeatures | None = field(default=None)

    def __post_init__(self):
        probs = _as_float("probs", self.probs, ndim=3)
        n_s, n_a, n_k = probs.shape
        if n_s == 0 or n_a == 0 or n_k == 0:
            raise ValueError(f"probs must have at least one state, action and successor (got shape {probs.shape})")
        ns = _as_index("next_states", self.next_states, ndim=3)
        if ns.shape != probs.shape:
            raise ValueError(f"next_states must have the shape of probs {probs.shape} (got {ns.shape})")
        ns = _as_index("next_states", ns, high=n_s)  # n_s comes from probs: compare shapes first
        if probs.min() < 0:
            idx = np.unravel_index(np.argmin(probs), probs.shape)
            raise ValueError(f"probs must be non-negative (got {probs[idx]} at (s, a, k) = {tuple(int(i) for i in idx)})")
        sums = probs.sum(axis=2)
        bad = np.abs(sums - 1.0) > _PROB_ATOL
        if bad.any():
            s, a = (int(i) for i in np.argwhere(bad)[0])
            raise ValueError(
                f"probs must sum to 1 over successors for every (s, a) (got {sums[s, a]:.6g} at s={s}, a={a}); "
                "normalise each row of transition probabilities"
            )
        rewards = (
            np.zeros_like(probs)
            if self.rewards is None
            else _as_float("rewards", self.rewards, ndim=3, shape=probs.shape)
        )
        if self.terminal is None:
            terminal = np.zeros(n_s, dtype=bool)
        else:
            t = np.asarray(self.terminal)
            if t.shape != (n_s,):
                raise ValueError(f"terminal must have shape ({n_s},) (got {t.shape})")
            if t.dtype != bool and not np.all((t == 0) | (t == 1)):
                raise TypeError(f"terminal must be a boolean mask (got dtype {t.dtype})")
            terminal = np.array(t, dtype=bool, copy=True)
        if self.start is None:
            if terminal.all():
                raise ValueError("terminal marks every state; at least one state must be non-terminal")
            start = (~terminal).astype(np.float64)
            start /= start.sum()
        else:
            start = _as_float("start", self.start, ndim=1, shape=(n_s,))
            if start.min() < 0 or abs(start.sum() - 1.0) > 1e-8:
                raise ValueError(
                    f"start must be a probability distribution over states (got min {start.min():.3g}, "
                    f"sum {start.sum():.6g})"
                )
        discount = _as_real("discount", self.discount, low=0.0, high=1.0, low_open=True)
        if self.features is not None:
            if not isinstance(self.features, TransitionFeatures):
                raise TypeError(
                    f"features must be a TransitionFeatures (got {type(self.features).__name__})"
                )
            if self.features.n_states != n_s or self.features.n_actions != n_a:
                raise ValueError(
                    f"features must be defined for {n_s} states and {n_a} actions "
                    f"(got {self.features.n_states} states and {self.features.n_actions} actions)"
                )
        if terminal.any():
            ok = _kernels.reaches_terminal(ns, probs, terminal)
            stuck = np.flatnonzero((start > 0) & ~ok)
            if stuck.size:
                raise ValueError(
                    f"no policy reaches a terminal state from start state(s) {stuck[:5].tolist()}; "
                    "the goal must be reachable from every start state"
                )
        for key, val in (("next_states", ns), ("probs", probs), ("rewards", rewards), ("terminal", terminal), ("start", start)):
            object.__setattr__(self, key, _readonly(val))
        object.__setattr__(self, "discount", discount)

    # ---------------------------------------------------------------- sizes
    @property
    def n_states(self) -> int:
        """Number of states S."""
        return self.probs.shape[0]

    @property
    def n_actions(self) -> int:
        """Number of actions A."""
        return self.probs.shape[1]

    @property
    def n_successors(self) -> int:
        """Padded successor width K."""
        return self.probs.shape[2]

    @property
    def n_features(self) -> int:
        """Number of transition features (0 without features)."""
        return 0 if self.features is None else self.features.n_features

    # --------------------------------------------------------- constructors
    @classmethod
    def from_dense(cls, transitions: ArrayLike, rewards: ArrayLike | None = None, *,
                   terminal: ArrayLike | None = None, start: ArrayLike | None = None,
                   discount: float = 1.0, features: TransitionFeatures | None = None) -> MDP:
        """Build an MDP from a dense transition tensor ``transitions[s, a, s']``.

        Parameters
        ----------
        transitions : array_like, shape (S, A, S)
            ``P(s' | s, a)``; rows must sum to one.
        rewards : array_like, shape (S, A, S), (S, A) or (S,), optional
            R(s, a, s'), R(s, a) or R(s') (reward on entering s').
        terminal, start, discount, features
            As in :class:`MDP`.

        Returns
        -------
        MDP

        Examples
        --------
        >>> import numpy as np
        >>> P = np.full((3, 2, 3), 1 / 3)
        >>> MDP.from_dense(P, discount=0.9).n_successors
        3
        """
        P = _as_float("transitions", transitions, ndim=3)
        n_s, n_a = P.shape[:2]
        if P.shape[2] != n_s:
            raise ValueError(f"transitions must have shape (S, A, S) (got {P.shape})")
        if rewards is None:
            R = np.zeros_like(P)
        else:
            R = _as_float("rewards", rewards)
            if R.shape == (n_s,):
                R = np.broadcast_to(R[None, None, :], P.shape)
            elif R.shape == (n_s, n_a):
                R = np.broadcast_to(R[:, :, None], P.shape)
            elif R.shape != P.shape:
                raise ValueError(f"rewards must have shape {P.shape}, {(n_s, n_a)} or {(n_s,)} (got {R.shape})")
        width = max(1, int((P > 0).sum(axis=2).max()))
        order = np.argsort(~(P > 0), axis=2, kind="stable")[:, :, :width]
        ns = order
        probs = np.take_along_axis(P, order, axis=2)
        rw = np.take_along_axis(np.asarray(R), order, axis=2)
        ns = np.where(probs > 0, ns, np.arange(n_s)[:, None, None])
        rw = np.where(probs > 0, rw, 0.0)
        return cls(ns, probs, rw, terminal=terminal, start=start, discount=discount, features=features)

    def replace(self, **changes: Any) -> MDP:
        """A new MDP with some fields replaced (validated again).

        Examples
        --------
        >>> import numpy as np
        >>> mdp = MDP.from_dense(np.full((2, 1, 2), 0.5))
        >>> mdp.replace(discount=0.5).discount
        0.5
        """
        kw = dict(
            next_states=self.next_states, probs=self.probs, rewards=self.rewards, terminal=self.terminal,
            start=self.start, discount=self.discount, features=self.features,
        )
        unknown = set(changes) - set(kw)
        if unknown:
            raise TypeError(f"replace got unknown field(s) {sorted(unknown)}; fields are {sorted(kw)}")
        kw.update(changes)
        return MDP(**kw)

    def penalised(self, penalties: ArrayLike) -> MDP:
        """The MDP with rewards ``R(s, a, s') - penalties . phi(s, a, s')``.

        Parameters
        ----------
        penalties : array_like, shape (n_features,)

        Returns
        -------
        MDP

        Examples
        --------
        >>> import numpy as np
        >>> f = TransitionFeatures(action=np.eye(2), n_states=2)
        >>> mdp = MDP.from_dense(np.full((2, 2, 2), 0.5), features=f)
        >>> mdp.penalised([0.0, 3.0]).rewards[0, 1].tolist()
        [-3.0, -3.0]
        """
        if self.features is None:
            raise ValueError("penalised needs an MDP with features (got features=None)")
        values = self.features.transition_values(
            self.features.check_weights(penalties, "penalties"), self.next_states
        )
        return self.replace(rewards=self.rewards - values)

    # -------------------------------------------------------------- helpers
    def expected_rewards(self) -> np.ndarray:
        """Expected reward ``r[s, a] = sum_k probs[s, a, k] rewards[s, a, k]`` (zero at terminals), shape (S, A)."""
        no_penalty = np.zeros(self.n_states)
        return _kernels.penalised_expected_rewards(
            self.next_states, self.probs, self.rewards, self.terminal, no_penalty, np.zeros(self.n_actions), no_penalty
        )

    def dense_transitions(self) -> np.ndarray:
        """The dense tensor ``P[s, a, s']`` (for small MDPs and tests), shape (S, A, S)."""
        P = np.zeros((self.n_states, self.n_actions, self.n_states))
        s_idx, a_idx, _ = np.indices(self.probs.shape)
        np.add.at(P, (s_idx, a_idx, self.next_states), self.probs)
        return P

    def successor_index(self, s: int, a: int, s_next: int) -> int:
        """Slot ``k`` with ``next_states[s, a, k] == s_next`` and positive probability, or -1."""
        row = np.flatnonzero((self.next_states[s, a] == s_next) & (self.probs[s, a] > 0))
        return int(row[0]) if row.size else -1
