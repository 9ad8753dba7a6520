"""The classic context effects of choice as ready-to-run MDFT scenarios.

Three scenarios reproduce the similarity, attraction and compromise effects
with the canonical parameters of Hotaling, Busemeyer & Li (2010)
(``docs/concepts.md``, section 7): options A = (1, 3) and B = (3, 1), plus a
third option that changes the choice between them. Each scenario is compared
with the binary baseline {A, B}.

:func:`context_effects` runs one, several or all of them and returns a
:class:`ContextEffects` collection of :class:`EffectResult` objects holding the
choice shares, their standard errors, the size of the effect and whether it is
shown at the stated significance criterion.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
import os
from dataclasses import dataclass, field
from typing import Any, Iterator, Sequence

import numpy as np

from ._typing import SeedLike
from ._export import builtin, describe_stopping, fmt, stopping_dict, table, to_json
from ._validation import MAX_SAMPLES, as_count, as_float_array, as_generator, as_scalar
from .closed_form import choice_probabilities
from .model import MDFTModel
from .simulate import simulate
from .stopping import FixedTime, Threshold

__all__ = [
    "ATTRACTION",
    "COMPROMISE",
    "CANONICAL_THETA",
    "ContextEffect",
    "ContextEffects",
    "EffectResult",
    "SCENARIOS",
    "SIMILARITY",
    "context_effects",
    "default_stopping",
]

#: Preference threshold of the canonical parameter set (Hotaling et al. 2010).
CANONICAL_THETA = 17.5
_DEFAULT_MAX_STEPS = 10_000
#: Fewest Monte Carlo trials per option set: with fewer, the binomial standard errors of
#: the shares are too coarse to test an effect (and a share can be 0 by chance alone).
_MIN_SAMPLES = 100
_MEASURES = ("relative_share", "margin")
_METHODS = ("monte_carlo", "analytic")


def _as_tuple(name, value) -> tuple:
    if isinstance(value, (int, np.integer)) and not isinstance(value, bool):
        return (value,)
    try:
        return tuple(value)
    except TypeError:
        raise TypeError(f"{name} must be a sequence of option indices (got {value!r})") from None


def _index(name, value, n) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise TypeError(f"{name} must hold integer option indices (got {value!r})")
    if not 0 <= value < n:
        raise ValueError(f"{name} must hold option indices in [0, {n - 1}] (got {value})")
    return int(value)


@dataclass(frozen=True)
class ContextEffect:
    """One context-effect scenario: a ternary option set against a binary baseline.

    Parameters
    ----------
    name : str
        Short name, used to select the scenario (``"similarity"`` ...).
    labels : tuple of str, length n_options
        One label per option (row of ``M``).
    M : tuple of tuples, shape (n_options, n_attributes)
        Evaluations ``M[option, attribute]`` of the full (ternary) set.
    target : int
        Index of the option the effect favours.
    rivals : tuple of int
        Options the target is compared with. For ``measure="relative_share"``
        exactly one rival; for ``measure="margin"`` one or more.
    measure : {"relative_share", "margin"}
        How the effect is measured (see Notes).
    baseline : tuple of int, default (0, 1)
        Indices of the two options of the binary baseline.
    expected : str
        The expected effect, in words.
    direction : {1, -1}, default 1
        Sign the effect size is expected to have.
    w : tuple of float, default (0.5, 0.5)
        Attention weights.
    phi1, phi2, beta, sigma2 : float
        Model parameters (``docs/concepts.md``, section 4); the canonical
        values by default.
    source : str
        Where the option set and parameters come from.

    Notes
    -----
    With ``t`` the target and ``r`` a rival, ``P3`` the ternary and ``P2`` the
    binary choice shares:

    * ``relative_share``: effect size ``P3(t) / (P3(t) + P3(r)) - P2(t) / (P2(t) + P2(r))``,
      the change of the target's share among choices of target or rival
      when the third option is added.
    * ``margin``: effect size ``P3(t) - max_r P3(r)``, how much more often the
      target is chosen than its strongest rival in the ternary set. The binary
      baseline is reported alongside: it shows that the rivals are balanced
      on their own.

    Examples
    --------
    >>> SIMILARITY.labels
    ('A', 'B', 'S')
    >>> SIMILARITY.model().n_options
    3
    >>> SIMILARITY.binary_model().M
    array([[1., 3.],
           [3., 1.]])
    """

    name: str
    labels: tuple
    M: tuple
    target: int
    rivals: tuple
    measure: str
    expected: str
    baseline: tuple = (0, 1)
    direction: int = 1
    w: tuple = (0.5, 0.5)
    phi1: float = 0.022
    phi2: float = 0.05
    beta: float = 12.0
    sigma2: float = 1.0
    source: str = "Hotaling, Busemeyer & Li (2010)"

    def __post_init__(self):
        if not isinstance(self.name, str) or not self.name:
            raise TypeError(f"name must be a non-empty string (got {self.name!r})")
        M = as_float_array("M", self.M, ndim=2)
        n, n_attributes = M.shape
        if n < 2 or n_attributes < 1:
            raise ValueError(
                f"M must have at least 2 options and 1 attribute (got shape {M.shape})"
            )
        object.__setattr__(self, "M", tuple(tuple(float(x) for x in row) for row in M))
        if not hasattr(self.labels, "__iter__") or isinstance(self.labels, dict):
            raise TypeError(f"labels must be a sequence of {n} strings (got {self.labels!r})")
        labels = tuple(str(label) for label in self.labels)
        if len(labels) != n:
            raise ValueError(
                f"labels must have one entry per option (row of M), {n} (got {len(labels)}: "
                f"{labels})"
            )
        object.__setattr__(self, "labels", labels)
        object.__setattr__(self, "target", _index("target", self.target, n))
        rivals = tuple(_index("rivals", r, n) for r in _as_tuple("rivals", self.rivals))
        baseline = tuple(_index("baseline", b, n) for b in _as_tuple("baseline", self.baseline))
        if not isinstance(self.measure, str) or self.measure not in _MEASURES:
            raise ValueError(f"measure must be one of {_MEASURES} (got {self.measure!r})")
        if not rivals or self.target in rivals or len(set(rivals)) != len(rivals):
            raise ValueError(
                f"rivals must be distinct options other than the target {self.target} "
                f"(got {rivals})"
            )
        if len(baseline) != 2 or baseline[0] == baseline[1]:
            raise ValueError(f"baseline must hold two distinct options (got {baseline})")
        if self.measure == "relative_share":
            if len(rivals) != 1:
                raise ValueError(
                    f"rivals must hold exactly one option for measure='relative_share' "
                    f"(got {rivals})"
                )
            if set(baseline) != {self.target, rivals[0]}:
                raise ValueError(
                    "baseline must be the target and its rival for measure='relative_share' "
                    f"(got baseline {baseline}, target {self.target}, rivals {rivals})"
                )
        object.__setattr__(self, "rivals", rivals)
        object.__setattr__(self, "baseline", baseline)
        if (isinstance(self.direction, bool) or not isinstance(self.direction, numbers.Real)
                or self.direction not in (1, -1)):
            raise ValueError(f"direction must be 1 or -1 (got {self.direction!r})")
        w = as_float_array("w", self.w, shape=(n_attributes,))
        object.__setattr__(self, "w", tuple(float(x) for x in w))
        for name in ("phi1", "phi2", "beta", "sigma2"):
            object.__setattr__(self, name, as_scalar(name, getattr(self, name), low=0.0))
        self.model()  # validates w and the parameters as MDFTModel does

    @property
    def n_options(self) -> int:
        """Number of options in the ternary set."""
        return len(self.M)

    @property
    def parameters(self) -> dict:
        """The model parameters as keyword arguments of :class:`mdft.MDFTModel`."""
        return dict(phi1=self.phi1, phi2=self.phi2, beta=self.beta, sigma2=self.sigma2)

    def model(self) -> MDFTModel:
        """The MDFT model of the full option set."""
        return MDFTModel(self.M, self.w, **self.parameters)

    def binary_model(self) -> MDFTModel:
        """The MDFT model of the binary baseline (same parameters)."""
        return self.model().subset(list(self.baseline))

    def to_dict(self) -> dict:
        """The scenario's fields as JSON-ready builtins.

        Examples
        --------
        >>> COMPROMISE.to_dict()["M"]
        [[1.0, 3.0], [3.0, 1.0], [2.0, 2.0]]
        """
        return builtin({f.name: getattr(self, f.name) for f in dataclasses.fields(self)})

    def with_parameters(self, **changes: Any) -> "ContextEffect":
        """Return a copy with some fields replaced (e.g. other parameters).

        Examples
        --------
        >>> ATTRACTION.with_parameters(phi2=0.04).phi2
        0.04
        """
        return dataclasses.replace(self, **changes)


SIMILARITY = ContextEffect(
    name="similarity",
    labels=("A", "B", "S"),
    M=((1.0, 3.0), (3.0, 1.0), (0.9, 3.1)),
    target=1,
    rivals=(0,),
    measure="relative_share",
    expected="adding S, similar to A, raises B's share relative to A",
)
"""Similarity: S = (0.9, 3.1) is almost a copy of A; B gains relative to A."""

ATTRACTION = ContextEffect(
    name="attraction",
    labels=("A", "B", "D"),
    M=((1.0, 3.0), (3.0, 1.0), (0.5, 2.5)),
    target=0,
    rivals=(1,),
    measure="relative_share",
    expected="adding D, dominated by A only, raises A's share relative to B",
)
"""Attraction: D = (0.5, 2.5) is dominated by A, not by B; A gains relative to B."""

COMPROMISE = ContextEffect(
    name="compromise",
    labels=("A", "B", "C"),
    M=((1.0, 3.0), (3.0, 1.0), (2.0, 2.0)),
    target=2,
    rivals=(0, 1),
    measure="margin",
    expected="the middle option C is chosen more often than either extreme",
)
"""Compromise: C = (2, 2) lies halfway between A and B and beats both."""

#: The three canonical scenarios, by name.
SCENARIOS = {s.name: s for s in (SIMILARITY, ATTRACTION, COMPROMISE)}


@dataclass(frozen=True, eq=False)
class EffectResult:
    """Outcome of one context-effect scenario.

    Attributes
    ----------
    scenario : ContextEffect
        The scenario that was run.
    stopping : FixedTime or Threshold
        The stopping rule.
    method : {"monte_carlo", "analytic"}
        How the choice probabilities were obtained.
    n_samples : int
        Trials per option set (0 for ``method="analytic"``).
    ternary, ternary_se : ndarray, shape (n_options,)
        Choice shares in the full set and their standard errors.
    binary, binary_se : ndarray, shape (2,)
        Choice shares in the binary baseline (options ``scenario.baseline``) and
        their standard errors.
    p_undecided_ternary, p_undecided_binary : float
        Fraction of trials that did not decide (threshold stopping).
    ternary_measure, binary_measure : float
        The measure of the scenario in each set (``binary_measure`` is NaN for
        ``measure="margin"``).
    effect_size : float
        ``ternary_measure - binary_measure`` (relative share) or the ternary
        margin.
    standard_error : float
        Standard error of ``effect_size`` (0 for the analytic method).
    z : float
        ``direction * effect_size / standard_error``.
    criterion : float
        Number of standard errors required.
    shown : bool
        True if ``direction * effect_size > criterion * standard_error`` (and
        ``> 0`` for the analytic method).
    trajectories : ndarray, shape (n_trajectories, n_steps + 1, n_options), or None
        Preference trajectories of a few ternary trials, as recorded by
        :func:`mdft.simulate`.
    mean_response_times : ndarray, shape (n_options,), or None
        Mean decision step per chosen option in the ternary set (threshold
        stopping only).

    Examples
    --------
    >>> res = context_effects("compromise", n_samples=4000, rng=0)["compromise"]
    >>> res.scenario.labels, res.scenario.measure
    (('A', 'B', 'C'), 'margin')
    >>> bool(res.ternary[2] > max(res.ternary[0], res.ternary[1])), res.shown
    (True, True)
    """

    scenario: ContextEffect
    stopping: object
    method: str
    n_samples: int
    ternary: np.ndarray
    ternary_se: np.ndarray
    binary: np.ndarray
    binary_se: np.ndarray
    p_undecided_ternary: float
    p_undecided_binary: float
    ternary_measure: float
    binary_measure: float
    effect_size: float
    standard_error: float
    z: float
    criterion: float
    shown: bool
    trajectories: np.ndarray | None = field(default=None, repr=False)
    mean_response_times: np.ndarray | None = field(default=None, repr=False)

    @property
    def name(self) -> str:
        """The scenario's name."""
        return self.scenario.name

    def __repr__(self) -> str:
        return (
            f"EffectResult(name={self.name!r}, effect_size={self.effect_size:.4g}, "
            f"standard_error={self.standard_error:.4g}, z={self.z:.4g}, shown={self.shown})"
        )

    def summary(self) -> str:
        """A text table of the choice shares with and without the third option, and the effect.

        Examples
        --------
        >>> res = context_effects("attraction", n_samples=2000, rng=0)["attraction"]
        >>> print(res.summary())  # doctest: +ELLIPSIS
        attraction: adding D, dominated by A only, raises A's share relative to B
        threshold 17.5 (at most 10,000 steps), monte_carlo, 2,000 trials per option set
        option  ternary    s.e.  binary    s.e.
        A        0.5...
        B        0.4...
        D        0.0...       -       -
        relative_share: ... -> ..., effect +0.0... (s.e. 0.0..., z = ...): ...
        """
        sc = self.scenario
        binary_at = {opt: k for k, opt in enumerate(sc.baseline)}
        rows = []
        for i, label in enumerate(sc.labels):
            k = binary_at.get(i)
            rows.append([label, fmt(self.ternary[i]), fmt(self.ternary_se[i]),
                         "-" if k is None else fmt(self.binary[k]),
                         "-" if k is None else fmt(self.binary_se[k])])
        samples = (f"{self.n_samples:,} trials per option set" if self.n_samples
                   else "no sampling error")
        verdict = (f"shown at {self.criterion:g} s.e." if self.shown else "not shown")
        if sc.measure == "margin":
            measure = f"margin {fmt(self.ternary_measure)}"
        else:
            measure = (f"relative_share: {fmt(self.binary_measure)} -> "
                       f"{fmt(self.ternary_measure)}")
        return "\n".join([
            f"{sc.name}: {sc.expected}",
            f"{describe_stopping(self.stopping)}, {self.method}, {samples}",
            table(["option", "ternary", "s.e.", "binary", "s.e."], rows),
            f"{measure}, effect {fmt(self.effect_size, '+.4f')} "
            f"(s.e. {fmt(self.standard_error)}, z = {fmt(self.z, '.1f')}): {verdict}",
        ])

    def to_dict(self, *, trajectories: bool = False) -> dict:
        """The result as JSON-ready builtins (NaN, e.g. the binary measure of a margin,
        becomes None).

        Parameters
        ----------
        trajectories : bool, default False
            Also export the recorded preference trajectories.

        Examples
        --------
        >>> d = context_effects("compromise", n_samples=1000, rng=0)["compromise"].to_dict()
        >>> d["scenario"]["name"], d["stopping"]["rule"], d["binary_measure"]
        ('compromise', 'threshold', None)
        """
        out = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        out["scenario"] = self.scenario.to_dict()
        out["stopping"] = stopping_dict(self.stopping)
        if not trajectories:
            del out["trajectories"]
        return builtin(out)

    def to_json(self, path: str | os.PathLike | None = None, *, trajectories: bool = False) -> str:
        """:meth:`to_dict` as JSON text, also written to ``path`` if given."""
        return to_json(self.to_dict(trajectories=trajectories), path)


