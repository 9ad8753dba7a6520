"""Fitting MDFT to observed choices by maximum likelihood.

Data are choice counts on one or more subsets of a common option set (:class:`ChoiceData`).
:func:`fit` estimates any chosen subset of the parameters ``w``, ``phi1``, ``phi2``,
``beta``, ``sigma2`` and, optionally, the evaluations ``M``, holding the others fixed, by
maximising the multinomial log-likelihood

    log L = sum_k [ log(n_k! / prod_i c_ki!) + sum_i c_ki log p_ki(theta) ]

where ``c_ki`` is the number of times option ``i`` of subset ``k`` was chosen out of
``n_k`` trials and ``p_ki`` the model's choice probability for that subset:

* fixed deliberation time: the closed form (:func:`mdft.choice_probabilities`);
* threshold stopping: the exact Markov-chain method (``mdft.threshold_probabilities``)
  where it is available for the subset size, otherwise Monte Carlo simulation
  (``mdft.simulate``) with common random numbers (the same seed for every evaluation).

See ``docs/fitting.md`` for the parametrisation, identifiability and the decisions taken.
"""

from __future__ import annotations

import math
import numbers
import warnings
from dataclasses import dataclass, field

import numpy as np
from scipy import optimize, special

from ._validation import as_attention, as_count, as_float_array, as_scalar
from .closed_form import _fixed_time_probabilities
from .model import MDFTModel, UnstableFeedbackWarning

__all__ = ["ChoiceData", "FitConvergenceWarning", "FitResult", "fit"]

#: Parameters :func:`fit` can estimate, in the order of the free-parameter vector.
PARAMETERS = ("w", "phi1", "phi2", "beta", "sigma2", "M")
_SCALARS = ("phi1", "phi2", "beta", "sigma2")
#: Default search bounds of the scalar parameters.
DEFAULT_BOUNDS = {
    "phi1": (0.0, 1.0),
    "phi2": (0.0, 0.5),
    "beta": (0.0, 50.0),
    "sigma2": (1e-3, 25.0),
}
#: Default first start of the scalar parameters (the canonical values of the literature).
DEFAULT_START = {"phi1": 0.022, "phi2": 0.05, "beta": 12.0, "sigma2": 1.0}
#: Floor on a predicted probability inside the log-likelihood.
PROBABILITY_FLOOR = 1e-12


class FitConvergenceWarning(RuntimeWarning):
    """The optimiser stopped before its convergence criterion was met."""


# ============================================================================ data
def _as_subset(name, value, n_options=None):
    arr = np.asarray(value)
    if arr.ndim != 1 or arr.size == 0 or arr.dtype.kind not in "iu":
        if arr.ndim == 1 and arr.dtype.kind == "f" and np.all(arr == np.round(arr)):
            arr = arr.astype(np.int64)
        else:
            raise TypeError(f"{name} must be a 1-d sequence of option indices (got {value!r})")
    arr = arr.astype(np.int64)
    if arr.size < 2:
        raise ValueError(f"{name} must hold at least two options (got {arr.tolist()})")
    if len(set(arr.tolist())) != arr.size:
        raise ValueError(f"{name} must hold distinct options (got {arr.tolist()})")
    if arr.min() < 0:
        raise ValueError(f"{name} must hold non-negative option indices (got {arr.tolist()})")
    if n_options is not None and arr.max() >= n_options:
        raise ValueError(
            f"{name} refers to option {arr.max()} but the option set has {n_options} options "
            f"(indices 0 to {n_options - 1})"
        )
    arr.flags.writeable = False
    return arr


def _as_counts(name, value, size):
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise TypeError(f"{name} must be a sequence of counts (got {value!r})") from exc
    if arr.ndim != 1 or arr.size != size:
        raise ValueError(
            f"{name} must hold one count per option of its subset, length {size} "
            f"(got shape {arr.shape})"
        )
    if not np.all(np.isfinite(arr)) or np.any(arr < 0) or np.any(arr != np.round(arr)):
        raise ValueError(f"{name} must hold non-negative whole numbers (got {arr.tolist()})")
    out = arr.astype(np.int64)
    if out.sum() == 0:
        raise ValueError(f"{name} sums to 0: every subset needs at least one observed choice")
    out.flags.writeable = False
    return out


