"""Demonstrations: sets of trajectories, sampling from a policy, and expert demonstrations.

A trajectory is a sequence of transitions ``(s_t, a_t, s_{t+1})``, t = 0..T-1.
:class:`Demonstrations` stores a set of them flat: trajectory ``i`` is
``states[offsets[i]:offsets[i + 1]]`` (and the same slice of ``actions`` and
``next_states``).
"""

from __future__ import annotations

import warnings
from typing import Sequence
from dataclasses import dataclass

import numpy as np

from . import _kernels
from .mdp import MDP, _as_int, _check_size
from .planning import check_policy, soft_value_iteration
from ._repr import compact_repr
from ._typing import ArrayLike, SeedLike

__all__ = ["Demonstrations", "sample_trajectories", "generate_demonstrations"]


def _sequences(name, value):
    """``value`` as a list, or a TypeError naming it when it is not a sequence."""
    if isinstance(value, (str, bytes, dict)) or not hasattr(value, "__iter__"):
        raise TypeError(f"{name} must be a sequence (got {type(value).__name__})")
    return list(value)


def _ints(name, value):
    arr = np.asarray(value)
    if arr.size and not np.issubdtype(arr.dtype, np.integer):
        raise TypeError(f"{name} must hold integers (got dtype {arr.dtype})")
    arr = np.array(arr, dtype=np.int64, copy=True).ravel()
    if arr.size and arr.min() < 0:
        raise ValueError(f"{name} must hold non-negative indices (got {arr.min()})")
    arr.flags.writeable = False
    return arr