@dataclass(frozen=True)
class ContextEffects:
    """A collection of :class:`EffectResult`, indexable by position or name.

    Examples
    --------
    >>> results = context_effects("attraction", n_samples=2000, rng=0)
    >>> results.names
    ('attraction',)
    >>> results["attraction"].scenario is ATTRACTION
    True
    """

    results: tuple

    @property
    def names(self) -> tuple:
        """The scenario names, in order."""
        return tuple(r.name for r in self.results)

    @property
    def all_shown(self) -> bool:
        """True if every scenario shows its expected effect."""
        return all(r.shown for r in self.results)

    def __len__(self) -> int:
        return len(self.results)

    def __iter__(self) -> Iterator[EffectResult]:
        return iter(self.results)

    def __getitem__(self, key) -> EffectResult:
        if isinstance(key, str):
            for r in self.results:
                if r.name == key:
                    return r
            raise KeyError(f"no scenario named {key!r}; available: {list(self.names)}")
        return self.results[key]

    def summary(self) -> str:
        """One row per scenario: the measure with and without the third option, the effect.

        Examples
        --------
        >>> print(context_effects(n_samples=5000, rng=0).summary())  # doctest: +ELLIPSIS
        scenario    measure         binary  ternary   effect    s.e.  ...  shown
        similarity  relative_share  0.5...  yes
        attraction  relative_share  0.4...  yes
        compromise  margin               -   0.1...  yes
        all three effects shown (criterion: 3 standard errors)
        """
        rows = [[r.name, r.scenario.measure, fmt(r.binary_measure), fmt(r.ternary_measure),
                 fmt(r.effect_size, "+.4f"), fmt(r.standard_error), fmt(r.z, ".1f"),
                 "yes" if r.shown else "no"] for r in self.results]
        shown = sum(r.shown for r in self.results)
        n = len(self.results)
        words = {1: "one", 2: "two", 3: "three"}
        verdict = (f"all {words.get(n, n)} effects shown" if shown == n and n > 1
                   else f"{shown} of {n} effects shown")
        criteria = sorted({r.criterion for r in self.results})
        crit = ", ".join(f"{c:g}" for c in criteria)
        return (table(["scenario", "measure", "binary", "ternary", "effect", "s.e.", "z",
                       "shown"], rows, left=2)
                + f"\n{verdict} (criterion: {crit} standard errors)")

    def to_dict(self, *, trajectories: bool = False) -> dict:
        """``{"results": [...], "all_shown": bool}``, each result as :meth:`EffectResult.to_dict`.

        Examples
        --------
        >>> import json
        >>> d = context_effects("similarity", n_samples=1000, rng=0).to_dict()
        >>> [r["scenario"]["name"] for r in d["results"]], type(json.dumps(d))
        (['similarity'], <class 'str'>)
        """
        return {"results": [r.to_dict(trajectories=trajectories) for r in self.results],
                "all_shown": self.all_shown}

    def to_json(self, path: str | os.PathLike | None = None, *, trajectories: bool = False) -> str:
        """:meth:`to_dict` as JSON text, also written to ``path`` if given."""
        return to_json(self.to_dict(trajectories=trajectories), path)


