"""Fixed-time choice probabilities without simulation (Roe, Busemeyer & Townsend 2001).

For fixed deliberation time ``T`` the preference state ``P(T)`` has mean and covariance

    xi(T)    = sum_{k<T} S^k mu + S^T P0,             mu  = C M w
    Omega(T) = sum_{k<T} S^k Phi (S^k)^T,             Phi = C M Psi M^T C^T + sigma2 C C^T,
                                                      Psi = diag(w) - w w^T

and, approximating ``P(T)`` by the normal distribution ``N(xi, Omega)``, option ``i`` is
chosen with probability ``Pr(L_i P(T) > 0)`` where ``L_i`` is the ``(n-1, n)`` difference
matrix (+1 at ``i``, -1 at each rival).

The sums are accumulated by repeated doubling of the triple ``(S^t, sum S^k mu,
sum S^k Phi S^kT)``, which needs ``O(log T)`` products of ``n x n`` matrices and never
inverts ``I - S`` (whose inverse does not exist when the spectral radius of ``S`` is 1).

The orthant probabilities are computed

* exactly for one comparison (two options): the normal CDF;
* exactly for two comparisons (three options): Owen's T function;
* for three or more comparisons by Genz's separation of variables with a fixed,
  deterministic set of randomised quasi-Monte Carlo points (smooth in the parameters,
  absolute error about 1e-5, estimated from independent scramblings);

with the degenerate cases (zero-variance differences, e.g. ``sigma2 = 0``) handled
exactly: a difference with zero variance is decided by the sign of its mean, and options
whose preferences are equal with probability one share their probability equally (ties
are broken uniformly at random, as in the simulation).
"""

from __future__ import annotations

import os
import warnings
from dataclasses import dataclass
from functools import lru_cache
from typing import Sequence

import numpy as np
from scipy import special

from ._typing import SeedLike
from ._export import builtin, fmt, labels_for, table, to_json
from ._repr import compact_repr
from ._edgeworth import (attention_cumulants, bivariate_cdf, error_estimate, geometric_sums,
                         lattice_terms, lumpiness)
from ._validation import MAX_STEPS, as_count, as_scalar
from .model import MDFTModel, UnstableFeedbackWarning, warn_if_growing

__all__ = [
    "ClosedFormAccuracyWarning",
    "MixtureProbabilities",
    "choice_probabilities",
    "mixture_choice_probabilities",
    "preference_moments",
]

#: Relative size (to the overall variance scale) below which a variance counts as zero.
_VAR_RTOL = 1e-12
#: Relative size (to the overall scale of the means) below which a mean difference is a tie.
_TIE_RTOL = 1e-9
#: Tolerance on ``|sum(p) - 1|`` for the exact (n <= 3) computation and for the
#: quasi-Monte Carlo one (n >= 4; or ten times its estimated error if larger).
_SUM_TOL_EXACT = 1e-8
_SUM_TOL_QMC = 1e-5
#: Number of scramblings and points per scrambling of the quasi-Monte Carlo rule.
_QMC_SHIFTS = 8
_QMC_POINTS = 512
_QMC_SEED = 20011
#: Four or more options: an option whose best single comparison is won with probability
#: below this gets that bound as its probability instead of a quasi-Monte Carlo integral.
_NEGLIGIBLE = 1e-13
#: ``method="auto"``: default tolerance on each probability, and the factor by which the
#: error estimate must stay below it for the normal approximation to be returned.
DEFAULT_TOL = 0.002
_SAFETY = 2.0
#: Beyond this many standard deviations of the rest, the last attention draw splits P(T)
#: into separate modes and the error estimate is not trusted.
_LUMPY_MAX = 3.0
#: Exact fallbacks: enumerate attention sequences up to this many; otherwise the exact
#: mixture with a fixed seed, from this many sequences up to the cap, and at most this
#: many sequence-steps of work.
_ENUMERATE_MAX = 4096
_MIXTURE_SEED = 20_011
_MIXTURE_START = 20_000
_MIXTURE_MAX = 200_000
_MIXTURE_WORK = 20_000_000
_METHODS = ("auto", "normal")
#: Attention sequences simulated together by the exact mixture.
_MIXTURE_BLOCK = 8192


class ClosedFormAccuracyWarning(RuntimeWarning):
    """No longer emitted; kept so that code which filters it keeps working.

    Closed-form probabilities that do not sum to one within the method's tolerance now
    raise a ``ValueError`` (or, with ``method="auto"``, fall back to an exact method).
    """


class _OrthantSumError(ValueError):
    """The orthant probabilities miss a sum of one by more than the method's error."""


def _check_model(model) -> None:
    if not isinstance(model, MDFTModel):
        raise TypeError(f"model must be an mdft.MDFTModel (got {type(model).__name__})")


