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
from typing import Sequence

import numpy as np
from scipy import special

from ._typing import SeedLike
from ._export import builtin, fmt, labels_for, table, to_json
from ._repr import compact_repr
from ._orthant import (_TIE_RTOL, _OrthantSumError, _ordered_cholesky, _orthant_bivariate,
                       _probabilities_from_moments, sov_orthants_many)
from ._edgeworth import (attention_cumulants, bivariate_cdf, error_estimate, geometric_sums,
                         lattice_terms, lumpiness)
from ._validation import MAX_STEPS, as_count, as_generator, as_scalar
from .model import MDFTModel, UnstableFeedbackWarning, warn_if_growing

__all__ = [
    "ClosedFormAccuracyWarning",
    "MixtureProbabilities",
    "choice_probabilities",
    "mixture_choice_probabilities",
    "preference_moments",
]

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
# Control variates of the mixture: rows needed per column, the relative singular value
# below which a direction is left out, and the largest adjustment (in plain standard errors)
# that is believed.
_CV_ROWS_PER_COLUMN = 20
_CV_RCOND = 1e-6
_CV_MAX_SHIFT = 5.0
#: Four or more options: randomised separation-of-variables points per attention sequence,
#: and the smallest pivot of a comparison covariance's factor, relative to its largest
#: standard deviation, that counts as regular.
_SOV_POINTS = 4
_SOV_REGULAR = 1e-7


class ClosedFormAccuracyWarning(RuntimeWarning):
    """No longer emitted; kept so that code which filters it keeps working.

    Closed-form probabilities that do not sum to one within the method's tolerance now
    raise a ``ValueError`` (or, with ``method="auto"``, fall back to an exact method).
    """



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
        and no exact method applies at an affordable cost (``sigma2 = 0`` with a
        deliberation too long to enumerate, or an exact mixture that would need more than
        its work limit). With either method, if
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
    falls back to the exact mixture (:func:`mixture_choice_probabilities`,
    ``sigma2 > 0``) with a fixed seed and enough sequences for three standard
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


def _conditional_orthants(means, noise, rng=None):
    """``Pr(choose i | mean)`` for ``N(mean, noise)``, many means (N, n).

    Two or three options: exact (normal CDF, bivariate normal). Four or more: unbiased
    estimates from :data:`_SOV_POINTS` randomised points of Genz's separation of variables
    per mean, drawn from ``rng``, with the comparisons ordered at the average mean.
    """
    n = means.shape[1]
    f = np.empty(means.shape)
    singular = False
    with np.errstate(divide="ignore", invalid="ignore"):  # checked just below
        for i in range(n):
            L = -np.eye(n)[np.arange(n) != i]
            L[:, i] = 1.0
            mm = means @ L.T
            cc = L @ noise @ L.T
            if n == 2:
                f[:, i] = special.ndtr(mm[:, 0] / np.sqrt(cc[0, 0]))
            elif n == 3:
                f[:, i] = _bivariate_orthant_many(mm, cc)
            else:
                perm, chol = _ordered_cholesky(mm.mean(axis=0), cc)
                diag = np.diag(chol)
                if not diag.min() > _SOV_REGULAR * np.sqrt(np.abs(np.diag(cc)).max()):
                    singular = True
                    break
                u = rng.random((means.shape[0], _SOV_POINTS, n - 2))
                f[:, i] = sov_orthants_many(mm[:, perm], chol, u)
    if singular or not np.all(np.isfinite(f)):
        scale = float(np.abs(np.diag(noise)).max())
        raise ValueError(
            "the exact mixture cannot vouch for this model: the noise covariance of P(T) is "
            f"numerically singular (variances up to {scale:.3g}, their differences lost to "
            "rounding), as when the feedback S grows preferences over many steps; shorten "
            "n_steps or use mdft.simulate"
        )
    return f


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
    sequences and computes each orthant probability exactly for two or three options, or
    estimates it without bias for four or more (conditional Monte Carlo), with the first
    two moments of the attention sum as control variates. It is unbiased
    and removes the one approximation of :func:`choice_probabilities`; use it to check that
    approximation or where it matters (short deliberations, few attributes).

    Parameters
    ----------
    model : MDFTModel
        Any number of options, ``sigma2 > 0``.
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
    are known exactly (:func:`preference_moments` with ``sigma2 = 0``). With four or more
    options each orthant probability is itself estimated, without bias, from a few
    randomised points of Genz's separation of variables (Genz 1992) per sequence; the
    standard errors include that randomness.

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
    if not model.sigma2 > 0:
        raise ValueError(
            f"mixture_choice_probabilities needs sigma2 > 0 (got {model.sigma2}); with no "
            "noise P(T) is discrete: use mdft.simulate"
        )
    rng = as_generator("rng", rng)
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
    f = _conditional_orthants(base + A, noise, rng)
    # Control variates: first and second moments of A, known exactly.
    D = A - att_mean
    iu = np.triu_indices(n)
    Q = (D[:, :, None] * D[:, None, :])[:, iu[0], iu[1]] - att_cov[iu]
    X = np.hstack([D, Q])
    # A control variate that does not vary (one attribute, or an attribute direction the
    # model ignores) is rounding noise: regressing on it would amplify that noise.
    a_scale = max(float(np.abs(A).max()), 1.0)
    col_scale = np.concatenate([np.full(n, a_scale), np.full(Q.shape[1], a_scale**2)])
    sd = X.std(axis=0)
    keep = sd > 1e-9 * col_scale
    est, se = _control_variate_mean(f, X[:, keep] / sd[keep])
    est = np.clip(est, 0.0, 1.0)
    est = est / est.sum()
    est.flags.writeable = False
    se.flags.writeable = False
    return MixtureProbabilities(probabilities=est, standard_errors=se, n_sequences=n_sequences)


