"""Fitting MDFT to observed choices (and response times) by maximum likelihood.

:func:`fit` estimates any chosen subset of the parameters ``w``, ``phi1``, ``phi2``,
``beta``, ``sigma2``, the threshold ``theta`` and the evaluations ``M``, holding the others
fixed. The pieces live in their own modules: the data in :mod:`mdft.choice_data`, the
likelihood and its engines in :mod:`mdft.likelihood`, the multi-start optimiser in
:mod:`mdft.optimise` and the result in :mod:`mdft.fit_result`.

See ``docs/fitting.md`` for the parametrisation, identifiability and the decisions taken.
"""

from __future__ import annotations

import math
import threading
import warnings

import numpy as np

from ._fit_errors import standard_errors
from ._fit_params import DEFAULT_BOUNDS, PARAMETERS, Layout, check_names, resolve
from ._validation import as_count, as_float_array, as_generator, as_scalar
from .choice_data import ChoiceData
from .fit_result import FitResult
from .likelihood import (INFEASIBLE, LOOSER_TOLERANCES, Likelihood, check_threshold_options,
                         choose_engine, quiet_model, stopping_kind)
from .model import GROWTH_LIMIT, REFERENCE_STEPS, growth_factor
from .optimise import multistart

__all__ = ["ChoiceData", "FitConvergenceWarning", "FitResult", "fit", "DEFAULT_BOUNDS"]


class FitConvergenceWarning(RuntimeWarning):
    """The fit may not have found the maximum of the likelihood (see ``FitResult.message``)."""


