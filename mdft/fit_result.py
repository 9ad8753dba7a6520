"""The result of :func:`mdft.fit`: estimates, uncertainty, fit statistics and diagnostics."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ._fit_params import check_values
from .choice_data import _as_subset
from .model import MDFTModel

__all__ = ["FitResult"]


def to_builtin(value):
    """``value`` as JSON-serialisable builtins: arrays become lists, NaN becomes None."""
    if isinstance(value, dict):
        return {str(k): to_builtin(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [to_builtin(v) for v in value]
    if isinstance(value, np.ndarray):
        return to_builtin(value.tolist())
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return None if not math.isfinite(float(value)) else float(value)
    if value is None or isinstance(value, str):
        return value
    return repr(value)


def _fmt(x):
    return "nan" if x is None or not np.isfinite(x) else f"{x:.4g}"


@dataclass(frozen=True, eq=False)
class FitResult:
    """Result of :func:`mdft.fit`.

    Attributes
    ----------
    params : dict
        All parameter values at the optimum: ``w`` (ndarray), ``phi1``, ``phi2``, ``beta``,
        ``sigma2``, ``theta`` (floats; ``theta`` is None for fixed time) and ``M`` (ndarray),
        fitted or held fixed.
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
        Log-likelihood at the optimum: multinomial (with its coefficient) for choices only;
        ``sum_trials log f(choice, time)`` when response times are in it (see ``likelihood``).
    n_params : int
        Number of free parameters (``w`` counts ``n_attributes - 1``; ``M`` counts
        ``(n_options - 1) * n_attributes``, its first row being held as the anchor).
    n_observations : int
        Total number of trials.
    aic, bic : float
        ``2 k - 2 log L`` and ``k log(N) - 2 log L``.
    converged : bool
        True only when a start that reached the best log-likelihood met its optimiser's
        criterion, at least two starts reached it (when ``n_starts > 1``), no fitted
        parameter lies on a bound of its range and the likelihood engine did not warn at
        the optimum.
    n_iter : int
        Iterations of the best start.
    message : str
        The optimiser's message for the best start, and the reasons for
        ``converged=False``.
    start_log_likelihoods : tuple of float
        Log-likelihood reached from every start (a spread hints at several optima).
    n_agree : int
        Number of starts that reached the best log-likelihood (within the agreement tolerance).
    on_bound : tuple of str
        Fitted parameters whose estimate lies on (or next to) a bound of its range.
    likelihood : str
        ``"choices"``, ``"choices and decision steps"`` or ``"choices and binned decision
        steps"``.
    rt_bins : ndarray or None
        Bin edges in steps of a binned response-time likelihood (``edges[b] < t <=
        edges[b + 1]``).
    n_evaluations : int
        Evaluations of the likelihood, all starts and the screen included.
    observed, predicted : tuple of ndarray
        Observed and fitted choice shares per subset.
    mse : float
        Mean squared difference between predicted and observed shares over all
        (subset, option) cells.
    engine : str
        ``"closed_form"``, ``"threshold_exact"`` or ``"simulation"``.
    stopping : object
        The stopping rule given (its ``theta`` is the start when ``"theta"`` is fitted).
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
    >>> print(res.summary().splitlines()[0])
    MDFT fit: 1 parameter, 2000 trials, likelihood of choices, engine closed_form
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
    n_agree: int = 1
    on_bound: tuple = ()
    likelihood: str = "choices"
    rt_bins: np.ndarray | None = field(default=None, repr=False)
    n_evaluations: int = 0
    _likelihood: Any = field(repr=False, default=None)

    def __repr__(self) -> str:
        est = ", ".join(f"{k}={_short(self.params[k])}" for k in self.fitted)
        return (f"FitResult({est}, log_likelihood={self.log_likelihood:.6g}, "
                f"converged={self.converged}, engine={self.engine!r})")

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
        return tuple(self._likelihood.predict(self.params, subs))

    def log_likelihood_at(self, params) -> float:
        """The log-likelihood of the fitted data at other parameter values.

        Same likelihood as :attr:`log_likelihood` (same engine, same response-time
        treatment, the same simulation seed), so the two are comparable: e.g. at the true
        parameters of synthetic data, which the maximum must not fall below.

        Parameters
        ----------
        params : dict
            Values of any of ``w``, ``phi1``, ``phi2``, ``beta``, ``sigma2``, ``theta``, ``M``;
            the others are taken from :attr:`params`.

        Examples
        --------
        >>> import mdft
        >>> data = mdft.ChoiceData([[0, 1]], [[60, 40]])
        >>> res = mdft.fit(data, [[1.0, 3.0], [3.0, 1.0]], stopping=20, params=["w"],
        ...                fixed=dict(phi1=0.022, phi2=0.05, beta=12.0, sigma2=1.0), rng=0)
        >>> bool(res.log_likelihood_at({"w": [0.5, 0.5]}) < res.log_likelihood)
        True
        """
        if not isinstance(params, dict):
            raise TypeError(f"params must be a dict of parameter values (got {params!r})")
        bad = [k for k in params if k not in self.params]
        if bad:
            raise ValueError(f"params has unknown parameter name(s) {bad}; allowed: "
                             f"{sorted(self.params)}")
        p = dict(self.params)
        p.update(check_values(params, self.params))
        return float(self._likelihood.log_likelihood(p))

    def summary(self) -> str:
        """A small text table: each fitted value with its standard error, then fit statistics.

        Examples
        --------
        >>> import mdft
        >>> data = mdft.ChoiceData([[0, 1]], [[60, 40]])
        >>> res = mdft.fit(data, [[1.0, 3.0], [3.0, 1.0]], stopping=20, params=["w"],
        ...                fixed=dict(phi1=0.022, phi2=0.05, beta=12.0, sigma2=1.0), rng=0)
        >>> print(res.summary())  # doctest: +NORMALIZE_WHITESPACE
        MDFT fit: 1 parameter, 100 trials, likelihood of choices, engine closed_form
        parameter      estimate    std err
        w[0]             0.4645    0.01769
        w[1]             0.5355    0.01769
        log-likelihood -2.511  AIC 7.021  BIC 9.626
        converged True (5 of 5 starts agree)
        """
        k = self.n_params
        lines = [f"MDFT fit: {k} parameter{'s' if k != 1 else ''}, {self.n_observations} "
                 f"trials, likelihood of {self.likelihood}, engine {self.engine}",
                 f"{'parameter':<12s} {'estimate':>10s} {'std err':>10s}"]
        for name in self.fitted:
            value, se = self.params[name], self.standard_errors[name]
            if name in ("w", "M"):
                flat_v = np.asarray(value).ravel()
                flat_s = np.asarray(se).ravel()
                if name == "w":
                    labels = [f"w[{j}]" for j in range(flat_v.size)]
                else:
                    nc = np.asarray(value).shape[1]
                    labels = [f"M[{i // nc},{i % nc}]" for i in range(flat_v.size)]
                for lab, v, s in zip(labels, flat_v, flat_s):
                    lines.append(f"{lab:<12s} {_fmt(v):>10s} {_fmt(s):>10s}")
            else:
                lines.append(f"{name:<12s} {_fmt(value):>10s} {_fmt(se):>10s}")
        lines.append(f"log-likelihood {self.log_likelihood:.4g}  AIC {self.aic:.4g}  "
                     f"BIC {self.bic:.4g}")
        tail = f"converged {self.converged} ({self.n_agree} of "
        tail += f"{len(self.start_log_likelihoods)} starts agree)"
        if self.on_bound:
            tail += f"; on a bound: {', '.join(self.on_bound)}"
        lines.append(tail)
        return "\n".join(lines)

    def to_dict(self) -> dict:
        """The result as JSON-serialisable builtins (arrays as lists, NaN as None).

        Examples
        --------
        >>> import json, mdft
        >>> data = mdft.ChoiceData([[0, 1]], [[60, 40]])
        >>> res = mdft.fit(data, [[1.0, 3.0], [3.0, 1.0]], stopping=20, params=["w"],
        ...                fixed=dict(phi1=0.022, phi2=0.05, beta=12.0, sigma2=1.0), rng=0)
        >>> d = json.loads(json.dumps(res.to_dict()))
        >>> round(d["params"]["w"][0], 2), d["converged"]
        (0.46, True)
        """
        out = {}
        for name in ("params", "fitted", "standard_errors", "se_notes", "covariance", "labels",
                     "log_likelihood", "n_params", "n_observations", "aic", "bic", "converged",
                     "n_iter", "message", "start_log_likelihoods", "n_agree", "on_bound",
                     "likelihood", "rt_bins", "n_evaluations", "observed", "predicted", "mse",
                     "engine"):
            out[name] = to_builtin(getattr(self, name))
        out["stopping"] = to_builtin(_stopping_dict(self.stopping))
        return out


def _stopping_dict(stopping):
    if hasattr(stopping, "theta"):
        return {"theta": stopping.theta, "max_steps": getattr(stopping, "max_steps", None)}
    return {"n_steps": getattr(stopping, "n_steps", stopping)}


def _short(value):
    if isinstance(value, np.ndarray):
        return np.array2string(value, precision=4, separator=", ") if value.size <= 8 else (
            f"<array shape={value.shape}>")
    return f"{value:.4g}" if isinstance(value, float) else repr(value)