@dataclass(frozen=True, eq=False)
class Demonstrations:
    """A set of trajectories, stored flat.

    Parameters
    ----------
    offsets : array_like of int, shape (n_trajectories + 1,)
        Trajectory ``i`` is transitions ``offsets[i]:offsets[i + 1]``; ``offsets[0] = 0``.
    states, actions, next_states : array_like of int, shape (n_transitions,)
        ``s_t``, ``a_t`` and ``s_{t+1}`` of every transition.
    reached_terminal : array_like of bool, shape (n_trajectories,), optional
        Whether each trajectory ended by entering a terminal state (``None``: unknown).

    Notes
    -----
    Every trajectory has at least one transition and is contiguous
    (``next_states[t] == states[t + 1]`` inside a trajectory). Use
    :meth:`check` to verify the transitions against an MDP.

    Examples
    --------
    >>> d = Demonstrations.from_sequences([[0, 1, 2], [0, 2]], [[1, 1], [5]])
    >>> len(d), d.n_transitions, d.lengths.tolist()
    (2, 3, [2, 1])
    >>> d.trajectory(0)
    ([0, 1, 2], [1, 1])
    """

    __repr__ = compact_repr

    offsets: np.ndarray
    states: np.ndarray
    actions: np.ndarray
    next_states: np.ndarray
    reached_terminal: np.ndarray | None = None

    def __post_init__(self):
        off = _ints("offsets", self.offsets)
        st, ac, ns = (_ints(k, getattr(self, k)) for k in ("states", "actions", "next_states"))
        if off.size < 2:
            raise ValueError("demonstrations must hold at least one trajectory (got none)")
        if off[0] != 0 or off[-1] != st.size or np.any(np.diff(off) < 0):
            raise ValueError(
                f"offsets must rise from 0 to the number of transitions ({st.size}) (got {off[0]} .. {off[-1]})"
            )
        if not (st.size == ac.size == ns.size):
            raise ValueError(
                f"states, actions and next_states must have equal length (got {st.size}, {ac.size}, {ns.size})"
            )
        empty = np.flatnonzero(np.diff(off) == 0)
        if empty.size:
            raise ValueError(f"every trajectory must have at least one transition (trajectory {empty[0]} is empty)")
        inner = np.ones(st.size, dtype=bool)
        inner[off[1:] - 1] = False  # last transition of each trajectory
        broken = np.flatnonzero(inner[:-1] & (ns[:-1] != st[1:]))
        if broken.size:
            t = int(broken[0])
            i = int(np.searchsorted(off, t, side="right") - 1)
            raise ValueError(
                f"trajectory {i} is not contiguous: transition {t - off[i]} ends in {ns[t]} "
                f"but the next one starts in {st[t + 1]}"
            )
        reached = None
        if self.reached_terminal is not None:
            reached = np.array(self.reached_terminal, dtype=bool, copy=True).ravel()
            if reached.size != off.size - 1:
                raise ValueError(
                    f"reached_terminal must have one entry per trajectory ({off.size - 1}) (got {reached.size})"
                )
            reached.flags.writeable = False
        for key, val in (("offsets", off), ("states", st), ("actions", ac), ("next_states", ns), ("reached_terminal", reached)):
            object.__setattr__(self, key, val)

    # ---------------------------------------------------------------- views
    def __len__(self) -> int:
        return self.offsets.size - 1

    @property
    def n_transitions(self) -> int:
        """Total number of transitions."""
        return int(self.states.size)

    @property
    def lengths(self) -> np.ndarray:
        """Number of transitions of each trajectory, shape (n_trajectories,)."""
        return np.diff(self.offsets)

    @property
    def time_steps(self) -> np.ndarray:
        """Step index t of every transition within its trajectory, shape (n_transitions,)."""
        return np.arange(self.n_transitions) - np.repeat(self.offsets[:-1], self.lengths)

    @property
    def start_states(self) -> np.ndarray:
        """First state of each trajectory, shape (n_trajectories,)."""
        return self.states[self.offsets[:-1]]

    def trajectory(self, i: int) -> tuple[list[int], list[int]]:
        """``(state_sequence, action_sequence)`` of trajectory ``i`` as lists (T + 1 and T entries)."""
        i = int(i)
        if not 0 <= i < len(self):
            raise IndexError(f"trajectory index must be in [0, {len(self)}) (got {i})")
        a, b = self.offsets[i], self.offsets[i + 1]
        return self.states[a:b].tolist() + [int(self.next_states[b - 1])], self.actions[a:b].tolist()

    def subset(self, indices: ArrayLike) -> "Demonstrations":
        """The trajectories at ``indices`` (in that order; negative indices count from the end),
        or those where a boolean mask of one entry per trajectory is True.

        Examples
        --------
        >>> d = Demonstrations.from_sequences([[0, 1], [1, 2], [2, 0]], [[0], [0], [1]])
        >>> d.subset([2, 0]).trajectory(0)
        ([2, 0], [1])
        """
        raw = np.asarray(indices)
        if raw.dtype == np.bool_:  # a mask, as in numpy indexing (not 0/1 indices)
            if raw.shape != (len(self),):
                raise ValueError(f"a boolean indices mask must have one entry per trajectory ({len(self)}) "
                                 f"(got shape {raw.shape})")
            raw = np.flatnonzero(raw)
        elif raw.size and not np.issubdtype(raw.dtype, np.integer):
            raise TypeError(f"indices must be integers or a boolean mask (got dtype {raw.dtype})")
        idx = raw.astype(np.int64).ravel()
        if idx.size == 0:
            raise ValueError("indices must select at least one trajectory (got none)")
        if idx.min() < -len(self) or idx.max() >= len(self):
            raise ValueError(f"indices must lie in [-{len(self)}, {len(self)}) (got {idx.min()} .. {idx.max()})")
        idx = idx % len(self)
        parts = [np.arange(self.offsets[i], self.offsets[i + 1]) for i in idx]
        take = np.concatenate(parts)
        off = np.concatenate([[0], np.cumsum(self.lengths[idx])])
        reached = None if self.reached_terminal is None else self.reached_terminal[idx]
        return Demonstrations(off, self.states[take], self.actions[take], self.next_states[take], reached)

    # ------------------------------------------------------- constructors
    @classmethod
    def from_sequences(cls, state_sequences: Sequence[Sequence[int]],
                       action_sequences: Sequence[Sequence[int]]) -> "Demonstrations":
        """Build from per-trajectory state sequences (T + 1 states) and action sequences (T actions).

        This is the format of the paper's ``state_seq`` / ``action_seq`` lists.
        """
        ss = _sequences("state_sequences", state_sequences)
        aa = _sequences("action_sequences", action_sequences)
        if len(ss) == 0:
            raise ValueError("demonstrations must hold at least one trajectory (got none)")
        if len(ss) != len(aa):
            raise ValueError(
                f"state_sequences and action_sequences must have one entry per trajectory (got {len(ss)} and {len(aa)})"
            )
        st, ac, ns, lens = [], [], [], []
        for i, (s, a) in enumerate(zip(ss, aa)):
            s = _sequences(f"state_sequences[{i}]", s)
            a = _sequences(f"action_sequences[{i}]", a)
            if len(a) == 0:
                raise ValueError(
                    "action_sequences: every trajectory must have at least one transition "
                    f"(trajectory {i} is empty)"
                )
            if len(s) != len(a) + 1:
                raise ValueError(
                    f"trajectory {i} must have one more state than actions (got {len(s)} states, {len(a)} actions)"
                )
            st += s[:-1]
            ns += s[1:]
            ac += a
            lens.append(len(a))
        return cls(np.concatenate([[0], np.cumsum(lens)]), st, ac, ns)

    def to_dict(self) -> dict:
        """``{"state_seq": [...], "action_seq": [...]}`` as in the paper's JSON files."""
        seqs = [self.trajectory(i) for i in range(len(self))]
        return {"state_seq": [s for s, _ in seqs], "action_seq": [a for _, a in seqs]}

    # ------------------------------------------------------------ checking
    def check(self, mdp: MDP) -> np.ndarray:
        """Verify the trajectories against ``mdp``; return the successor slot of each transition.

        Raises ValueError naming the first trajectory with a state or action out
        of range, or a transition that has probability zero in ``mdp``, or that
        leaves a terminal state.

        Returns
        -------
        ndarray of int, shape (n_transitions,)
            ``k`` with ``mdp.next_states[s_t, a_t, k] == s_{t+1}``.
        """
        if not isinstance(mdp, MDP):
            raise TypeError(f"mdp must be an irl.MDP (got {type(mdp).__name__})")

        def where(mask):
            t = int(np.flatnonzero(mask)[0])
            i = int(np.searchsorted(self.offsets, t, side="right") - 1)
            return t, i, t - int(self.offsets[i])

        for name, arr, high in (("states", self.states, mdp.n_states), ("next_states", self.next_states, mdp.n_states),
                                ("actions", self.actions, mdp.n_actions)):
            bad = arr >= high
            if bad.any():
                t, i, step = where(bad)
                raise ValueError(
                    f"demonstrations {name} must be < {high} for this MDP (trajectory {i}, step {step} has {arr[t]})"
                )
        from_terminal = mdp.terminal[self.states]
        if from_terminal.any():
            t, i, step = where(from_terminal)
            raise ValueError(
                f"trajectory {i} acts from the terminal state {self.states[t]} at step {step}; "
                "trajectories must stop on entering a terminal state"
            )
        rows_s = mdp.next_states[self.states, self.actions]
        rows_p = mdp.probs[self.states, self.actions]
        match = (rows_s == self.next_states[:, None]) & (rows_p > 0)
        ok = match.any(axis=1)
        if not ok.all():
            t, i, step = where(~ok)
            raise ValueError(
                f"trajectory {i}, step {step}: the transition ({self.states[t]}, {self.actions[t]}, "
                f"{self.next_states[t]}) has probability zero in the MDP"
            )
        return match.argmax(axis=1)