def _control_variate_mean(f, X):
    """Mean of ``f`` (N, n) and its standard errors, with control variates ``X`` (N, p).

    The columns of ``X`` have known mean zero and unit spread. The regression estimator
    needs many more rows than columns, and nearly collinear columns (an attribute the
    attention never picks, few distinct sequences) would let rounding noise into huge
    coefficients: directions below ``_CV_RCOND`` of the largest singular value are left
    out, and an adjustment larger than ``_CV_MAX_SHIFT`` plain standard errors (which a
    sound regression does not make) falls back to the plain mean.
    """
    N = f.shape[0]
    plain = f.mean(axis=0)
    plain_se = f.std(axis=0, ddof=1) / np.sqrt(N)
    if X.shape[1] == 0 or N < _CV_ROWS_PER_COLUMN * X.shape[1]:
        return plain, plain_se
    Xbar = X.mean(axis=0)
    Xc = X - Xbar  # sample-centred: the regression estimator
    fc = f - plain
    coef, _, rank, _ = np.linalg.lstsq(Xc, fc, rcond=_CV_RCOND)
    est = plain - Xbar @ coef
    if np.any(np.abs(est - plain) > _CV_MAX_SHIFT * plain_se + 1e-15):
        return plain, plain_se
    resid = fc - Xc @ coef
    se = resid.std(axis=0, ddof=rank + 1) / np.sqrt(N)
    return est, se


def _bivariate_orthant_many(m, c):
    """``Pr(Y1 > 0, Y2 > 0)`` for many means ``m`` (N, 2) and one regular covariance ``c``."""
    s1, s2 = np.sqrt(c[0, 0]), np.sqrt(c[1, 1])
    rho = float(np.clip(c[0, 1] / (s1 * s2), -1.0, 1.0))
    h, k = m[:, 0] / s1, m[:, 1] / s2
    if abs(rho) > 1.0 - 1e-12:
        return np.array([_orthant_bivariate(row, c) for row in m])
    p = bivariate_cdf(h, k, np.full(h.shape, rho))
    return np.clip(p, 0.0, 1.0)
