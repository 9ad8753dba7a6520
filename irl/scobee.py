"""The baseline: greedy maximum-likelihood inference of hard constraints (Scobee & Sastry, 2020).

Scobee & Sastry ("Maximum Likelihood Constraint Inference for Inverse
Reinforcement Learning", ICLR 2020) model demonstrations in a deterministic MDP
with the maximum entropy distribution over trajectories of a finite horizon,
``P(tau) = exp(R(tau)) / Z_C`` for every trajectory ``tau`` that satisfies the
constraint set ``C`` and 0 otherwise. A candidate constraint here is one
transition feature of the MDP (for a :class:`~irl.gridworld.GridWorld`: a
state, an action or a colour); a trajectory violates it when one of its
transitions has that feature (``phi_c(s, a, s') != 0``), or when it starts in a
state whose destination feature it is (the state is occupied).

Adding a constraint ``c`` that no demonstration violates leaves ``R(tau_i)``
unchanged and shrinks the normaliser to ``Z_{C+c} = Z_C (1 - A_c)``, where
``A_c`` is the probability, under the current model, that a trajectory violates
``c``. The log-likelihood of ``N`` demonstrations therefore grows by
``-N log(1 - A_c)``: the most likely constraint is the one that removes the most
probability mass from non-demonstrated trajectories. The method adds
constraints greedily, one at a time, always in the model constrained by those
already chosen.

``A_c`` is computed for every candidate at once by the forward "feature
accrual" pass of Scobee & Sastry's Algorithm 1: the probability of being in
state ``s`` at time ``t`` having already accrued feature ``c``, propagated with
the time-indexed maximum entropy policy of the finite-horizon soft value
iteration (:func:`irl.planning.soft_value_iteration`).

Stopping rule: the Kullback-Leibler divergence from the empirical distribution
of the demonstrated *trajectories* to the model's trajectory distribution,

    KL(p_D || P_C) = sum_tau p_D(tau) log p_D(tau) - (1/N) sum_i log P_C(tau_i),

falls by exactly ``-log(1 - A_c)`` when ``c`` is added. The method stops when
that decrease is below ``min_kl_decrease``, when the divergence itself is at most
``kl_threshold``, or when no admissible candidate remains.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np
import scipy.sparse as sp

from ._validation import check_indices, split_trajectory, trajectory_list
from .mdp import MDP, _as_int, _as_real
from .planning import soft_value_iteration
from ._repr import compact_repr
from ._typing import ArrayLike
from .demonstrations import Demonstrations

__all__ = ["HardConstraintResult", "infer_hard_constraints"]

logger = logging.getLogger(__name__)

_HARD_PENALTY = 1.0e4
"""Penalty standing in for a removed transition: exp(-1e4) is exactly 0 in float64."""

_DETERMINISTIC_TOL = 1e-12

_MAX_ACCRUAL_CELLS = 50_000_000
"""Largest (transitions x candidates) array the accrual pass may hold (400 MB of float64)."""


# --------------------------------------------------------------------------- input


def _as_trajectories(demonstrations, n_states, n_actions):
    """Integer (states, actions) pairs with len(states) == len(actions) + 1."""
    if demonstrations is None:
        raise ValueError("demonstrations must hold at least one trajectory (got None)")
    out = []
    for i, traj in enumerate(trajectory_list(demonstrations, "demonstrations")):
        s, a = split_trajectory(traj, i, noun="demonstration", dicts=True)
        if s.size == 0:
            raise ValueError(f"demonstration {i} has no state")
        if s.size != a.size + 1:
            raise ValueError(
                f"demonstration {i} has {s.size} states and {a.size} actions; "
                "it must have one more state than actions"
            )
        check_indices(s, a, i, noun="demonstration", n_states=n_states, n_actions=n_actions)
        out.append((s.astype(np.int64), a.astype(np.int64)))
    return out


def _check_deterministic(mdp):
    live = ~mdp.terminal
    biggest = mdp.probs.max(axis=2)[live]
    if biggest.size and np.min(biggest) < 1.0 - _DETERMINISTIC_TOL:
        s, a = np.argwhere((mdp.probs.max(axis=2) < 1.0 - _DETERMINISTIC_TOL) & live[:, None])[0]
        raise ValueError(
            "Scobee & Sastry's method assumes deterministic transitions, but state "
            f"{int(s)} action {int(a)} has several successors (largest probability "
            f"{mdp.probs[s, a].max():.3g}); use a world with p_slip=0, or MESC-IRL for stochastic worlds"
        )


def _candidate_mask(candidates, n_features):
    if candidates is None:
        return np.ones(n_features, dtype=bool)
    arr = np.asarray(candidates)
    if arr.size == 0:
        raise ValueError("candidates must name at least one feature (got none); pass None to "
                         "consider every feature")
    if arr.dtype == bool:
        if arr.shape != (n_features,):
            raise ValueError(f"candidates as a mask must have shape ({n_features},) (got {arr.shape})")
        return arr.copy()
    if arr.ndim != 1 or (arr.size and not np.issubdtype(arr.dtype, np.integer)):
        raise TypeError(f"candidates must be feature indices or a boolean mask (got dtype {arr.dtype})")
    if arr.size and (arr.min() < 0 or arr.max() >= n_features):
        bad = int(arr.max() if arr.max() >= n_features else arr.min())
        raise ValueError(f"candidates must be feature indices in [0, {n_features}) (got {bad})")
    mask = np.zeros(n_features, dtype=bool)
    mask[arr] = True
    return mask


def _nonempty(mask):
    if not mask.any():
        raise ValueError("candidates must name at least one feature (got none); pass None to "
                         "consider every feature")
    return mask


# --------------------------------------------------------------------------- model pieces


class _Transitions:
    """The live transitions of a deterministic MDP and the features each one has."""

    def __init__(self, mdp):
        S = mdp.n_states
        feats = mdp.features
        s_idx, a_idx, k_idx = np.nonzero((mdp.probs > 0) & ~mdp.terminal[:, None, None])
        self.src = s_idx
        self.act = a_idx
        self.dst = mdp.next_states[s_idx, a_idx, k_idx]
        self.prob = mdp.probs[s_idx, a_idx, k_idx]
        phi = feats.source[self.src] + feats.action[self.act] + feats.destination[self.dst]
        self.has = sp.csr_array(sp.csr_array(phi) != 0, dtype=np.float64)  # (E, F), 1 where c is on
        self.start_has = sp.csr_array(feats.destination != 0, dtype=np.float64)  # (S, F): occupying s
        n_e = self.src.size
        self.index = {(int(a), int(b), int(c)): e for e, (a, b, c) in enumerate(zip(self.src, self.act, self.dst))}
        self.scatter = sp.csr_array((np.ones(n_e), (self.dst, np.arange(n_e))), shape=(S, n_e))
        self.terminal = mdp.terminal
        self.n_features = phi.shape[1]

    def accrual(self, policy, start, columns=None):
        """A[c] = P(a trajectory violates c) under the time-indexed ``policy`` (Algorithm 1).

        Only the features in ``columns`` (default all) are tracked; the others are 0.
        """
        cols = np.arange(self.n_features) if columns is None else np.asarray(columns, dtype=np.int64)
        out = np.zeros(self.n_features)
        if cols.size == 0:
            return out
        has = self.has[:, cols].toarray()
        d = start.copy()
        acc = start[:, None] * self.start_has[:, cols].toarray()
        done = np.zeros(cols.size)
        for t in range(policy.shape[0]):
            w = policy[t, self.src, self.act] * self.prob  # P(a, s' | s) for each live transition
            acc_src = acc[self.src]
            d_src = d[self.src]
            contrib = w[:, None] * (acc_src + (d_src[:, None] - acc_src) * has)
            acc = self.scatter @ contrib
            d = self.scatter @ (w * d_src)
            if self.terminal.any():
                done += acc[self.terminal].sum(axis=0)
                acc[self.terminal] = 0.0
                d[self.terminal] = 0.0
        out[cols] = np.clip(done + acc.sum(axis=0), 0.0, 1.0)
        return out

    def violated(self, trajs):
        """Features that some demonstration has (on a transition, or by occupying its first state)."""
        rows = []
        for s, a in trajs:
            for t in range(a.size):
                key = (int(s[t]), int(a[t]), int(s[t + 1]))
                e = self.index.get(key)
                if e is None:
                    raise ValueError(
                        f"a demonstration takes action {key[1]} in state {key[0]} to state {key[2]}, "
                        "a transition the MDP does not allow"
                    )
                rows.append(e)
        hit = np.zeros(self.n_features, dtype=bool)
        if rows:
            hit |= np.asarray(self.has[np.unique(rows)].sum(axis=0)).ravel() > 0
        starts = np.unique([int(s[0]) for s, _ in trajs])
        hit |= np.asarray(self.start_has[starts].sum(axis=0)).ravel() > 0
        return hit


def _log_likelihoods(trajs, mdp, log_policy):
    """log P_C(tau_i) = log start(s_0) + sum_t log pi_t(a_t | s_t) (deterministic transitions)."""
    out = np.empty(len(trajs))
    H = log_policy.shape[0]
    with np.errstate(divide="ignore"):
        log_start = np.log(mdp.start)
    for i, (s, a) in enumerate(trajs):
        n = a.size
        if n > H:
            raise ValueError(
                f"demonstration {i} takes {n} steps, more than the horizon {H}; "
                "pass a horizon at least as long as the longest demonstration"
            )
        out[i] = log_start[s[0]] + log_policy[np.arange(n), s[:n], a[:n]].sum()
    return out


def _empirical_entropy(trajs):
    keys = {}
    for s, a in trajs:
        k = (s.tobytes(), a.tobytes())
        keys[k] = keys.get(k, 0) + 1
    p = np.array(list(keys.values()), dtype=np.float64) / len(trajs)
    return float(-np.sum(p * np.log(p)))


# --------------------------------------------------------------------------- result


@dataclass(frozen=True, eq=False)
class HardConstraintResult:
    """Hard constraints inferred by :func:`infer_hard_constraints`, in the order they were added.

    Attributes
    ----------
    constraints : ndarray of int, shape (n_constraints,)
        Feature indices of the inferred constraints, most likely first.
    names : tuple of str
        Their feature names.
    eliminated_mass : ndarray, shape (n_constraints,)
        ``A_c``: the share of the model's remaining trajectory mass each
        constraint removed when it was added.
    kl : ndarray, shape (n_constraints,)
        ``KL(p_D || P_C)`` (nats) after each addition.
    kl_initial : float
        The divergence of the unconstrained nominal model.
    log_likelihood : ndarray, shape (n_constraints,)
        Mean log-likelihood of the demonstrations after each addition.
    mask : ndarray of bool, shape (n_features,)
        True on the inferred constraints.
    stop_reason : str
        ``"kl_decrease"``, ``"kl_threshold"``, ``"no_candidate"`` or ``"max_constraints"``.
    horizon : int
        Horizon of the trajectory distribution.
    n_iter : int
        Greedy steps taken (candidates evaluated for addition).

    Examples
    --------
    >>> from irl.gridworld import GridWorld
    >>> world = GridWorld(3, 0, 2, p_slip=0.0)
    >>> res = infer_hard_constraints(world.nominal_mdp, [([0, 3, 4, 5, 2], [2, 1, 1, 3])])
    >>> res.n_constraints == len(res.names) == int(res.mask.sum()), res.stop_reason
    (True, 'kl_decrease')
    >>> bool(res.kl[-1] < res.kl_initial)
    True
    """

    __repr__ = compact_repr

    constraints: np.ndarray
    names: tuple
    eliminated_mass: np.ndarray
    kl: np.ndarray
    kl_initial: float
    log_likelihood: np.ndarray
    mask: np.ndarray
    stop_reason: str
    horizon: int
    n_iter: int

    @property
    def n_constraints(self) -> int:
        """Number of inferred constraints (``len(constraints)``)."""
        return int(self.constraints.size)

    def summary(self) -> str:
        """The inferred constraints in order, with the KL divergence after each, as text.

        Examples
        --------
        >>> from irl.gridworld import GridWorld
        >>> world = GridWorld(3, 0, 2, p_slip=0.0)
        >>> res = infer_hard_constraints(world.nominal_mdp, [([0, 3, 4, 5, 2], [2, 1, 1, 3])])
        >>> print(res.summary())
        4 hard constraints (stopped: kl_decrease), horizon 8, KL of the nominal model 8.4543
          #  constraint               removed mass         KL
          1  state 1                        0.9699     4.9516
          2  action down_right              0.9121     2.5198
          3  action up_right                0.8960     0.2561
          4  action up_left                 0.1604     0.0812
        """
        rows = [f"{'#':>3s}  {'constraint':<24s} {'removed mass':>12s} {'KL':>10s}"]
        rows += [f"{k + 1:3d}  {name:<24s} {m:12.4f} {kl:10.4f}"
                 for k, (name, m, kl) in enumerate(zip(self.names, self.eliminated_mass,
                                                       self.kl))]
        return (f"{self.n_constraints} hard constraints (stopped: {self.stop_reason}), "
                f"horizon {self.horizon}, KL of the nominal model {self.kl_initial:.4f}\n"
                + "\n".join(rows))

    def penalties(self, penalty: float = _HARD_PENALTY) -> np.ndarray:
        """Penalty vector putting ``penalty`` on each inferred constraint, shape (n_features,).

        ``mdp.penalised(result.penalties())`` is the inferred constrained MDP.

        Examples
        --------
        >>> from irl.gridworld import GridWorld
        >>> world = GridWorld(3, 0, 2, p_slip=0.0)
        >>> res = infer_hard_constraints(world.nominal_mdp, [([0, 3, 4, 5, 2], [2, 1, 1, 3])])
        >>> pen = res.penalties(50.0)
        >>> float(pen.max()), int((pen > 0).sum()) == res.n_constraints
        (50.0, True)
        """
        penalty = _as_real("penalty", penalty, low=0.0)
        return np.where(self.mask, penalty, 0.0)

    def policy(self, mdp: MDP) -> np.ndarray:
        """The inferred model's policy: maximum entropy in ``mdp`` with the constraints imposed.

        Parameters
        ----------
        mdp : MDP
            The nominal MDP the constraints were inferred in.

        Returns
        -------
        ndarray, shape (horizon, n_states, n_actions)
            Time-indexed policy of the undiscounted finite-horizon soft value
            iteration; under it every trajectory that violates an inferred
            constraint has probability zero. Sample it with
            :func:`irl.demonstrations.sample_trajectories` and
            ``max_steps=result.horizon``.

        Examples
        --------
        >>> from irl.gridworld import GridWorld
        >>> world = GridWorld(3, 0, 2, p_slip=0.0)
        >>> res = infer_hard_constraints(world.nominal_mdp, [([0, 3, 4, 5, 2], [2, 1, 1, 3])], horizon=6)
        >>> pol = res.policy(world.nominal_mdp)
        >>> pol.shape, float(pol[0, 0, 1])  # moving right from 0 enters the forbidden cell 1
        ((6, 9, 8), 0.0)
        """
        if not isinstance(mdp, MDP) or mdp.features is None:
            raise TypeError(f"mdp must be an irl.MDP with features (got {type(mdp).__name__})")
        if mdp.n_features != self.mask.size:
            raise ValueError(
                f"mdp must have the {self.mask.size} features the constraints were inferred on "
                f"(got {mdp.n_features})"
            )
        model = mdp.replace(discount=1.0).penalised(self.penalties())
        return soft_value_iteration(model, horizon=self.horizon).policy


# --------------------------------------------------------------------------- algorithm


def infer_hard_constraints(
    mdp: MDP,
    demonstrations: Demonstrations | Sequence[Any],
    *,
    horizon: int | None = None,
    candidates: ArrayLike | None = None,
    min_kl_decrease: float = 0.1,
    kl_threshold: float | None = None,
    max_constraints: int | None = None,
) -> HardConstraintResult:
    """Greedy maximum-likelihood inference of hard constraints (Scobee & Sastry, 2020).

    Parameters
    ----------
    mdp : MDP
        The nominal MDP, deterministic (every non-terminal state-action pair
        has one successor), with transition features; each feature is a
        candidate constraint. Its discount is not used: the method's
        likelihood is that of undiscounted finite-horizon trajectories.
    demonstrations : Demonstrations or sequence
        Demonstrated trajectories in the true constrained world: a
        :class:`~irl.demonstrations.Demonstrations` set, or a sequence of
        objects with integer arrays ``.states`` and ``.actions`` (one more
        state than actions), ``(states, actions)`` pairs, or dicts with
        ``state_seq`` and ``action_seq`` (the paper's JSON files).
    horizon : int, optional
        Length ``T`` of the model's trajectories; at least the longest
        demonstration. Default: twice the longest demonstration.
    candidates : array_like of int or bool, optional
        Features that may become constraints (indices or a mask); default all.
    min_kl_decrease : float, optional
        Stop when adding the best admissible candidate would lower the
        trajectory KL divergence by less than this (nats; default 0.1).
    kl_threshold : float, optional
        Also stop once the KL divergence is at most this (default: no such rule).
    max_constraints : int, optional
        Upper bound on the number of constraints (default: no bound beyond
        the number of candidates).

    Returns
    -------
    HardConstraintResult

    Raises
    ------
    TypeError
        If ``mdp`` is not an :class:`~irl.mdp.MDP` or has no features.
    ValueError
        If the MDP is not deterministic, there is no demonstration, a
        demonstration leaves the MDP's transitions or is longer than the horizon.

    Notes
    -----
    A candidate is admissible if no demonstration has its feature: constraints
    that a demonstration violates would make the demonstrations impossible
    (likelihood zero). Constraints are imposed by a penalty of ``1e4`` on
    their features, which gives forbidden trajectories a probability of
    exactly zero in double precision. The step's KL decrease is
    ``-log(1 - A_c)`` with ``A_c`` the probability mass of trajectories that
    violate ``c`` under the current model; ties are broken by the lower
    feature index.

    Examples
    --------
    >>> from irl.gridworld import GridWorld
    >>> world = GridWorld(3, 0, 2, p_slip=0.0, discount=1.0)
    >>> demo = ([0, 3, 4, 5, 2], [2, 1, 1, 3])  # around the middle of the bottom row
    >>> res = infer_hard_constraints(world.nominal_mdp, [demo], horizon=6)
    >>> res.names[0]
    'state 1'
    """
    if not isinstance(mdp, MDP):
        raise TypeError(f"mdp must be an irl.MDP (got {type(mdp).__name__})")
    if mdp.features is None:
        raise TypeError("mdp must have transition features: each feature is a candidate constraint")
    _check_deterministic(mdp)
    trajs = _as_trajectories(demonstrations, mdp.n_states, mdp.n_actions)
    longest = max(a.size for _, a in trajs)
    if horizon is None:
        horizon = max(1, 2 * longest)
    horizon = _as_int("horizon", horizon)
    if horizon < longest:
        raise ValueError(
            f"horizon must be at least the longest demonstration ({longest} steps) (got {horizon})"
        )
    min_kl_decrease = _as_real("min_kl_decrease", min_kl_decrease, low=0.0)
    if kl_threshold is not None:
        kl_threshold = _as_real("kl_threshold", kl_threshold, low=0.0)
    if max_constraints is not None:
        max_constraints = _as_int("max_constraints", max_constraints, low=0)
    cand = _nonempty(_candidate_mask(candidates, mdp.n_features))

    base = mdp.replace(discount=1.0)
    trans = _Transitions(base)
    admissible = cand & ~trans.violated(trajs)
    cells = trans.src.size * int(admissible.sum())
    if cells > _MAX_ACCRUAL_CELLS:
        raise ValueError(
            f"the accrual pass would track {int(admissible.sum())} candidate features over "
            f"{trans.src.size} transitions ({8 * cells / 1e9:.1f} GB per step); "
            "pass candidates= to restrict the search"
        )
    entropy = _empirical_entropy(trajs)
    names = base.features.names

    chosen: list[int] = []
    masses: list[float] = []
    kls: list[float] = []
    lls: list[float] = []
    penalties = np.zeros(mdp.n_features)

    def fit_model(pen):
        model = base.penalised(pen) if pen.any() else base
        res = soft_value_iteration(model, horizon=horizon)
        log_pol = res.q_values - res.values[:-1, :, None]
        ll = _log_likelihoods(trajs, model, log_pol)
        return res.policy, float(ll.mean())

    policy, mean_ll = fit_model(penalties)
    kl_initial = -entropy - mean_ll
    kl_now = kl_initial
    stop = "no_candidate"
    n_iter = 0
    # Each pass adds one admissible candidate or stops, so this loop always ends by a break.
    for _ in range(int(admissible.sum()) + 1):
        if kl_threshold is not None and kl_now <= kl_threshold:
            stop = "kl_threshold"
            break
        if max_constraints is not None and len(chosen) >= max_constraints:
            stop = "max_constraints"
            break
        n_iter += 1
        mass = trans.accrual(policy, base.start, np.flatnonzero(admissible))
        score = np.where(admissible, mass, -np.inf)
        best = int(np.argmax(score))
        a_best = float(mass[best])
        if not np.isfinite(score[best]) or a_best <= 0.0:
            stop = "no_candidate"
            break
        decrease = -np.log1p(-a_best) if a_best < 1.0 else np.inf
        if decrease < min_kl_decrease:
            stop = "kl_decrease"
            break
        penalties[best] = _HARD_PENALTY
        admissible[best] = False
        policy, mean_ll = fit_model(penalties)
        kl_now = -entropy - mean_ll
        chosen.append(best)
        masses.append(a_best)
        kls.append(kl_now)
        lls.append(mean_ll)
        logger.debug("added %s (eliminated mass %.4g, KL %.4g)", names[best], a_best, kl_now)

    mask = np.zeros(mdp.n_features, dtype=bool)
    mask[chosen] = True
    return HardConstraintResult(
        constraints=np.array(chosen, dtype=np.int64),
        names=tuple(names[c] for c in chosen),
        eliminated_mass=np.array(masses),
        kl=np.array(kls),
        kl_initial=float(kl_initial),
        log_likelihood=np.array(lls),
        mask=mask,
        stop_reason=stop,
        horizon=horizon,
        n_iter=n_iter,
    )
