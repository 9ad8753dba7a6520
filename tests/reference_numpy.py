"""A slow, obviously correct NumPy implementation of the MDFT dynamics, for tests.

One trial is simulated exactly as the equations read (``docs/concepts.md``):

    P(0) = P0,   P(t) = S P(t-1) + C (M W(t) + eps(t)),

where ``W(t)`` is the unit vector of the attended attribute (attribute ``j``
with probability ``w[j]``) and ``eps(t) ~ N(0, sigma2 I)``.

Random draws, in this order at every step:

1. the attended attribute: one ``rng.random()`` uniform ``u``, attribute ``j``
   the first with ``u < cumsum(w)[j]`` (no draw when there is one attribute);
2. the noise: ``rng.standard_normal(n_options)`` (no draw when ``sigma2 == 0``).

A tie for the largest preference is broken with one more ``rng.random()``
uniform ``u``: among the ``k`` tied options (in increasing index order) the one
at position ``floor(u * k)`` wins. ``rng`` is a ``numpy.random.Generator`` or
any object with the same ``random()`` and ``standard_normal(size)`` methods.

Every function takes a model-like object with the attributes ``M``, ``w``,
``S``, ``C``, ``sigma2`` and ``P0`` (an :class:`mdft.MDFTModel` will do).
"""

from __future__ import annotations

import numpy as np

UNDECIDED = -1


def attended_attribute(w, u):
    """Index of the attribute attended for the uniform draw ``u`` in [0, 1)."""
    cumw = np.cumsum(w)
    return int(np.searchsorted(cumw[:-1], u, side="right"))


def choose_largest(P, rng):
    """Index of the largest entry of ``P``, exact ties broken uniformly at random."""
    tied = np.flatnonzero(P == P.max())
    if tied.size == 1:
        return int(tied[0])
    return int(tied[int(rng.random() * tied.size)])


def step(model, P, rng):
    """One step of the dynamics: return ``P(t)`` from ``P = P(t-1)``."""
    n_options, n_attributes = model.M.shape
    j = 0 if n_attributes == 1 else attended_attribute(model.w, rng.random())
    if model.sigma2 > 0:
        eps = np.sqrt(model.sigma2) * rng.standard_normal(n_options)
    else:
        eps = np.zeros(n_options)
    return model.S @ P + model.C @ (model.M[:, j] + eps)


def fixed_time_trial(model, n_steps, rng):
    """One fixed-time trial.

    Returns
    -------
    choice : int
        ``argmax P(n_steps)`` (ties at random).
    trajectory : ndarray, shape (n_steps + 1, n_options)
        ``P(0), ..., P(n_steps)``.
    """
    P = np.array(model.P0, dtype=float)
    trajectory = [P]
    for _ in range(n_steps):
        P = step(model, P, rng)
        trajectory.append(P)
    return choose_largest(P, rng), np.array(trajectory)


def threshold_trial(model, theta, max_steps, rng):
    """One trial stopped by the threshold ``theta``.

    The trial stops at the first step ``t`` where some preference is
    ``>= theta`` and chooses the largest preference at that step.

    Returns
    -------
    choice : int
        The chosen option, or ``UNDECIDED`` (-1) after ``max_steps`` steps.
    step : int
        The decision step ``t`` (1-based), or ``UNDECIDED``.
    trajectory : ndarray, shape (step + 1, n_options)
        ``P(0), ..., P(step)`` (``max_steps + 1`` rows for an undecided trial).
    """
    P = np.array(model.P0, dtype=float)
    trajectory = [P]
    for t in range(1, max_steps + 1):
        P = step(model, P, rng)
        trajectory.append(P)
        if P.max() >= theta:
            return choose_largest(P, rng), t, np.array(trajectory)
    return UNDECIDED, UNDECIDED, np.array(trajectory)


def simulate_fixed_time(model, n_samples, n_steps, rng):
    """Choices of ``n_samples`` independent fixed-time trials, shape (n_samples,)."""
    return np.array([fixed_time_trial(model, n_steps, rng)[0] for _ in range(n_samples)])


def simulate_threshold(model, n_samples, theta, max_steps, rng):
    """Choices and decision steps of ``n_samples`` threshold trials (``-1``: undecided)."""
    out = [threshold_trial(model, theta, max_steps, rng)[:2] for _ in range(n_samples)]
    choices, steps = np.array(out, dtype=np.int64).reshape(n_samples, 2).T
    return choices, steps


def choice_frequencies(choices, n_options):
    """Fraction of trials choosing each option (undecided trials, ``-1``, excluded)."""
    choices = np.asarray(choices)
    return np.bincount(choices[choices >= 0], minlength=n_options) / choices.size
