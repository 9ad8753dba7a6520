"""The paper's expressiveness results (Section 4 and appendix) as checkable constructions.

* Greedy is expressible by WA and by MDFT (:func:`greedy_preferences`): one-hot preferences
  on the greedy action reproduce Greedy's choices under either orchestrator.
* Theorem 2 (:func:`wa_most_likely_interval`, :func:`compromise_witness`): MDFT can make the
  middle ("compromise") action the most likely where no WA weights can. The WA family of a
  state is the segment between ``sq_n`` and ``sq_c``, so "no WA weights" is decided
  exactly by intersecting linear inequalities in ``w_n``.
* Theorem 3 (:func:`identity_mdft`, :func:`enumerate_fixed_time`): any distribution over
  ``k`` actions is the choice distribution of MDFT with ``k`` attributes, ``M = I``,
  attention ``w = p``, one deliberation step and no noise.
* The MDFT-vs-WA experiment (:func:`mdft_vs_wa_instance`, :func:`mdft_vs_wa`): how well
  two-attribute MDFT, with ``M = [sq_n, sq_c]`` fixed, reproduces WA distributions when its
  attention weights are fitted.
"""

from __future__ import annotations

import itertools
import math
import warnings
from dataclasses import dataclass

import numpy as np
from scipy import optimize

import irl
import mdft

from .orchestrators import GreedyOrchestrator, _check_weights
from .preferences import ActionPreferences

__all__ = [
    "greedy_preferences",
    "wa_most_likely_interval",
    "wa_weights_for",
    "CompromiseWitness",
    "compromise_witness",
    "PAPER_COMPROMISE_SQ",
    "identity_mdft",
    "enumerate_fixed_time",
    "MDFTvsWAInstance",
    "MDFTvsWAResult",
    "mdft_vs_wa_instance",
    "mdft_vs_wa",
]

#: The paper's Theorem-2 example: sq_n = (1/6, 1/3, 1/2), sq_c = (1/2, 1/3, 1/6).
PAPER_COMPROMISE_SQ = (np.array([1 / 6, 1 / 3, 1 / 2]), np.array([1 / 2, 1 / 3, 1 / 6]))

#: The paper's orchestrator settings.
PAPER_SETTINGS = dict(phi1=0.01, phi2=0.01, beta=2.0, sigma2=1.0)

#: The canonical compromise parameters (phi1 = 0.022, phi2 = 0.05, beta = 12, sigma2 = 1 on
#: the attribute scale of (1, 3), (2, 2), (3, 1)) moved to the scale of the paper's sq's,
#: which are those options divided by 6: distances shrink by 6**2, so phi1 grows by 6**4,
#: and valences shrink by 6, so the noise variance shrinks by 6**2. The choice
#: probabilities are those of the canonical model.
CANONICAL_ON_SQ_SCALE = dict(phi1=0.022 * 6.0**4, phi2=0.05, beta=12.0, sigma2=1.0 / 36.0)

#: The default Theorem-2 witness settings: the paper's orchestrator settings with the
#: canonical lateral inhibition (phi1, phi2) moved to the scale of the sq's. Only phi1
#: matters for the effect: with phi1 = 0.01 and attribute differences below 1,
#: ``exp(-phi1 D**2)`` is about 1 for every pair, so the inhibition does not depend on
#: distance and cannot favour the middle option.
WITNESS_SETTINGS = dict(phi1=0.022 * 6.0**4, phi2=0.05, beta=2.0, sigma2=1.0, n_steps=100)

_MAX_SEQUENCES = 1_000_000

#: Margin by which WA's probability of an action must exceed every other's to count as
#: "strictly most likely" (rounding of the sq's is far below it).
_MARGIN = 1e-12