#: ``quiet.on`` set in a thread: its fits keep their convergence verdict in the result and
#: do not warn (``fit_many``'s workers; ``warnings.catch_warnings`` is not thread-safe).
quiet = threading.local()


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
    response_times="auto",
    rt_bins=None,
    n_confirm=2,
    agree_tol=None,
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
        ``"sigma2"`` (the noise variance), ``"theta"`` (the threshold; threshold stopping
        only, starting from ``stopping.theta``) and ``"M"``.
    fixed : dict, optional
        Values of every parameter in ``w``, ``phi1``, ``phi2``, ``beta``, ``sigma2`` that is
        not estimated (required: nothing is filled in silently).
    start : dict, optional
        First starting point for some fitted parameters. Unspecified ones start at the
        canonical values (``phi1=0.022, phi2=0.05, beta=12, sigma2=1``, uniform ``w``, the
        given ``M``) clipped to the bounds; for the further starts see ``n_starts``.
    bounds : dict, optional
        ``(low, high)`` per fitted scalar parameter (defaults in ``DEFAULT_BOUNDS``:
        ``phi1 (0, 1)``, ``phi2 (0, 0.5)``, ``beta (0, 50)``, ``sigma2 (1e-3, 25)``,
        ``theta (1, 100)``) and for
        ``"M"`` (scalars or arrays; default the range of ``M`` widened by its span on each
        side). ``w`` always ranges over the whole simplex.
    n_starts : int, default 5
        Number of local optimisations; the best is kept. The first starts at ``start``; the
        others at the best, mutually distant points of a global screen of
        ``n_screen_per_start * (n_starts - 1)`` scrambled Sobol points over the bounded box.
        When only one start reaches the best log-likelihood, up to ``n_confirm`` further
        screen points are tried. ``n_starts=1`` skips the screen and the agreement check,
        so its optimum is a local one that nothing confirms: ``converged`` is then False.
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
    n_confirm : int, default 2
        Extra starts allowed to confirm (or improve on) a best optimum reached only once.
    agree_tol : float, optional
        Two starts agree when their log-likelihoods differ by at most this; default 0.01
        (smooth likelihoods) or 0.5 (simulated ones, whose optimiser stops on a step
        function). On a likelihood smooth only to a tolerance (the exact engine with a
        subset of three options) they also agree within its noise's band
        (``docs/fitting.md``, "Likelihoods smooth to a tolerance").
    response_times : {"auto", True, False}, default "auto"
        Put the response times of ``data`` in the likelihood: ``"auto"`` when the data have
        them and stopping is a threshold, True to require it, False for choices only. The
        times must be decision steps (whole numbers from 1 to ``max_steps``).
    rt_bins : None, int or array_like, optional
        How response times enter: None uses every decision step with the exact engine
        (``rt_pmf`` of ``mdft.threshold_probabilities``) and 10 quantile bins of the
        observed steps with simulation; an int asks for that many quantile bins; an array
        gives bin edges in steps (``edges[b] < t <= edges[b + 1]``, from below 1 to at
        least ``max_steps``).
    method : {"auto", "threshold_exact", "simulation"}
        Engine for threshold stopping; ``"auto"`` uses ``mdft.threshold_probabilities`` when
        every subset has 2 options (0.01-0.12 s per subset and evaluation) and simulation
        otherwise: with 3 options the exact engine takes about 0.2 s per subset and
        evaluation at the median, seconds on some models, so a fit takes minutes (ask for it
        with ``"threshold_exact"``; ``docs/fitting.md``, section 7). Where it cannot meet
        its default tolerances it tries again at ``atol=3e-3, rt_rtol=1e-2`` (the message
        counts those evaluations), and only a model it cannot vouch for at those is
        infeasible for the optimiser (section 3, "Where the exact engine cannot vouch").
        That likelihood is smooth only to about 1e-6 of itself; the optimiser's steps and
        the standard errors' Hessian are sized for it (section 3). Fixed time always uses
        the closed form.
    threshold_options : dict, optional
        Extra keyword arguments of ``mdft.threshold_probabilities`` (e.g. ``atol``), for
        the ``"threshold_exact"`` engine only: given with another engine, or with a name
        that is not such an argument, it raises ``ValueError``. Tolerances given here
        (``atol`` or ``rt_rtol``) are kept: the engine then makes no second try at looser
        ones.

    Returns
    -------
    FitResult

    Warns
    -----
    FitConvergenceWarning
        Whenever ``converged`` is False: no start that reached the best log-likelihood met
        its optimiser's criterion, the starts disagree (only one reached the best
        log-likelihood, even after ``n_confirm`` further starts), there was a single start
        (``n_starts=1``), a fitted parameter lies on a bound, or the exact threshold engine
        warned at the optimum.

    Notes
    -----
    The optimiser works on the unit cube: each bounded scalar is mapped linearly onto
    ``[0, 1]``, ``w`` by stick-breaking (``w_1 = v_1``, ``w_2 = (1 - v_1) v_2``, ...), and
    ``M`` entry by entry with its first row held fixed (adding a constant to a column of
    ``M`` changes neither ``C M`` nor the distances, so one row must anchor it). Smooth
    likelihoods (closed form, exact threshold method) use L-BFGS-B with central
    finite-difference gradients; a simulated likelihood uses bounded Nelder-Mead with common
    random numbers.
    Standard errors come from the inverse of the central-difference Hessian of the negative
    log-likelihood, mapped to natural units by the delta method; they are NaN (with a reason
    in ``se_notes``) for estimates on a bound, where the Hessian is not positive definite
    (a parameter that is not identified) and for simulated likelihoods.

    With choices only, the threshold ``theta`` and the noise ``sigma2`` are nearly
    confounded (a larger threshold and more noise give similar shares); response times
    separate them (``docs/fitting.md`` measures how much better the parameters are
    recovered).

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
    fitted = check_names("params", params)
    if not fitted:
        raise ValueError("params is empty: name at least one parameter to fit")
    fitted = tuple(k for k in PARAMETERS if k in fitted)
    n_starts = as_count("n_starts", n_starts)
    max_iter = as_count("max_iter", max_iter)
    tol = as_scalar("tol", tol, low=0.0, low_inclusive=False)
    n_samples = as_count("n_samples", n_samples)
    n_screen_per_start = as_count("n_screen_per_start", n_screen_per_start)
    n_confirm = as_count("n_confirm", n_confirm, low=0)
    if agree_tol is not None:
        agree_tol = as_scalar("agree_tol", agree_tol, low=0.0)
    if response_times not in ("auto", True, False):
        raise ValueError(
            f"response_times must be 'auto', True or False (got {response_times!r})"
        )
    kind, spec = stopping_kind(stopping)
    engine = choose_engine(kind, method, data.subsets)
    threshold_options = check_threshold_options(threshold_options, engine)
    use_rt = bool(response_times) and data.has_response_times and kind == "threshold"
    if response_times is True and not use_rt:
        raise ValueError(
            "response_times=True needs data with response times (ChoiceData.from_trials(..., "
            "response_times=...)) and stopping=mdft.Threshold(theta); got "
            f"{'no response times' if not data.has_response_times else 'fixed-time stopping'}"
        )
    if rt_bins is not None and not use_rt:
        raise ValueError("rt_bins is given but response times are not in the likelihood")
    values, res_bounds, first = resolve(M, fitted, fixed, start, bounds,
                                        spec[0] if kind == "threshold" else None)
    rng = as_generator("rng", rng)
    lik = Likelihood(data, stopping, engine, use_rt=use_rt, rt_bins=rt_bins,
                     n_samples=n_samples, seed=int(rng.integers(2**31)),
                     threshold_options=threshold_options)
    layout = Layout(fitted, values, res_bounds, n, J)
    n_obs = int(sum(c.sum() for c in data.counts))

    def negloglik(u):
        return lik.negative(layout.unpack(np.clip(u, 0.0, 1.0)))

    smooth = engine != "simulation"
    if agree_tol is None:
        agree_tol = 0.01 if smooth else 0.5
    out = multistart(negloglik, layout.pack(first), n_starts=n_starts,
                     n_screen=n_screen_per_start * (n_starts - 1), rng=rng, smooth=smooth,
                     max_iter=max_iter, tol=tol, fatol=tol * n_obs, agree_tol=agree_tol,
                     n_confirm=n_confirm, noise=lik.noise)
    best = out.best
    if best.fun >= INFEASIBLE:
        raise ValueError(
            "the likelihood could not be evaluated at any start (every prediction failed; "
            f"first: {lik.first_failure or 'no finite value'}); check the bounds, the "
            "stopping rule, threshold_options and the data"
        )
    u_hat = best.x
    p_hat = layout.unpack(u_hat)
    on_bound = tuple(dict.fromkeys(layout.block_of(i) for i in out.on_bound))
    problems = list(out.problems)
    lik.negative(p_hat)
    optimum_loosened = lik.last_loosened
    if lik.last_warnings:
        # the exact engine cannot vouch for its answer at the optimum
        problems.append("the likelihood engine warned at the optimum: "
                        + "; ".join(dict.fromkeys(lik.last_warnings)))
    if on_bound:
        problems.append(
            f"{', '.join(on_bound)} on a bound of its range (widen bounds= if the range allows)"
        )
    model = quiet_model(p_hat["M"], p_hat)
    steps = spec if kind == "fixed" else REFERENCE_STEPS
    growth = growth_factor(model.spectral_radius, steps)
    if growth > GROWTH_LIMIT:
        # the likelihood of such a model says little: its preferences run away along S's
        # leading direction, whatever the other parameters are
        over = "the" if kind == "fixed" else "a reference deliberation of"
        problems.append(
            f"the fitted model's feedback matrix S is unstable (spectral radius "
            f"{model.spectral_radius:.4g}: preferences can grow by a factor of {growth:.3g} over "
            f"{over} {steps} steps); lower phi2 (its bound or fixed value) or raise phi1"
        )
    converged = out.converged and not lik.last_warnings and growth <= GROWTH_LIMIT
    message = best.message if not problems else "; ".join(problems)
    if lik.n_failed:
        # reported, not fatal: corners of the box where preferences overflow are common
        message += (f"; {lik.n_failed} of {lik.n_evaluations} likelihood evaluations failed "
                    f"and counted as impossible (first: {lik.first_failure})")
    if lik.n_loosened:
        # vouched for, at tolerances about three times the defaults: reported, not a failure
        where = ", the optimum's among them," if optimum_loosened else ""
        message += (f"; the exact engine vouched for {lik.n_loosened} of {lik.n_evaluations} "
                    f"likelihood evaluations{where} only at atol="
                    f"{LOOSER_TOLERANCES['atol']:g}, rt_rtol={LOOSER_TOLERANCES['rt_rtol']:g} "
                    "(it could not meet its defaults there)")
    if not converged and not getattr(quiet, "on", False):
        warnings.warn(
            f"the fit may not have found the maximum: {message}; raise n_starts or max_iter, "
            "or check the bounds",
            FitConvergenceWarning,
            stacklevel=2,
        )

    cov, ses, notes = standard_errors(negloglik, layout, u_hat, smooth, noise=lik.noise)
    loglik = -float(best.fun) + lik.constant
    k = layout.size
    preds = tuple(lik.predict(p_hat))
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
        n_iter=best.n_iter,
        message=message,
        start_log_likelihoods=tuple(-float(r.fun) + lik.constant for r in out.runs),
        observed=observed,
        predicted=preds,
        mse=float(sq.mean()),
        engine=engine,
        stopping=stopping,
        model=model,
        n_agree=out.n_agree,
        on_bound=on_bound,
        likelihood=lik.label,
        rt_bins=lik.edges,
        n_evaluations=lik.n_evaluations,
        _likelihood=lik,
    )
