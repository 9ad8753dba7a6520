"""Scores for learned constraints and for the behaviour they produce.

Three families of measures, all pure functions of arrays:

* **hard constraints** (a constraint is there or not): precision, recall,
  false positive rate and false discovery rate of a predicted set of
  constraints against the true set, both given as boolean masks over the same
  candidates (for a :class:`~irl.gridworld.GridWorld` the natural candidates are
  its features: every state, every action and every colour);
* **soft constraints** (each candidate has a probability ``zeta`` of being a
  constraint, paper Section 3.2): the false positives and false negatives at a
  tolerance ``chi`` of the paper's Section 3.3;
* **behaviour**: Kullback-Leibler and Jensen-Shannon divergences between the
  state-action visitation frequencies of two sets of trajectories.

Notes
-----
The paper (and its code) reports a "false positive rate" computed as
``FP / (TP + FP)``, the fraction of *predicted* constraints that are wrong. That
is the false discovery rate, ``1 - precision``; it ignores missed constraints
entirely (predicting nothing scores a perfect 0). Here the false positive rate
has its usual meaning, ``FP / (FP + TN)``, the fraction of the candidates that
are *not* constraints and were predicted to be; the paper's number is
:attr:`HardConstraintScores.false_discovery_rate`.
"""

from __future__ import annotations

import numbers
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Sequence

import numpy as np
from scipy.special import rel_entr

from ._validation import check_indices, is_flat_set, split_trajectory, trajectory_list
from .mdp import _as_int, _as_real, _check_size
from ._typing import ArrayLike

if TYPE_CHECKING:
    from .demonstrations import Demonstrations

__all__ = [
    "HardConstraintScores",
    "SoftConstraintErrors",
    "hard_constraint_scores",
    "precision",
    "recall",
    "false_positive_rate",
    "false_discovery_rate",
    "soft_constraint_errors",
    "visitation_counts",
    "kl_divergence",
    "js_divergence",
    "visitation_kl_divergence",
    "visitation_js_divergence",
]


# --------------------------------------------------------------------------- validation


def _as_mask(name: str, value) -> np.ndarray:
    """A 1-d boolean copy of ``value``; numbers are accepted only as 0/1."""
    arr = np.asarray(value)
    if arr.dtype == object:
        raise TypeError(f"{name} must be an array of booleans (got {value!r})")
    if arr.ndim == 0:
        raise ValueError(f"{name} must be a 1-d array of booleans (got a scalar {arr.item()!r})")
    if arr.dtype != np.bool_:
        if not np.issubdtype(arr.dtype, np.number):
            raise TypeError(f"{name} must be an array of booleans (got dtype {arr.dtype})")
        if not np.all((arr == 0) | (arr == 1)):
            raise ValueError(
                f"{name} must hold booleans or 0/1 (got values other than 0 and 1); "
                "threshold probabilities first, e.g. zeta >= 0.6"
            )
    if arr.ndim != 1:
        raise ValueError(f"{name} must be a 1-d array (got shape {arr.shape}); flatten it first")
    if arr.size == 0:
        raise ValueError(f"{name} must not be empty: there are no candidate constraints to score")
    return arr.astype(bool)


def _same_shape(names: tuple[str, str], a: np.ndarray, b: np.ndarray) -> None:
    if a.shape != b.shape:
        raise ValueError(
            f"{names[0]} and {names[1]} must have the same shape "
            f"(got {a.shape} and {b.shape}); they must score the same candidates"
        )


def _as_vector(name: str, value, what: str) -> np.ndarray:
    """``value`` as a new finite 1-d float array; ``what`` names its entries in the TypeError."""
    try:
        arr = np.array(value, dtype=np.float64)
    except OverflowError:
        raise ValueError(f"{name} must be finite (got a number too large for a float)") from None
    except (TypeError, ValueError) as exc:
        raise TypeError(f"{name} must be an array of {what} (got {value!r})") from exc
    if arr.ndim != 1:
        raise ValueError(f"{name} must be a 1-d array (got shape {arr.shape})")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite (got NaN or infinity)")
    return arr