def preference_moments(model: MDFTModel, n_steps: int) -> tuple[np.ndarray, np.ndarray]:
    """Mean and covariance of the preference state ``P(n_steps)``.

    Parameters
    ----------
    model : MDFTModel
        The model (``S``, ``C``, ``M``, ``w``, ``sigma2``, ``P0``).
    n_steps : int
        Deliberation time ``T``, at least 1.

    Returns
    -------
    mean : ndarray, shape (n_options,)
        ``xi(T) = sum_{k<T} S^k mu + S^T P0`` with ``mu = C M w``.
    cov : ndarray, shape (n_options, n_options)
        ``Omega(T) = sum_{k<T} S^k Phi (S^k)^T``, symmetric positive semi-definite.

    Raises
    ------
    ValueError
        If the moments overflow (a strongly expansive ``S`` over a very long horizon).

    Warns
    -----
    UnstableFeedbackWarning
        If preferences can grow more than tenfold over ``n_steps`` steps
        (``rho(S) ** n_steps > 10``, ``docs/concepts.md``).

    Notes
    -----
    These are exact moments of MDFT's preference state (Roe et al. 2001): the valence
    ``V(t) = C (M W(t) + eps(t))`` has mean ``mu`` and covariance ``Phi = C M Psi M^T C^T
    + sigma2 C C^T`` (``Psi = diag(w) - w w^T``) and is independent across steps. The sums
    are formed by doubling (``O(log T)`` matrix products); ``I - S`` is never inverted, so
    a spectral radius of 1 or slightly above is no problem.

    Examples
    --------
    >>> import mdft
    >>> model = mdft.MDFTModel([[1, 3], [3, 1]], [0.5, 0.5],
    ...                        phi1=0.022, phi2=0.05, beta=12.0)
    >>> mean, cov = mdft.preference_moments(model, 100)
    >>> mean.round(6).tolist()
    [0.0, 0.0]
    >>> round(float(cov[0, 0]), 2)
    80.92
    """
    _check_model(model)
    n_steps = as_count("n_steps", n_steps, low=1, high=MAX_STEPS)
    S = np.asarray(model.S)
    mu = model.valence_mean
    phi = model.valence_covariance
    with np.errstate(over="ignore", invalid="ignore"):
        mean, cov = _moments(S, mu, phi, np.asarray(model.P0), n_steps)
    if not (np.all(np.isfinite(mean)) and np.all(np.isfinite(cov))):
        raise ValueError(
            f"n_steps={n_steps} is too long for this model: the moments of P(T) are not finite "
            f"(spectral radius of S {model.spectral_radius:.6g}), preferences overflow; use "
            "fewer steps or a feedback matrix with spectral radius closer to 1"
        )
    warn_if_growing(model.spectral_radius, n_steps, stacklevel=2)
    return mean, cov


def _moments(S, mu, phi, P0, n_steps):
    """``(sum_{k<T} S^k mu + S^T P0, sum_{k<T} S^k Phi S^kT)`` by repeated doubling."""
    A, (m, O) = geometric_sums(S, (mu, phi), n_steps)
    mean = m + A @ P0
    cov = 0.5 * (O + O.T)
    return mean, cov