@dataclass(frozen=True, init=False, eq=False)
class ChoiceData:
    """Observed choices on subsets of a common option set.

    Parameters
    ----------
    subsets : sequence of sequence of int
        ``subsets[k]`` lists the options (indices into the common option set, i.e. rows of
        ``M``) offered in choice set ``k``; at least two distinct options each.
    counts : sequence of sequence of int
        ``counts[k][i]`` is how often ``subsets[k][i]`` was chosen; same lengths as
        ``subsets``; non-negative, at least one choice per subset.
    n_options : int, optional
        Size of the common option set; by default one more than the largest index used.

    Attributes
    ----------
    subsets, counts : tuple of ndarray
        Read-only integer arrays.
    n_options : int
    response_times : tuple or None
        From :meth:`from_trials` with response times: ``response_times[k][i]`` is the
        array of response times of the trials of subset ``k`` that chose its ``i``-th option.

    Notes
    -----
    Two constructors: counts per subset (this constructor, or :meth:`from_shares` for
    proportions with a known number of trials) and one row per trial (:meth:`from_trials`).

    Examples
    --------
    >>> import mdft
    >>> data = mdft.ChoiceData([[0, 1], [0, 1, 2]], [[55, 45], [30, 28, 42]])
    >>> data.n_subsets, data.n_options, data.n_trials.tolist()
    (2, 3, [100, 100])
    >>> [s.round(2).tolist() for s in data.shares]
    [[0.55, 0.45], [0.3, 0.28, 0.42]]
    """

    subsets: tuple
    counts: tuple
    n_options: int
    response_times: tuple | None = field(default=None, repr=False)

    def __init__(self, subsets, counts, *, n_options=None, response_times=None):
        if isinstance(subsets, (str, bytes)) or not hasattr(subsets, "__len__"):
            raise TypeError(f"subsets must be a sequence of option subsets (got {subsets!r})")
        if len(subsets) == 0:
            raise ValueError("subsets is empty: ChoiceData needs at least one observed subset")
        if isinstance(counts, (str, bytes)) or not hasattr(counts, "__len__"):
            raise TypeError(f"counts must be a sequence of count vectors (got {counts!r})")
        if len(counts) != len(subsets):
            raise ValueError(
                f"counts must have one row per subset: got {len(counts)} rows of counts for "
                f"{len(subsets)} subsets"
            )
        if n_options is not None:
            n_options = as_count("n_options", n_options, low=2)
        subs = tuple(_as_subset(f"subsets[{k}]", s, n_options) for k, s in enumerate(subsets))
        cnts = tuple(_as_counts(f"counts[{k}]", c, s.size) for k, (s, c) in
                     enumerate(zip(subs, counts)))
        if n_options is None:
            n_options = int(max(s.max() for s in subs)) + 1
        object.__setattr__(self, "subsets", subs)
        object.__setattr__(self, "counts", cnts)
        object.__setattr__(self, "n_options", int(n_options))
        object.__setattr__(self, "response_times", response_times)

    # ---------------------------------------------------------------- constructors
    @classmethod
    def from_counts(cls, subsets, counts, *, n_options=None) -> "ChoiceData":
        """Counts per subset; the same as the constructor.

        Examples
        --------
        >>> import mdft
        >>> mdft.ChoiceData.from_counts([[2, 0]], [[7, 3]]).n_options
        3
        """
        return cls(subsets, counts, n_options=n_options)

    @classmethod
    def from_shares(cls, subsets, shares, n_trials, *, n_options=None, atol=1e-6) -> "ChoiceData":
        """Choice proportions with a known number of trials per subset.

        Parameters
        ----------
        subsets : sequence of sequence of int
        shares : sequence of sequence of float
            Proportions per subset; each row sums to one.
        n_trials : int or sequence of int
            Trials per subset (one number for all, or one per subset). ``shares * n_trials``
            must be whole numbers (within ``atol * n_trials``).

        Examples
        --------
        >>> import mdft
        >>> d = mdft.ChoiceData.from_shares([[0, 1, 2]], [[0.25, 0.5, 0.25]], 1000)
        >>> d.counts[0].tolist()
        [250, 500, 250]
        """
        if isinstance(subsets, (str, bytes)) or not hasattr(subsets, "__len__"):
            raise TypeError(f"subsets must be a sequence of option subsets (got {subsets!r})")
        if hasattr(shares, "__len__") and len(shares) != len(subsets):
            raise ValueError(
                f"shares must have one row per subset: got {len(shares)} rows for "
                f"{len(subsets)} subsets"
            )
        n = np.atleast_1d(np.asarray(n_trials))
        if n.ndim != 1 or n.dtype.kind not in "iu" or np.any(n < 1):
            raise ValueError(f"n_trials must be a positive integer or one per subset (got {n_trials!r})")
        if n.size == 1:
            n = np.repeat(n, len(subsets))
        if n.size != len(subsets):
            raise ValueError(
                f"n_trials must be one number or one per subset ({len(subsets)}); got {n.size}"
            )
        counts = []
        for k, (row, nk) in enumerate(zip(shares, n)):
            r = as_float_array(f"shares[{k}]", row, ndim=1)
            if np.any(r < 0) or abs(r.sum() - 1.0) > 1e-6:
                raise ValueError(
                    f"shares[{k}] must be non-negative and sum to 1 (got sum {r.sum():.6g})"
                )
            c = r * nk
            if np.any(np.abs(c - np.round(c)) > atol * nk + 1e-9):
                raise ValueError(
                    f"shares[{k}] * n_trials is not a whole number of choices "
                    f"(got {c.tolist()}); check n_trials"
                )
            counts.append(np.round(c).astype(np.int64))
        return cls(subsets, counts, n_options=n_options)

    @classmethod
    def from_trials(cls, subsets, choices, response_times=None, *, n_options=None) -> "ChoiceData":
        """One row per trial: the subset offered, the option chosen, optionally the time.

        Trials are grouped by the set of options offered (order does not matter).

        Parameters
        ----------
        subsets : sequence of sequence of int
            ``subsets[t]``: options offered on trial ``t`` (indices into the option set).
        choices : sequence of int
            ``choices[t]``: the option chosen on trial ``t``, an index into the option set
            that must be one of ``subsets[t]``.
        response_times : sequence of float, optional
            ``response_times[t]``: the response time of trial ``t`` (finite, >= 0). Kept in
            :attr:`response_times`; the likelihood uses choices only.

        Examples
        --------
        >>> import mdft
        >>> d = mdft.ChoiceData.from_trials([[0, 1], [1, 0], [0, 1, 2]], [1, 1, 2],
        ...                                 response_times=[12, 30, 21])
        >>> [s.tolist() for s in d.subsets], [c.tolist() for c in d.counts]
        ([[0, 1], [0, 1, 2]], [[0, 2], [0, 0, 1]])
        >>> d.mean_response_times[0].tolist()
        [nan, 21.0]
        """
        if isinstance(subsets, (str, bytes)) or not hasattr(subsets, "__len__"):
            raise TypeError(f"subsets must be a sequence with one subset per trial (got {subsets!r})")
        choices_arr = np.asarray(choices)
        if choices_arr.ndim != 1 or (choices_arr.size and choices_arr.dtype.kind not in "iu"):
            raise TypeError(f"choices must be a 1-d sequence of option indices (got {choices!r})")
        if len(subsets) == 0:
            raise ValueError("no trials: subsets and choices are empty")
        if choices_arr.size != len(subsets):
            raise ValueError(
                f"choices must have one entry per trial: got {choices_arr.size} choices for "
                f"{len(subsets)} trials"
            )
        rts = None
        if response_times is not None:
            rts = as_float_array("response_times", response_times, ndim=1)
            if rts.size != len(subsets):
                raise ValueError(
                    f"response_times must have one entry per trial: got {rts.size} for "
                    f"{len(subsets)} trials"
                )
            if np.any(rts < 0):
                raise ValueError("response_times must be >= 0")
        groups: dict[tuple, list[int]] = {}
        for t, s in enumerate(subsets):
            sub = _as_subset(f"subsets[{t}]", s, n_options)
            c = int(choices_arr[t])
            if c not in sub.tolist():
                raise ValueError(
                    f"choices[{t}] = {c} is not one of the options offered on that trial "
                    f"({sub.tolist()})"
                )
            groups.setdefault(tuple(sorted(sub.tolist())), []).append(t)
        out_subsets, out_counts, out_rts = [], [], []
        for key, trials in groups.items():
            sub = list(key)
            ch = choices_arr[trials]
            out_subsets.append(sub)
            out_counts.append([int(np.sum(ch == o)) for o in sub])
            if rts is not None:
                times = rts[trials]
                per = []
                for o in sub:
                    a = times[ch == o].copy()
                    a.flags.writeable = False
                    per.append(a)
                out_rts.append(tuple(per))
        return cls(out_subsets, out_counts, n_options=n_options,
                   response_times=tuple(out_rts) if rts is not None else None)

    # ---------------------------------------------------------------- summaries
    @property
    def n_subsets(self) -> int:
        """Number of subsets."""
        return len(self.subsets)

    @property
    def n_trials(self) -> np.ndarray:
        """Trials per subset, shape (n_subsets,)."""
        return np.array([c.sum() for c in self.counts])

    @property
    def shares(self) -> tuple:
        """Observed choice proportions per subset."""
        return tuple(c / c.sum() for c in self.counts)

    @property
    def mean_response_times(self) -> tuple | None:
        """Mean response time per option of each subset (NaN where never chosen), or None."""
        if self.response_times is None:
            return None
        return tuple(
            np.array([a.mean() if a.size else np.nan for a in per]) for per in self.response_times
        )

    def log_multinomial_coefficient(self) -> float:
        """``sum_k log(n_k! / prod_i c_ki!)``, the data-only term of the log-likelihood."""
        total = 0.0
        for c in self.counts:
            total += special.gammaln(c.sum() + 1.0) - special.gammaln(c + 1.0).sum()
        return float(total)