def _as_probabilities(name: str, value) -> np.ndarray:
    arr = _as_vector(name, value, "probabilities")
    if np.any((arr < 0) | (arr > 1)):
        bad = arr[(arr < 0) | (arr > 1)][0]
        raise ValueError(f"{name} must lie in [0, 1] (got {bad})")
    return arr


def _as_nonnegative(name: str, value) -> np.ndarray:
    try:
        arr = np.array(value, dtype=np.float64)
    except OverflowError:
        raise ValueError(f"{name} must be finite (got a number too large for a float)") from None
    except (TypeError, ValueError) as exc:
        raise TypeError(f"{name} must be an array of non-negative numbers (got {value!r})") from exc
    if arr.ndim == 0:
        raise ValueError(f"{name} must be an array (got the scalar {arr.item()!r})")
    if arr.size == 0:
        raise ValueError(f"{name} must not be empty (got an array of size 0)")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite (got NaN or infinity)")
    if np.any(arr < 0):
        raise ValueError(f"{name} must be non-negative (got {arr[arr < 0][0]})")
    return arr


def _as_positive_int(name: str, value) -> int:
    if isinstance(value, bool) or not isinstance(value, (numbers.Integral, np.integer)):
        raise TypeError(f"{name} must be an integer (got {value!r})")
    if int(value) < 1:
        raise ValueError(f"{name} must be >= 1 (got {int(value)})")
    return _as_int(name, value)


# --------------------------------------------------------------------------- hard constraints


@dataclass(frozen=True)
class HardConstraintScores:
    """Confusion counts and rates of a predicted set of hard constraints.

    Attributes
    ----------
    n_true_positive, n_false_positive, n_false_negative, n_true_negative : int
        Candidates predicted and true, predicted but not true, true but not
        predicted, neither.
    precision : float
        ``TP / (TP + FP)``: the fraction of predicted constraints that are real.
    recall : float
        ``TP / (TP + FN)``: the fraction of real constraints that were found.
    false_positive_rate : float
        ``FP / (FP + TN)``: the fraction of non-constraints predicted to be constraints.
    false_discovery_rate : float
        ``FP / (TP + FP) = 1 - precision``: what the paper calls "false positive rate".

    Notes
    -----
    Ratios whose denominator is zero take the conventions of
    :func:`hard_constraint_scores` (or its ``zero_division`` value).

    Examples
    --------
    >>> s = hard_constraint_scores([True, False, False], [True, True, False])
    >>> s.n_true_positive, s.n_false_positive, s.precision, s.false_discovery_rate
    (1, 1, 0.5, 0.5)
    """

    n_true_positive: int
    n_false_positive: int
    n_false_negative: int
    n_true_negative: int
    precision: float
    recall: float
    false_positive_rate: float
    false_discovery_rate: float

    def summary(self) -> str:
        """The confusion counts and the four rates, as text.

        Examples
        --------
        >>> print(hard_constraint_scores([True, False, False], [True, True, False]).summary())
        predicted constraints: 1 true positive, 1 false positive, 0 false negative, 1 true negative
        precision 0.5000, recall 1.0000, false positive rate 0.5000, false discovery rate 0.5000
        """
        return (
            f"predicted constraints: {self.n_true_positive} true positive, "
            f"{self.n_false_positive} false positive, {self.n_false_negative} false negative, "
            f"{self.n_true_negative} true negative\n"
            f"precision {self.precision:.4f}, recall {self.recall:.4f}, false positive rate "
            f"{self.false_positive_rate:.4f}, false discovery rate {self.false_discovery_rate:.4f}"
        )


def _ratio(num: int, den: int, default: float) -> float:
    return float(num) / float(den) if den > 0 else float(default)


