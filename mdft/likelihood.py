"""The likelihood of choice data (and response times) under an MDFT model.

Three engines predict what a model does on each offered subset:

* ``"closed_form"`` (fixed time): the Gaussian closed form of the choice probabilities;
* ``"threshold_exact"`` (threshold stopping): ``mdft.threshold_probabilities``, whose
  ``rt_pmf`` gives the joint distribution of choice and decision step;
* ``"simulation"`` (threshold stopping): ``mdft.simulate`` with common random numbers (the
  same seed at every evaluation, so the objective is a deterministic function).

Choices only: the multinomial log-likelihood ``sum_k [log(n_k! / prod_i c_ki!) +
sum_i c_ki log p_ki]``. With response times (threshold stopping): the log-likelihood of the
trials, ``sum_trials log f(choice, time)``, where ``f`` is the probability of choosing the
option at that decision step (``"steps"``) or within that bin of decision steps
(``"bins"``), given that the trial decided within ``max_steps``.
"""

from __future__ import annotations

import inspect
import numbers
import warnings

import numpy as np

from ._threshold_bound import decision_bound
from ._validation import as_count, as_float_array, as_scalar
from .closed_form import _fixed_time_probabilities
from .model import MDFTModel, UnstableFeedbackWarning
from .threshold_result import ThresholdToleranceError

__all__ = ["Likelihood", "stopping_kind"]

#: Floor on a predicted probability inside the log-likelihood.
PROBABILITY_FLOOR = 1e-12
#: Value of the negative log-likelihood where the model cannot be evaluated.
INFEASIBLE = 1e300
#: Why an evaluation failed, where no exception names it.
OVERFLOW = "the predicted probabilities are not finite (preferences overflow)"
NO_DECISION = ("the model decides in no trial within max_steps (every choice probability "
               "is 0), so the shares given a decision are undefined")
#: Default number of quantile bins of response times for a simulated likelihood.
DEFAULT_RT_BINS = 10
#: The simulated likelihood skips its trials where the bound on deciding at all
#: (``mdft._threshold_bound.decision_bound``) times the trials is at most this: the
#: expected number of trials that would decide.
UNREACHED_TRIALS = 0.01
#: Relative noise of the exact engine's log-likelihood on three options: the chain's spread
#: of the summed preference is measured on a short simulation with a fixed seed
#: (``mdft._plane_spread``), whose walks decide a step earlier or later as the parameters
#: move, so the likelihood jumps by small amounts at every scale. Measured on 8 random
#: triples of 300 trials (steps of 2e-6 in sigma2, theta and w): 7e-8 to 6e-6 of the
#: log-likelihood (``docs/fitting.md``, "Likelihoods smooth to a tolerance").
PLANE_NOISE = 3e-6
#: Tolerances of the exact engine's second try at an evaluation where it could not meet its
#: defaults (atol 1e-3, rt_rtol 3e-3): about three times looser. Where the moment closure's
#: term sits at the defaults, whole regions of a triple's parameters are refused at them and
#: answered at these, with log-likelihoods within 0.07 of the defaults' near the optimum
#: (``docs/fitting.md``, "Where the exact engine cannot vouch").
LOOSER_TOLERANCES = {"atol": 3e-3, "rt_rtol": 1e-2}


class _Undecided:
    """What the trials of a threshold out of reach would give: no decision."""

    p_undecided = 1.0

    def __init__(self, n_options):
        self.probabilities = np.zeros(n_options)


def stopping_kind(stopping):
    """Return ``("fixed", n_steps)`` or ``("threshold", (theta, max_steps))``."""
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