def choice_probabilities(model: MDFTModel, n_steps: int, *, method: str = "auto",
                         tol: float = DEFAULT_TOL) -> np.ndarray:
    """Fixed-time choice probabilities, from the normal approximation where it is accurate.

    Parameters
    ----------
    model : MDFTModel
        The model.
    n_steps : int
        Deliberation time ``T``, at least 1; the option with the largest ``P(T)`` is chosen.
    method : {"auto", "normal"}, default "auto"
        ``"normal"``: the normal approximation of ``P(T)`` (Roe et al. 2001), always;
        deterministic and smooth in the parameters (what :func:`mdft.fit` uses).
        ``"auto"``: the exact law when the attention sequences are few enough to
        enumerate (at most 4,096; two or three options, or ``sigma2 = 0``); otherwise the
        normal approximation when its estimated error is at most ``tol / 2`` for every
        option, otherwise the exact mixture (below), otherwise a ``ValueError``.
    tol : float, default 0.002
        ``method="auto"``: the absolute error allowed on each probability, in (0, 0.5].

    Returns
    -------
    probabilities : ndarray, shape (n_options,)
        They sum to one.

    Raises
    ------
    ValueError
        With ``method="auto"``, if the normal approximation may be off by more than ``tol``
        and no exact method applies at an affordable cost (four or more options, or
        ``sigma2 = 0``, with a deliberation too long to enumerate). With either method, if
        the orthant probabilities do not sum to one within their numerical error, or the
        moments overflow.

    Notes
    -----
    The noise ``eps(t)`` is Gaussian but the attention process is not, so ``P(T)`` is a
    mixture of normals; the normal with the same two moments, ``N(xi(T), Omega(T))``
    (:func:`preference_moments`), is the classical approximation. Option ``i`` is chosen
    with probability ``Pr(L_i P(T) > 0)``: the normal CDF for two options, Owen's T
    function for three (both exact for the normal distribution), Genz's separation of
    variables on a fixed set of scrambled Sobol points for four or more (deterministic,
    absolute error about 1e-5). Differences with zero variance (as with ``sigma2 = 0``)
    are decided by the sign of their mean; options equal with probability one split
    their probability equally.

    ``method="auto"`` first enumerates the attention sequences when there are at most
    4,096 of them (``J^T``; two or three options, or any number without noise): that is
    the exact law at about the cost of the estimate. Otherwise it estimates the error of
    the approximation from the exact third and fourth cumulants of the attention sum (the
    leading Edgeworth terms of each option's orthant probability: in closed form for two
    options, by finite differences of Owen's T for three, by quasi-Monte Carlo capped by
    a Cauchy-Schwarz bound for four or more) and, when that estimate exceeds ``tol / 2``,
    falls back to the exact mixture (:func:`mixture_choice_probabilities`, two or three
    options, ``sigma2 > 0``) with a fixed seed and enough sequences for three standard
    errors within ``tol``.
    ``docs/closed_form.md`` gives the accuracy of the estimate on random models.

    Examples
    --------
    >>> import mdft
    >>> M = [[1, 3], [3, 1], [2, 2]]  # A, B and the compromise C
    >>> model = mdft.MDFTModel(M, [0.5, 0.5], phi1=0.022, phi2=0.05, beta=12.0)
    >>> p = mdft.choice_probabilities(model, 100)
    >>> p.round(3).tolist()
    [0.285, 0.285, 0.43]
    >>> round(float(p.sum()), 12)
    1.0

    At ``T = 3`` there are eight attention sequences: they are enumerated, which gives
    the exact law; the normal approximation is off by 0.004 here.

    >>> mdft.choice_probabilities(model, 3).round(4).tolist()
    [0.3736, 0.3736, 0.2527]
    >>> mdft.choice_probabilities(model, 3, method="normal").round(4).tolist()
    [0.3715, 0.3715, 0.2571]
    """
    _check_model(model)
    n_steps = as_count("n_steps", n_steps, low=1, high=MAX_STEPS)
    if not isinstance(method, str) or method not in _METHODS:
        raise ValueError(f"method must be 'auto' or 'normal' (got {method!r})")
    tol = as_scalar("tol", tol, low=0.0, high=0.5, low_inclusive=False)
    with warnings.catch_warnings():
        # warn once, below, with the caller's line
        warnings.simplefilter("ignore", UnstableFeedbackWarning)
        mean, cov = preference_moments(model, n_steps)
    warn_if_growing(model.spectral_radius, n_steps, stacklevel=2)
    try:
        p = _probabilities_from_moments(mean, cov)
    except _OrthantSumError as exc:
        if method == "normal":
            raise ValueError(f"{exc}; use mdft.simulate for this model") from None
        p, reason = None, str(exc)
    if method == "normal":
        return p
    if _n_sequences(model, n_steps) <= _ENUMERATE_MAX and (model.n_options <= 3
                                                          or model.sigma2 == 0):
        # few attention sequences: the exact law costs about as much as the estimate
        return _enumerated_probabilities(model, n_steps)
    lumpy = lumpiness(cov, np.asarray(model.C) @ np.asarray(model.M), np.asarray(model.w))
    if p is not None and lumpy > _LUMPY_MAX:
        p, reason = None, (f"P(T) is far from normal: the last attention draw alone moves a "
                           f"comparison by {lumpy:.3g} standard deviations of the rest (more "
                           f"than {_LUMPY_MAX:g}), where the error estimate cannot be trusted")
    if p is not None:
        est = float(_normal_error(model, n_steps, mean, cov, p, tol / _SAFETY).max())
        if est <= tol / _SAFETY:
            return p
        reason = (f"the normal approximation's estimated error is {est:.2g}, above "
                  f"tol/{_SAFETY:g} = {tol / _SAFETY:.2g}")
    exact, why_not = _exact_probabilities(model, n_steps, tol)
    if exact is not None:
        return exact
    raise ValueError(
        f"choice_probabilities cannot vouch for its answer: {reason}, for a model with "
        f"{model.n_options} options, {model.n_attributes} attributes, sigma2="
        f"{model.sigma2:g}, rho(S)={model.spectral_radius:.4g} and n_steps={n_steps}, and "
        f"{why_not}. Use mdft.simulate (Monte Carlo with standard errors), a larger tol, "
        "or method='normal' to accept the normal approximation knowingly"
    )


def _normal_error(model, n_steps, mean, cov, p, enough=0.0):
    """Per-option error estimate of the normal approximation (see :mod:`mdft._edgeworth`)."""
    S = np.asarray(model.S)
    CM = np.asarray(model.C) @ np.asarray(model.M)
    with np.errstate(over="ignore", invalid="ignore"):
        k3, k4 = attention_cumulants(S, CM, np.asarray(model.w), n_steps)
    if not (np.all(np.isfinite(k3)) and np.all(np.isfinite(k4))):
        return np.full(p.shape, np.inf)
    w = np.asarray(model.w)
    C = np.asarray(model.C)
    with np.errstate(over="ignore", invalid="ignore"):
        _, (noise,) = geometric_sums(S, (model.sigma2 * (C @ C.T),), n_steps)
    lattice = lattice_terms(mean, cov, noise, CM, w)
    return error_estimate(mean, cov, k3, k4, p, max(enough - lattice.max(), 0.0)) + lattice


def _n_sequences(model, n_steps):
    """Number of attention sequences with positive probability, capped above the limit."""
    J = int(np.count_nonzero(np.asarray(model.w) > 0))
    if J <= 1:
        return 1
    return J**n_steps if n_steps * np.log(J) <= np.log(_ENUMERATE_MAX) + 1e-9 else _ENUMERATE_MAX + 1


def _exact_probabilities(model, n_steps, tol):
    """``(probabilities, None)`` from an exact method, or ``(None, why not)``."""
    n = model.n_options
    if _n_sequences(model, n_steps) <= _ENUMERATE_MAX and (n <= 3 or model.sigma2 == 0):
        return _enumerated_probabilities(model, n_steps), None
    if n > 3:
        return None, (f"no exact method applies (the exact mixture handles 2 or 3 options, "
                      f"and the {model.n_attributes}**{n_steps} attention sequences are too "
                      f"many to enumerate)")
    if model.sigma2 == 0:
        return None, ("no exact method applies (without noise the exact mixture does not "
                      "exist, and the attention sequences are too many to enumerate)")
    n_seq = _MIXTURE_START
    for _ in range(2):
        if n_seq * n_steps > _MIXTURE_WORK:
            return None, (f"the exact mixture would need {n_seq:,} sequences of {n_steps} "
                          f"steps, more than the {_MIXTURE_WORK:,} sequence-steps allowed")
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UnstableFeedbackWarning)
            res = mixture_choice_probabilities(model, n_steps, n_sequences=n_seq,
                                               rng=_MIXTURE_SEED)
        se = float(res.standard_errors.max())
        if 3.0 * se <= tol:
            return np.array(res.probabilities), None
        n_seq = int(np.ceil(1.2 * n_seq * (3.0 * se / tol) ** 2))
        if n_seq > _MIXTURE_MAX:
            break
    return None, (f"the exact mixture cannot reach three standard errors within tol with "
                  f"at most {_MIXTURE_MAX:,} sequences")