def _zero_division(value) -> float | None:
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise TypeError(f"zero_division must be None or a real number (got {value!r})")
    try:
        return float(value)  # NaN is allowed: it marks an undefined ratio on request
    except OverflowError:
        raise ValueError("zero_division must be a float (got an integer too large for one)"
                         ) from None


def hard_constraint_scores(true: ArrayLike, predicted: ArrayLike, *,
                           zero_division: float | None = None) -> HardConstraintScores:
    """Score a predicted set of hard constraints against the true set.

    Parameters
    ----------
    true : array_like of bool, shape (n_candidates,)
        ``true[i]`` is True where candidate ``i`` is a real constraint.
    predicted : array_like of bool, shape (n_candidates,)
        ``predicted[i]`` is True where candidate ``i`` was inferred to be a
        constraint. For probabilities ``zeta`` pass ``zeta >= threshold``.
    zero_division : float or None, optional
        Value of a ratio whose denominator is zero. ``None`` (default) uses the
        conventions: precision 1 and false discovery rate 0 when nothing is
        predicted (no discovery, so no false discovery), recall 1 when there is
        no true constraint (nothing to find), false positive rate 0 when every
        candidate is a constraint. Pass ``float("nan")`` to mark such ratios as
        undefined instead.

    Returns
    -------
    HardConstraintScores

    Raises
    ------
    ValueError
        If the masks differ in shape or hold values other than booleans or 0/1.

    Notes
    -----
    The paper's "false positive rate" (its Figures 2 and appendix) is the false
    discovery rate ``FP / (TP + FP)``; see the module notes.

    Examples
    --------
    >>> s = hard_constraint_scores([True, True, False, False], [True, False, True, False])
    >>> s.precision, s.recall, s.false_positive_rate, s.false_discovery_rate
    (0.5, 0.5, 0.5, 0.5)
    """
    t = _as_mask("true", true)
    p = _as_mask("predicted", predicted)
    _same_shape(("true", "predicted"), t, p)
    zd = _zero_division(zero_division)
    tp = int(np.count_nonzero(t & p))
    fp = int(np.count_nonzero(~t & p))
    fn = int(np.count_nonzero(t & ~p))
    tn = int(np.count_nonzero(~t & ~p))
    return HardConstraintScores(
        n_true_positive=tp,
        n_false_positive=fp,
        n_false_negative=fn,
        n_true_negative=tn,
        precision=_ratio(tp, tp + fp, 1.0 if zd is None else zd),
        recall=_ratio(tp, tp + fn, 1.0 if zd is None else zd),
        false_positive_rate=_ratio(fp, fp + tn, 0.0 if zd is None else zd),
        false_discovery_rate=_ratio(fp, tp + fp, 0.0 if zd is None else zd),
    )


def precision(true: ArrayLike, predicted: ArrayLike, *, zero_division: float | None = None) -> float:
    """Fraction of the predicted constraints that are real, ``TP / (TP + FP)``.

    Parameters and conventions as in :func:`hard_constraint_scores`.

    Examples
    --------
    >>> precision([True, False, False], [True, True, False])
    0.5
    """
    return hard_constraint_scores(true, predicted, zero_division=zero_division).precision


def recall(true: ArrayLike, predicted: ArrayLike, *, zero_division: float | None = None) -> float:
    """Fraction of the real constraints that were predicted, ``TP / (TP + FN)``.

    Parameters and conventions as in :func:`hard_constraint_scores`.

    Examples
    --------
    >>> recall([True, True, False, False], [True, False, False, True])
    0.5
    """
    return hard_constraint_scores(true, predicted, zero_division=zero_division).recall


def false_positive_rate(true: ArrayLike, predicted: ArrayLike, *,
                        zero_division: float | None = None) -> float:
    """Fraction of the non-constraints predicted to be constraints, ``FP / (FP + TN)``.

    Parameters and conventions as in :func:`hard_constraint_scores`. This is
    *not* the paper's "false positive rate", which is
    :func:`false_discovery_rate`.

    Examples
    --------
    >>> round(false_positive_rate([True, False, False, False], [True, True, False, False]), 4)  # 1 / 3
    0.3333
    """
    return hard_constraint_scores(true, predicted, zero_division=zero_division).false_positive_rate