def default_stopping() -> Threshold:
    """The default stopping rule of :func:`context_effects`: ``Threshold(17.5)``.

    The threshold of the canonical parameter set, with at most 10,000
    steps per trial. Under it all three canonical effects appear; no single
    fixed deliberation time shows all three (``docs/concepts.md``, section 8).

    Examples
    --------
    >>> default_stopping().theta
    17.5
    """
    return Threshold(CANONICAL_THETA, max_steps=_DEFAULT_MAX_STEPS)


def context_effects(
    scenarios: str | ContextEffect | Sequence[str | ContextEffect] | None = None,
    *,
    stopping: FixedTime | Threshold | None = None,
    n_samples: int = 20_000,
    method: str = "monte_carlo",
    criterion: float = 3.0,
    n_trajectories: int = 0,
    rng: SeedLike = None,
) -> ContextEffects:
    """Run context-effect scenarios against their binary baselines.

    Parameters
    ----------
    scenarios : str, ContextEffect or sequence of them, optional
        Which scenarios to run: a name (``"similarity"``, ``"attraction"``,
        ``"compromise"``), a :class:`ContextEffect`, or a sequence of these.
        All three canonical scenarios by default.
    stopping : FixedTime or Threshold, optional
        Stopping rule; :func:`default_stopping` (threshold 17.5) by default.
    n_samples : int, default 20_000
        Monte Carlo trials per option set (ternary and binary each), at least 100 (fewer
        cannot give a standard error worth the name) and at most 100,000,000.
    method : {"monte_carlo", "analytic"}, default "monte_carlo"
        ``"analytic"`` uses :func:`mdft.choice_probabilities` (the closed
        form; exact where the normal approximation may be off by more than
        0.002, or an error where no exact method applies) for fixed time and :func:`mdft.threshold_probabilities`
        for threshold stopping (two or three options; for three it can take
        minutes, or refuse a model whose error it cannot bound, see
        ``docs/threshold_exact.md``); no sampling error then.
    criterion : float, default 3.0
        The effect counts as shown when it lies in the expected direction by
        more than ``criterion`` standard errors (a one-sided test).
    n_trajectories : int, default 0
        Preference trajectories of the ternary set to keep for plotting
        (Monte Carlo only).
    rng : None, int or numpy.random.Generator
        Randomness, resolved with :func:`numpy.random.default_rng`. Each option
        set gets its own child generator, spawned in order.

    Returns
    -------
    ContextEffects
        One :class:`EffectResult` per scenario, in the order given.

    Notes
    -----
    Scenarios sharing the same baseline model (same options and parameters)
    share one simulation of it. Standard errors: for a relative share
    ``r = k_t / (k_t + k_r)`` (counts of target and rival) the binomial
    ``sqrt(r (1 - r) / (k_t + k_r))``; for a margin ``p_t - p_r`` the
    multinomial ``sqrt((p_t + p_r - (p_t - p_r)**2) / n)``; ternary and binary
    sets are simulated independently, so their variances add.

    Examples
    --------
    >>> results = context_effects(n_samples=5000, rng=0)
    >>> results.names
    ('similarity', 'attraction', 'compromise')
    >>> results.all_shown
    True
    >>> bool(results["compromise"].effect_size > 0)
    True
    """
    chosen = _resolve_scenarios(scenarios)
    if stopping is None:
        stopping = default_stopping()
    _check_stopping(stopping)
    if method not in _METHODS:
        raise ValueError(f"method must be one of {_METHODS} (got {method!r})")
    criterion = as_scalar("criterion", criterion, low=0.0)
    if method == "monte_carlo":
        n_samples = as_count("n_samples", n_samples, low=_MIN_SAMPLES, high=MAX_SAMPLES)
        n_trajectories = as_count("n_trajectories", n_trajectories, low=0)
        gen = as_generator("rng", rng)
        run: _MonteCarlo | _Analytic = _MonteCarlo(stopping, n_samples, gen)
    else:
        if n_trajectories:
            raise ValueError(
                f"n_trajectories must be 0 for method='analytic' (got {n_trajectories}); "
                "trajectories come from Monte Carlo trials"
            )
        n_samples = 0
        run = _Analytic(stopping)

    results = []
    cache: dict = {}
    for scenario in chosen:
        ternary = run(scenario.model(), n_trajectories)
        baseline = scenario.binary_model()
        key = (baseline.M.tobytes(), scenario.w, tuple(scenario.parameters.items()))
        if key not in cache:
            cache[key] = run(baseline, 0)
        binary = cache[key]
        results.append(_evaluate(scenario, ternary, binary, stopping, method, n_samples, criterion))
    return ContextEffects(tuple(results))