def sample_trajectories(mdp: MDP, policy: ArrayLike, n: int, *, rng: SeedLike = None,
                        max_steps: int | None = None,
                        start: ArrayLike | None = None) -> Demonstrations:
    """Sample trajectories of a policy in an MDP.

    Parameters
    ----------
    mdp : MDP
    policy : array_like, shape (S, A) or (H, S, A)
        Stationary or time-indexed policy (step t >= H uses ``policy[H - 1]``).
    n : int
        Number of trajectories.
    rng : None, int or numpy.random.Generator
    max_steps : int, optional
        Steps after which a trajectory that has not entered a terminal state is
        cut (default: H for a time-indexed policy, else 1000). Cut trajectories
        are kept, flagged in ``reached_terminal``, and counted in a warning.
    start : array_like, shape (S,), optional
        Start distribution (default ``mdp.start``).

    Returns
    -------
    Demonstrations

    Examples
    --------
    >>> from irl import GridWorld, soft_value_iteration
    >>> mdp = GridWorld(3, 0, 8).nominal_mdp
    >>> pol = soft_value_iteration(mdp).policy
    >>> d = sample_trajectories(mdp, pol, 5, rng=0)
    >>> len(d), bool(d.reached_terminal.all())
    (5, True)
    """
    if not isinstance(mdp, MDP):
        raise TypeError(f"mdp must be an irl.MDP (got {type(mdp).__name__})")
    pol = check_policy(mdp, policy)
    n = _as_int("n", n)
    time_indexed = pol.ndim == 3
    if max_steps is None:
        max_steps = pol.shape[0] if time_indexed else 1000
    max_steps = _as_int("max_steps", max_steps)
    _check_size(f"n={n} trajectories of up to max_steps={max_steps} steps", n * max_steps)
    if start is None:
        p0 = mdp.start
    else:
        from .mdp import _as_float

        p0 = _as_float("start", start, ndim=1, shape=(mdp.n_states,))
        if p0.min() < 0 or abs(p0.sum() - 1) > 1e-8:
            raise ValueError("start must be a probability distribution over states")
    if not time_indexed:
        pol = pol[None]
    rng = np.random.default_rng(rng)
    off, st, ac, ns, reached = _kernels.sample_trajectories(
        mdp.next_states, mdp.probs, mdp.terminal, np.ascontiguousarray(pol), time_indexed,
        np.ascontiguousarray(p0), n, max_steps, rng,
    )
    if mdp.terminal.any() and not reached.all():
        warnings.warn(
            f"{int((~reached).sum())} of {n} trajectories did not reach a terminal state within "
            f"max_steps={max_steps}; they are kept and flagged in reached_terminal",
            RuntimeWarning,
            stacklevel=2,
        )
    if np.any(np.diff(off) == 0):
        raise ValueError("start must put no mass on terminal states: a trajectory would be empty")
    return Demonstrations(off, st, ac, ns, reached)