# ============================================================================ result
@dataclass(frozen=True, eq=False)
class FitResult:
    """Result of :func:`fit`.

    Attributes
    ----------
    params : dict
        All parameter values at the optimum: ``w`` (ndarray), ``phi1``, ``phi2``, ``beta``,
        ``sigma2`` (floats) and ``M`` (ndarray), fitted or held fixed.
    fitted : tuple of str
        Names of the estimated parameters.
    standard_errors : dict
        Standard error of each fitted parameter (same shape as its value), from the inverse
        of the numerical Hessian of the negative log-likelihood; NaN where undefined.
    se_notes : dict
        Why a standard error is undefined (empty string where defined).
    covariance : ndarray, shape (n_labels, n_labels)
        Asymptotic covariance of the fitted values listed in :attr:`labels` (NaN rows and
        columns where undefined).
    labels : tuple of str
        Names of the entries of :attr:`covariance`, e.g. ``"w[0]"``, ``"phi1"``, ``"M[1,0]"``.
    log_likelihood : float
        Multinomial log-likelihood at the optimum (with the multinomial coefficient).
    n_params : int
        Number of free parameters (``w`` counts ``n_attributes - 1``; ``M`` counts
        ``(n_options - 1) * n_attributes``, its first row being held as the anchor).
    n_observations : int
        Total number of trials.
    aic, bic : float
        ``2 k - 2 log L`` and ``k log(N) - 2 log L``.
    converged : bool
        Whether the best start converged.
    n_iter : int
        Iterations of the best start.
    message : str
        The optimiser's message for the best start.
    start_log_likelihoods : tuple of float
        Log-likelihood reached from every start (a spread hints at several optima).
    observed, predicted : tuple of ndarray
        Observed and fitted choice shares per subset.
    mse : float
        Mean squared difference between predicted and observed shares over all
        (subset, option) cells.
    engine : str
        ``"closed_form"``, ``"threshold_exact"`` or ``"simulation"``.
    stopping : object
        The stopping rule used.
    model : MDFTModel
        The fitted model on the whole option set.

    Examples
    --------
    >>> import mdft
    >>> data = mdft.ChoiceData([[0, 1], [0, 1, 2]], [[520, 480], [300, 310, 390]])
    >>> res = mdft.fit(data, [[1, 3], [3, 1], [2, 2]], stopping=40, params=["w"],
    ...                fixed=dict(phi1=0.022, phi2=0.05, beta=12.0, sigma2=1.0), rng=0)
    >>> res.fitted, res.n_params, res.converged
    (('w',), 1, True)
    >>> bool(res.aic == 2 * res.n_params - 2 * res.log_likelihood)
    True
    """

    params: dict
    fitted: tuple
    standard_errors: dict
    se_notes: dict
    covariance: np.ndarray
    labels: tuple
    log_likelihood: float
    n_params: int
    n_observations: int
    aic: float
    bic: float
    converged: bool
    n_iter: int
    message: str
    start_log_likelihoods: tuple
    observed: tuple
    predicted: tuple
    mse: float
    engine: str
    stopping: object
    model: MDFTModel = field(repr=False)
    _settings: dict = field(repr=False, default_factory=dict)

    def predict(self, subsets) -> tuple:
        """Predicted choice shares of the fitted model on the given subsets.

        Parameters
        ----------
        subsets : sequence of sequence of int
            Subsets of the option set (indices into ``M``).

        Returns
        -------
        tuple of ndarray
            One probability vector per subset, in the subset's order.

        Examples
        --------
        >>> import mdft
        >>> data = mdft.ChoiceData([[0, 1]], [[60, 40]])
        >>> res = mdft.fit(data, [[1.0, 3.0], [3.0, 1.0]], stopping=20, params=["w"],
        ...                fixed=dict(phi1=0.022, phi2=0.05, beta=12.0, sigma2=1.0), rng=0)
        >>> [p.round(2).tolist() for p in res.predict([[1, 0]])]
        [[0.4, 0.6]]
        """
        n = self.params["M"].shape[0]
        subs = [_as_subset(f"subsets[{k}]", s, n) for k, s in enumerate(subsets)]
        return tuple(_predict(self.params, subs, self.stopping, self.engine, self._settings))


