"""Fast fixed-time MDFT choices for agents: :func:`decide` builds the model inside the kernel."""

from __future__ import annotations

import math

import numpy as np

from . import _kernels
from ._typing import ArrayLike, SeedLike
from ._validation import MAX_OPTIONS, MAX_STEPS, as_count, as_float_array, as_generator, as_scalar
from .simulate import (N_CHUNKS, _attention_cuts, _check_growth, _nonempty_chunks,
                       _stream_states)

__all__ = ["decide"]

#: Largest number of decisions per chunk in :func:`decide`.
_DECISIONS_PER_CHUNK = 256

#: Below this many steps of work (decisions x steps) the chunks run one after the other in
#: the calling thread. A step of :func:`decide` costs far more than one of
#: :func:`mdft.simulate` (the feedback product and the noise of every option), so a few
#: hundred microseconds of work already pay for waking the pool.
_PARALLEL_DECISION_WORK = 10_000


def decide(M: ArrayLike, w: ArrayLike, *, phi1: float, phi2: float, beta: float,
           sigma2: float = 1.0, n_steps: int, rng: SeedLike = None) -> int | np.ndarray:
    """One fixed-time MDFT deliberation per decision, the model built inside the kernel.

    The fast path for agents that choose among options at every step: no
    :class:`MDFTModel` is built; the Hotaling distance, the feedback matrix
    ``S`` and the standard contrast are computed from each ``M`` inside the
    compiled kernel, ``P(0) = 0``, and one trial of ``n_steps`` steps decides.

    Parameters
    ----------
    M : array_like, shape (n_options, n_attributes) or (n_decisions, n_options, n_attributes)
        Evaluations of one decision, or of a batch of decisions.
    w : array_like, shape (n_attributes,) or (n_decisions, n_attributes)
        Attention weights, shared by the batch or one row per decision;
        non-negative, each row summing to one.
    phi1, phi2, beta : float
        Parameters of the feedback matrix ``S = I - phi2 exp(-phi1 D**2)`` and
        of Hotaling's distance ``D`` (``docs/concepts.md``), all >= 0.
    sigma2 : float, default 1.0
        Variance of the valence noise, >= 0.
    n_steps : int
        Deliberation time, at least 1 and at most 10,000,000.
    rng : None, int, array_like or numpy.random.Generator, optional
        Resolved with :func:`numpy.random.default_rng`. A batch is split into
        chunks whose number depends on ``n_decisions`` only, so the result does
        not depend on the number of threads.

    Returns
    -------
    int or ndarray of int, shape (n_decisions,)
        The chosen option(s).

    Notes
    -----
    Equivalent in distribution to ``simulate(MDFTModel(M, w, ...), 1,
    stopping=FixedTime(n_steps))`` for each decision, without building the
    model. Like :func:`simulate`, it refuses a deliberation over which the
    preferences would overflow (spectral radius ``rho(S) > 1`` with
    ``n_steps * log(rho(S)) > 690``); the check computes ``rho(S)`` only for
    batches whose Gershgorin bound ``|1 - phi2| + phi2 (n_options - 1)``
    allows such growth.

    Examples
    --------
    >>> import mdft
    >>> M = [[0.9, 0.1], [0.1, 0.9], [0.5, 0.5]]
    >>> choice = mdft.decide(M, [0.5, 0.5], phi1=0.01, phi2=0.01, beta=2.0,
    ...                      n_steps=100, rng=0)
    >>> choice
    0
    >>> mdft.decide([M, M], [0.5, 0.5], phi1=0.01, phi2=0.01, beta=2.0,
    ...             n_steps=100, rng=0).shape
    (2,)
    """
    Marr = as_float_array("M", M)
    if Marr.ndim not in (2, 3):
        raise ValueError(
            "M must have shape (n_options, n_attributes) or (n_decisions, n_options, "
            f"n_attributes) (got shape {Marr.shape})"
        )
    single = Marr.ndim == 2
    batch = np.ascontiguousarray(Marr[None] if single else Marr)
    n_decisions, n_options, n_attributes = batch.shape
    if n_decisions < 1:
        raise ValueError(f"M must hold at least one decision (got shape {Marr.shape})")
    if n_options < 2:
        raise ValueError(
            f"M must have at least 2 options (got shape {Marr.shape}); MDFT compares options"
        )
    if n_options > MAX_OPTIONS:
        raise ValueError(f"M must have at most {MAX_OPTIONS:,} options (got shape {Marr.shape})")
    if n_attributes < 1:
        raise ValueError(f"M must have at least 1 attribute (got shape {Marr.shape})")
    if not np.isfinite(batch).all():
        raise ValueError("M must contain only finite values (got NaN or infinity in M)")
    w_rows = _batch_attention(w, n_decisions, n_attributes)
    phi1 = as_scalar("phi1", phi1, low=0.0)
    phi2 = as_scalar("phi2", phi2, low=0.0)
    beta = as_scalar("beta", beta, low=0.0)
    sigma2 = as_scalar("sigma2", sigma2, low=0.0)
    n_steps = as_count("n_steps", n_steps, high=MAX_STEPS)
    spread = float(batch.max() - batch.min())
    if spread > 1e70 or max(beta, 1.0) * n_attributes * spread**2 > 1e150:
        raise ValueError(
            f"M and beta={beta:g} give distances between options too large for floating point "
            f"(M spans {spread:.3g}); rescale M or lower beta"
        )
    _check_batch_growth(batch, phi1, phi2, beta, n_steps)
    generator = as_generator("rng", rng)
    n_chunks = -(-n_decisions // _DECISIONS_PER_CHUNK)
    n_chunks = min(N_CHUNKS, max(n_chunks, 2 if n_decisions > 1 else 1))
    states = _stream_states(generator, n_chunks)
    bounds = (np.arange(n_chunks + 1, dtype=np.int64) * n_decisions) // n_chunks
    cuts = _attention_cuts(w_rows)
    out = np.empty(n_decisions, dtype=np.int64)
    args = (batch, cuts, phi1, phi2, beta, math.sqrt(sigma2), n_steps)
    with np.errstate(over="ignore"):
        if n_decisions * n_steps >= _PARALLEL_DECISION_WORK:
            _kernels.decide_chunks(states, bounds, *args, out)
        else:
            for c in _nonempty_chunks(bounds):
                _kernels.decide_chunk(states[c], bounds[c], bounds[c + 1], *args, out)
    if np.any(out < 0):
        raise ValueError(
            f"preferences overflow over n_steps={n_steps} steps in {int(np.sum(out < 0))} of "
            f"{n_decisions} decisions (they are not finite, so argmax P(T) means nothing); "
            "lower n_steps or phi2, raise phi1, or rescale M"
        )
    return int(out[0]) if single else out


def _check_batch_growth(batch, phi1, phi2, beta, n_steps):
    """:func:`_check_growth` for the largest spectral radius of a batch of decisions.

    Every row of ``S = I - phi2 exp(-phi1 D**2)`` has absolute sum at most
    ``|1 - phi2| + phi2 (n - 1)`` (Gershgorin), so the eigenvalues are computed only when
    that bound allows overflow; ``S`` is symmetric, hence ``eigvalsh``.
    """
    n_options, n_attributes = batch.shape[1:]
    bound = abs(1.0 - phi2) + phi2 * (n_options - 1)
    if bound <= 1.0 or n_steps * math.log(bound) <= 690.0:
        return
    worst = 0.0
    for lo in range(0, batch.shape[0], 4096):
        M = batch[lo:lo + 4096]
        diff = M[:, :, None, :] - M[:, None, :, :]
        D = (diff**2).sum(axis=3) + (beta - 1.0) * diff.sum(axis=3) ** 2 / n_attributes
        S = np.eye(n_options) - phi2 * np.exp(-phi1 * D**2)
        worst = max(worst, float(np.abs(np.linalg.eigvalsh(S)).max()))
    _check_growth(worst, n_steps)


def _batch_attention(w, n_decisions: int, n_attributes: int) -> np.ndarray:
    """Validate ``w`` of :func:`decide`, vectorised: rows (n, n_attributes) summing to one."""
    arr = as_float_array("w", w)
    if arr.ndim == 1:
        arr = arr[None]
        shape_ok = arr.shape[1] == n_attributes
    else:
        shape_ok = arr.ndim == 2 and arr.shape == (n_decisions, n_attributes)
    if not shape_ok:
        raise ValueError(
            f"w must have shape ({n_attributes},) or ({n_decisions}, {n_attributes}) to match "
            f"M (got shape {np.shape(w)})"
        )
    if arr.min() < 0:
        bad = arr[(arr < 0).any(axis=1)][0]
        raise ValueError(f"w must be non-negative (got {bad.tolist()})")
    totals = arr.sum(axis=1)
    if np.abs(totals - 1.0).max() > 1e-6:
        off = np.abs(totals - 1.0) > 1e-6
        raise ValueError(
            f"w must sum to 1 (got {totals[off][0]:.6g}); pass normalised attention weights"
        )
    return arr / totals[:, None]