def _enumerated_probabilities(model, n_steps):
    """Exact fixed-time probabilities by enumerating every attention sequence.

    Conditionally on the sequence, ``P(T)`` is normal (``sigma2 > 0``: exact orthant, two
    or three options) or a point (``sigma2 = 0``: the argmax, ties split equally). The
    caller keeps the number of sequences small.
    """
    n = model.n_options
    w = np.asarray(model.w)
    keep = w > 0
    S = np.asarray(model.S)
    CM = (np.asarray(model.C) @ np.asarray(model.M))[:, keep]
    w = w[keep]
    A = np.zeros((1, n))
    weight = np.ones(1)
    for _ in range(n_steps):
        A = ((A @ S.T)[:, None, :] + CM.T[None, :, :]).reshape(-1, n)
        weight = (weight[:, None] * w[None, :]).ravel()
    C = np.asarray(model.C)
    base, noise = _moments(S, np.zeros(n), model.sigma2 * (C @ C.T), np.asarray(model.P0),
                           n_steps)
    means = base + A
    if model.sigma2 > 0:
        f = _conditional_orthants(means, noise)
    else:
        top = means.max(axis=1, keepdims=True)
        tie = _TIE_RTOL * max(float(np.abs(means).max()), 1e-300)
        f = (means >= top - tie).astype(float)
        f /= f.sum(axis=1, keepdims=True)
    p = weight @ f
    return p / p.sum()


def _conditional_orthants(means, noise):
    """``Pr(choose i | mean)`` for ``N(mean, noise)``, many means (N, n), n = 2 or 3."""
    n = means.shape[1]
    f = np.empty(means.shape)
    for i in range(n):
        L = -np.eye(n)[np.arange(n) != i]
        L[:, i] = 1.0
        mm = means @ L.T
        cc = L @ noise @ L.T
        if n == 2:
            f[:, i] = special.ndtr(mm[:, 0] / np.sqrt(cc[0, 0]))
        else:
            f[:, i] = _bivariate_orthant_many(mm, cc)
    return f


def _probabilities_from_moments(mean, cov):
    """Choice probabilities of ``argmax`` for ``P ~ N(mean, cov)``, ties split equally."""
    n = mean.shape[0]
    var_scale = max(float(np.max(np.abs(np.diag(cov)))), 0.0)
    mean_scale = max(float(np.max(np.abs(mean))), np.sqrt(var_scale), 1e-300)
    var_tol = _VAR_RTOL * max(var_scale, mean_scale**2)
    tie_tol = _TIE_RTOL * mean_scale

    if n <= 3:
        fast = _small_regular(mean, cov, var_tol)
        if fast is not None:
            return fast

    # Options whose preferences are equal with probability one form a class.
    dvar = np.diag(cov)[:, None] + np.diag(cov)[None, :] - 2.0 * cov
    dmean = mean[:, None] - mean[None, :]
    same = (np.abs(dvar) <= var_tol) & (np.abs(dmean) <= tie_tol)
    labels = -np.ones(n, dtype=np.int64)
    reps = []
    for i in range(n):
        if labels[i] >= 0:
            continue
        labels[i] = len(reps)
        reps.append(i)
        stack = [i]
        while stack:  # connected components: bounded by n pushes
            a = stack.pop()
            for b in np.flatnonzero(same[a] & (labels < 0)):
                labels[b] = labels[i]
                stack.append(int(b))
    reps = np.asarray(reps)
    k = reps.size
    if k == 1:
        return np.full(n, 1.0 / n)

    m_r = mean[reps]
    c_r = cov[np.ix_(reps, reps)]
    p_class = np.empty(k)
    err = 0.0
    for a in range(k):
        rivals = np.delete(np.arange(k), a)
        m = m_r[a] - m_r[rivals]
        c = (c_r[a, a] - c_r[a, rivals][None, :] - c_r[rivals, a][:, None]
             + c_r[np.ix_(rivals, rivals)])
        if k > 3:
            # Pr(all comparisons won) <= Pr(the hardest one won): skip the orthant
            # integral where that bound is negligible (absolute error below _NEGLIGIBLE).
            v = np.diag(c)
            reg = v > var_tol
            bound = float(special.ndtr(np.min(m[reg] / np.sqrt(v[reg])))) if reg.any() else 1.0
            if np.any(~reg & (m < -tie_tol)):
                bound = 0.0
            if bound < _NEGLIGIBLE:
                p_class[a] = bound
                continue
        p_class[a], e = _orthant(m, 0.5 * (c + c.T), var_tol, tie_tol)
        err += e

    total = p_class.sum()
    tol = _SUM_TOL_EXACT if k <= 3 else max(_SUM_TOL_QMC, 10.0 * err)
    if not np.isfinite(total) or abs(total - 1.0) > tol:
        raise _OrthantSumError(
            f"the closed-form choice probabilities sum to {total:.10g} instead of 1 "
            f"(tolerance {tol:.2g}): the orthant integrals are not accurate for these moments"
        )
    p_class = np.clip(p_class, 0.0, None)
    p_class /= p_class.sum()
    sizes = np.bincount(labels, minlength=k)
    return p_class[labels] / sizes[labels]