def false_discovery_rate(true: ArrayLike, predicted: ArrayLike, *,
                         zero_division: float | None = None) -> float:
    """Fraction of the predicted constraints that are wrong, ``FP / (TP + FP)``.

    This is what the paper and its code call the "false positive rate"; it
    equals ``1 - precision`` and ignores missed constraints. Parameters and
    conventions as in :func:`hard_constraint_scores`.

    Examples
    --------
    >>> false_discovery_rate([True, False, False, False], [True, True, False, False])
    0.5
    """
    return hard_constraint_scores(true, predicted, zero_division=zero_division).false_discovery_rate


# --------------------------------------------------------------------------- soft constraints


@dataclass(frozen=True)
class SoftConstraintErrors:
    """False positives and negatives of soft constraints at tolerance ``chi``.

    Attributes
    ----------
    false_positives : float
        ``n_false_positive / n_candidates``: the paper's ``fp``.
    false_negatives : float
        ``n_false_negative / n_candidates``: the paper's ``fn``.
    false_positive_share : float
        ``n_false_positive / n_unconstrained``: the same count over the
        candidates that can be false positives (0 if there are none).
    false_negative_share : float
        ``n_false_negative / n_constrained`` (0 if there is no constraint).
    n_false_positive, n_false_negative : int
        The counts.
    n_candidates, n_constrained, n_unconstrained : int
        All candidates scored, those with a true cost ``c(x) != 0`` and those with ``c(x) = 0``.
    chi : float
        The tolerance used.

    Examples
    --------
    >>> e = soft_constraint_errors([0, -50], [0.27, 0.82], [0.9, 0.8], chi=0.2)
    >>> e.n_false_positive, e.false_positives, e.false_positive_share
    (1, 0.5, 1.0)
    """

    false_positives: float
    false_negatives: float
    false_positive_share: float
    false_negative_share: float
    n_false_positive: int
    n_false_negative: int
    n_candidates: int
    n_constrained: int
    n_unconstrained: int
    chi: float

    def summary(self) -> str:
        """The counts and the paper's shares, as text.

        Examples
        --------
        >>> print(soft_constraint_errors([0, -50], [0.27, 0.82], [0.9, 0.8], chi=0.2).summary())
        soft constraints at chi = 0.2, 2 candidates (1 constrained, 1 unconstrained)
        false positives: 1 (0.5000 of all, 1.0000 of the unconstrained)
        false negatives: 0 (0.0000 of all, 0.0000 of the constrained)
        """
        return (
            f"soft constraints at chi = {self.chi:g}, {self.n_candidates} candidates "
            f"({self.n_constrained} constrained, {self.n_unconstrained} unconstrained)\n"
            f"false positives: {self.n_false_positive} ({self.false_positives:.4f} of all, "
            f"{self.false_positive_share:.4f} of the unconstrained)\n"
            f"false negatives: {self.n_false_negative} ({self.false_negatives:.4f} of all, "
            f"{self.false_negative_share:.4f} of the constrained)"
        )


