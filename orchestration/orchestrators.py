"""The three orchestrators of the paper's Section 4: Greedy, weighted average and MDFT.

Each combines, in every state ``s``, the softmax preferences ``sq_n(s, .)`` of a nominal
MDP and ``sq_c(s, .)`` of a constrained one (:class:`~orchestration.ActionPreferences`):

* Greedy: ``argmax_a max(q_c(s, a), q_n(s, a))`` (deterministic);
* weighted average (WA): ``p(a) = w_n sq_n(s, a) + w_c sq_c(s, a)``;
* MDFT: one MDFT deliberation over the feasible actions with ``M = [sq_n, sq_c]``
  (options x 2 attributes) and attention ``w = (w_n, w_c)``.

All share the small interface of :class:`Orchestrator`: ``action_probabilities(state)``
(the exact distribution of a decision), ``act(state, rng)`` (one decision) and
``decide_many(states, rng)`` (a batch of independent decisions, used by rollouts).
"""

from __future__ import annotations

import abc
import numbers
import warnings

import numpy as np

import mdft

from .preferences import ActionPreferences, action_preferences, check_state, check_states

__all__ = [
    "Orchestrator",
    "GreedyOrchestrator",
    "WeightedAverageOrchestrator",
    "MDFTOrchestrator",
]

#: Relative tolerance within which Q-values count as tied for Greedy.
GREEDY_TIE_RTOL = 1e-9

#: ``atol`` of :func:`mdft.threshold_probabilities` for the threshold distribution
#: conditional on deciding within ``n_steps`` (scaled by the probability of deciding).
THRESHOLD_ATOL = 1e-3

#: Undecided share above which the conditional distribution is asked again, tighter.
CONDITIONAL_RERUN = 0.01

#: Most restarts of a threshold deliberation that did not decide within ``n_steps``.
MAX_RESTARTS = 1000


