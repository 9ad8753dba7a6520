"""The paper's gridworld: any size, eight moves, slip, coloured cells and soft constraints.

Conventions
-----------
- A ``size x size`` grid; cell ``(x, y)`` is state ``s = y * size + x`` (x is the
  column, y the row; ``y`` grows "up").
- Eight actions, in the order of the paper's code (:data:`ACTIONS`):
  left, right, up, down, up_left, up_right, down_left, down_right, with moves
  ``(dx, dy)`` given by :data:`ACTION_MOVES`.
- Slip: with probability ``p_slip`` the executed action is drawn uniformly from
  all eight actions, so the intended one has probability ``1 - p_slip + p_slip / 8``.
- A move that would leave the grid is clipped to the nearest cell inside it
  (``boundary="clip"``: a diagonal move along an edge slides along the edge);
  ``boundary="stay"`` keeps the agent in place instead.
- Features of a transition (s, a, s'), in this order: one-hot destination state
  (``size**2``), one-hot chosen action (8), one-hot colour of the destination
  (none, blue, green): ``size**2 + 11`` features (92 for 9 x 9).
- Nominal reward: ``-step_cost`` per cardinal move, ``-step_cost * sqrt(2)`` per
  diagonal move (of the chosen action), ``+goal_reward`` on entering the goal,
  which is absorbing. Each true constraint adds ``-penalty`` to every transition
  that has its feature (penalties add up).
"""

from __future__ import annotations

import math
from dataclasses import KW_ONLY, dataclass, fields
from functools import cached_property
from typing import Any, Sequence

import numpy as np

from . import _kernels
from .mdp import MDP, TransitionFeatures, _as_int, _as_real
from ._typing import SeedLike

__all__ = ["ACTIONS", "ACTION_MOVES", "COLOURS", "GridWorld"]

ACTIONS = ("left", "right", "up", "down", "up_left", "up_right", "down_left", "down_right")
"""Action names, index = action number."""

ACTION_MOVES = ((-1, 0), (1, 0), (0, 1), (0, -1), (-1, 1), (1, 1), (-1, -1), (1, -1))
"""``(dx, dy)`` of each action."""

COLOURS = ("none", "blue", "green")
"""Cell colours, index = colour number."""


def _index_tuple(name, values, high, names=None):
    if isinstance(values, (str, bytes, dict)) or not hasattr(values, "__iter__"):
        raise TypeError(f"{name} must be a sequence of indices (got {values!r})")
    out = []
    for v in values:
        if names is not None and isinstance(v, str):
            if v not in names:
                raise ValueError(f"{name} must hold names from {names} or indices (got {v!r})")
            out.append(names.index(v))
            continue
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)):
            raise TypeError(f"{name} must hold integer indices (got {v!r})")
        if not 0 <= int(v) < high:
            raise ValueError(f"{name} must hold indices in [0, {high}) (got {int(v)})")
        out.append(int(v))
    if len(set(out)) != len(out):
        dup = sorted({x for x in out if out.count(x) > 1})
        raise ValueError(f"{name} must not repeat entries (got duplicates {dup})")
    return tuple(out)