# ============================================================================ engines
def _stopping_kind(stopping):
    """Return ("fixed", n_steps) or ("threshold", (theta, max_steps))."""
    if isinstance(stopping, numbers.Integral) and not isinstance(stopping, bool):
        return "fixed", as_count("stopping", stopping)
    if hasattr(stopping, "n_steps"):
        return "fixed", as_count("stopping.n_steps", stopping.n_steps)
    if hasattr(stopping, "theta"):
        theta = as_scalar("stopping.theta", stopping.theta, low=0.0, low_inclusive=False)
        max_steps = as_count("stopping.max_steps", getattr(stopping, "max_steps", 10_000))
        return "threshold", (theta, max_steps)
    raise TypeError(
        "stopping must be mdft.FixedTime(n_steps), mdft.Threshold(theta, ...) or an integer "
        f"number of steps (got {stopping!r})"
    )


def _threshold_exact_function():
    try:
        from . import threshold_exact
    except ImportError:
        return None
    return getattr(threshold_exact, "threshold_probabilities", None)


def _quiet_model(M, p):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UnstableFeedbackWarning)
        return MDFTModel(M, p["w"], phi1=p["phi1"], phi2=p["phi2"], beta=p["beta"],
                         sigma2=p["sigma2"])


def _predict(p, subsets, stopping, engine, settings):
    kind, spec = _stopping_kind(stopping)
    M = p["M"]
    out = []
    for k, sub in enumerate(subsets):
        Ms = M[sub]
        if engine == "closed_form":
            q = _fixed_time_probabilities(Ms, p["w"], p["phi1"], p["phi2"], p["beta"],
                                          p["sigma2"], spec)
            if q is None:
                q = np.full(sub.size, np.nan)
        elif engine == "threshold_exact":
            theta, max_steps = spec
            res = settings["threshold_fn"](_quiet_model(Ms, p), theta, max_steps=max_steps,
                                           **settings["threshold_options"])
            q = _conditional(res)
        else:
            import mdft

            res = mdft.simulate(_quiet_model(Ms, p), settings["n_samples"], stopping=stopping,
                                rng=settings["seed"] + k)
            q = _conditional(res)
        out.append(np.asarray(q, dtype=np.float64))
    return out


def _conditional(res):
    """Choice probabilities given a decision (undecided trials are not in choice data)."""
    q = np.asarray(res.probabilities, dtype=np.float64)
    total = q.sum()
    return q / total if total > 0 else np.full(q.size, np.nan)


# ============================================================================ parameters
class _Layout:
    """Maps the unit cube of the optimiser to named parameter values and back."""

    def __init__(self, fitted, values, bounds, n_options, n_attributes):
        self.fitted = fitted
        self.values = values
        self.bounds = bounds
        self.n, self.J = n_options, n_attributes
        self.blocks = []  # (name, size)
        for name in PARAMETERS:
            if name not in fitted:
                continue
            if name == "w":
                self.blocks.append(("w", self.J - 1))
            elif name == "M":
                self.blocks.append(("M", (self.n - 1) * self.J))
            else:
                self.blocks.append((name, 1))
        self.size = sum(s for _, s in self.blocks)
        labels = []
        for name, _ in self.blocks:
            if name == "w":
                labels += [f"w[{j}]" for j in range(self.J)]
            elif name == "M":
                labels += [f"M[{i},{j}]" for i in range(1, self.n) for j in range(self.J)]
            else:
                labels.append(name)
        self.labels = tuple(labels)

    def unpack(self, u):
        p = dict(self.values)
        pos = 0
        for name, size in self.blocks:
            x = u[pos:pos + size]
            pos += size
            if name == "w":
                p["w"] = _stick_to_simplex(x)
            elif name == "M":
                lo, hi = self.bounds["M"]
                M = np.array(self.values["M"], dtype=np.float64)
                M[1:] = (lo[1:] + x.reshape(self.n - 1, self.J) * (hi[1:] - lo[1:]))
                p["M"] = M
            else:
                lo, hi = self.bounds[name]
                p[name] = float(lo + x[0] * (hi - lo))
        return p

    def pack(self, p):
        u = np.empty(self.size)
        pos = 0
        for name, size in self.blocks:
            if name == "w":
                u[pos:pos + size] = _simplex_to_stick(np.asarray(p["w"], dtype=np.float64))
            elif name == "M":
                lo, hi = self.bounds["M"]
                u[pos:pos + size] = ((np.asarray(p["M"])[1:] - lo[1:]) / (hi[1:] - lo[1:])).ravel()
            else:
                lo, hi = self.bounds[name]
                u[pos] = (p[name] - lo) / (hi - lo)
            pos += size
        return u

    def natural(self, u):
        """The labelled natural values (``w`` in full, ``M`` without its anchor row)."""
        p = self.unpack(u)
        out = []
        for name, _ in self.blocks:
            if name == "w":
                out += list(p["w"])
            elif name == "M":
                out += list(p["M"][1:].ravel())
            else:
                out.append(p[name])
        return np.array(out)