_RIVALS3 = np.array([[1, 2], [0, 2], [0, 1]])


def _small_regular(mean, cov, var_tol):
    """Vectorised exact path for 2 or 3 options with a regular covariance of differences.

    Returns ``None`` when a difference has (near) zero variance, a correlation is (near)
    +-1 or a standardised mean is exactly zero; the general path handles those.
    """
    if mean.size == 2:
        v = cov[0, 0] + cov[1, 1] - 2.0 * cov[0, 1]
        if not v > var_tol:
            return None
        p0 = float(special.ndtr((mean[0] - mean[1]) / np.sqrt(v)))
        return np.array([p0, 1.0 - p0])
    d = np.diag(cov)
    a = _RIVALS3[:, 0]
    b = _RIVALS3[:, 1]
    i = np.arange(3)
    m1, m2 = mean - mean[a], mean - mean[b]
    v1 = d + d[a] - 2.0 * cov[i, a]
    v2 = d + d[b] - 2.0 * cov[i, b]
    c12 = d - cov[i, a] - cov[i, b] + cov[a, b]
    if not (np.all(v1 > var_tol) and np.all(v2 > var_tol)):
        return None
    s1, s2 = np.sqrt(v1), np.sqrt(v2)
    h, k = m1 / s1, m2 / s2
    rho = c12 / (s1 * s2)
    if np.any(np.abs(rho) > 1.0 - 1e-9) or np.any(h == 0.0) or np.any(k == 0.0):
        return None
    root = np.sqrt(1.0 - rho * rho)
    a_h = (k - rho * h) / (h * root)
    a_k = (h - rho * k) / (k * root)
    corr = np.where(h * k > 0.0, 0.0, 0.5)
    p = (0.5 * (special.ndtr(h) + special.ndtr(k)) - special.owens_t(h, a_h)
         - special.owens_t(k, a_k) - corr)
    p = np.clip(p, 0.0, 1.0)
    total = p.sum()
    if not abs(total - 1.0) <= _SUM_TOL_EXACT:
        return None
    return p / total


def _orthant(m, c, var_tol, tie_tol):
    """``Pr(Y > 0)`` for ``Y ~ N(m, c)`` (possibly singular); returns (p, error estimate)."""
    d = np.diag(c)
    det = d <= var_tol
    if np.any(det):
        # Zero-variance comparisons are decided by their mean. A zero mean here is a tie
        # with an option of another class, which the class construction rules out up to
        # rounding; count it as a half.
        md = m[det]
        factor = 1.0
        if np.any(md < -tie_tol):
            return 0.0, 0.0
        factor = 0.5 ** int(np.count_nonzero(np.abs(md) <= tie_tol))
        keep = ~det
        m, c = m[keep], c[np.ix_(keep, keep)]
        if m.size == 0:
            return factor, 0.0
        p, e = _orthant(m, c, var_tol, tie_tol)
        return factor * p, factor * e
    q = m.size
    if q == 1:
        return float(special.ndtr(m[0] / np.sqrt(c[0, 0]))), 0.0
    A = _pivoted_cholesky(c, var_tol)
    r = A.shape[1]
    if r == 1:
        return _orthant_rank1(m, A[:, 0]), 0.0
    if q == 2:
        return _orthant_bivariate(m, c), 0.0
    if r == q:
        # Regular covariance: Genz's ordering (most constraining comparison first).
        perm, L = _ordered_cholesky(m, c)
        return _orthant_sov(m[perm], L)
    return _orthant_sov(m, A)


def _ordered_cholesky(m, c):
    """Cholesky factor of ``c`` with Genz & Bretz's variable ordering for ``Pr(Y > 0)``.

    At each step the comparison least likely to be won, given the earlier ones at their
    truncated means, comes next; this lowers the variance of the separation of variables.
    Returns the permutation and the lower-triangular factor of ``c[perm][:, perm]``.
    """
    q = m.size
    c = c.copy()
    a = -m.copy()  # lower limits of Y - m
    perm = np.arange(q)
    L = np.zeros((q, q))
    y = np.zeros(q)
    for k in range(q):
        rest = np.arange(k, q)
        var = np.diag(c)[rest] - (L[rest, :k] ** 2).sum(axis=1)
        sd = np.sqrt(np.maximum(var, 1e-300))
        lim = (a[rest] - L[rest, :k] @ y[:k]) / sd
        j = k + int(np.argmax(lim))  # smallest Pr(z > lim)
        if j != k:
            for arr in (a, perm):
                arr[[k, j]] = arr[[j, k]]
            c[[k, j]] = c[[j, k]]
            c[:, [k, j]] = c[:, [j, k]]
            L[[k, j]] = L[[j, k]]
        d = c[k, k] - L[k, :k] @ L[k, :k]
        if d <= 0.0:
            d = 1e-300
        L[k, k] = np.sqrt(d)
        if k + 1 < q:
            L[k + 1:, k] = (c[k + 1:, k] - L[k + 1:, :k] @ L[k, :k]) / L[k, k]
        t = (a[k] - L[k, :k] @ y[:k]) / L[k, k]
        # Mean of a standard normal truncated to (t, inf), computed in logs for large t.
        y[k] = np.exp(-0.5 * t * t - 0.5 * np.log(2.0 * np.pi) - special.log_ndtr(-t))
    return perm, L