@dataclass(frozen=True, eq=False)
class GridWorld:
    """The gridworld of the paper (DESIGN.md section 3), with its true soft constraints.

    Parameters
    ----------
    size : int
        Width and height (>= 2).
    start, goal : int
        Start state and absorbing goal state (distinct).
    blue, green : sequence of int
        Blue and green cells (disjoint).
    constrained_states : sequence of int
        States whose entering costs ``penalty``.
    constrained_actions : sequence of int or str
        Actions (indices or names from :data:`ACTIONS`) that cost ``penalty``.
    constrained_colours : sequence of int or str
        Colours (indices or names from :data:`COLOURS`) whose entering costs ``penalty``.
    p_slip : float
        Probability that the executed action is uniform over all eight.
    penalty : float
        Size (>= 0) of each true constraint's penalty; the paper uses 50.
    step_cost, goal_reward : float
        Nominal reward parameters (4 and 10 in the paper).
    discount : float
        Discount of the MDPs built from the world (default 1; see docs/irl.md, Decisions).
    boundary : {"clip", "stay"}
        What a move off the grid does.

    Notes
    -----
    ``nominal_mdp`` has the nominal reward R_N; ``constrained_mdp`` has the true
    R_C = R_N - omega* . phi with omega* = ``true_penalties`` (``penalty`` on each
    constrained feature). Both carry the features, so MESC-IRL can learn
    omega from demonstrations of ``constrained_mdp``.

    Examples
    --------
    >>> w = GridWorld(9, 0, 8, blue=[4, 13, 22], constrained_states=[31], constrained_actions=["up_left"])
    >>> w.n_states, w.n_features
    (81, 92)
    >>> w.feature_names[31], w.feature_names[81 + 4], w.feature_names[91]
    ('state 31', 'action up_left', 'colour green')
    >>> round(float(w.true_penalties.sum()), 1)
    100.0
    """

    size: int
    start: int
    goal: int
    _: KW_ONLY
    blue: tuple = ()
    green: tuple = ()
    constrained_states: tuple = ()
    constrained_actions: tuple = ()
    constrained_colours: tuple = ()
    p_slip: float = 0.1
    penalty: float = 50.0
    step_cost: float = 4.0
    goal_reward: float = 10.0
    discount: float = 1.0
    boundary: str = "clip"

    def __post_init__(self):
        size = _as_int("size", self.size, low=2)
        n = size * size
        start = _index_tuple("start", [self.start], n)[0]
        goal = _index_tuple("goal", [self.goal], n)[0]
        if start == goal:
            raise ValueError(f"start and goal must differ (got both {start})")
        blue = _index_tuple("blue", self.blue, n)
        green = _index_tuple("green", self.green, n)
        both = sorted(set(blue) & set(green))
        if both:
            raise ValueError(f"blue and green must be disjoint (cells {both} are in both)")
        set_ = object.__setattr__
        set_(self, "size", size)
        set_(self, "start", start)
        set_(self, "goal", goal)
        set_(self, "blue", blue)
        set_(self, "green", green)
        set_(self, "constrained_states", _index_tuple("constrained_states", self.constrained_states, n))
        set_(self, "constrained_actions", _index_tuple("constrained_actions", self.constrained_actions, 8, ACTIONS))
        set_(self, "constrained_colours", _index_tuple("constrained_colours", self.constrained_colours, 3, COLOURS))
        set_(self, "p_slip", _as_real("p_slip", self.p_slip, low=0.0, high=1.0))
        set_(self, "penalty", _as_real("penalty", self.penalty, low=0.0))
        set_(self, "step_cost", _as_real("step_cost", self.step_cost))
        set_(self, "goal_reward", _as_real("goal_reward", self.goal_reward))
        set_(self, "discount", _as_real("discount", self.discount, low=0.0, high=1.0, low_open=True))
        if not isinstance(self.boundary, str) or self.boundary not in ("clip", "stay"):
            raise ValueError(f"boundary must be 'clip' or 'stay' (got {self.boundary!r})")

    # ----------------------------------------------------------------- sizes
    @property
    def n_states(self) -> int:
        """Number of cells, ``size**2``."""
        return self.size * self.size

    @property
    def n_actions(self) -> int:
        """Eight moves."""
        return len(ACTIONS)

    @property
    def n_features(self) -> int:
        """``size**2 + 8 + 3``."""
        return self.n_states + self.n_actions + len(COLOURS)

    @property
    def feature_slices(self) -> dict:
        """Slices of the ``"state"``, ``"action"`` and ``"colour"`` blocks of the feature vector."""
        S, A = self.n_states, self.n_actions
        return {"state": slice(0, S), "action": slice(S, S + A), "colour": slice(S + A, S + A + len(COLOURS))}

    @cached_property
    def feature_names(self) -> tuple:
        """``"state s"``, ``"action name"``, ``"colour name"``, in feature order."""
        return (
            tuple(f"state {s}" for s in range(self.n_states))
            + tuple(f"action {a}" for a in ACTIONS)
            + tuple(f"colour {c}" for c in COLOURS)
        )

    def state(self, x: int, y: int) -> int:
        """State index of cell ``(x, y)``."""
        return int(y) * self.size + int(x)

    def coords(self, s: int) -> tuple[int, int]:
        """Cell ``(x, y)`` of state ``s``."""
        return int(s) % self.size, int(s) // self.size

    @cached_property
    def colours(self) -> np.ndarray:
        """Colour index of every cell, shape (n_states,) (0 none, 1 blue, 2 green)."""
        c = np.zeros(self.n_states, dtype=np.int64)
        c[list(self.blue)] = 1
        c[list(self.green)] = 2
        c.flags.writeable = False
        return c

    # ------------------------------------------------------------- dynamics
    def move(self, s: int, a: int) -> int:
        """The cell reached from ``s`` by executing action ``a`` (no slip)."""
        x, y = self.coords(s)
        dx, dy = ACTION_MOVES[int(a)]
        nx, ny = x + dx, y + dy
        if 0 <= nx < self.size and 0 <= ny < self.size:
            return self.state(nx, ny)
        if self.boundary == "stay":
            return int(s)
        return self.state(min(max(nx, 0), self.size - 1), min(max(ny, 0), self.size - 1))

    def _moves(self):
        S = self.n_states
        x = np.arange(S) % self.size
        y = np.arange(S) // self.size
        d = np.asarray(ACTION_MOVES)
        nx = x[:, None] + d[None, :, 0]
        ny = y[:, None] + d[None, :, 1]
        inside = (nx >= 0) & (nx < self.size) & (ny >= 0) & (ny < self.size)
        cx = np.clip(nx, 0, self.size - 1)
        cy = np.clip(ny, 0, self.size - 1)
        dest = cy * self.size + cx
        if self.boundary == "stay":
            dest = np.where(inside, dest, np.arange(S)[:, None])
        return dest  # (S, 8): cell reached by executing each action

    @cached_property
    def features(self) -> TransitionFeatures:
        """Destination-state, action and destination-colour one-hot features (sparse)."""
        import scipy.sparse as sp

        S, A, F = self.n_states, self.n_actions, self.n_features
        dst = sp.csr_array(
            (np.ones(2 * S), (np.repeat(np.arange(S), 2), np.stack([np.arange(S), S + A + self.colours], 1).ravel())),
            shape=(S, F),
        )
        act = sp.csr_array((np.ones(A), (np.arange(A), S + np.arange(A))), shape=(A, F))
        return TransitionFeatures(action=act, destination=dst, names=self.feature_names, n_states=S)

    @cached_property
    def true_penalties(self) -> np.ndarray:
        """omega*: ``penalty`` on each constrained feature, zero elsewhere, shape (n_features,)."""
        w = np.zeros(self.n_features)
        sl = self.feature_slices
        w[[sl["state"].start + s for s in self.constrained_states]] = self.penalty
        w[[sl["action"].start + a for a in self.constrained_actions]] = self.penalty
        w[[sl["colour"].start + c for c in self.constrained_colours]] = self.penalty
        w.flags.writeable = False
        return w

    @cached_property
    def constraint_mask(self) -> np.ndarray:
        """Boolean mask of the truly constrained features, shape (n_features,)."""
        m = self.true_penalties > 0
        m.flags.writeable = False
        return m

    @cached_property
    def nominal_mdp(self) -> MDP:
        """The MDP with the nominal reward R_N (no constraints)."""
        S, A = self.n_states, self.n_actions
        dest = self._moves()
        slip = np.full((A, A), self.p_slip / A) + (1.0 - self.p_slip) * np.eye(A)  # [intended, executed]
        cand = np.broadcast_to(dest[:, None, :], (S, A, A))
        prob = np.broadcast_to(slip[None, :, :], (S, A, A))
        ns, probs = _kernels.merge_successors(np.ascontiguousarray(cand), np.ascontiguousarray(prob))
        cost = np.array([self.step_cost * math.hypot(*m) for m in ACTION_MOVES])
        rewards = -cost[None, :, None] + self.goal_reward * (ns == self.goal)
        rewards = np.broadcast_to(rewards, ns.shape)
        terminal = np.zeros(S, dtype=bool)
        terminal[self.goal] = True
        start = np.zeros(S)
        start[self.start] = 1.0
        return MDP(ns, probs, rewards, terminal=terminal, start=start, discount=self.discount, features=self.features)

    @cached_property
    def constrained_mdp(self) -> MDP:
        """The true constrained MDP, rewards ``R_N - true_penalties . phi``."""
        return self.nominal_mdp.penalised(self.true_penalties)

    def replace(self, **changes: Any) -> "GridWorld":
        """A new world with some fields changed, e.g. ``world.replace(p_slip=0.0)``."""
        kw = {f.name: getattr(self, f.name) for f in fields(self)}
        unknown = set(changes) - set(kw)
        if unknown:
            raise TypeError(f"replace got unknown field(s) {sorted(unknown)}; fields are {sorted(kw)}")
        kw.update(changes)
        size, start, goal = kw.pop("size"), kw.pop("start"), kw.pop("goal")
        return GridWorld(size, start, goal, **kw)

    # --------------------------------------------------------- construction
    def constraint_free_path_exists(self) -> bool:
        """Whether some deterministic path from start to goal avoids every true constraint.

        The path may use only unconstrained actions and may not enter a
        constrained state or a cell of a constrained colour.
        """
        banned = np.zeros(self.n_states, dtype=bool)
        banned[list(self.constrained_states)] = True
        for c in self.constrained_colours:
            banned |= self.colours == c
        if banned[self.goal]:
            return False
        dest = self._moves()
        allowed = [a for a in range(self.n_actions) if a not in self.constrained_actions]
        seen = np.zeros(self.n_states, dtype=bool)
        seen[self.start] = True
        frontier = [self.start]
        while frontier:  # each state enters the frontier at most once
            nxt = []
            for s in frontier:
                for a in allowed:
                    t = int(dest[s, a])
                    if not seen[t] and not banned[t]:
                        seen[t] = True
                        nxt.append(t)
            frontier = nxt
        return bool(seen[self.goal])

    @classmethod
    def random(
        cls,
        size: int = 9,
        *,
        rng: SeedLike = None,
        n_blue: int = 6,
        n_green: int = 6,
        n_constrained_states: int = 6,
        n_constrained_actions: int = 2,
        constrained_colours: Sequence[int | str] = ("blue", "green"),
        min_distance: float = 8.0,
        max_tries: int = 1000,
        **kwargs: Any,
    ) -> "GridWorld":
        """A random world as in the paper, without duplicate constraints and with a feasible goal.

        Blue, green and constrained cells are distinct cells drawn without
        replacement; start and goal are drawn from the remaining cells with
        Euclidean distance >= ``min_distance``; the constrained actions are
        distinct. Layouts in which no constraint-free path leads from start
        to goal (see :meth:`constraint_free_path_exists`) are redrawn.

        Parameters
        ----------
        size : int
        rng : None, int or numpy.random.Generator
        n_blue, n_green, n_constrained_states, n_constrained_actions : int
        constrained_colours : sequence of int or str
        min_distance : float
            Minimum Euclidean distance between start and goal, in cells.
        max_tries : int
            Layouts drawn before giving up with ValueError.
        **kwargs
            Other :class:`GridWorld` fields (``p_slip``, ``penalty``, ...).

        Examples
        --------
        >>> w = GridWorld.random(rng=0)
        >>> len(set(w.blue) | set(w.green) | set(w.constrained_states))
        18
        >>> w.constraint_free_path_exists()
        True
        >>> GridWorld.random(rng=0).constrained_states == w.constrained_states
        True
        """
        rng = np.random.default_rng(rng)
        size = _as_int("size", size, low=2)
        n = size * size
        counts = [_as_int(k, v, low=0) for k, v in (("n_blue", n_blue), ("n_green", n_green), ("n_constrained_states", n_constrained_states))]
        n_ca = _as_int("n_constrained_actions", n_constrained_actions, low=0)
        if n_ca > 8:
            raise ValueError(f"n_constrained_actions must be <= 8 (got {n_ca})")
        if sum(counts) + 2 > n:
            raise ValueError(f"a {size} x {size} grid has {n} cells, too few for {sum(counts)} special cells plus start and goal")
        min_distance = _as_real("min_distance", min_distance, low=0.0)
        if min_distance > math.hypot(size - 1, size - 1):
            raise ValueError(f"min_distance must be at most the diagonal of a {size} x {size} grid, "
                             f"{math.hypot(size - 1, size - 1):.4g} cells (got {min_distance:g})")
        max_tries = _as_int("max_tries", max_tries)
        xy = np.stack([np.arange(n) % size, np.arange(n) // size], 1)
        for _ in range(max_tries):
            cells = rng.choice(n, sum(counts), replace=False)
            blue = cells[: counts[0]]
            green = cells[counts[0]: counts[0] + counts[1]]
            cs = cells[counts[0] + counts[1]:]
            free = np.setdiff1d(np.arange(n), cells)
            pair = None
            for i in rng.permutation(free.size):  # start: uniform among cells with a partner
                dist = np.hypot(*(xy[free] - xy[free[i]]).T)
                partners = np.flatnonzero(dist >= max(min_distance, 1e-9))
                if partners.size:
                    pair = (i, partners[rng.integers(partners.size)])
                    break
            if pair is None:
                continue
            i, j = pair
            ca = rng.choice(8, n_ca, replace=False)
            world = cls(
                size, int(free[i]), int(free[j]),
                blue=tuple(int(v) for v in blue), green=tuple(int(v) for v in green),
                constrained_states=tuple(int(v) for v in cs), constrained_actions=tuple(int(v) for v in ca),
                constrained_colours=tuple(constrained_colours), **kwargs,
            )
            if world.constraint_free_path_exists():
                return world
        raise ValueError(
            f"no layout with a constraint-free path from start to goal at distance >= {min_distance} "
            f"was found in {max_tries} tries; use fewer special cells or a larger grid"
        )

    @classmethod
    def from_dict(cls, entry: dict, **kwargs: Any) -> "GridWorld":
        """A world from one entry of the paper's JSON files (``-50`` marks a true constraint).

        Parameters
        ----------
        entry : dict
            With ``start``, ``goal``, ``blue``, ``green``, ``state_reward``
            (size**2), ``action_reward`` (8) and ``color_reward`` (3).
        **kwargs
            Other fields (``p_slip``, ``discount``, ...). ``penalty`` (default 50)
            is also the marker looked for.

        Examples
        --------
        >>> e = {"start": 0, "goal": 3, "blue": [1], "green": [], "state_reward": [0, -50, 0, 10],
        ...      "action_reward": [-4] * 7 + [-50], "color_reward": [0, -50, 0]}
        >>> w = GridWorld.from_dict(e)
        >>> w.size, w.constrained_states, w.constrained_actions, w.constrained_colours
        (2, (1,), (7,), (1,))
        """
        for key in ("start", "goal", "state_reward", "action_reward", "color_reward"):
            if key not in entry:
                raise ValueError(f"entry must have the key {key!r} (got keys {sorted(entry)})")
        sr = np.asarray(entry["state_reward"], dtype=float)
        size = int(round(math.sqrt(sr.size)))
        if size * size != sr.size:
            raise ValueError(f"state_reward must have size**2 entries (got {sr.size})")
        ar = np.asarray(entry["action_reward"], dtype=float)
        cr = np.asarray(entry["color_reward"], dtype=float)
        if ar.size != 8 or cr.size != 3:
            raise ValueError(f"action_reward and color_reward must have 8 and 3 entries (got {ar.size} and {cr.size})")
        marker = -float(kwargs.get("penalty", 50.0))
        hit = lambda v: np.flatnonzero(np.isclose(v, marker)).tolist()  # noqa: E731
        return cls(
            size, int(entry["start"]), int(entry["goal"]),
            blue=tuple(entry.get("blue", ())), green=tuple(entry.get("green", ())),
            constrained_states=tuple(hit(sr)), constrained_actions=tuple(hit(ar)),
            constrained_colours=tuple(hit(cr)), **kwargs,
        )

    def to_dict(self) -> dict:
        """The world in the paper's JSON format (inverse of :meth:`from_dict` for the layout)."""
        sr = np.zeros(self.n_states)
        sr[self.goal] = self.goal_reward
        sr[list(self.constrained_states)] = -self.penalty
        ar = [-self.step_cost * math.hypot(*m) for m in ACTION_MOVES]
        for a in self.constrained_actions:
            ar[a] = -self.penalty
        cr = [0.0, 0.0, 0.0]
        for c in self.constrained_colours:
            cr[c] = -self.penalty
        return {
            "start": self.start, "goal": self.goal, "blue": list(self.blue), "green": list(self.green),
            "state_reward": sr.tolist(), "action_reward": ar, "color_reward": cr,
        }