def _stick_to_simplex(v):
    """Stick-breaking map from [0, 1]^(J-1) onto the simplex of J weights."""
    w = np.empty(v.size + 1)
    rest = 1.0
    for j, vj in enumerate(v):
        w[j] = rest * vj
        rest -= w[j]
    w[-1] = max(rest, 0.0)
    return w


def _simplex_to_stick(w):
    v = np.empty(w.size - 1)
    rest = 1.0
    for j in range(w.size - 1):
        v[j] = w[j] / rest if rest > 1e-15 else 0.5
        rest -= w[j]
    return np.clip(v, 0.0, 1.0)


def _check_names(name, names):
    if isinstance(names, str):
        names = [names]
    try:
        names = list(names)
    except TypeError as exc:
        raise TypeError(f"{name} must be a sequence of parameter names (got {names!r})") from exc
    bad = [x for x in names if x not in PARAMETERS]
    if bad:
        raise ValueError(f"{name} has unknown parameter name(s) {bad}; allowed: {list(PARAMETERS)}")
    if len(set(names)) != len(names):
        raise ValueError(f"{name} lists a parameter twice (got {names})")
    return names


def _resolve(M, fitted, fixed, start, bounds):
    n, J = M.shape
    fixed = dict(fixed or {})
    start = dict(start or {})
    bounds = dict(bounds or {})
    for label, d in (("fixed", fixed), ("start", start), ("bounds", bounds)):
        bad = [k for k in d if k not in PARAMETERS]
        if bad:
            raise ValueError(
                f"{label} has unknown parameter name(s) {bad}; allowed: {list(PARAMETERS)}"
            )
    clash = [k for k in fixed if k in fitted]
    if clash:
        raise ValueError(f"parameter(s) {clash} are both fitted and given in fixed; choose one")
    if "M" in fixed:
        raise ValueError("M is given as the positional argument, not in fixed")
    for label, d in (("start", start), ("bounds", bounds)):
        extra = [k for k in d if k not in fitted]
        if extra:
            raise ValueError(f"{label} names parameter(s) {extra} that are not being fitted")
    missing = [k for k in ("w", *_SCALARS) if k not in fitted and k not in fixed]
    if missing:
        raise ValueError(
            f"fixed must give a value for every parameter that is not fitted; missing {missing}"
        )
    if "w" in fitted and J < 2:
        raise ValueError("w cannot be fitted with a single attribute (it is fixed at [1.0])")
    if "w" in bounds:
        raise ValueError("bounds cannot be given for w: it is fitted over the whole simplex")
    if "M" in fitted and n < 2:
        raise ValueError("M needs at least two options to be fitted")

    values = {"M": M}
    if "w" in fixed:
        values["w"] = as_attention(fixed["w"], J, name="fixed['w']")
    else:
        values["w"] = np.full(J, 1.0 / J)
    for k in _SCALARS:
        if k in fixed:
            low = 0.0
            values[k] = as_scalar(f"fixed[{k!r}]", fixed[k], low=low)
        else:
            values[k] = DEFAULT_START[k]

    res_bounds = {}
    for k in _SCALARS:
        if k not in fitted:
            continue
        lo, hi = bounds.get(k, DEFAULT_BOUNDS[k])
        lo = as_scalar(f"bounds[{k!r}][0]", lo, low=0.0)
        hi = as_scalar(f"bounds[{k!r}][1]", hi)
        if not hi > lo:
            raise ValueError(f"bounds[{k!r}] must satisfy lower < upper (got ({lo}, {hi}))")
        res_bounds[k] = (lo, hi)
    if "M" in fitted:
        if "M" in bounds:
            lo, hi = bounds["M"]
            lo = np.broadcast_to(as_float_array("bounds['M'][0]", lo), M.shape).astype(float)
            hi = np.broadcast_to(as_float_array("bounds['M'][1]", hi), M.shape).astype(float)
        else:
            span = max(float(M.max() - M.min()), 1.0)
            lo = np.full(M.shape, M.min() - span)
            hi = np.full(M.shape, M.max() + span)
        if np.any(hi[1:] <= lo[1:]):
            raise ValueError("bounds['M'] must satisfy lower < upper for every entry")
        res_bounds["M"] = (lo, hi)

    first = dict(values)
    for k, v in start.items():
        if k == "w":
            first["w"] = as_attention(v, J, name="start['w']")
        elif k == "M":
            Mv = as_float_array("start['M']", v, shape=M.shape)
            lo, hi = res_bounds["M"]
            if np.any(Mv[1:] < lo[1:]) or np.any(Mv[1:] > hi[1:]):
                raise ValueError("start['M'] lies outside bounds['M']; widen the bounds or move the start")
            if not np.array_equal(Mv[0], M[0]):
                raise ValueError("start['M'] must keep the first row of M (the anchor row) unchanged")
            first["M"] = Mv
        else:
            x = as_scalar(f"start[{k!r}]", v)
            lo, hi = res_bounds[k]
            if not lo <= x <= hi:
                raise ValueError(
                    f"start[{k!r}] = {x} lies outside bounds [{lo}, {hi}]; widen the bounds or "
                    "move the start"
                )
            first[k] = x
    for k in _SCALARS:
        if k in fitted and k not in start:
            lo, hi = res_bounds[k]
            first[k] = float(min(max(first[k], lo), hi))
    if "M" in fitted and "M" not in start:
        lo, hi = res_bounds["M"]
        if np.any(M[1:] < lo[1:]) or np.any(M[1:] > hi[1:]):
            raise ValueError("M lies outside bounds['M']; the given M is the start of the fit")
    return values, res_bounds, first