def soft_constraint_errors(true_cost: ArrayLike, zeta_true: ArrayLike, zeta_pred: ArrayLike, *,
                           chi: float = 0.2) -> SoftConstraintErrors:
    """The paper's false positives and false negatives for soft constraints (Section 3.3).

    Parameters
    ----------
    true_cost : array_like, shape (n_candidates,)
        The true cost ``c(x)`` of each candidate constraint ``x`` (for example
        the true penalty of each feature); any non-zero entry marks a
        constraint. A boolean mask works too.
    zeta_true : array_like, shape (n_candidates,)
        ``zeta_C*(x)``: the probability that ``x`` is a constraint in the true
        constrained world (paper Section 3.2), in [0, 1].
    zeta_pred : array_like, shape (n_candidates,)
        ``zeta_C(x)``: the learned probability, in [0, 1].
    chi : float, optional
        Tolerance in [0, 1] (default 0.2, the paper's best value).

    Returns
    -------
    SoftConstraintErrors

    Notes
    -----
    With ``N`` the number of candidates scored (all ``x``, constrained or not),

    * ``fp = |{x : c(x) = 0 and zeta_C(x) - zeta_C*(x) > chi}| / N``,
    * ``fn = |{x : c(x) != 0 and zeta_C*(x) - zeta_C(x) > chi}| / N``,

    the paper's definitions, whose "Num. Constraints" is read as the number of
    candidate constraints considered. Because ``N`` pools both kinds, ``fp``
    is at most the share of unconstrained candidates and ``fn`` at most the
    share of constrained ones; the fields ``false_positive_share`` and
    ``false_negative_share`` divide by the size of each kind instead.
    Comparisons are strict, as in the paper.

    Examples
    --------
    >>> e = soft_constraint_errors([0, 0, -50, -50], [0.1, 0.1, 0.9, 0.9],
    ...                            [0.5, 0.2, 0.3, 0.8], chi=0.2)
    >>> e.n_false_positive, e.n_false_negative, e.false_positives, e.false_negative_share
    (1, 1, 0.25, 0.5)
    """
    cost = _as_vector("true_cost", true_cost, "numbers")
    zt = _as_probabilities("zeta_true", zeta_true)
    zp = _as_probabilities("zeta_pred", zeta_pred)
    _same_shape(("true_cost", "zeta_true"), cost, zt)
    _same_shape(("zeta_true", "zeta_pred"), zt, zp)
    if cost.size == 0:
        raise ValueError("true_cost must not be empty: there are no candidate constraints to score")
    chi = _as_real("chi", chi, low=0.0, high=1.0)
    constrained = cost != 0
    n = cost.size
    n_c = int(np.count_nonzero(constrained))
    n_u = n - n_c
    fp = int(np.count_nonzero(~constrained & (zp - zt > chi)))
    fn = int(np.count_nonzero(constrained & (zt - zp > chi)))
    return SoftConstraintErrors(
        false_positives=fp / n,
        false_negatives=fn / n,
        false_positive_share=_ratio(fp, n_u, 0.0),
        false_negative_share=_ratio(fn, n_c, 0.0),
        n_false_positive=fp,
        n_false_negative=fn,
        n_candidates=n,
        n_constrained=n_c,
        n_unconstrained=n_u,
        chi=chi,
    )


# --------------------------------------------------------------------------- divergences


def _as_distributions(p, q):
    """``p`` and ``q`` as float arrays of the same shape, each normalised to sum to one."""
    pa = _as_nonnegative("p", p)
    qa = _as_nonnegative("q", q)
    _same_shape(("p", "q"), pa, qa)
    sp, sq = pa.sum(), qa.sum()
    if sp <= 0:
        raise ValueError("p must have positive total mass (got all zeros)")
    if sq <= 0:
        raise ValueError("q must have positive total mass (got all zeros)")
    return pa / sp, qa / sq


def kl_divergence(p: ArrayLike, q: ArrayLike) -> float:
    """Kullback-Leibler divergence ``KL(p || q) = sum p log(p / q)`` in nats.

    Parameters
    ----------
    p, q : array_like, same shape
        Non-negative weights; each is normalised to sum to one (so counts work).

    Returns
    -------
    float
        The divergence, ``>= 0``. It is ``inf`` (never NaN) where ``p`` puts
        mass on an entry where ``q`` has none; terms with ``p = 0`` contribute
        zero. Smooth counts first (see :func:`visitation_kl_divergence`) to
        keep it finite.

    Examples
    --------
    >>> round(kl_divergence([0.5, 0.5], [0.25, 0.75]), 4)
    0.1438
    >>> kl_divergence([1, 1], [1, 0])
    inf
    """
    pa, qa = _as_distributions(p, q)
    value = float(np.sum(rel_entr(pa, qa)))
    return max(value, 0.0)