# ----------------------------------------------------------------------------- internals
@dataclass(frozen=True, eq=False)
class _Shares:
    probabilities: np.ndarray
    standard_errors: np.ndarray
    counts: np.ndarray | None
    n_samples: int
    p_undecided: float
    trajectories: np.ndarray | None = None
    mean_response_times: np.ndarray | None = None


class _MonteCarlo:
    def __init__(self, stopping, n_samples, gen):
        self.stopping, self.n_samples, self.gen = stopping, n_samples, gen

    def __call__(self, model, n_trajectories):
        (child,) = self.gen.spawn(1)
        res = simulate(
            model, self.n_samples, stopping=self.stopping, rng=child,
            n_trajectories=n_trajectories,
        )
        rts = res.mean_response_times if isinstance(self.stopping, Threshold) else None
        return _Shares(
            probabilities=np.asarray(res.probabilities, dtype=float),
            standard_errors=np.asarray(res.standard_errors, dtype=float),
            counts=np.asarray(res.counts),
            n_samples=int(res.n_samples),
            p_undecided=float(res.p_undecided),
            trajectories=res.trajectories if n_trajectories else None,
            mean_response_times=None if rts is None else np.asarray(rts, dtype=float),
        )


class _Analytic:
    def __init__(self, stopping):
        self.stopping = stopping

    def __call__(self, model, n_trajectories):
        if isinstance(self.stopping, FixedTime):
            p = np.asarray(choice_probabilities(model, self.stopping.n_steps), dtype=float)
            p_undecided = 0.0
            rts = None
        else:
            from .threshold_exact import threshold_probabilities

            res = threshold_probabilities(
                model, self.stopping.theta, max_steps=self.stopping.max_steps, fallback="raise"
            )
            p = np.asarray(res.probabilities, dtype=float)
            p_undecided = float(res.p_undecided)
            rts = np.asarray(res.mean_response_times, dtype=float)
        return _Shares(p, np.zeros_like(p), None, 0, p_undecided, None, rts)