# ============================================================================ fit
def fit(
    data,
    M,
    *,
    stopping,
    params=("w",),
    fixed=None,
    start=None,
    bounds=None,
    n_starts=5,
    rng=None,
    max_iter=500,
    tol=1e-10,
    n_samples=20_000,
    method="auto",
    n_screen_per_start=8,
    threshold_options=None,
) -> FitResult:
    """Fit MDFT parameters to choice data by maximum likelihood.

    Parameters
    ----------
    data : ChoiceData
        Observed choice counts on subsets of the option set.
    M : array_like, shape (n_options, n_attributes)
        Evaluations of the whole option set; the start value if ``"M"`` is fitted.
    stopping : FixedTime, Threshold or int
        The stopping rule: ``mdft.FixedTime(n_steps)`` (or just ``n_steps``) or
        ``mdft.Threshold(theta, max_steps=...)``.
    params : sequence of str, default ("w",)
        Parameters to estimate, any of ``"w"``, ``"phi1"``, ``"phi2"``, ``"beta"``,
        ``"sigma2"`` (the noise variance) and ``"M"``.
    fixed : dict, optional
        Values of every parameter in ``w``, ``phi1``, ``phi2``, ``beta``, ``sigma2`` that is
        not estimated (required: nothing is filled in silently).
    start : dict, optional
        First starting point for some fitted parameters. Unspecified ones start at the
        canonical values (``phi1=0.022, phi2=0.05, beta=12, sigma2=1``, uniform ``w``, the
        given ``M``) clipped to the bounds; for the further starts see ``n_starts``.
    bounds : dict, optional
        ``(low, high)`` per fitted scalar parameter (defaults in ``DEFAULT_BOUNDS``:
        ``phi1 (0, 1)``, ``phi2 (0, 0.5)``, ``beta (0, 50)``, ``sigma2 (1e-3, 25)``) and for
        ``"M"`` (scalars or arrays; default the range of ``M`` widened by its span on each
        side). ``w`` always ranges over the whole simplex.
    n_starts : int, default 5
        Number of optimiser starts; the best is kept. The first is ``start``; the others
        are the best of ``n_screen_per_start * (n_starts - 1)`` points drawn uniformly from
        the bounds (for a simulated likelihood: the first draws, unscreened).
    rng : None, int or numpy.random.Generator
        Randomness of the extra starts (and of the simulation seed, if simulation is used).
    max_iter : int, default 500
        Iterations per start.
    tol : float, default 1e-10
        Relative tolerance on the objective for L-BFGS-B (``ftol``) or Nelder-Mead
        (``fatol``, scaled by the number of trials).
    n_samples : int, default 20000
        Trials per subset and evaluation when threshold stopping is simulated.
    n_screen_per_start : int, default 8
        Screening points per extra start (see ``n_starts``).
    method : {"auto", "threshold_exact", "simulation"}
        Engine for threshold stopping; ``"auto"`` uses ``mdft.threshold_probabilities`` when
        every subset has 2 options (about 0.3 s per evaluation) and simulation otherwise
        (the lattice method for 3 options costs seconds per evaluation, too slow for an
        optimiser; ask for it explicitly with ``"threshold_exact"``). Fixed time always uses
        the closed form.
    threshold_options : dict, optional
        Extra keyword arguments of ``mdft.threshold_probabilities`` (e.g. ``n_cells``).

    Returns
    -------
    FitResult

    Warns
    -----
    FitConvergenceWarning
        If the best start did not converge.

    Notes
    -----
    The optimiser works on the unit cube: each bounded scalar is mapped linearly onto
    ``[0, 1]``, ``w`` by stick-breaking (``w_1 = v_1``, ``w_2 = (1 - v_1) v_2``, ...), and
    ``M`` entry by entry with its first row held fixed (adding a constant to a column of
    ``M`` changes neither ``C M`` nor the distances, so one row must anchor it). Smooth
    likelihoods (closed form, exact threshold method) use L-BFGS-B with central
    finite-difference gradients; a simulated likelihood uses bounded Nelder-Mead with common random numbers.
    Standard errors come from the inverse of the central-difference Hessian of the negative
    log-likelihood, mapped to natural units by the delta method; they are NaN (with a reason
    in ``se_notes``) for estimates on a bound, where the Hessian is not positive definite
    (a parameter that is not identified) and for simulated likelihoods.

    Examples
    --------
    Generate counts from a known model and recover the attention weight:

    >>> import numpy as np, mdft
    >>> M = np.array([[1.0, 3.0], [3.0, 1.0], [2.0, 2.0]])
    >>> truth = dict(phi1=0.022, phi2=0.05, beta=12.0, sigma2=1.0)
    >>> subsets = [[0, 1], [0, 1, 2]]
    >>> rng = np.random.default_rng(0)
    >>> counts = [rng.multinomial(2000, mdft.choice_probabilities(
    ...     mdft.MDFTModel(M[s], [0.6, 0.4], **truth), 50)) for s in subsets]
    >>> res = mdft.fit(mdft.ChoiceData(subsets, counts), M, stopping=50,
    ...                params=["w"], fixed=truth, rng=0)
    >>> round(float(res.params["w"][0]), 2), res.converged
    (0.6, True)
    """
    if not isinstance(data, ChoiceData):
        raise TypeError(
            f"data must be an mdft.ChoiceData (got {type(data).__name__}); build one with "
            "ChoiceData(subsets, counts) or ChoiceData.from_trials(...)"
        )
    M = as_float_array("M", M, ndim=2)
    n, J = M.shape
    if data.n_options > n:
        raise ValueError(
            f"data refers to {data.n_options} options but M has only {n} rows; "
            "pass the evaluations of the whole option set"
        )
    fitted = _check_names("params", params)
    if not fitted:
        raise ValueError("params is empty: name at least one parameter to fit")
    fitted = tuple(k for k in PARAMETERS if k in fitted)
    n_starts = as_count("n_starts", n_starts)
    max_iter = as_count("max_iter", max_iter)
    tol = as_scalar("tol", tol, low=0.0, low_inclusive=False)
    n_samples = as_count("n_samples", n_samples)
    n_screen_per_start = as_count("n_screen_per_start", n_screen_per_start)
    if method not in ("auto", "threshold_exact", "simulation"):
        raise ValueError(
            f"method must be 'auto', 'threshold_exact' or 'simulation' (got {method!r})"
        )
    kind, spec = _stopping_kind(stopping)
    values, res_bounds, first = _resolve(M, fitted, fixed, start, bounds)
    rng = np.random.default_rng(rng)

    settings = {"n_samples": n_samples, "seed": int(rng.integers(2**31)),
                "threshold_options": dict(threshold_options or {})}
    if kind == "fixed":
        engine = "closed_form"
    else:
        fn = _threshold_exact_function()
        small = max(s.size for s in data.subsets) <= 2
        if method == "threshold_exact" and fn is None:
            raise ValueError(
                "method='threshold_exact' needs mdft.threshold_probabilities, which is not "
                "available; use method='simulation'"
            )
        if method == "threshold_exact" or (method == "auto" and fn is not None and small):
            engine = "threshold_exact"
            settings["threshold_fn"] = fn
        else:
            import mdft

            if not hasattr(mdft, "simulate"):
                raise ValueError(
                    "threshold stopping needs mdft.simulate or mdft.threshold_probabilities, "
                    "neither of which is available"
                )
            engine = "simulation"

    layout = _Layout(fitted, values, res_bounds, n, J)
    subsets = data.subsets
    counts = [c.astype(np.float64) for c in data.counts]
    n_obs = int(sum(c.sum() for c in data.counts))
    const = data.log_multinomial_coefficient()

    def negloglik(u):
        p = layout.unpack(np.clip(u, 0.0, 1.0))
        try:
            preds = _predict(p, subsets, stopping, engine, settings)
        except (ValueError, FloatingPointError):
            return 1e300
        total = 0.0
        for q, c in zip(preds, counts):
            if not np.all(np.isfinite(q)):
                return 1e300
            total -= float(c @ np.log(np.maximum(q, PROBABILITY_FLOOR)))
        return total

    starts = [layout.pack(first)]
    if n_starts > 1:
        # Screen random points of the unit cube and start from the best of them: the
        # likelihood can be flat where every predicted probability is 0 or 1.
        n_screen = n_screen_per_start * (n_starts - 1)
        cand = rng.uniform(0.0, 1.0, size=(n_screen, layout.size))
        if engine == "simulation":
            cand = cand[: n_starts - 1]
        else:
            vals = np.array([negloglik(u) for u in cand])
            cand = cand[np.argsort(vals, kind="stable")[: n_starts - 1]]
        starts += list(cand)

    smooth = engine != "simulation"
    runs = []
    for u0 in starts:
        if smooth:
            res = optimize.minimize(
                negloglik, u0, method="L-BFGS-B", jac="3-point",
                bounds=[(0.0, 1.0)] * layout.size,
                options={"maxiter": max_iter, "ftol": tol, "gtol": 1e-7},
            )
        else:
            res = optimize.minimize(
                negloglik, u0, method="Nelder-Mead", bounds=[(0.0, 1.0)] * layout.size,
                options={"maxiter": max_iter * layout.size, "xatol": 1e-4,
                         "fatol": tol * n_obs, "adaptive": layout.size > 3},
            )
        runs.append(res)
    best = min(runs, key=lambda r: r.fun)
    u_hat = np.clip(best.x, 0.0, 1.0)
    p_hat = layout.unpack(u_hat)
    converged = bool(best.success)
    if not converged:
        warnings.warn(
            f"the fit did not converge ({best.message}); raise max_iter or n_starts, or check "
            "the bounds",
            FitConvergenceWarning,
            stacklevel=2,
        )

    cov, ses, notes = _standard_errors(negloglik, layout, u_hat, smooth)
    loglik = -float(best.fun) + const
    k = layout.size
    preds = tuple(_predict(p_hat, subsets, stopping, engine, settings))
    observed = data.shares
    sq = np.concatenate([(a - b) ** 2 for a, b in zip(preds, observed)])
    return FitResult(
        params=p_hat,
        fitted=fitted,
        standard_errors=ses,
        se_notes=notes,
        covariance=cov,
        labels=layout.labels,
        log_likelihood=loglik,
        n_params=k,
        n_observations=n_obs,
        aic=2.0 * k - 2.0 * loglik,
        bic=k * math.log(n_obs) - 2.0 * loglik,
        converged=converged,
        n_iter=int(getattr(best, "nit", 0)),
        message=str(best.message),
        start_log_likelihoods=tuple(-float(r.fun) + const for r in runs),
        observed=observed,
        predicted=preds,
        mse=float(sq.mean()),
        engine=engine,
        stopping=stopping,
        model=_quiet_model(p_hat["M"], p_hat),
        _settings=settings,
    )