def generate_demonstrations(mdp: MDP, n: int, *, rng: SeedLike = None, horizon: int | None = None,
                            max_steps: int | None = None, max_iter: int = 10_000,
                            tol: float = 1e-10) -> Demonstrations:
    """Demonstrations from the soft (maximum causal entropy) policy of ``mdp``, as in the paper.

    Parameters
    ----------
    mdp : MDP
        Typically the true constrained MDP, e.g. ``GridWorld.constrained_mdp``.
    n : int
        Number of trajectories.
    rng : None, int or numpy.random.Generator
    horizon : int, optional
        ``None`` (default, as in the paper's code): the stationary soft policy.
        An int: the time-indexed policy of that horizon.
    max_steps, max_iter, tol
        Passed to :func:`sample_trajectories` and :func:`irl.soft_value_iteration`.

    Returns
    -------
    Demonstrations

    Raises
    ------
    ValueError
        If the stationary soft value iteration does not converge (its
        policy would not be the soft policy of ``mdp``).

    Examples
    --------
    >>> from irl import GridWorld
    >>> world = GridWorld.random(rng=0)
    >>> demos = generate_demonstrations(world.constrained_mdp, 10, rng=0)
    >>> len(demos), int(demos.start_states[0]) == world.start
    (10, True)
    """
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # replaced by the error below
        soft = soft_value_iteration(mdp, horizon=horizon, max_iter=max_iter, tol=tol)
    if not soft.converged:
        raise ValueError(
            f"the soft value iteration of mdp did not converge in max_iter={max_iter} iterations (tol={tol:g}), "
            "so its soft policy is not known; with discount 1 the soft values are infinite where, for example, a "
            "policy can stay away from the terminal states at a reward per step above "
            f"-log(n_actions) = {-np.log(mdp.n_actions):.3g} (the entropy of a uniform choice outweighs the "
            "cost). Use a discount < 1, a finite horizon=, or a larger max_iter"
        )
    return sample_trajectories(mdp, soft.policy, n, rng=rng, max_steps=max_steps)