def _evaluate(scenario, tern, bina, stopping, method, n_samples, criterion) -> EffectResult:
    t = scenario.target
    p3 = tern.probabilities
    p2 = bina.probabilities
    if scenario.measure == "relative_share":
        (r,) = scenario.rivals
        # positions of target and rival within the binary baseline
        bt, br = scenario.baseline.index(t), scenario.baseline.index(r)
        m3, se3 = _relative_share(p3[t], p3[r], tern)
        m2, se2 = _relative_share(p2[bt], p2[br], bina)
        effect = m3 - m2
        se = math.sqrt(se3**2 + se2**2)
    else:
        r = max(scenario.rivals, key=lambda i: p3[i])
        m3 = float(p3[t] - p3[r])
        m2 = math.nan
        effect = m3
        if tern.n_samples:
            se = math.sqrt(max(p3[t] + p3[r] - (p3[t] - p3[r]) ** 2, 0.0) / tern.n_samples)
        else:
            se = 0.0
    signed = scenario.direction * effect
    if se > 0:
        z = signed / se
        shown = bool(signed > criterion * se)
    else:
        z = math.copysign(math.inf, signed) if signed != 0 and not math.isnan(signed) else 0.0
        shown = bool(signed > 0) if method == "analytic" else False
    if math.isnan(effect):
        z, shown = math.nan, False
    return EffectResult(
        scenario=scenario,
        stopping=stopping,
        method=method,
        n_samples=n_samples,
        ternary=_readonly(p3),
        ternary_se=_readonly(tern.standard_errors),
        binary=_readonly(p2),
        binary_se=_readonly(bina.standard_errors),
        p_undecided_ternary=tern.p_undecided,
        p_undecided_binary=bina.p_undecided,
        ternary_measure=float(m3),
        binary_measure=float(m2),
        effect_size=float(effect),
        standard_error=float(se),
        z=float(z),
        criterion=criterion,
        shown=shown,
        trajectories=tern.trajectories,
        mean_response_times=tern.mean_response_times,
    )