def js_divergence(p: ArrayLike, q: ArrayLike) -> float:
    """Jensen-Shannon divergence in nats, ``(KL(p || m) + KL(q || m)) / 2`` with ``m = (p + q) / 2``.

    Parameters
    ----------
    p, q : array_like, same shape
        Non-negative weights, each normalised to sum to one.

    Returns
    -------
    float
        In ``[0, log 2]``; finite even where the supports differ.

    Examples
    --------
    >>> round(js_divergence([1, 0], [0, 1]), 6) == round(float(np.log(2)), 6)
    True
    """
    pa, qa = _as_distributions(p, q)
    m = 0.5 * (pa + qa)
    value = 0.5 * float(np.sum(rel_entr(pa, m))) + 0.5 * float(np.sum(rel_entr(qa, m)))
    return min(max(value, 0.0), float(np.log(2.0)))


def visitation_counts(trajectories: Demonstrations | Sequence[Any], *, n_states: int,
                      n_actions: int) -> np.ndarray:
    """Count how often each state-action pair occurs in a set of trajectories.

    Parameters
    ----------
    trajectories : Demonstrations or sequence
        A :class:`~irl.demonstrations.Demonstrations` set, or a sequence
        whose trajectories are each an object with integer arrays ``.states``
        and ``.actions``, a ``(states, actions)`` pair, or
        an ``(n, 2)`` integer array of ``(state, action)`` rows. A trajectory
        may list one more state than actions (its final state, where no
        action is taken; it is not counted).
    n_states, n_actions : int
        Size of the state and action sets.

    Returns
    -------
    counts : ndarray of int64, shape (n_states, n_actions)

    Raises
    ------
    ValueError
        If there is no trajectory, or a state or action is out of range.

    Examples
    --------
    >>> visitation_counts([([0, 1, 2], [1, 1])], n_states=3, n_actions=2)
    array([[0, 1],
           [0, 1],
           [0, 0]])
    """
    n_states = _as_positive_int("n_states", n_states)
    n_actions = _as_positive_int("n_actions", n_actions)
    _check_size(f"n_states={n_states} x n_actions={n_actions}", n_states * n_actions)
    if is_flat_set(trajectories) and hasattr(trajectories, "states") and hasattr(trajectories, "actions"):
        s = np.asarray(trajectories.states)
        a = np.asarray(trajectories.actions)
        if len(trajectories) == 0 or s.size == 0:
            raise ValueError("trajectories must hold at least one trajectory (got an empty set)")
        if s.shape != a.shape or s.ndim != 1:
            raise ValueError(f"a flat set needs one state per action (got {s.shape} states, {a.shape} actions)")
        if s.min() < 0 or s.max() >= n_states:
            raise ValueError(f"trajectories have a state outside [0, {n_states}) (got {int(s.max())})")
        if a.min() < 0 or a.max() >= n_actions:
            raise ValueError(f"trajectories have an action outside [0, {n_actions}) (got {int(a.max())})")
        counts = np.zeros((n_states, n_actions), dtype=np.int64)
        np.add.at(counts, (s.astype(np.intp), a.astype(np.intp)), 1)
        return counts
    if isinstance(trajectories, np.ndarray) and trajectories.ndim == 2 and trajectories.shape[1] == 2:
        trajectories = [trajectories]
    items = trajectory_list(trajectories, "trajectories")
    counts = np.zeros((n_states, n_actions), dtype=np.int64)
    for i, traj in enumerate(items):
        s, a = split_trajectory(traj, i, noun="trajectory", rows=True)
        # A trajectory may list one more state than actions (the state reached last).
        if s.size not in (a.size, a.size + 1):
            raise ValueError(
                f"trajectory {i} has {s.size} states and {a.size} actions; "
                "there must be as many states as actions, or one more"
            )
        check_indices(s, a, i, noun="trajectory", n_states=n_states, n_actions=n_actions)
        np.add.at(counts, (s[: a.size].astype(np.intp), a.astype(np.intp)), 1)
    if counts.sum() == 0:
        raise ValueError("trajectories hold no state-action pair (every trajectory is empty)")
    return counts