def _orthant_rank1(m, a):
    """``Pr(m + a z > 0)`` for scalar ``z ~ N(0, 1)``: an interval of ``z``."""
    lo, hi = -np.inf, np.inf
    for mj, aj in zip(m, a):
        if aj > 0:
            lo = max(lo, -mj / aj)
        elif aj < 0:
            hi = min(hi, -mj / aj)
        elif mj <= 0:
            return 0.0
    if hi <= lo:
        return 0.0
    return float(special.ndtr(hi) - special.ndtr(lo))


def _orthant_bivariate(m, c):
    """``Pr(Y1 > 0, Y2 > 0)`` for a non-singular bivariate normal, by Owen's T function."""
    s1, s2 = np.sqrt(c[0, 0]), np.sqrt(c[1, 1])
    h, k = m[0] / s1, m[1] / s2
    rho = float(np.clip(c[0, 1] / (s1 * s2), -1.0, 1.0))
    root = np.sqrt(max(1.0 - rho * rho, 0.0))
    if h == 0.0 and k == 0.0:
        return 0.25 + np.arcsin(rho) / (2.0 * np.pi)
    # Owen (1956): Phi2(h, k; rho) = (Phi(h) + Phi(k))/2 - T(h, a_h) - T(k, a_k) - c.
    a_h = (k - rho * h) / (h * root) if h != 0.0 else np.copysign(np.inf, k - rho * h)
    a_k = (h - rho * k) / (k * root) if k != 0.0 else np.copysign(np.inf, h - rho * k)
    corr = 0.0 if (h * k > 0.0 or (h * k == 0.0 and h + k >= 0.0)) else 0.5
    p = (0.5 * (special.ndtr(h) + special.ndtr(k)) - special.owens_t(h, a_h)
         - special.owens_t(k, a_k) - corr)
    return float(min(max(p, 0.0), 1.0))


def _pivoted_cholesky(c, tol):
    """Lower-trapezoidal ``A`` (q, r) with ``A A^T = c`` up to ``tol``; rows keep their order.

    The pivoting order (largest remaining variance first) decides which column each row
    ends in; the rows themselves are not permuted.
    """
    q = c.shape[0]
    resid = c.copy()
    cols = []
    order = []
    for _ in range(q):
        diag = np.diag(resid).copy()
        diag[order] = -np.inf
        j = int(np.argmax(diag))
        if diag[j] <= tol:
            break
        col = resid[:, j] / np.sqrt(diag[j])
        col[order] = 0.0
        cols.append(col)
        order.append(j)
        resid = resid - np.outer(col, col)
    A = np.array(cols).T if cols else np.zeros((q, 0))
    return A


@lru_cache(maxsize=32)
def _qmc_points(dim):
    from scipy.stats import qmc

    pts = np.empty((_QMC_SHIFTS, _QMC_POINTS, dim))
    for s in range(_QMC_SHIFTS):
        sampler = qmc.Sobol(d=dim, scramble=True, rng=np.random.default_rng(_QMC_SEED + s))
        pts[s] = sampler.random(_QMC_POINTS)
    pts.flags.writeable = False
    return pts


def _orthant_sov(m, A):
    """Genz's separation of variables for ``Pr(m + A z > 0)``, ``z ~ N(0, I_r)``.

    ``A`` comes from :func:`_pivoted_cholesky`: the pivot rows give the order in which
    the ``z`` are integrated; every row constrains the ``z`` up to its last non-zero column.
    """
    q, r = A.shape
    # Column order: the pivot row of column j is the row with the largest |A[:, j]| that is
    # zero in all later columns; process columns in order 0..r-1.
    scale = np.max(np.abs(A), axis=1)
    nz = np.abs(A) > 1e-14 * scale[:, None]
    last = np.array([np.flatnonzero(nz[i]).max() for i in range(q)])
    u = _qmc_points(r)  # (shifts, points, r)
    z = np.zeros(u.shape[:2] + (r,))
    weight = np.ones(u.shape[:2])
    for j in range(r):
        rows = np.flatnonzero(last == j)
        piv = A[rows, j]
        # Bounds on z_j from every row that ends in column j: A[i, j] z_j > -(m_i + ...).
        bound = -(m[rows] + z[..., :j] @ A[rows, :j].T) / piv  # (shifts, points, rows)
        pos, neg = piv > 0, piv < 0
        lo = bound[..., pos].max(axis=-1) if pos.any() else np.full(u.shape[:2], -np.inf)
        hi = bound[..., neg].min(axis=-1) if neg.any() else np.full(u.shape[:2], np.inf)
        plo, phi = special.ndtr(lo), special.ndtr(hi)
        width = np.clip(phi - plo, 0.0, None)
        weight = weight * width
        if j < r - 1:
            x = plo + u[..., j] * width
            z[..., j] = special.ndtri(np.clip(x, 1e-300, 1.0 - 1e-16))
    means = weight.mean(axis=1)
    p = float(means.mean())
    err = float(3.0 * means.std(ddof=1) / np.sqrt(means.size))
    return min(max(p, 0.0), 1.0), err