def _relative_share(p_target, p_rival, shares: _Shares):
    total = p_target + p_rival
    if total <= 0:
        how = (f"in {shares.n_samples:,} trials" if shares.n_samples
               else "with positive probability")
        raise ValueError(
            f"the relative share is undefined: neither the target nor its rival was chosen "
            f"{how}; raise n_samples or check the scenario"
        )
    r = float(p_target / total)
    if shares.n_samples == 0:
        return r, 0.0
    k = total * shares.n_samples  # trials that chose target or rival
    return r, math.sqrt(r * (1.0 - r) / k)


def _resolve_scenarios(scenarios) -> tuple:
    if scenarios is None:
        return tuple(SCENARIOS.values())
    if isinstance(scenarios, (str, ContextEffect)):
        scenarios = [scenarios]
    if not isinstance(scenarios, Sequence) or len(scenarios) == 0:
        raise TypeError(
            "scenarios must be a scenario name, a ContextEffect or a non-empty sequence of "
            f"them (got {scenarios!r})"
        )
    out = []
    for s in scenarios:
        if isinstance(s, ContextEffect):
            out.append(s)
        elif isinstance(s, str) and s in SCENARIOS:
            out.append(SCENARIOS[s])
        elif isinstance(s, str):
            raise ValueError(f"scenarios: unknown scenario {s!r}; known: {sorted(SCENARIOS)}")
        else:
            raise TypeError(
                f"scenarios must hold names or ContextEffect objects (got {type(s).__name__})"
            )
    return tuple(out)


def _check_stopping(stopping) -> None:
    if not isinstance(stopping, (FixedTime, Threshold)):
        raise TypeError(
            f"stopping must be mdft.FixedTime or mdft.Threshold (got {type(stopping).__name__})"
        )


def _readonly(a) -> np.ndarray:
    a = np.array(a, dtype=float, copy=True)
    a.flags.writeable = False
    return a