def quiet_model(M, p):
    """The model of parameter dict ``p`` on evaluations ``M``, without stability warnings."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UnstableFeedbackWarning)
        return MDFTModel(M, p["w"], phi1=p["phi1"], phi2=p["phi2"], beta=p["beta"],
                         sigma2=p["sigma2"])


def _threshold_exact_function():
    try:
        from . import threshold_exact
    except ImportError:  # pragma: no cover - the module ships with the package
        return None
    return getattr(threshold_exact, "threshold_probabilities", None)


def choose_engine(kind, method, subsets):
    """The engine name for a stopping kind, the ``method`` argument and the subsets."""
    if method not in ("auto", "threshold_exact", "simulation"):
        raise ValueError(
            f"method must be 'auto', 'threshold_exact' or 'simulation' (got {method!r})"
        )
    if kind == "fixed":
        return "closed_form"
    small = max(s.size for s in subsets) <= 2
    if method == "threshold_exact" or (method == "auto" and small):
        if _threshold_exact_function() is None:  # pragma: no cover
            raise ValueError("method='threshold_exact' needs mdft.threshold_probabilities")
        return "threshold_exact"
    return "simulation"


#: ``mdft.threshold_probabilities`` arguments that a likelihood sets itself.
_SET_BY_LIKELIHOOD = ("model", "theta", "max_steps")


def check_threshold_options(options, engine):
    """``options`` (``fit``'s ``threshold_options``) as a dict, checked: a dict of
    ``mdft.threshold_probabilities`` keywords, given only where that engine runs."""
    if options is None:
        return {}
    if not isinstance(options, dict):
        raise TypeError("threshold_options must be a dict of mdft.threshold_probabilities "
                        f"keyword arguments (got {type(options).__name__})")
    if not options:
        return {}
    if engine != "threshold_exact":
        raise ValueError(
            f"threshold_options is given, but this fit uses the {engine!r} engine, which does "
            "not call mdft.threshold_probabilities (it is used with threshold stopping when "
            "every subset has 2 options, or with method='threshold_exact')"
        )
    fn = _threshold_exact_function()
    allowed = [k for k in inspect.signature(fn).parameters if k not in _SET_BY_LIKELIHOOD]
    unknown = [k for k in options if k not in allowed]
    if unknown:
        raise ValueError(f"threshold_options has unknown name(s) {unknown}; allowed: {allowed} "
                         "(model, theta and max_steps come from the fit)")
    return dict(options)


def _as_steps(data, max_steps):
    """The response times of ``data`` as integer decision steps, checked."""
    out = []
    for k, per in enumerate(data.response_times):
        row = []
        for i, t in enumerate(per):
            if t.size and (np.any(t != np.round(t)) or t.min() < 1):
                bad = t[(t != np.round(t)) | (t < 1)][0]
                raise ValueError(
                    f"response_times[{k}][{i}] must be decision steps, whole numbers >= 1, to "
                    f"enter the likelihood (got values such as {bad:g}); convert times to "
                    "steps first, or pass response_times=False to fit choices only"
                )
            if t.size and t.max() > max_steps:
                raise ValueError(
                    f"response_times[{k}][{i}] holds a decision step of {int(t.max())}, beyond "
                    f"stopping.max_steps={max_steps}; raise max_steps"
                )
            row.append(t.astype(np.int64))
        out.append(row)
    return out


def _bin_edges(steps, rt_bins, max_steps):
    """Bin edges in steps: ``edges[b] < step <= edges[b + 1]``, covering 0 to max_steps."""
    if isinstance(rt_bins, numbers.Integral) and not isinstance(rt_bins, bool):
        n_bins = as_count("rt_bins", rt_bins)
        pooled = np.concatenate([t for row in steps for t in row]).astype(np.float64)
        inner = np.unique(np.floor(np.quantile(pooled, np.linspace(0, 1, n_bins + 1)[1:-1])))
        edges = np.concatenate([[0.0], inner[(inner > 0) & (inner < max_steps)],
                                [float(max_steps)]])
        return np.unique(edges)
    edges = as_float_array("rt_bins", rt_bins, ndim=1)
    if edges.size < 2 or np.any(np.diff(edges) <= 0):
        raise ValueError(
            f"rt_bins must be an integer or increasing bin edges in steps (got {edges.tolist()})"
        )
    if edges[0] >= 1 or edges[-1] < max_steps:
        raise ValueError(
            f"rt_bins edges must cover every decision step 1..max_steps={max_steps}: "
            f"start below 1 and end at or above max_steps (got {edges[0]:g} to {edges[-1]:g})"
        )
    return edges


class Likelihood:
    """The log-likelihood of ``data`` as a function of a parameter dict.

    Parameters
    ----------
    data : ChoiceData
    stopping : FixedTime, Threshold or int
    engine : str
        From :func:`choose_engine`.
    use_rt : bool
        Put the response times of ``data`` in the likelihood (threshold stopping).
    rt_bins : None, int or array_like
        None: decision steps (exact engine) or ``DEFAULT_RT_BINS`` quantile bins
        (simulation); an int: that many quantile bins of the pooled observed steps;
        an array: bin edges in steps.
    n_samples, seed, threshold_options :
        Settings of the simulation and exact engines.
    """

    def __init__(self, data, stopping, engine, *, use_rt, rt_bins, n_samples, seed,
                 threshold_options):
        self.kind, self.spec = stopping_kind(stopping)
        self.stopping = stopping
        self.engine = engine
        self.subsets = data.subsets
        self.n_samples = n_samples
        self.seed = seed
        self.threshold_options = dict(threshold_options or {})
        self.counts = [c.astype(np.float64) for c in data.counts]
        self.use_rt = bool(use_rt)
        self.rt_mode = "none"
        self.edges = None
        if self.use_rt:
            max_steps = self.spec[1]
            steps = _as_steps(data, max_steps)
            if rt_bins is None and engine == "threshold_exact":
                self.rt_mode = "steps"
                # per subset: (step index, option index, count) of the observed cells
                self.cells = []
                for row in steps:
                    t = np.concatenate(row)
                    o = np.concatenate([np.full(a.size, i) for i, a in enumerate(row)])
                    key = (t - 1) * len(row) + o
                    uniq, cnt = np.unique(key, return_counts=True)
                    self.cells.append((uniq // len(row), uniq % len(row), cnt.astype(float)))
            else:
                self.rt_mode = "bins"
                self.edges = _bin_edges(steps, DEFAULT_RT_BINS if rt_bins is None else rt_bins,
                                        max_steps)
                self.cells = []
                for row in steps:
                    table = np.zeros((self.edges.size - 1, len(row)))
                    for i, t in enumerate(row):
                        b = np.searchsorted(self.edges, t, side="left") - 1
                        np.add.at(table[:, i], b, 1.0)
                    self.cells.append(table)
            self.constant = 0.0
        else:
            self.constant = data.log_multinomial_coefficient()
        self.n_evaluations = 0
        #: Evaluations where the model could not be evaluated (treated as impossible).
        self.n_failed = 0
        self.first_failure = ""
        #: Warnings of the exact engine at the latest evaluation (reported at the optimum).
        self.last_warnings = []
        #: The exact engine's second try at :data:`LOOSER_TOLERANCES`: asked where the
        #: caller's threshold_options set neither tolerance; the evaluations that needed
        #: it; whether the latest did (reported at the optimum).
        self.may_loosen = not {"atol", "rt_rtol"} & set(self.threshold_options)
        self.n_loosened = 0
        self.last_loosened = False

    @property
    def noise(self) -> float:
        """Relative noise up to which the negative log-likelihood is smooth in the
        parameters: :data:`PLANE_NOISE` with the exact engine on a subset of three options,
        else 0 (smooth to rounding; the simulated likelihood is a step function instead)."""
        if self.engine == "threshold_exact" and any(len(s) == 3 for s in self.subsets):
            return PLANE_NOISE
        return 0.0

    @property
    def label(self) -> str:
        """What the likelihood is of: choices, or choices and decision steps / binned times."""
        return {"none": "choices", "steps": "choices and decision steps",
                "bins": "choices and binned decision steps"}[self.rt_mode]

    # ------------------------------------------------------------ engines
    def _threshold(self, p):
        theta = p["theta"] if p.get("theta") is not None else self.spec[0]
        return float(theta), self.spec[1]

    def _run(self, p, k, sub):
        """One subset: the exact result or the simulation result (threshold stopping)."""
        Ms = p["M"][sub]
        theta, max_steps = self._threshold(p)
        if self.engine == "threshold_exact":
            fn = _threshold_exact_function()
            # a likelihood must not switch to a noisy method mid-optimisation
            options = {"fallback": "raise", **self.threshold_options}
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always", RuntimeWarning)
                model = quiet_model(Ms, p)
                try:
                    res = fn(model, theta, max_steps=max_steps, **options)
                except ThresholdToleranceError:
                    if not self.may_loosen:
                        raise
                    # the chain ran and its error stayed beyond the defaults (in a triple,
                    # mostly the moment closure's term, which no grid lowers): a second try
                    # at tolerances about three times looser, reported with the fit
                    res = fn(model, theta, max_steps=max_steps,
                             **{**options, **LOOSER_TOLERANCES})
                    self.last_loosened = True
            self.last_warnings += [str(w.message) for w in caught]
            return res
        import mdft

        model = quiet_model(Ms, p)
        reach = UNREACHED_TRIALS / self.n_samples
        if decision_bound(model, theta, max_steps, target=reach) <= reach:
            # a threshold out of reach: the trials would all run max_steps steps to decide
            # nothing (but for a chance below UNREACHED_TRIALS that one of them decides)
            return _Undecided(len(sub))
        return mdft.simulate(model, self.n_samples,
                             stopping=mdft.Threshold(theta, max_steps=max_steps),
                             rng=self.seed + k)

    def predict(self, p, subsets=None):
        """Choice shares given a decision, one vector per subset."""
        subsets = self.subsets if subsets is None else subsets
        out = []
        for k, sub in enumerate(subsets):
            if self.engine == "closed_form":
                q = _fixed_time_probabilities(p["M"][sub], p["w"], p["phi1"], p["phi2"],
                                              p["beta"], p["sigma2"], self.spec)
                q = np.full(sub.size, np.nan) if q is None else q
            else:
                q = _conditional(self._run(p, k, sub).probabilities)
            out.append(np.asarray(q, dtype=np.float64))
        return out

    def _rt_term(self, res, k, n_options):
        """``-sum log f(choice, time)`` of subset ``k`` from an exact or simulated result."""
        decided = 1.0 - float(res.p_undecided)
        if not decided > 0:
            return self._failed(NO_DECISION)
        if self.engine == "threshold_exact":
            pmf = np.asarray(res.rt_pmf, dtype=np.float64)
        else:
            pmf = res.response_time_pmf()
        if self.rt_mode == "steps":
            t, o, c = self.cells[k]
            f = pmf[t, o] / decided
            return -float(c @ np.log(np.maximum(f, PROBABILITY_FLOOR)))
        cum = np.vstack([np.zeros((1, n_options)), np.cumsum(pmf, axis=0)])
        idx = np.clip(self.edges.astype(np.int64), 0, pmf.shape[0])
        binned = np.diff(cum[idx], axis=0)
        if self.engine == "simulation":
            # half a simulated trial in every cell, so an unsimulated cell is unlikely, not
            # impossible (the estimate's own resolution is 1 / n_samples)
            binned = (binned * self.n_samples + 0.5) / (decided * self.n_samples
                                                        + 0.5 * binned.size)
        else:
            binned = binned / decided
        return -float(np.sum(self.cells[k] * np.log(np.maximum(binned, PROBABILITY_FLOOR))))

    def negative(self, p):
        """Negative log-likelihood (without the constant); ``INFEASIBLE`` where undefined."""
        self.n_evaluations += 1
        self.last_warnings = []
        self.last_loosened = False
        total = 0.0
        try:
            if self.use_rt:
                for k, sub in enumerate(self.subsets):
                    total += self._rt_term(self._run(p, k, sub), k, sub.size)
            else:
                for q, c in zip(self.predict(p), self.counts):
                    if not np.all(np.isfinite(q)):
                        # the closed form's moments overflow; a threshold engine's shares
                        # given a decision are undefined only where no trial decides
                        return self._failed(OVERFLOW if self.engine == "closed_form"
                                            else NO_DECISION)
                    total -= float(c @ np.log(np.maximum(q, PROBABILITY_FLOOR)))
        except (ValueError, FloatingPointError) as exc:
            # e.g. preferences that overflow, or an engine that cannot vouch for its answer
            return self._failed(f"{type(exc).__name__}: {exc}")
        self.n_loosened += self.last_loosened
        return total if np.isfinite(total) else INFEASIBLE

    def _failed(self, reason):
        """Count an evaluation that failed, keep the first reason, and return INFEASIBLE."""
        self.n_failed += 1
        self.first_failure = self.first_failure or reason
        return INFEASIBLE

    def log_likelihood(self, p):
        """The log-likelihood at parameter dict ``p`` (with its constant)."""
        return -self.negative(p) + self.constant


def _conditional(probabilities):
    """Choice probabilities given a decision (undecided trials are not in choice data)."""
    q = np.asarray(probabilities, dtype=np.float64)
    total = q.sum()
    return q / total if total > 0 else np.full(q.size, np.nan)