def _hotaling_feedback(M, phi1, phi2, beta):
    """``S`` from evaluations without validation (the same formula as :mod:`mdft.model`)."""
    diff = M[:, None, :] - M[None, :, :]
    D = (diff**2).sum(axis=2) + (beta - 1.0) * diff.sum(axis=2) ** 2 / M.shape[1]
    return np.eye(M.shape[0]) - phi2 * np.exp(-phi1 * D**2)


def _fixed_time_probabilities(M, w, phi1, phi2, beta, sigma2, n_steps):
    """Normal-approximation probabilities from validated arrays (used by :mod:`mdft.fit`).

    The likelihood of a fit is that of the normal approximation (``method="normal"``):
    deterministic and smooth in the parameters. Returns ``None`` where the moments
    overflow or the orthant probabilities do not sum to one (an infeasible trial point).
    """
    n = M.shape[0]
    C = np.full((n, n), -1.0 / (n - 1))
    np.fill_diagonal(C, 1.0)
    S = _hotaling_feedback(M, phi1, phi2, beta)
    CM = C @ M
    mu = CM @ w
    phi = CM @ (np.diag(w) - np.outer(w, w)) @ CM.T + sigma2 * (C @ C.T)
    with np.errstate(over="ignore", invalid="ignore"):
        mean, cov = _moments(S, mu, phi, np.zeros(n), n_steps)
    if not (np.all(np.isfinite(mean)) and np.all(np.isfinite(cov))):
        return None
    try:
        return _probabilities_from_moments(mean, cov)
    except _OrthantSumError:
        return None


# ============================================================== exact mixture (conditional MC)
@dataclass(frozen=True, eq=False)
class MixtureProbabilities:
    """Fixed-time choice probabilities without the normal approximation of ``P(T)``.

    Attributes
    ----------
    probabilities : ndarray, shape (n_options,)
        Estimated choice probabilities; they sum to one.
    standard_errors : ndarray, shape (n_options,)
        Monte Carlo standard errors over the sampled attention sequences (after the
        control variates).
    n_sequences : int
        Number of attention sequences sampled.

    Examples
    --------
    >>> import mdft
    >>> model = mdft.MDFTModel([[1, 3], [3, 1]], [0.5, 0.5], phi1=0.022, phi2=0.05, beta=12.0)
    >>> res = mdft.mixture_choice_probabilities(model, 20, n_sequences=1000, rng=0)
    >>> res.probabilities.round(2).tolist(), res.n_sequences  # two mirror-image options
    ([0.5, 0.5], 1000)
    """

    __repr__ = compact_repr

    probabilities: np.ndarray
    standard_errors: np.ndarray
    n_sequences: int

    def summary(self, labels: Sequence[str] | None = None) -> str:
        """A text table of the probabilities and their standard errors.

        Examples
        --------
        >>> import mdft
        >>> model = mdft.MDFTModel([[1, 3], [3, 1]], [0.5, 0.5], phi1=0.022, phi2=0.05,
        ...                        beta=12.0)
        >>> res = mdft.mixture_choice_probabilities(model, 20, n_sequences=1000, rng=0)
        >>> print(res.summary(labels=["A", "B"]))
        exact mixture over 1,000 attention sequences
        option  P(choose)    s.e.
        A          0.5018  0.0030
        B          0.4982  0.0030
        """
        names = labels_for(labels, self.probabilities.shape[0])
        rows = [[name, fmt(p), fmt(se)]
                for name, p, se in zip(names, self.probabilities, self.standard_errors)]
        return (f"exact mixture over {self.n_sequences:,} attention sequences\n"
                + table(["option", "P(choose)", "s.e."], rows))

    def to_dict(self) -> dict:
        """The result as JSON-ready builtins.

        Examples
        --------
        >>> MixtureProbabilities(np.array([0.5, 0.5]), np.array([0.01, 0.01]), 100).to_dict()
        {'probabilities': [0.5, 0.5], 'standard_errors': [0.01, 0.01], 'n_sequences': 100}
        """
        return builtin({"probabilities": self.probabilities,
                        "standard_errors": self.standard_errors,
                        "n_sequences": self.n_sequences})

    def to_json(self, path: str | os.PathLike | None = None) -> str:
        """:meth:`to_dict` as JSON text, also written to ``path`` if given."""
        return to_json(self.to_dict(), path)