def _check_weights(weights) -> np.ndarray:
    try:
        w = np.array(weights, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise TypeError(f"weights must be a pair of real numbers (w_n, w_c) (got {weights!r})") from exc
    if w.shape != (2,):
        raise ValueError(f"weights must be a pair (w_n, w_c) (got shape {w.shape}: {weights!r})")
    if not np.all(np.isfinite(w)) or w.min() < 0:
        raise ValueError(f"weights must be finite and non-negative (got {w.tolist()})")
    if abs(w.sum() - 1.0) > 1e-9:
        raise ValueError(
            f"weights must sum to 1 (got {w.tolist()}, sum {w.sum():.6g}); pass (w_n, 1 - w_n)"
        )
    w = w / w.sum()
    w.flags.writeable = False
    return w


def _check_nonnegative(name, value) -> float:
    if isinstance(value, bool) or not isinstance(value, (numbers.Real, np.floating, np.integer)):
        raise TypeError(f"{name} must be a real number (got {value!r})")
    x = float(value)
    if not np.isfinite(x) or x < 0:
        raise ValueError(f"{name} must be finite and >= 0 (got {x})")
    return x


class Orchestrator(abc.ABC):
    """Common interface of the orchestrators.

    Subclasses are built from a nominal and a constrained :class:`irl.MDP`, or with
    ``from_preferences`` from an :class:`~orchestration.ActionPreferences` (to reuse one
    value iteration across many weights).

    Attributes
    ----------
    preferences : ActionPreferences
        Q-values and softmax preferences of both MDPs.
    n_states, n_actions : int
    """

    preferences: ActionPreferences

    def __init__(self, nominal, constrained, *, temperature=1.0, **options):
        prefs = action_preferences(nominal, constrained, temperature=temperature)
        self._setup(prefs, **options)

    @classmethod
    def from_preferences(cls, prefs, *args, temperature=None, **options):
        """Build from precomputed :class:`~orchestration.ActionPreferences`.

        ``temperature`` may be given only to check that it is the one of ``prefs``.
        """
        if not isinstance(prefs, ActionPreferences):
            raise TypeError(
                f"prefs must be an orchestration.ActionPreferences (got {type(prefs).__name__}); "
                "build one with orchestration.action_preferences(nominal, constrained)"
            )
        if temperature is not None and float(temperature) != prefs.temperature:
            raise ValueError(
                f"temperature={temperature} differs from the temperature of prefs "
                f"({prefs.temperature}); the softmax is fixed when the preferences are built"
            )
        self = cls.__new__(cls)
        self._setup(prefs, *args, **options)
        return self

    @abc.abstractmethod
    def _setup(self, prefs, **options): ...

    @property
    def n_states(self) -> int:
        """Number of states."""
        return self.preferences.n_states

    @property
    def n_actions(self) -> int:
        """Number of actions."""
        return self.preferences.n_actions

    def _state(self, state) -> int:
        s = check_state(state, self.n_states)
        if self.preferences.terminal[s]:
            raise ValueError(f"state {s} is terminal: no action is taken there")
        return s

    def _states(self, states) -> np.ndarray:
        arr = check_states(states, self.n_states)
        bad = self.preferences.terminal[arr]
        if bad.any():
            raise ValueError(f"states must not be terminal (got terminal state {arr[bad][0]})")
        return arr

    @abc.abstractmethod
    def action_probabilities(self, state) -> np.ndarray:
        """Exact distribution of one decision in ``state``, shape (n_actions,)."""

    def act(self, state, rng=None) -> int:
        """One decision in ``state``: the chosen action.

        Parameters
        ----------
        state : int
            A non-terminal state.
        rng : None, int or numpy.random.Generator
            Source of randomness (unused by Greedy).

        Examples
        --------
        >>> import irl, orchestration
        >>> world = irl.GridWorld(3, 0, 8)
        >>> wa = orchestration.WeightedAverageOrchestrator(
        ...     world.nominal_mdp, world.constrained_mdp, weights=(0.5, 0.5))
        >>> wa.act(0, rng=1) == wa.act(0, rng=1)
        True
        """
        s = self._state(state)
        return int(self._decide(np.array([s]), np.random.default_rng(rng))[0])

    def decide_many(self, states, rng=None) -> np.ndarray:
        """Independent decisions, one in each of ``states``.

        Parameters
        ----------
        states : array_like of int, shape (n,)
            Non-terminal states (repeats allowed: one decision each).
        rng : None, int or numpy.random.Generator

        Returns
        -------
        ndarray of int, shape (n,)
            The chosen actions. For MDFT one compiled call of :func:`mdft.decide` per
            pattern of feasible actions.

        Examples
        --------
        >>> import irl, orchestration
        >>> world = irl.GridWorld(3, 0, 8)
        >>> greedy = orchestration.GreedyOrchestrator(world.nominal_mdp, world.constrained_mdp)
        >>> greedy.decide_many([0, 0, 4]).tolist() == [greedy.act(0), greedy.act(0), greedy.act(4)]
        True
        """
        arr = self._states(states)
        if arr.size == 0:
            return np.empty(0, dtype=np.int64)
        return self._decide(arr, np.random.default_rng(rng))

    @abc.abstractmethod
    def _decide(self, states: np.ndarray, generator: np.random.Generator) -> np.ndarray: ...

    def policy(self) -> np.ndarray:
        """``policy[s, a]``: :meth:`action_probabilities` of every non-terminal state.

        Terminal rows are uniform over the feasible actions (no decision is taken there).

        Examples
        --------
        >>> import irl, orchestration
        >>> world = irl.GridWorld(3, 0, 8)
        >>> wa = orchestration.WeightedAverageOrchestrator(
        ...     world.nominal_mdp, world.constrained_mdp, weights=(0.5, 0.5))
        >>> wa.policy().shape
        (9, 8)
        """
        prefs = self.preferences
        out = prefs.feasible / prefs.feasible.sum(axis=1, keepdims=True)
        for s in np.flatnonzero(~prefs.terminal):
            out[s] = self.action_probabilities(int(s))
        return out


def _sample_rows(p: np.ndarray, generator: np.random.Generator) -> np.ndarray:
    """One draw from each row of ``p`` (rows are distributions), by inverse CDF."""
    cum = np.cumsum(p, axis=1)
    u = generator.random(p.shape[0]) * cum[:, -1]
    # first index whose cumulative sum exceeds u: never an action of zero probability
    return np.minimum((cum <= u[:, None]).sum(axis=1), p.shape[1] - 1)


# ---------------------------------------------------------------------- Greedy
class GreedyOrchestrator(Orchestrator):
    """Greedy: the action with the highest Q-value in either MDP.

    Parameters
    ----------
    nominal, constrained : irl.MDP
        The nominal and the (true or learned) constrained MDP; same states, actions and
        transitions.
    temperature : float, default 1.0
        Softmax temperature of the preferences (Greedy itself uses only the Q-values).

    Notes
    -----
    ``pi_G(s) = argmax_{a feasible} max(q_c(s, a), q_n(s, a))`` (the paper's Section 4).
    Greedy is deterministic: actions whose score is within ``1e-9`` (relative) of the best
    count as tied, and the tie goes to the lowest action index.

    Examples
    --------
    >>> import irl, orchestration
    >>> world = irl.GridWorld(3, 0, 8, p_slip=0.0, constrained_states=(4,))
    >>> greedy = orchestration.GreedyOrchestrator(world.nominal_mdp, world.constrained_mdp)
    >>> greedy.act(0), greedy.action_probabilities(0).tolist()
    (5, [0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0])
    """

    def _setup(self, prefs):
        self.preferences = prefs
        score = np.where(prefs.feasible, np.maximum(prefs.q_nominal, prefs.q_constrained), -np.inf)
        best = score.max(axis=1, keepdims=True)
        tied = score >= best - GREEDY_TIE_RTOL * np.maximum(1.0, np.abs(best))
        self._actions = np.argmax(tied, axis=1).astype(np.int64)
        self._actions.flags.writeable = False

    @property
    def greedy_actions(self) -> np.ndarray:
        """The action Greedy takes in every state, shape (n_states,)."""
        return self._actions

    def action_probabilities(self, state) -> np.ndarray:
        """One-hot distribution on the greedy action of ``state``."""
        s = self._state(state)
        p = np.zeros(self.n_actions)
        p[self._actions[s]] = 1.0
        return p

    def _decide(self, states, generator):
        return self._actions[states].copy()

    def __repr__(self):
        return f"GreedyOrchestrator(n_states={self.n_states}, n_actions={self.n_actions})"


# ------------------------------------------------------------ weighted average
class WeightedAverageOrchestrator(Orchestrator):
    """Weighted average (WA): sample from ``w_n sq_n(s, .) + w_c sq_c(s, .)``.

    Parameters
    ----------
    nominal, constrained : irl.MDP
        The nominal and the (true or learned) constrained MDP.
    weights : pair of float
        ``(w_n, w_c)``, non-negative, summing to one.
    temperature : float, default 1.0
        Softmax temperature of ``sq_n`` and ``sq_c``.

    Notes
    -----
    ``p_WA(a) = w_n sq_n(s, a) + w_c sq_c(s, a)`` (the paper's Section 4); the
    distribution is exact and a decision is one draw from it.

    Examples
    --------
    >>> import irl, orchestration
    >>> world = irl.GridWorld(3, 0, 8, p_slip=0.0, constrained_states=(4,))
    >>> wa = orchestration.WeightedAverageOrchestrator(
    ...     world.nominal_mdp, world.constrained_mdp, weights=(0.5, 0.5))
    >>> p = wa.action_probabilities(0)
    >>> round(float(p.sum()), 12), wa.act(0, rng=0) in range(8)
    (1.0, True)
    """

    def __init__(self, nominal, constrained, weights, *, temperature=1.0):
        super().__init__(nominal, constrained, temperature=temperature, weights=weights)

    @classmethod
    def from_preferences(cls, prefs, weights, *, temperature=None):
        """Build from precomputed :class:`~orchestration.ActionPreferences`.

        Examples
        --------
        >>> import irl, orchestration
        >>> world = irl.GridWorld(3, 0, 8)
        >>> prefs = orchestration.action_preferences(world.nominal_mdp, world.constrained_mdp)
        >>> [orchestration.WeightedAverageOrchestrator.from_preferences(prefs, (w, 1 - w)).weights[0]
        ...  for w in (0.0, 0.5)]
        [0.0, 0.5]
        """
        return super().from_preferences(prefs, temperature=temperature, weights=weights)

    def _setup(self, prefs, weights):
        self.preferences = prefs
        self._w = _check_weights(weights)
        p = self._w[0] * prefs.sq_nominal + self._w[1] * prefs.sq_constrained
        self._p = p / p.sum(axis=1, keepdims=True)
        self._p.flags.writeable = False

    @property
    def weights(self) -> tuple:
        """``(w_n, w_c)``."""
        return (float(self._w[0]), float(self._w[1]))

    def action_probabilities(self, state) -> np.ndarray:
        """``w_n sq_n(s, .) + w_c sq_c(s, .)``, shape (n_actions,)."""
        return self._p[self._state(state)].copy()

    def _decide(self, states, generator):
        return _sample_rows(self._p[states], generator)

    def __repr__(self):
        return (f"WeightedAverageOrchestrator(weights={self.weights}, n_states={self.n_states}, "
                f"n_actions={self.n_actions})")


# ------------------------------------------------------------------------ MDFT
class MDFTOrchestrator(Orchestrator):
    """MDFT: one deliberation of Multi-alternative Decision Field Theory per decision.

    Parameters
    ----------
    nominal, constrained : irl.MDP
        The nominal and the (true or learned) constrained MDP.
    weights : pair of float
        Attention ``w = (w_n, w_c)``: at each deliberation step the nominal attribute is
        attended with probability ``w_n``, the constrained one with ``w_c``.
    phi1, phi2, beta : float, default 0.01, 0.01, 2.0
        Feedback matrix ``S = I - phi2 exp(-phi1 D**2)`` with Hotaling's distance ``D``
        (``beta`` weighs the dominance direction); the paper's orchestrator settings.
    sigma2 : float, default 1.0
        Variance of the valence noise.
    n_steps : int, default 100
        Fixed stopping: deliberation time ``T``; the action with the largest ``P(T)``
        is chosen. With ``threshold``: the longest deliberation (see below).
    threshold : float, optional
        Threshold stopping: the deliberation stops at the first step where a preference
        reaches ``threshold`` and chooses that option. A deliberation that has not
        decided after ``n_steps`` steps is started afresh (at most ``MAX_RESTARTS``
        times, else ``RuntimeError``), so the choice distribution is the threshold
        distribution *conditional on deciding within* ``n_steps`` steps.
    temperature : float, default 1.0
        Softmax temperature of ``sq_n`` and ``sq_c``.

    Notes
    -----
    In state ``s`` the options are the feasible actions, ``M = [sq_n(s, .), sq_c(s, .)]``
    (k x 2) and the dynamics is ``P(t+1) = S P(t) + C (M W(t+1) + eps(t+1))`` from
    ``P(0) = 0`` (``docs/concepts.md``). A state with one feasible action chooses it.

    ``act`` and ``decide_many`` run one deliberation per decision (:func:`mdft.decide`,
    compiled, for fixed stopping). ``action_probabilities`` is computed without
    sampling: for fixed stopping by :func:`mdft.choice_probabilities` (the closed form
    of Roe et al. 2001: exact first two moments of ``P(T)``, normal orthant
    probabilities); ``docs/orchestration.md`` reports its measured accuracy for
    orchestrator inputs. For threshold stopping by :func:`mdft.threshold_probabilities`:
    its error-controlled chain for states with two or three feasible actions, its
    simulation to the same tolerances (seeded, so repeatable) for more, or where the chain
    cannot vouch for its answer.

    With ``sq`` entries in ``[0, 1]`` the options are close together, so ``S`` is close
    to ``I - phi2 * ones`` and its spectral radius is about 1 (often 1 + 1e-5): over a
    fixed, finite ``T`` this is harmless, and the engine's
    :class:`mdft.UnstableFeedbackWarning` is not repeated for every state.

    Examples
    --------
    >>> import irl, orchestration
    >>> world = irl.GridWorld(3, 0, 8, p_slip=0.0, constrained_states=(4,))
    >>> orch = orchestration.MDFTOrchestrator(
    ...     world.nominal_mdp, world.constrained_mdp, weights=(0.5, 0.5))
    >>> p = orch.action_probabilities(0)
    >>> p.shape, round(float(p.sum()), 9)
    ((8,), 1.0)
    >>> orch.act(0, rng=0) in range(8)
    True
    >>> orch.decide_many([0, 0, 1], rng=0).shape
    (3,)
    """

    def __init__(self, nominal, constrained, weights, *, phi1=0.01, phi2=0.01, beta=2.0,
                 sigma2=1.0, n_steps=100, threshold=None, temperature=1.0):
        super().__init__(nominal, constrained, temperature=temperature, weights=weights,
                         phi1=phi1, phi2=phi2, beta=beta, sigma2=sigma2, n_steps=n_steps,
                         threshold=threshold)

    @classmethod
    def from_preferences(cls, prefs, weights, *, phi1=0.01, phi2=0.01, beta=2.0, sigma2=1.0,
                         n_steps=100, threshold=None, temperature=None):
        """Build from precomputed :class:`~orchestration.ActionPreferences`.

        Examples
        --------
        >>> import irl, orchestration
        >>> world = irl.GridWorld(3, 0, 8)
        >>> prefs = orchestration.action_preferences(world.nominal_mdp, world.constrained_mdp)
        >>> orchestration.MDFTOrchestrator.from_preferences(prefs, (0.3, 0.7)).weights
        (0.3, 0.7)
        """
        return super().from_preferences(prefs, temperature=temperature, weights=weights,
                                        phi1=phi1, phi2=phi2, beta=beta, sigma2=sigma2,
                                        n_steps=n_steps, threshold=threshold)

    def _setup(self, prefs, weights, phi1, phi2, beta, sigma2, n_steps, threshold):
        self.preferences = prefs
        self._w = _check_weights(weights)
        self.phi1 = _check_nonnegative("phi1", phi1)
        self.phi2 = _check_nonnegative("phi2", phi2)
        self.beta = _check_nonnegative("beta", beta)
        self.sigma2 = _check_nonnegative("sigma2", sigma2)
        if threshold is None:
            self.stopping = mdft.FixedTime(n_steps)
        else:
            if isinstance(threshold, bool) or not isinstance(threshold, (numbers.Real, np.floating)):
                raise TypeError(f"threshold must be a real number or None (got {threshold!r})")
            if not np.isfinite(threshold) or threshold <= 0:
                raise ValueError(f"threshold must be finite and > 0, or None (got {threshold})")
            self.stopping = mdft.Threshold(float(threshold), max_steps=n_steps)
        self.n_steps = self.stopping.max_steps if threshold is not None else self.stopping.n_steps
        self.threshold = None if threshold is None else float(threshold)
        # Feasible-action patterns: one group of states per distinct feasibility row.
        patterns, self._group = np.unique(prefs.feasible, axis=0, return_inverse=True)
        self._group = self._group.ravel()
        self._group_actions = [np.flatnonzero(row) for row in patterns]
        self._M = np.ascontiguousarray(
            np.stack([prefs.sq_nominal, prefs.sq_constrained], axis=-1))  # (S, A, 2)
        self._cache = {}

    @property
    def weights(self) -> tuple:
        """``(w_n, w_c)``."""
        return (float(self._w[0]), float(self._w[1]))

    def model(self, state) -> mdft.MDFTModel:
        """The MDFT model of ``state``: options are its feasible actions.

        Raises ``ValueError`` for a state with a single feasible action (nothing to
        deliberate).

        Examples
        --------
        >>> import irl, orchestration
        >>> world = irl.GridWorld(3, 0, 8)
        >>> orch = orchestration.MDFTOrchestrator(
        ...     world.nominal_mdp, world.constrained_mdp, weights=(0.5, 0.5))
        >>> orch.model(0).M.shape
        (8, 2)
        """
        s = self._state(state)
        actions, M = self.preferences.attributes(s)
        if actions.size < 2:
            raise ValueError(f"state {s} has a single feasible action: there is nothing to deliberate")
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", mdft.UnstableFeedbackWarning)
            return mdft.MDFTModel(M, self._w, phi1=self.phi1, phi2=self.phi2, beta=self.beta,
                                  sigma2=self.sigma2)

    def action_probabilities(self, state) -> np.ndarray:
        """Choice distribution of one deliberation in ``state``, shape (n_actions,).

        Fixed stopping: :func:`mdft.choice_probabilities`; threshold stopping:
        :func:`mdft.threshold_probabilities` conditional on deciding within ``n_steps``
        (simulated to its tolerances for more than three feasible actions). Results are
        cached per state.
        """
        s = self._state(state)
        if s not in self._cache:
            self._cache[s] = self._probabilities(s)
        return self._cache[s].copy()

    def _probabilities(self, s):
        actions = self._group_actions[self._group[s]]
        out = np.zeros(self.n_actions)
        if actions.size == 1:
            out[actions[0]] = 1.0
            return out
        model = self.model(s)
        if self.threshold is None:
            try:
                p = mdft.choice_probabilities(model, self.n_steps)
            except ValueError as exc:
                raise ValueError(f"state {s}: {exc}") from exc
        else:
            p = self._threshold_probabilities(s, model)
        out[actions] = p
        return out

    def _threshold_probabilities(self, s, model):
        # Conditional on deciding: dividing by the probability d of deciding divides the
        # error too, so where d < 1 - CONDITIONAL_RERUN the answer is asked again with the
        # tolerance scaled by d (one more call; the chain or its simulation may refuse).
        res, decided = self._threshold_answer(s, model, THRESHOLD_ATOL)
        if decided < 1.0 - CONDITIONAL_RERUN:
            res, _ = self._threshold_answer(s, model, THRESHOLD_ATOL * decided)
        return np.asarray(res.probabilities) / res.probabilities.sum()

    def _threshold_answer(self, s, model, atol):
        """:func:`mdft.threshold_probabilities` and the probability of deciding, or a
        ValueError naming the state."""
        try:
            res = mdft.threshold_probabilities(model, self.threshold, max_steps=self.n_steps,
                                               atol=atol)
        except ValueError as exc:
            raise ValueError(f"state {s}: {exc}") from exc
        decided = 1.0 - res.p_undecided
        if decided < 1e-9:
            raise ValueError(
                f"state {s}: a deliberation almost never reaches threshold={self.threshold:g} "
                f"within n_steps={self.n_steps} steps (probability {decided:.3g}); raise "
                "n_steps or lower the threshold"
            )
        return res, decided

    def _decide(self, states, generator):
        out = np.empty(states.size, dtype=np.int64)
        groups = self._group[states]
        for g in np.unique(groups):
            rows = np.flatnonzero(groups == g)
            actions = self._group_actions[g]
            if actions.size == 1:
                out[rows] = actions[0]
            elif self.threshold is None:
                if actions.size == self.n_actions:
                    M = self._M[states if rows.size == states.size else states[rows]]
                else:
                    M = self._M[states[rows]][:, actions]
                idx = mdft.decide(M, self._w, phi1=self.phi1, phi2=self.phi2, beta=self.beta,
                                  sigma2=self.sigma2, n_steps=self.n_steps, rng=generator)
                out[rows] = actions[idx]
            else:
                out[rows] = self._threshold_decisions(states[rows], actions, generator)
        return out

    def _threshold_decisions(self, states, actions, generator):
        out = np.empty(states.size, dtype=np.int64)
        for s in np.unique(states):
            rows = np.flatnonzero(states == s)
            model = self.model(int(s))
            chosen = []
            pending = rows.size
            for _ in range(MAX_RESTARTS):
                res = mdft.simulate(model, pending, stopping=self.stopping, rng=generator)
                got = res.choices[res.choices >= 0]
                chosen.append(got)
                pending -= got.size
                if pending == 0:
                    break
            if pending:
                raise RuntimeError(
                    f"state {int(s)}: {pending} deliberation(s) did not reach threshold="
                    f"{self.threshold:g} within n_steps={self.n_steps} steps in {MAX_RESTARTS} "
                    "attempts; raise n_steps or lower the threshold"
                )
            out[rows] = actions[np.concatenate(chosen)]
        return out

    def __repr__(self):
        stop = (f"n_steps={self.n_steps}" if self.threshold is None
                else f"threshold={self.threshold:g}, n_steps={self.n_steps}")
        return (f"MDFTOrchestrator(weights={self.weights}, phi1={self.phi1:g}, phi2={self.phi2:g}, "
                f"beta={self.beta:g}, sigma2={self.sigma2:g}, {stop})")