def _as_distribution(name, value, size=None) -> np.ndarray:
    try:
        p = np.array(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise TypeError(f"{name} must be an array of probabilities (got {value!r})") from exc
    if p.ndim != 1 or p.size < 1 or (size is not None and p.size != size):
        want = "a 1-d array" if size is None else f"shape ({size},)"
        raise ValueError(f"{name} must be {want} (got shape {p.shape})")
    if not np.all(np.isfinite(p)) or p.min() < 0 or abs(p.sum() - 1.0) > 1e-9:
        raise ValueError(f"{name} must be a probability distribution (non-negative, summing to 1) "
                         f"(got {np.round(p, 6).tolist()})")
    return p / p.sum()


def _one_state_preferences(sq_n, sq_c) -> ActionPreferences:
    """Preferences of a single state with the given softmax rows (Q = log sq, T = 1)."""
    with np.errstate(divide="ignore"):
        qn, qc = np.log(sq_n), np.log(sq_c)
    low = min(qn[np.isfinite(qn)].min(), qc[np.isfinite(qc)].min()) - 50.0
    # an action with zero probability in one MDP only: a very low but finite Q-value
    qn, qc = np.where(np.isfinite(qn), qn, low), np.where(np.isfinite(qc), qc, low)
    return ActionPreferences(q_nominal=qn[None], q_constrained=qc[None], sq_nominal=sq_n[None],
                             sq_constrained=sq_c[None], feasible=np.ones((1, sq_n.size), bool),
                             temperature=1.0)


# ------------------------------------------------------------------ Greedy
def greedy_preferences(greedy) -> ActionPreferences:
    """Preferences under which WA and MDFT make exactly Greedy's choices (the paper's Theorem 1).

    Parameters
    ----------
    greedy : GreedyOrchestrator

    Returns
    -------
    ActionPreferences
        ``sq_n(s, .) = sq_c(s, .) =`` the one-hot vector of Greedy's action in ``s``.
        ``WeightedAverageOrchestrator.from_preferences(prefs, (w, 1 - w))`` then chooses
        Greedy's action with probability 1 for every ``w``, and so does
        ``MDFTOrchestrator.from_preferences(prefs, (w, 1 - w), sigma2=0, n_steps=1)``:
        its first valence is ``C M e_j``, which is 1 for Greedy's action and
        ``-1/(k - 1)`` for every other, whichever attribute ``j`` is attended.

    Examples
    --------
    >>> import irl, orchestration
    >>> from orchestration.expressiveness import greedy_preferences
    >>> world = irl.GridWorld(3, 0, 8, p_slip=0.0, constrained_states=(4,))
    >>> greedy = orchestration.GreedyOrchestrator(world.nominal_mdp, world.constrained_mdp)
    >>> prefs = greedy_preferences(greedy)
    >>> wa = orchestration.WeightedAverageOrchestrator.from_preferences(prefs, (0.3, 0.7))
    >>> bool((wa.action_probabilities(0) == greedy.action_probabilities(0)).all())
    True
    """
    if not isinstance(greedy, GreedyOrchestrator):
        raise TypeError(f"greedy must be a GreedyOrchestrator (got {type(greedy).__name__})")
    prefs = greedy.preferences
    onehot = np.zeros((prefs.n_states, prefs.n_actions))
    onehot[np.arange(prefs.n_states), greedy.greedy_actions] = 1.0
    # Q-values whose maximum (in both MDPs) is Greedy's action, so Greedy is unchanged
    q = np.where(onehot > 0, 0.0, -1.0)
    return ActionPreferences(q_nominal=q, q_constrained=q, sq_nominal=onehot,
                             sq_constrained=onehot, feasible=np.ones_like(onehot, dtype=bool),
                             temperature=prefs.temperature, terminal=prefs.terminal,
                             nominal=prefs.nominal)


# ------------------------------------------------------------------ Theorem 2
def wa_most_likely_interval(sq_n, sq_c, action):
    """The weights ``w_n`` for which WA makes ``action`` strictly the most likely.

    Parameters
    ----------
    sq_n, sq_c : array_like, shape (k,)
        The two preference distributions of one state.
    action : int
        Index of the action.

    Returns
    -------
    tuple of float or None
        ``(low, high)``: the interval of ``w_n`` in ``[0, 1]`` where
        ``p_WA(action) > p_WA(a) + 1e-12`` for every other ``a`` (open at an end where
        a condition binds); ``None`` when no weights do.

    Notes
    -----
    ``p_WA(a) = w_n sq_n(a) + (1 - w_n) sq_c(a)`` is linear in ``w_n``, so the WA family
    is the segment from ``sq_c`` (``w_n = 0``) to ``sq_n`` (``w_n = 1``). Each condition
    ``p_WA(action) - p_WA(a) = d_c + w_n (d_n - d_c) > 0`` with ``d = sq(action) - sq(a)``
    is a half-line in ``w_n``; their intersection with ``[0, 1]`` is the answer, found
    exactly (no grid).

    Examples
    --------
    The paper's example: no WA weights make the middle action the most likely.

    >>> from orchestration.expressiveness import wa_most_likely_interval
    >>> print(wa_most_likely_interval([1/6, 1/3, 1/2], [1/2, 1/3, 1/6], 1))
    None
    >>> [round(x, 6) for x in wa_most_likely_interval([1/6, 1/3, 1/2], [1/2, 1/3, 1/6], 2)]
    [0.5, 1.0]
    """
    sq_n = _as_distribution("sq_n", sq_n)
    sq_c = _as_distribution("sq_c", sq_c, sq_n.size)
    if isinstance(action, bool) or not isinstance(action, (int, np.integer)) \
            or not 0 <= int(action) < sq_n.size:
        raise ValueError(f"action must be an index in [0, {sq_n.size}) (got {action!r})")
    low, high = 0.0, 1.0
    low_open = high_open = False
    for a in range(sq_n.size):
        if a == action:
            continue
        dn, dc = sq_n[action] - sq_n[a], sq_c[action] - sq_c[a]
        slope = dn - dc  # condition: dc + w slope > margin
        if abs(slope) <= _MARGIN:
            if dc <= _MARGIN:
                return None
        elif slope > 0.0:  # w > (margin - dc) / slope
            root = (_MARGIN - dc) / slope
            if root > low or (root == low and not low_open):
                low, low_open = root, True
        else:  # w < (margin - dc) / slope
            root = (_MARGIN - dc) / slope
            if root < high or (root == high and not high_open):
                high, high_open = root, True
    if low > high or (low == high and (low_open or high_open)):
        return None
    return (float(max(low, 0.0)), float(min(high, 1.0))) if low <= 1.0 and high >= 0.0 else None


def wa_weights_for(p, sq_n, sq_c, *, atol=1e-9):
    """The WA weights ``(w_n, w_c)`` that produce the distribution ``p``, or ``None``.

    ``p`` is WA-expressible exactly when it lies on the segment between ``sq_c`` and
    ``sq_n``: the least-squares ``w_n`` is computed and the residual checked against
    ``atol`` (largest absolute difference).

    Examples
    --------
    >>> from orchestration.expressiveness import wa_weights_for
    >>> wa_weights_for([0.3, 0.7], [0.0, 1.0], [1.0, 0.0])
    (0.7, 0.3)
    >>> print(wa_weights_for([0.2, 0.6, 0.2], [1/6, 1/3, 1/2], [1/2, 1/3, 1/6]))
    None
    """
    sq_n = _as_distribution("sq_n", sq_n)
    sq_c = _as_distribution("sq_c", sq_c, sq_n.size)
    p = _as_distribution("p", p, sq_n.size)
    d = sq_n - sq_c
    denom = float(d @ d)
    w = 0.5 if denom == 0.0 else float(np.clip((p - sq_c) @ d / denom, 0.0, 1.0))
    if np.abs(w * sq_n + (1 - w) * sq_c - p).max() > atol:
        return None
    return (round(w, 12), round(1.0 - w, 12))


@dataclass(frozen=True, eq=False)
class CompromiseWitness:
    """A distribution MDFT produces and no WA weights can (the paper's Theorem 2).

    Attributes
    ----------
    sq_nominal, sq_constrained : ndarray, shape (3,)
        The state's preferences (the paper's example by default).
    weights : tuple of float
        MDFT attention ``(w_n, w_c)``.
    settings : dict
        ``phi1``, ``phi2``, ``beta``, ``sigma2`` and ``n_steps`` of the MDFT orchestrator.
    probabilities : ndarray, shape (3,)
        Its choice distribution (:func:`mdft.choice_probabilities`, normal approximation).
    wa_interval : None
        :func:`wa_most_likely_interval` for the middle action: ``None``, no WA weights
        make it the most likely.

    Examples
    --------
    >>> from orchestration.expressiveness import compromise_witness
    >>> orch = compromise_witness().orchestrator()
    >>> orch.action_probabilities(0).round(3).tolist()
    [0.235, 0.457, 0.308]
    """

    sq_nominal: np.ndarray
    sq_constrained: np.ndarray
    weights: tuple
    settings: dict
    probabilities: np.ndarray
    wa_interval: object

    def orchestrator(self):
        """The witness as an :class:`MDFTOrchestrator` over a one-state world (state 0)."""
        from .orchestrators import MDFTOrchestrator

        prefs = _one_state_preferences(self.sq_nominal, self.sq_constrained)
        return MDFTOrchestrator.from_preferences(prefs, self.weights, **self.settings)


def compromise_witness(sq_nominal=None, sq_constrained=None, *, weights=(0.55, 0.45),
                       settings=None) -> CompromiseWitness:
    """Build and check a Theorem-2 witness: MDFT makes the middle action the most likely.

    Parameters
    ----------
    sq_nominal, sq_constrained : array_like, shape (3,), optional
        Default: the paper's example ``(1/6, 1/3, 1/2)`` and ``(1/2, 1/3, 1/6)``.
    weights : pair of float, default (0.55, 0.45)
        The paper's attention weights.
    settings : dict, optional
        MDFT settings (``phi1``, ``phi2``, ``beta``, ``sigma2``, ``n_steps``). Default
        :data:`WITNESS_SETTINGS`: the paper's orchestrator settings (``beta = 2``,
        ``sigma2 = 1``, ``T = 100``) except ``phi1 = 0.022 * 6**4`` and ``phi2 = 0.05``, the
        canonical lateral inhibition moved to the scale of the sq's.

    Returns
    -------
    CompromiseWitness

    Raises
    ------
    ValueError
        If the construction is not a witness: MDFT does not make action 1 strictly the
        most likely, or some WA weights do.

    Notes
    -----
    Under the paper's own orchestrator settings (``phi1 = phi2 = 0.01``, ``beta = 2``,
    ``sigma2 = 1``, ``T = 100``) the paper's example is *not* a witness: the middle
    action gets about 0.326 and the third about 0.406 (``docs/orchestration.md``), and
    this function raises for those settings.

    Examples
    --------
    >>> from orchestration.expressiveness import compromise_witness
    >>> wit = compromise_witness()
    >>> wit.probabilities.round(3).tolist(), wit.wa_interval
    ([0.235, 0.457, 0.308], None)
    """
    if sq_nominal is None and sq_constrained is None:
        sq_n, sq_c = (p.copy() for p in PAPER_COMPROMISE_SQ)
    else:
        sq_n = _as_distribution("sq_nominal", sq_nominal, 3)
        sq_c = _as_distribution("sq_constrained", sq_constrained, 3)
    w = _check_weights(weights)
    cfg = dict(WITNESS_SETTINGS) if settings is None else dict(settings)
    unknown = set(cfg) - {"phi1", "phi2", "beta", "sigma2", "n_steps"}
    if unknown:
        raise ValueError(f"settings has unknown keys {sorted(unknown)}; use phi1, phi2, beta, "
                         "sigma2 and n_steps")
    prefs = _one_state_preferences(sq_n, sq_c)
    from .orchestrators import MDFTOrchestrator

    p = MDFTOrchestrator.from_preferences(prefs, tuple(w), **cfg).action_probabilities(0)
    interval = wa_most_likely_interval(sq_n, sq_c, 1)
    if not p[1] > max(p[0], p[2]):
        raise ValueError(
            f"not a witness: under these settings MDFT gives {np.round(p, 4).tolist()}, the "
            "middle action is not the most likely"
        )
    if interval is not None:
        raise ValueError(f"not a witness: WA makes the middle action the most likely for w_n in "
                         f"{interval}")
    p.flags.writeable = False
    return CompromiseWitness(sq_n, sq_c, (float(w[0]), float(w[1])), cfg, p, interval)


# ------------------------------------------------------------------ Theorem 3
def identity_mdft(p) -> mdft.MDFTModel:
    """The MDFT model of the paper's Theorem 3: ``M = I_k``, ``w = p``, no noise.

    With one deliberation step, ``P(1) = C M e_j = C e_j`` for the attended attribute
    ``j``; its largest entry is option ``j``, so option ``j`` is chosen with probability
    ``w_j = p_j``. The noise must be zero (``sigma2 = 0``): with noise the first step
    no longer decides deterministically. ``phi1``, ``phi2``, ``beta`` play no role in
    one step from ``P(0) = 0``; they are set to the paper's orchestrator values.

    Examples
    --------
    >>> from orchestration.expressiveness import identity_mdft, enumerate_fixed_time
    >>> model = identity_mdft([0.2, 0.5, 0.3])
    >>> enumerate_fixed_time(model, 1).tolist()
    [0.2, 0.5, 0.3]
    """
    p = _as_distribution("p", p)
    if p.size < 2:
        raise ValueError(f"p must have at least 2 actions (got {p.size})")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", mdft.UnstableFeedbackWarning)
        return mdft.MDFTModel(np.eye(p.size), p, phi1=0.01, phi2=0.01, beta=2.0, sigma2=0.0)


def enumerate_fixed_time(model, n_steps) -> np.ndarray:
    """Exact fixed-time choice probabilities of a noiseless model by enumeration.

    Every attention sequence ``(j_1, ..., j_T)`` is enumerated with its probability
    ``prod w_{j_t}``; without noise it fixes ``P(T)``, and the option(s) with the
    largest preference win (ties split equally, as the engine breaks them uniformly).

    Parameters
    ----------
    model : mdft.MDFTModel
        A model with ``sigma2 == 0``.
    n_steps : int
        ``T``; ``n_attributes ** T`` must be at most 1,000,000.

    Returns
    -------
    ndarray, shape (n_options,)

    Examples
    --------
    >>> import mdft
    >>> from orchestration.expressiveness import enumerate_fixed_time
    >>> model = mdft.MDFTModel([[1.0, 0.0], [0.0, 1.0]], [0.3, 0.7], phi1=0.022, phi2=0.05,
    ...                        beta=12.0, sigma2=0.0)
    >>> enumerate_fixed_time(model, 1).tolist()
    [0.3, 0.7]
    """
    if not isinstance(model, mdft.MDFTModel):
        raise TypeError(f"model must be an mdft.MDFTModel (got {type(model).__name__})")
    if model.sigma2 != 0.0:
        raise ValueError(f"enumerate_fixed_time needs a noiseless model, sigma2 = 0 (got {model.sigma2})")
    if isinstance(n_steps, bool) or not isinstance(n_steps, (int, np.integer)) or n_steps < 1:
        raise ValueError(f"n_steps must be an integer >= 1 (got {n_steps!r})")
    J = model.n_attributes
    if J ** int(n_steps) > _MAX_SEQUENCES:
        raise ValueError(f"n_attributes ** n_steps = {J}**{n_steps} sequences exceed "
                         f"{_MAX_SEQUENCES:,}; use fewer steps")
    S, CM, w = np.asarray(model.S), np.asarray(model.C) @ np.asarray(model.M), np.asarray(model.w)
    out = np.zeros(model.n_options)
    for seq in itertools.product(range(J), repeat=int(n_steps)):
        prob = math.prod(w[j] for j in seq)
        if prob == 0.0:
            continue
        P = np.array(model.P0, dtype=np.float64)
        for j in seq:
            P = S @ P + CM[:, j]
        best = np.flatnonzero(P >= P.max() - 1e-12 * max(1.0, abs(P.max())))
        out[best] += prob / best.size
    return out


# ------------------------------------------------------- MDFT vs WA experiment
@dataclass(frozen=True, eq=False)
class MDFTvsWAInstance:
    """One instance of the paper's MDFT-vs-WA experiment.

    Attributes
    ----------
    seed : int
        The instance is a pure function of it.
    sq_nominal, sq_constrained : ndarray, shape (n_actions,)
        Random preference distributions (uniform on the simplex).
    wa_weights : tuple of float
        Random WA weights ``(w_n, 1 - w_n)``, ``w_n`` uniform on [0, 1].
    wa_probabilities : ndarray, shape (n_actions,)
        The WA distribution.
    counts : ndarray of int, shape (n_actions,)
        ``n_choices`` choices sampled from it.
    fitted_weights : tuple of float
        MDFT attention fitted to ``counts`` by maximum likelihood (:func:`mdft.fit`,
        ``M = [sq_n, sq_c]`` fixed).
    mdft_probabilities : ndarray, shape (n_actions,)
        The fitted MDFT's distribution.
    js_divergence : float
        JS divergence (nats) between ``wa_probabilities`` and ``mdft_probabilities``.
    exact_fit_weights : tuple of float
        The attention that minimises the JS divergence to the exact WA distribution.
    exact_fit_probabilities : ndarray, shape (n_actions,)
    exact_fit_js_divergence : float
        Its JS divergence: the part of ``js_divergence`` that no amount of data removes.

    Examples
    --------
    >>> from orchestration import mdft_vs_wa_instance
    >>> inst = mdft_vs_wa_instance(3, n_actions=3, n_choices=30, n_steps=10)
    >>> inst.wa_probabilities.shape, inst.seed
    ((3,), 3)
    """

    seed: int
    sq_nominal: np.ndarray
    sq_constrained: np.ndarray
    wa_weights: tuple
    wa_probabilities: np.ndarray
    counts: np.ndarray
    fitted_weights: tuple
    mdft_probabilities: np.ndarray
    js_divergence: float
    exact_fit_weights: tuple
    exact_fit_probabilities: np.ndarray
    exact_fit_js_divergence: float

    def __repr__(self) -> str:
        return (f"MDFTvsWAInstance(seed={self.seed}, n_actions={self.wa_probabilities.size}, "
                f"js_divergence={self.js_divergence:.6g}, "
                f"exact_fit_js_divergence={self.exact_fit_js_divergence:.6g})")

    def summary(self) -> str:
        """The WA and fitted MDFT distributions side by side, with both divergences.

        Examples
        --------
        >>> from orchestration import mdft_vs_wa_instance
        >>> inst = mdft_vs_wa_instance(3, n_actions=3, n_choices=30, n_steps=10)
        >>> print(inst.summary())  # doctest: +ELLIPSIS
        MDFT vs WA, seed 3: WA weights (...), MDFT fitted to 30 choices (...)
        action        WA    choices   MDFT fit  MDFT exact
        ...
        JS divergence (nats): ... fitted to the choices, ... best fit to the WA distribution
        """
        rows = [f"{'action':<8s} {'WA':>8s} {'choices':>10s} {'MDFT fit':>10s} {'MDFT exact':>11s}"]
        rows += [f"{a:<8d} {p:8.4f} {int(c):10d} {q:10.4f} {r:11.4f}"
                 for a, (p, c, q, r) in enumerate(zip(self.wa_probabilities, self.counts,
                                                       self.mdft_probabilities,
                                                       self.exact_fit_probabilities))]
        w = ", ".join(f"{v:.3f}" for v in self.wa_weights)
        f = ", ".join(f"{v:.3f}" for v in self.fitted_weights)
        return (f"MDFT vs WA, seed {self.seed}: WA weights ({w}), MDFT fitted to "
                f"{int(self.counts.sum())} choices ({f})\n" + "\n".join(rows) + "\n"
                f"JS divergence (nats): {self.js_divergence:.4f} fitted to the choices, "
                f"{self.exact_fit_js_divergence:.4f} best fit to the WA distribution")


def _mdft_probabilities(M, w_n, settings, n_steps):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", mdft.UnstableFeedbackWarning)
        model = mdft.MDFTModel(M, [w_n, 1.0 - w_n], **settings)
    # the normal approximation, as in mdft.fit: smooth in w_n, never switching method
    return mdft.choice_probabilities(model, n_steps, method="normal")


def mdft_vs_wa_instance(seed, *, n_actions=8, n_choices=100, n_steps=25, phi1=0.01, phi2=0.01,
                        beta=2.0, sigma2=1.0, n_starts=1) -> MDFTvsWAInstance:
    """One instance of the paper's MDFT-vs-WA experiment, a pure function of ``seed``.

    Parameters
    ----------
    seed : int
        Seeds :func:`numpy.random.default_rng` for the random sq's, weights and choices.
    n_actions : int, default 8
    n_choices : int, default 100
        Choices sampled from the WA distribution.
    n_steps : int, default 25
        MDFT deliberation time.
    phi1, phi2, beta, sigma2 : float
        MDFT settings, fixed in the fit (the paper's orchestrator values by default).
    n_starts : int, default 1
        Optimiser starts of :func:`mdft.fit` (one free parameter, a smooth likelihood).

    Returns
    -------
    MDFTvsWAInstance

    Notes
    -----
    ``sq_n, sq_c ~ Dirichlet(1, ..., 1)``, ``w_n ~ U(0, 1)``, ``p_WA = w_n sq_n + (1 -
    w_n) sq_c``, ``counts ~ Multinomial(n_choices, p_WA)``. The attention of an MDFT
    model with ``M = [sq_n, sq_c]`` is fitted to the counts by maximum likelihood with
    the fixed-time closed form (its normal approximation, ``method="normal"``, as in
    :func:`mdft.fit`), and separately chosen to minimise the JS divergence to
    ``p_WA`` itself (a grid of 21 weights refined by bounded Brent search).

    Examples
    --------
    >>> from orchestration import mdft_vs_wa_instance
    >>> inst = mdft_vs_wa_instance(0, n_actions=3, n_choices=50)
    >>> int(inst.counts.sum()), bool(inst.exact_fit_js_divergence <= inst.js_divergence + 1e-9)
    (50, True)
    """
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be a non-negative integer (got {seed!r})")
    for name, value, low in (("n_actions", n_actions, 2), ("n_choices", n_choices, 1),
                             ("n_steps", n_steps, 1), ("n_starts", n_starts, 1)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low:
            raise ValueError(f"{name} must be an integer >= {low} (got {value!r})")
    settings = dict(phi1=phi1, phi2=phi2, beta=beta, sigma2=sigma2)
    for name, value in settings.items():
        if not np.isfinite(value) or value < 0:
            raise ValueError(f"{name} must be finite and >= 0 (got {value!r})")
    rng = np.random.default_rng(int(seed))
    sq_n = rng.dirichlet(np.ones(n_actions))
    sq_c = rng.dirichlet(np.ones(n_actions))
    w_n = float(rng.uniform())
    p_wa = w_n * sq_n + (1.0 - w_n) * sq_c
    counts = rng.multinomial(n_choices, p_wa)
    M = np.stack([sq_n, sq_c], axis=1)

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", mdft.UnstableFeedbackWarning)
        warnings.simplefilter("ignore", mdft.FitConvergenceWarning)
        fit = mdft.fit(mdft.ChoiceData([list(range(n_actions))], [counts]), M, stopping=n_steps,
                       params=["w"], fixed=settings, n_starts=n_starts, rng=rng)
    w_fit = float(fit.params["w"][0])
    p_fit = _mdft_probabilities(M, w_fit, settings, n_steps)

    def objective(w):
        return irl.js_divergence(p_wa, _mdft_probabilities(M, float(w), settings, n_steps))

    grid = np.linspace(0.0, 1.0, 21)
    values = [objective(w) for w in grid]
    i = int(np.argmin(values))
    lo, hi = grid[max(i - 1, 0)], grid[min(i + 1, grid.size - 1)]
    best = optimize.minimize_scalar(objective, bounds=(lo, hi), method="bounded",
                                    options={"xatol": 1e-5})
    # the best of the grid, the refinement and the weights fitted to the sampled choices
    candidates = [(float(values[i]), float(grid[i])), (float(best.fun), float(best.x)),
                  (objective(w_fit), w_fit)]
    js_exact, w_exact = min(candidates)
    p_exact = _mdft_probabilities(M, w_exact, settings, n_steps)
    for arr in (sq_n, sq_c, p_wa, counts, p_fit, p_exact):
        arr.flags.writeable = False
    return MDFTvsWAInstance(
        seed=int(seed), sq_nominal=sq_n, sq_constrained=sq_c, wa_weights=(w_n, 1.0 - w_n),
        wa_probabilities=p_wa, counts=counts, fitted_weights=(w_fit, 1.0 - w_fit),
        mdft_probabilities=p_fit, js_divergence=irl.js_divergence(p_wa, p_fit),
        exact_fit_weights=(w_exact, 1.0 - w_exact), exact_fit_probabilities=p_exact,
        exact_fit_js_divergence=js_exact,
    )


@dataclass(frozen=True, eq=False)
class MDFTvsWAResult:
    """Aggregate of :func:`mdft_vs_wa`.

    Attributes
    ----------
    instances : tuple of MDFTvsWAInstance
    mean_js, se_js : float
        Mean JS divergence (nats) of the MDFT fitted to sampled choices, and its standard
        error over instances.
    mean_exact_js, se_exact_js : float
        The same for the attention fitted to the exact WA distributions.

    Examples
    --------
    >>> from orchestration import mdft_vs_wa
    >>> res = mdft_vs_wa(1, rng=0, n_actions=3, n_choices=30, n_steps=10)
    >>> res.n_instances, str(res.se_js)
    (1, 'nan')
    """

    instances: tuple
    mean_js: float
    se_js: float
    mean_exact_js: float
    se_exact_js: float

    @property
    def n_instances(self) -> int:
        """Number of instances."""
        return len(self.instances)

    def __repr__(self) -> str:
        return (f"MDFTvsWAResult(n_instances={self.n_instances}, mean_js={self.mean_js:.6g}, "
                f"se_js={self.se_js:.6g}, mean_exact_js={self.mean_exact_js:.6g}, "
                f"se_exact_js={self.se_exact_js:.6g})")

    def summary(self) -> str:
        """Mean JS divergences with their standard errors, as a text table.

        Examples
        --------
        >>> from orchestration import mdft_vs_wa
        >>> print(mdft_vs_wa(2, rng=0, n_actions=3, n_choices=30, n_steps=10).summary())
        ... # doctest: +ELLIPSIS
        MDFT vs WA over 2 instances: mean JS divergence (nats)
        MDFT fitted to sampled choices              ... +- ...
        MDFT best fit to the exact WA distribution  ... +- ...
        """
        return (f"MDFT vs WA over {self.n_instances} instances: mean JS divergence (nats)\n"
                f"{'MDFT fitted to sampled choices':<43s} {self.mean_js:.4f} +- {self.se_js:.4f}\n"
                f"{'MDFT best fit to the exact WA distribution':<43s} {self.mean_exact_js:.4f} "
                f"+- {self.se_exact_js:.4f}")


def _mean_se(x):
    x = np.asarray(x, dtype=np.float64)
    se = float(x.std(ddof=1) / np.sqrt(x.size)) if x.size > 1 else float("nan")
    return float(x.mean()), se


def mdft_vs_wa(n_instances=100, *, rng=None, progress=None, **options) -> MDFTvsWAResult:
    """The paper's MDFT-vs-WA experiment: :func:`mdft_vs_wa_instance` over many seeds.

    Parameters
    ----------
    n_instances : int, default 100
    rng : None, int or numpy.random.Generator
        Draws the instances' seeds (``integers(0, 2**63 - 1)``).
    progress : callable, optional
        Called as ``progress(i, n_instances)`` after each instance.
    **options
        Passed to :func:`mdft_vs_wa_instance`.

    Returns
    -------
    MDFTvsWAResult
        With ``n_instances = 1`` the standard errors are NaN (undefined).

    Examples
    --------
    >>> from orchestration import mdft_vs_wa
    >>> res = mdft_vs_wa(2, rng=0, n_actions=3, n_choices=50)
    >>> res.n_instances, bool(res.mean_exact_js <= res.mean_js + 1e-9)
    (2, True)
    """
    if isinstance(n_instances, bool) or not isinstance(n_instances, (int, np.integer)) \
            or n_instances < 1:
        raise ValueError(f"n_instances must be an integer >= 1 (got {n_instances!r})")
    if progress is not None and not callable(progress):
        raise TypeError(f"progress must be callable or None (got {progress!r})")
    seeds = np.random.default_rng(rng).integers(0, 2**63 - 1, size=int(n_instances))
    instances = []
    for i, seed in enumerate(seeds):
        instances.append(mdft_vs_wa_instance(int(seed), **options))
        if progress is not None:
            progress(i + 1, int(n_instances))
    mean_js, se_js = _mean_se([x.js_divergence for x in instances])
    mean_ex, se_ex = _mean_se([x.exact_fit_js_divergence for x in instances])
    return MDFTvsWAResult(tuple(instances), mean_js, se_js, mean_ex, se_ex)