def mixture_choice_probabilities(model: MDFTModel, n_steps: int, *, n_sequences: int = 20_000,
                                 rng: SeedLike = None) -> MixtureProbabilities:
    """Fixed-time choice probabilities from the exact mixture-of-normals law of ``P(T)``.

    Given the sequence of attended attributes, ``P(T)`` is exactly normal (the noise is
    Gaussian and enters linearly); the choice probabilities are therefore the average, over
    attention sequences, of normal orthant probabilities. This function samples the
    sequences and computes each orthant probability exactly (conditional Monte Carlo),
    with the first two moments of the attention sum as control variates. It is unbiased
    and removes the one approximation of :func:`choice_probabilities`; use it to check that
    approximation or where it matters (short deliberations, few attributes).

    Parameters
    ----------
    model : MDFTModel
        Two or three options and ``sigma2 > 0``.
    n_steps : int
        Deliberation time ``T``, at least 1.
    n_sequences : int, default 20000
        Attention sequences to sample, at least 100 and at most 10,000,000.
    rng : None, int or numpy.random.Generator
        Source of the attention sequences.

    Returns
    -------
    MixtureProbabilities

    Notes
    -----
    ``P(T) = S^T P0 + A + N`` with the attention sum ``A = sum_{k<T} S^k C M W(T-k)`` and
    the noise ``N ~ N(0, sigma2 sum_{k<T} S^k C C^T S^kT)``, independent of ``A``. The
    estimator averages ``Pr(L_i P(T) > 0 | A)`` over sampled ``A``; the control variates
    are the entries of ``A - E[A]`` and of ``(A - E[A])(A - E[A])^T - Cov(A)``, whose means
    are known exactly (:func:`preference_moments` with ``sigma2 = 0``).

    Examples
    --------
    >>> import mdft
    >>> from mdft.closed_form import mixture_choice_probabilities
    >>> model = mdft.MDFTModel([[1, 3], [3, 1], [0.9, 3.1]], [0.5, 0.5],
    ...                        phi1=0.022, phi2=0.05, beta=12.0)
    >>> res = mixture_choice_probabilities(model, 100, n_sequences=5000, rng=0)
    >>> bool(abs(res.probabilities.sum() - 1) < 1e-12), bool(res.standard_errors.max() < 2e-3)
    (True, True)
    """
    _check_model(model)
    n_steps = as_count("n_steps", n_steps, low=1, high=MAX_STEPS)
    n_sequences = as_count("n_sequences", n_sequences, low=100, high=10_000_000)
    n = model.n_options
    if n > 3:
        raise ValueError(
            f"mixture_choice_probabilities handles 2 or 3 options (got {n}); use "
            "choice_probabilities or mdft.simulate"
        )
    if not model.sigma2 > 0:
        raise ValueError(
            f"mixture_choice_probabilities needs sigma2 > 0 (got {model.sigma2}); with no "
            "noise P(T) is discrete: use mdft.simulate"
        )
    rng = np.random.default_rng(rng)
    S = np.asarray(model.S)
    C = np.asarray(model.C)
    CM = C @ np.asarray(model.M)
    w = np.asarray(model.w)
    with np.errstate(over="ignore", invalid="ignore"):
        base, noise = _moments(S, np.zeros(n), model.sigma2 * (C @ C.T), np.asarray(model.P0),
                               n_steps)
        att_mean, att_cov = _moments(S, CM @ w, CM @ (np.diag(w) - np.outer(w, w)) @ CM.T,
                                     np.zeros(n), n_steps)
    if not all(np.all(np.isfinite(x)) for x in (base, noise, att_mean, att_cov)):
        raise ValueError(
            f"n_steps={n_steps} is too long for this model: the moments of P(T) are not "
            "finite, preferences overflow"
        )
    warn_if_growing(model.spectral_radius, n_steps, stacklevel=2)
    # Attention sums of the sampled sequences: A(t+1) = S A(t) + C M e_{j(t+1)}.
    # Blocks of sequences keep the working set in cache (one block: the draws of one pass).
    A = np.empty((n_sequences, n))
    cum = np.cumsum(w)
    CMT = np.ascontiguousarray(CM.T)
    for lo in range(0, n_sequences, _MIXTURE_BLOCK):
        a = np.zeros((min(_MIXTURE_BLOCK, n_sequences - lo), n))
        for _ in range(n_steps):
            j = np.minimum(np.searchsorted(cum, rng.random(a.shape[0]), side="right"),
                           w.size - 1)
            a = a @ S.T + CMT[j]
        A[lo:lo + a.shape[0]] = a
    # Orthant probabilities of N(base + A, noise) for every sequence and option.
    f = _conditional_orthants(base + A, noise)
    # Control variates: first and second moments of A, known exactly.
    D = A - att_mean
    iu = np.triu_indices(n)
    Q = (D[:, :, None] * D[:, None, :])[:, iu[0], iu[1]] - att_cov[iu]
    X = np.hstack([D, Q])
    # A control variate that does not vary (one attribute, or an attribute direction the
    # model ignores) is rounding noise: regressing on it would amplify that noise.
    a_scale = max(float(np.abs(A).max()), 1.0)
    col_scale = np.concatenate([np.full(n, a_scale), np.full(Q.shape[1], a_scale**2)])
    X = X[:, X.std(axis=0) > 1e-9 * col_scale]
    Xbar = X.mean(axis=0)
    X = X - Xbar  # sample-centred: the regression estimator
    fc = f - f.mean(axis=0)
    coef, *_ = np.linalg.lstsq(X, fc, rcond=None)
    est = f.mean(axis=0) - Xbar @ coef
    resid = fc - X @ coef
    se = resid.std(axis=0, ddof=X.shape[1] + 1) / np.sqrt(n_sequences)
    est = np.clip(est, 0.0, 1.0)
    est = est / est.sum()
    est.flags.writeable = False
    se.flags.writeable = False
    return MixtureProbabilities(probabilities=est, standard_errors=se, n_sequences=n_sequences)


def _bivariate_orthant_many(m, c):
    """``Pr(Y1 > 0, Y2 > 0)`` for many means ``m`` (N, 2) and one regular covariance ``c``."""
    s1, s2 = np.sqrt(c[0, 0]), np.sqrt(c[1, 1])
    rho = float(np.clip(c[0, 1] / (s1 * s2), -1.0, 1.0))
    h, k = m[:, 0] / s1, m[:, 1] / s2
    if abs(rho) > 1.0 - 1e-12:
        return np.array([_orthant_bivariate(row, c) for row in m])
    p = bivariate_cdf(h, k, np.full(h.shape, rho))
    return np.clip(p, 0.0, 1.0)