def _smoothed(counts: np.ndarray, pseudocount: float) -> np.ndarray:
    x = counts.astype(np.float64).ravel() + pseudocount
    return x / x.sum()


def visitation_kl_divergence(
    trajectories_p: Demonstrations | Sequence[Any], trajectories_q: Demonstrations | Sequence[Any],
    *, n_states: int, n_actions: int, pseudocount: float = 0.5,
) -> float:
    """KL divergence between the state-action visitation frequencies of two trajectory sets.

    Parameters
    ----------
    trajectories_p, trajectories_q : sequence
        Two sets of trajectories (formats as in :func:`visitation_counts`),
        for example held-out demonstrations (``p``) and trajectories of a
        learned model (``q``).
    n_states, n_actions : int
        Size of the state and action sets.
    pseudocount : float, optional
        Added to the count of **every** state-action pair of both sets before
        normalising (additive, Lidstone smoothing). The default 0.5 is the
        Krichevsky-Trofimov (Jeffreys prior) estimator. Without it the
        divergence is infinite as soon as ``p`` visits a pair ``q`` never
        does. ``0`` gives the unsmoothed value, possibly ``inf`` (never NaN).
        The paper's code adds ``1e-6``, which makes unseen pairs dominate.

    Returns
    -------
    float
        ``KL(p_hat || q_hat)`` in nats, with ``p_hat = (n_p + alpha) / (N_p + alpha S A)``.

    Examples
    --------
    >>> demo = [([0, 1], [0]), ([0, 1], [0])]
    >>> model = [([0, 1], [0]), ([0, 1], [1])]
    >>> round(visitation_kl_divergence(demo, model, n_states=2, n_actions=2), 4)
    0.1819
    >>> round(visitation_kl_divergence(demo, model, n_states=2, n_actions=2, pseudocount=0), 4)  # log 2
    0.6931
    """
    alpha = _as_real("pseudocount", pseudocount, low=0.0)
    cp = visitation_counts(trajectories_p, n_states=n_states, n_actions=n_actions)
    cq = visitation_counts(trajectories_q, n_states=n_states, n_actions=n_actions)
    return kl_divergence(_smoothed(cp, alpha), _smoothed(cq, alpha))


def visitation_js_divergence(
    trajectories_p: Demonstrations | Sequence[Any], trajectories_q: Demonstrations | Sequence[Any],
    *, n_states: int, n_actions: int, pseudocount: float = 0.0,
) -> float:
    """Jensen-Shannon divergence between the state-action visitation frequencies of two sets.

    Parameters
    ----------
    trajectories_p, trajectories_q : sequence
        Two sets of trajectories (formats as in :func:`visitation_counts`).
    n_states, n_actions : int
        Size of the state and action sets.
    pseudocount : float, optional
        Additive smoothing as in :func:`visitation_kl_divergence`; the default
        is 0 because the Jensen-Shannon divergence is finite without it.

    Returns
    -------
    float
        In ``[0, log 2]`` nats.

    Examples
    --------
    >>> demo = [([0, 1], [0])]
    >>> round(visitation_js_divergence(demo, [([0, 1], [1])], n_states=2, n_actions=2), 4)
    0.6931
    """
    alpha = _as_real("pseudocount", pseudocount, low=0.0)
    cp = visitation_counts(trajectories_p, n_states=n_states, n_actions=n_actions)
    cq = visitation_counts(trajectories_q, n_states=n_states, n_actions=n_actions)
    return js_divergence(_smoothed(cp, alpha), _smoothed(cq, alpha))