def _standard_errors(negloglik, layout, u, smooth, step=1e-4, bound_tol=1e-3):
    """Covariance and standard errors from the numerical Hessian (in natural units)."""
    labels = layout.labels
    m = len(labels)
    cov = np.full((m, m), np.nan)
    ses, notes = {}, {}

    def fill(reason_by_block):
        pos = 0
        p = layout.unpack(u)
        for name, _ in layout.blocks:
            size = layout.J if name == "w" else (
                (layout.n - 1) * layout.J if name == "M" else 1)
            vals = np.sqrt(np.clip(np.diag(cov)[pos:pos + size], 0.0, None))
            vals = np.where(np.isfinite(np.diag(cov)[pos:pos + size]), vals, np.nan)
            if name == "w":
                ses["w"] = vals
            elif name == "M":
                full = np.full(p["M"].shape, np.nan)
                full[0] = 0.0
                full[1:] = vals.reshape(layout.n - 1, layout.J)
                ses["M"] = full
            else:
                ses[name] = float(vals[0])
            notes[name] = reason_by_block.get(name, "")
            pos += size

    if not smooth:
        fill({name: "undefined for a simulated likelihood (not smooth in the parameters)"
              for name, _ in layout.blocks})
        return cov, ses, notes

    interior = (u > bound_tol) & (u < 1.0 - bound_tol)
    reasons = {}
    # Which free coordinates each labelled natural value depends on.
    depends = []
    pos = 0
    for name, size in layout.blocks:
        if name == "w":
            depends += [np.arange(pos, pos + size)] * layout.J
        else:
            depends += [np.array([pos + i]) for i in range(size)]
        pos += size
    bad = ~interior
    idx = np.flatnonzero(interior)
    if idx.size:
        H = _hessian(negloglik, u, idx, step)
        # A coordinate that does not move the likelihood at all is not identified.
        d = np.diag(H)
        flat = d <= 1e-10 * max(float(np.max(np.abs(d))), 1e-300)
        for c in np.flatnonzero(flat):
            bad[idx[c]] = True
            reasons.setdefault(_block_of(layout, idx[c]),
                               "Hessian not positive definite: parameter not identified here")
        keep = ~flat
        idx, H = idx[keep], H[np.ix_(keep, keep)]
    cov_u = None
    if idx.size:
        try:
            np.linalg.cholesky(H)
            cov_u = np.linalg.inv(H)
        except np.linalg.LinAlgError:
            for c in idx:
                bad[c] = True
                reasons.setdefault(_block_of(layout, c),
                                   "Hessian not positive definite: parameter not identified here")
    for c in np.flatnonzero(~interior):
        reasons.setdefault(_block_of(layout, c), "estimate on (or next to) a bound of its range")
    if cov_u is not None:
        # Delta method: natural values as a function of the free interior coordinates.
        Jac = np.zeros((m, idx.size))
        for c, i in enumerate(idx):
            h = 1e-6
            up, dn = u.copy(), u.copy()
            up[i] += h
            dn[i] -= h
            Jac[:, c] = (layout.natural(up) - layout.natural(dn)) / (2 * h)
        full = Jac @ cov_u @ Jac.T
        ok = np.array([not np.any(bad[dep]) for dep in depends])
        cov[np.ix_(ok, ok)] = full[np.ix_(ok, ok)]
        # A block some of whose values are defined keeps a note only for the undefined ones.
        for name in list(reasons):
            if name == "M":
                pos_nat = sum(layout.J if b == "w" else sz for b, sz in layout.blocks
                              if PARAMETERS.index(b) < PARAMETERS.index("M"))
                n_undef = int(np.count_nonzero(~ok[pos_nat:]))
                reasons["M"] = f"{n_undef} entries undefined: " + reasons["M"]
    fill(reasons)
    return cov, ses, notes


def _block_of(layout, coordinate):
    """Name of the parameter block a free coordinate belongs to."""
    pos = 0
    for name, size in layout.blocks:
        if coordinate < pos + size:
            return name
        pos += size
    raise IndexError(coordinate)


def _hessian(f, u, idx, step):
    """Central-difference Hessian of ``f`` at ``u`` over the coordinates ``idx``."""
    k = idx.size
    H = np.empty((k, k))
    f0 = f(u)
    for a in range(k):
        i = idx[a]
        e_i = np.zeros_like(u)
        e_i[i] = step
        fp, fm = f(u + e_i), f(u - e_i)
        H[a, a] = (fp - 2.0 * f0 + fm) / step**2
        for b in range(a + 1, k):
            j = idx[b]
            e_j = np.zeros_like(u)
            e_j[j] = step
            H[a, b] = H[b, a] = (
                f(u + e_i + e_j) - f(u + e_i - e_j) - f(u - e_i + e_j) + f(u - e_i - e_j)
            ) / (4.0 * step**2)
    return 0.5 * (H + H.T)
