"""Monte Carlo simulation of MDFT: :func:`simulate`, and the simulation fallback's trials.

The dynamics (``docs/concepts.md``, Roe, Busemeyer & Townsend 2001) is

    P(t) = S P(t-1) + C (M W(t) + eps(t)),   P(0) = P0,

with ``W(t)`` the unit vector of the attribute attended at step ``t``
(attribute ``j`` with probability ``w[j]``) and ``eps(t) ~ N(0, sigma2 I)``.
A deliberation stops after a fixed number of steps (:class:`mdft.FixedTime`) or
as soon as a preference reaches a threshold (:class:`mdft.Threshold`), both in
:mod:`mdft.stopping`; the outcome is a :class:`mdft.SimulationResult`
(:mod:`mdft.simulation_result`). :func:`mdft.decide` (:mod:`mdft.decide`) is
the fast path of fixed-time choices for agents.

Randomness: every call resolves ``rng`` with :func:`numpy.random.default_rng`,
draws the states of a fixed number of independent streams from it (one per
chunk of trials, see ``docs/simulation.md``) and runs the chunks in parallel.
The result depends on the seed only, never on the number of threads.
"""

from __future__ import annotations

import math

import numpy as np

from . import _control_kernels, _kernels
from ._typing import SeedLike
from ._validation import MAX_SAMPLES, as_count, as_generator
from .model import MDFTModel, warn_if_growing
from .simulation_result import SimulationResult
from .stopping import FixedTime, Threshold

__all__ = ["simulate"]

#: Number of chunks (independent random streams) the trials are split into.
#: Fixed, so that the same seed gives the same result on any number of threads.
N_CHUNKS = 64

#: Below this many steps of work (trials x steps) the chunks run one after the
#: other in the calling thread: waking the thread pool would cost more than
#: it saves. The chunks and their streams are the same either way, and so is
#: the result.
_PARALLEL_WORK = 200_000

#: Largest attention table (n_steps * n_attributes * n_options doubles) the
#: fixed-time shortcut may build; past it the step-by-step kernel is used.
_MAX_TABLE_SIZE = 4_000_000

#: Budget (in doubles) of the table of block sums of the fixed-time shortcut:
#: 128 KiB keeps it in the level-2 cache, where a lookup per block is cheap.
_BLOCK_TABLE_BUDGET = 16_384

#: Most attention patterns per block (J ** block_size).
_MAX_PATTERNS = 256

#: Largest number of recorded trajectories.
MAX_TRAJECTORIES = 1000

#: Largest number of recorded preference values (n_trajectories x (steps + 1) x n_options).
_MAX_TRAJECTORY_VALUES = 20_000_000


# ---------------------------------------------------------------- simulate
def simulate(model: MDFTModel, n_samples: int, *, stopping: FixedTime | Threshold,
             rng: SeedLike = None, n_trajectories: int = 0) -> SimulationResult:
    """Simulate ``n_samples`` independent deliberations of an MDFT model.

    Parameters
    ----------
    model : MDFTModel
        The model (``M``, ``w``, ``S``, ``C``, ``sigma2``, ``P0``).
    n_samples : int
        Number of trials, at least 1 and at most 100,000,000 (``MAX_SAMPLES``).
    stopping : FixedTime or Threshold
        The stopping rule.
    rng : None, int, array_like or numpy.random.Generator, optional
        Source of randomness, resolved with :func:`numpy.random.default_rng`.
        The same seed gives bit-identical results whatever the number of numba
        threads.
    n_trajectories : int, default 0
        Record the preference trajectories of the first ``n_trajectories``
        trials (at most ``min(n_samples, 1000)``). They are simulated with the
        plain step-by-step dynamics and counted like every other trial.

    Returns
    -------
    SimulationResult

    Notes
    -----
    Each step draws the attended attribute (``w``), then the noise
    ``eps ~ N(0, sigma2 I)``, and updates ``P(t) = S P(t-1) + C (M W(t) + eps(t))``.
    For fixed time the kernel uses the exact decomposition

        P(T) = S^T P0 + sum_t S^(T-t) C M W(t) + xi,   xi ~ N(0, sigma2 sum_k S^k C C^T S^kT),

    the noise term being a single Gaussian vector per trial (an identity in
    distribution, not an approximation; ``docs/simulation.md``).
    Ties of the largest preference are broken uniformly at random.

    Examples
    --------
    The compromise effect: C = (2, 2) between A = (1, 3) and B = (3, 1).

    >>> import mdft
    >>> model = mdft.MDFTModel([[1, 3], [3, 1], [2, 2]], [0.5, 0.5],
    ...                        phi1=0.022, phi2=0.05, beta=12.0)
    >>> res = mdft.simulate(model, 20_000, stopping=mdft.FixedTime(100), rng=0)
    >>> bool(res.probabilities[2] > res.probabilities[0])
    True
    >>> round(float(res.probabilities.sum() + res.p_undecided), 6)
    1.0

    Threshold stopping reports response times and undecided trials:

    >>> res = mdft.simulate(model, 2_000, stopping=mdft.Threshold(17.5, max_steps=2_000),
    ...                     rng=0)
    >>> res.decision_steps.shape, res.n_undecided
    ((2000,), 0)
    >>> bool(res.mean_response_times[2] > res.mean_response_times[0])  # C takes longer
    True
    """
    if not isinstance(model, MDFTModel):
        raise TypeError(f"model must be an MDFTModel (got {type(model).__name__})")
    n_samples = as_count("n_samples", n_samples, high=MAX_SAMPLES)
    if not isinstance(stopping, (FixedTime, Threshold)):
        raise TypeError(
            "stopping must be mdft.FixedTime(n_steps) or mdft.Threshold(theta, max_steps) "
            f"(got {stopping!r})"
        )
    n_trajectories = as_count("n_trajectories", n_trajectories, low=0)
    limit = min(n_samples, MAX_TRAJECTORIES)
    if n_trajectories > limit:
        raise ValueError(
            f"n_trajectories must be <= min(n_samples, {MAX_TRAJECTORIES}) = {limit} "
            f"(got {n_trajectories}); trajectories are meant for plotting a few trials"
        )
    threshold = isinstance(stopping, Threshold)
    n_steps = stopping.max_steps if threshold else stopping.n_steps
    if n_trajectories * (n_steps + 1) * model.n_options > _MAX_TRAJECTORY_VALUES:
        raise ValueError(
            f"n_trajectories={n_trajectories} would record {n_trajectories} x {n_steps + 1} x "
            f"{model.n_options} preference values, more than {_MAX_TRAJECTORY_VALUES:,}; "
            "record fewer trajectories or lower the number of steps"
        )
    if threshold and np.max(model.P0) >= stopping.theta:
        raise ValueError(
            f"model.P0 must lie below the threshold theta={stopping.theta:g} "
            f"(got max P0 = {np.max(model.P0):g}); the deliberation would end before it starts"
        )
    generator = as_generator("rng", rng)
    states = _stream_states(generator, N_CHUNKS + 1)
    theta = stopping.theta if threshold else math.inf
    S = np.ascontiguousarray(model.S, dtype=np.float64)
    C = np.ascontiguousarray(model.C, dtype=np.float64)
    CM = np.ascontiguousarray(C @ model.M)
    P0 = np.ascontiguousarray(model.P0, dtype=np.float64)
    cuts = _attention_cuts(model.w)
    noise_sd = math.sqrt(model.sigma2)
    n = model.n_options

    # The recorded trials: the plain dynamics on their own stream.
    trajectories = trajectory_choices = None
    rec_choices = np.empty(n_trajectories, dtype=np.int64)
    rec_steps = np.empty(n_trajectories, dtype=np.int64)
    if n_trajectories:
        trajectories = np.full((n_trajectories, n_steps + 1, n), np.nan)
        with np.errstate(over="ignore"):
            _kernels.plain_recorded(states[N_CHUNKS], S, CM, C, noise_sd, cuts, P0, n_steps,
                                    theta, threshold, trajectories, rec_choices, rec_steps)
        if threshold:
            longest = int(np.where(rec_steps < 0, n_steps, rec_steps).max())
            trajectories = trajectories[:, : longest + 1].copy()
        trajectory_choices = _readonly(rec_choices.copy())
        trajectories = _readonly(trajectories)

    n_rest = n_samples - n_trajectories
    bounds = n_trajectories + (np.arange(N_CHUNKS + 1, dtype=np.int64) * n_rest) // N_CHUNKS
    chunk_states = states[:N_CHUNKS]
    counts = np.zeros(n, dtype=np.int64)
    if n_trajectories:
        counts += np.bincount(rec_choices[rec_choices >= 0], minlength=n)
    shortcut = None
    if not threshold:
        _check_growth(model.spectral_radius, n_steps)
        warn_if_growing(model.spectral_radius, n_steps, stacklevel=2)
        shortcut = _fixed_time_shortcut(S, CM, C, P0, model.sigma2, n_steps)
    if shortcut is not None:
        method = "shortcut"
        blocks, block_size, base, L = shortcut
        chunk_counts = np.zeros((N_CHUNKS, n), dtype=np.int64)
        args = (blocks, block_size, n_steps, base, L, cuts)
        with np.errstate(over="ignore"):
            if n_rest * n_steps >= _PARALLEL_WORK:
                _kernels.fixed_time_chunks(chunk_states, bounds, *args, chunk_counts)
            else:
                for c in _nonempty_chunks(bounds):
                    _kernels.fixed_time_chunk(chunk_states[c], bounds[c], bounds[c + 1], *args,
                                              chunk_counts[c])
        counts += chunk_counts.sum(axis=0)
        choices = steps = None
    else:
        method = "step-by-step"
        choices = np.empty(n_samples, dtype=np.int64)
        steps = np.empty(n_samples, dtype=np.int64)
        choices[:n_trajectories] = rec_choices
        steps[:n_trajectories] = rec_steps
        args = (S, CM, C, noise_sd, cuts, P0, n_steps, theta, threshold)
        _run_chunks(_kernels.plain_chunks, _kernels.plain_chunk, chunk_states, bounds, args,
                    choices, steps, n_rest * n_steps)
        counts += np.bincount(choices[n_trajectories:][choices[n_trajectories:] >= 0],
                              minlength=n)
        if not threshold:
            choices = steps = None

    n_undecided = int(n_samples - counts.sum())
    probabilities = counts / n_samples
    standard_errors = np.sqrt(probabilities * (1.0 - probabilities) / n_samples)
    mean_rt = None
    if threshold:
        decided = choices >= 0
        sums = np.bincount(choices[decided], weights=steps[decided], minlength=n)
        with np.errstate(invalid="ignore", divide="ignore"):
            mean_rt = np.where(counts > 0, sums / np.maximum(counts, 1), np.nan)
        choices, steps, mean_rt = _readonly(choices), _readonly(steps), _readonly(mean_rt)
    return SimulationResult(
        probabilities=_readonly(probabilities),
        counts=_readonly(counts),
        standard_errors=_readonly(standard_errors),
        n_samples=n_samples,
        n_undecided=n_undecided,
        p_undecided=n_undecided / n_samples,
        stopping=stopping,
        method=method,
        choices=choices,
        decision_steps=steps,
        mean_response_times=mean_rt,
        trajectories=trajectories,
        trajectory_choices=trajectory_choices,
    )


def _run_chunks(parallel, serial, states, bounds, args, choices, steps, work, per_chunk=()):
    """Run the trials ``bounds[0] <= k < bounds[-1]`` chunk by chunk (chunk ``c`` on the
    stream ``states[c]``), writing ``choices[k]`` and ``steps[k]`` (and into the arrays of
    ``per_chunk`` at index ``c``): in parallel where the ``work`` (trials times steps) pays
    for waking the thread pool, else one chunk after another in the calling thread; the same
    result either way."""
    with np.errstate(over="ignore"):
        if work >= _PARALLEL_WORK:
            parallel(states, bounds, *args, choices[bounds[0]:], steps[bounds[0]:],
                     *per_chunk)
        else:
            for c in _nonempty_chunks(bounds):
                lo, hi = bounds[c], bounds[c + 1]
                serial(states[c], lo, hi, *args, choices[lo:hi], steps[lo:hi],
                       *(out[c] for out in per_chunk))


def _reduced_args(model: MDFTModel, theta: float, max_steps: int):
    """The arguments of the two- and three-option fallback kernels
    (:func:`mdft._kernels.reduced_trial`): ``(S, CM, L, cuts, P0, max_steps, theta)``, or
    None where the model needs :func:`simulate`'s kernels (more than three options, or noise
    of rank above two)."""
    S = np.ascontiguousarray(model.S, dtype=np.float64)
    C = np.ascontiguousarray(model.C, dtype=np.float64)
    L = _noise_factor(S, C, model.sigma2, 1)
    if model.n_options > 3 or L.shape[1] > 2 or not np.isfinite(L).all():
        return None
    return (S, np.ascontiguousarray(C @ model.M), np.ascontiguousarray(L),
            _attention_cuts(model.w), np.ascontiguousarray(model.P0, dtype=np.float64),
            max_steps, float(theta))


def _chunk_layout(generator: np.random.Generator, n_samples: int):
    """The streams and chunk bounds of ``n_samples`` trials, and their empty choices and
    steps: ``(states, bounds, choices, steps)``."""
    states = _stream_states(generator, N_CHUNKS)
    bounds = (np.arange(N_CHUNKS + 1, dtype=np.int64) * n_samples) // N_CHUNKS
    return (states, bounds, np.empty(n_samples, dtype=np.int64),
            np.empty(n_samples, dtype=np.int64))


def _fallback_trials(model: MDFTModel, n_samples: int, theta: float, max_steps: int,
                     generator: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Choices and decision steps (``-1`` undecided) of ``n_samples`` trials of threshold
    stopping, for the simulation fallback of :func:`mdft.threshold_probabilities`, which
    has checked the model and ``theta``.

    With two or three options the noise ``C eps`` is drawn from its principal directions
    (:func:`mdft._kernels.reduced_trial`): one normal fewer per step with the contrast
    matrix, the same distribution as :func:`simulate`'s trials but not the same trials for
    the same stream. Other models run :func:`simulate`'s kernels. The trials are split into
    the same :data:`N_CHUNKS` streams, so a generator in the same state gives the same
    trials on any number of threads.
    """
    args = _reduced_args(model, theta, max_steps)
    if args is None:
        res = simulate(model, n_samples, stopping=Threshold(theta, max_steps=max_steps),
                       rng=generator)
        assert res.choices is not None and res.decision_steps is not None  # threshold stopping
        return res.choices, res.decision_steps
    states, bounds, choices, steps = _chunk_layout(generator, n_samples)
    _run_chunks(_kernels.reduced_chunks, _kernels.reduced_chunk, states, bounds, args,
                choices, steps, n_samples * max_steps)
    return choices, steps


def _controlled_trials(model: MDFTModel, n_samples: int, theta: float, max_steps: int,
                       generator: np.random.Generator, time_scale: float, rich: bool = True
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """:func:`_fallback_trials` with control variates (:mod:`mdft._control_kernels`):
    ``(choices, steps, grams)``, ``grams`` (2, size, size) the two folds' sums of ``v v^T``
    (:func:`mdft._control_kernels.gram_size`, made symmetric); None for the models
    :func:`_fallback_trials` hands to :func:`simulate` (more than three options, or noise of
    rank above two). Without ``rich`` only the monomials' sums are recorded (the others are
    zero).

    The position is measured from the start in units of ``theta``, and the step in units of
    ``time_scale``, so that the sums are of order one. (The monomials span the same functions
    from any origin; an origin far from the walks, such as the mean path's fixed point where
    ``S`` nearly keeps the preferences, only makes their fit ill-conditioned.)
    """
    control_args = _control_args(model, theta, max_steps, time_scale)
    if control_args is None:
        return None
    args, plane, opt = control_args
    states, bounds, choices, steps = _chunk_layout(generator, n_samples)
    size = _control_kernels.gram_size(model.n_options)
    grams = np.zeros((N_CHUNKS, 2, size, size))
    _run_chunks(_control_kernels.controlled_chunks, _control_kernels.controlled_chunk, states,
                bounds, (*args, plane, opt, bool(rich)), choices, steps, n_samples * max_steps,
                (grams,))
    return choices, steps, _control_kernels.symmetric(grams.sum(axis=0))


def _control_args(model: MDFTModel, theta: float, max_steps: int, time_scale: float):
    """The arguments of the controlled trials' kernels (:func:`_controlled_trials`):
    ``(args, plane, opt)``, ``args`` those of the plain trials (:func:`_reduced_args`),
    ``plane`` and ``opt`` as :func:`mdft._control_kernels.rich_trial` takes them; None where
    :func:`_reduced_args` is."""
    args = _reduced_args(model, theta, max_steps)
    if args is None:
        return None
    _, CM, L, _, P0, _, _ = args
    n = model.n_options
    w = np.asarray(model.w, dtype=np.float64)
    E = np.zeros((2, 3))
    if n == 3:
        E[0, :] = np.array([1.0, -1.0, 0.0]) / math.sqrt(2.0)
        E[1, :] = np.array([1.0, 1.0, -2.0]) / math.sqrt(6.0)
    else:
        E[0, :2] = np.array([1.0, -1.0]) / math.sqrt(2.0)
    plane = np.zeros((2, 7 + CM.shape[1]))
    plane[:, :n] = E[:, :n]
    plane[:, 3] = E[:, :n] @ P0
    plane[0, 4] = 1.0 / theta
    plane[1, 4] = 1.0 / max(time_scale, 1.0)
    plane[:, 5:5 + L.shape[1]] = E[:, :n] @ L
    plane[:, 7:] = E[:, :n] @ (CM - (CM @ w)[:, None])
    opt = np.zeros((3, 1 + CM.shape[1]))
    sd = np.sqrt(np.einsum("ij,ij->i", L, L))
    opt[:n, 0] = np.divide(1.0, sd, out=np.zeros(n), where=sd > 0)
    opt[:n, 1:] = CM - (CM @ w)[:, None]
    return args, plane, opt


# ---------------------------------------------------------------- helpers
def _stream_states(generator: np.random.Generator, n_streams: int) -> np.ndarray:
    """Draw the xoshiro256++ states of ``n_streams`` independent streams.

    Each state is 256 bits taken from the caller's generator; an all-zero
    state (the one state xoshiro cannot leave, probability 2**-256) is
    replaced by a fixed non-zero word.
    """
    states = generator.integers(0, 2**64, size=(n_streams, 4), dtype=np.uint64,
                                endpoint=False)
    if not states.any(axis=1).all():
        states[~states.any(axis=1), 0] = np.uint64(0x9E3779B97F4A7C15)
    return states


def _attention_cuts(w: np.ndarray) -> np.ndarray:
    """Integer attention thresholds ``cuts = ceil(cumw 2**53)`` (along the last axis).

    ``cumw`` is the cumulative sum of ``w`` with the entries from the last
    positive weight on set to exactly 1, so that a zero-weight attribute at
    the end is never attended, whatever the rounding of the sum. A 53-bit
    draw ``x`` (uniform ``u = x 2**-53``) attends the first ``j`` with
    ``u < cumw[j]``, i.e. with ``x < cuts[j]``. Works on one row
    (n_attributes,) or on rows (k, n_attributes).
    """
    w = np.asarray(w, dtype=np.float64)
    cumw = np.cumsum(w, axis=-1)
    if w[..., -1].min() > 0:
        cumw[..., -1] = 1.0
    else:
        J = w.shape[-1]
        last = J - 1 - np.argmax(w[..., ::-1] > 0, axis=-1)
        cumw[np.arange(J) >= np.expand_dims(last, -1)] = 1.0
    # cumw * 2**53 is exact (a power-of-two scaling) and at most 2**53.
    return np.ascontiguousarray(np.ceil(cumw * 2.0**53).astype(np.int64))


def _fixed_time_shortcut(S, CM, C, P0, sigma2, n_steps):
    """Precompute ``(blocks, block_size, base, L)`` of the fixed-time decomposition, or None.

    ``blocks`` holds the block sums of ``table[k, j] = S^k C M e_j``
    (:func:`mdft._kernels.block_table`), ``base = S^T P0`` and ``L`` (n, r)
    satisfies ``L L^T = sigma2 sum_{k<T} S^k C C^T S^kT``; with fewer than 4
    options the three are padded with zeros to width 4. Returns None when
    the table would be too large, or the summed noise covariance overflows while the
    preferences do not (then the step-by-step kernel runs instead); raises ``ValueError``
    when the components of ``P(T)`` overflow.
    """
    n, J = CM.shape
    if n_steps * J * n > _MAX_TABLE_SIZE:
        return None
    with np.errstate(over="ignore", invalid="ignore"):
        table = _kernels.attention_table(S, CM, n_steps)
        base = P0.copy()
        if np.any(P0 != 0):
            base = np.linalg.matrix_power(S, n_steps) @ P0
        L = _noise_factor(S, C, sigma2, n_steps)
    block_size = _block_size(n_steps, J, n)
    with np.errstate(over="ignore", invalid="ignore"):
        blocks = _kernels.block_table(table, block_size)
    if np.isfinite(blocks).all() and np.isfinite(base).all() and not np.isfinite(L).all():
        # the summed noise covariance grows like rho**(2 n_steps) and overflows before the
        # preferences do (like rho**n_steps): the step-by-step kernel runs instead
        return None
    if not (np.isfinite(blocks).all() and np.isfinite(base).all()):
        raise ValueError(
            f"preferences overflow over n_steps={n_steps} steps (the feedback matrix S has "
            f"spectral radius {np.max(np.abs(np.linalg.eigvals(S))):.6g}); lower n_steps or "
            "phi2, or raise phi1"
        )
    if n < 4:
        # Pad to width 4: the kernel then adds rows with straight-line code.
        padded = np.zeros(blocks.shape[:2] + (4,))
        padded[..., :n] = blocks
        padded_base = np.zeros(4)
        padded_base[:n] = base
        padded_L = np.zeros((4, L.shape[1]))
        padded_L[:n] = L
        blocks, base, L = padded, padded_base, padded_L
    return blocks, block_size, np.ascontiguousarray(base), np.ascontiguousarray(L)


def _check_growth(spectral_radius: float, n_steps: int) -> None:
    """Refuse a deliberation over which ``rho(S)^n_steps`` leaves floating point.

    With ``rho(S) > 1`` preferences grow like ``rho^t``; past about 1e300 they
    overflow and the choice ``argmax P(T)`` would be meaningless.
    """
    if spectral_radius > 1.0 and n_steps * math.log(spectral_radius) > 690.0:
        raise ValueError(
            f"preferences overflow over n_steps={n_steps} steps: the feedback matrix S has "
            f"spectral radius {spectral_radius:.6g} > 1, so they grow like "
            f"{spectral_radius:.6g}**{n_steps} "
            f"(about 1e{n_steps * math.log10(spectral_radius):.0f}); lower n_steps or phi2, "
            "or raise phi1"
        )



def _block_size(n_steps: int, n_attributes: int, n_options: int) -> int:
    """Steps per block of the attention lookup: the most whose table fits the budget.

    With one attribute the attention is not random and one block spans all steps.
    """
    if n_attributes == 1:
        return n_steps
    best = 1
    size = 2
    while size <= n_steps and n_attributes**size <= _MAX_PATTERNS:
        n_blocks = -(-n_steps // size)
        if n_blocks * n_attributes**size * n_options > _BLOCK_TABLE_BUDGET:
            break
        best = size
        size += 1
    return best


def _noise_factor(S, C, sigma2, n_steps):
    """``L`` (n, r) with ``L L^T = sigma2 sum_{k<n_steps} S^k C C^T (S^k)^T``.

    The sum is built by binary splitting, ``Sigma(a + m) = Sigma(a) + S^a
    Sigma(m) S^aT``, in O(log n_steps) matrix products; ``L`` keeps the
    eigenvectors whose eigenvalues exceed ``1e-13`` times the largest.
    """
    n = S.shape[0]
    if sigma2 == 0.0:
        return np.zeros((n, 0))
    total = np.zeros((n, n))
    S_prefix = np.eye(n)  # S^a for the steps already summed
    S_block = S.copy()  # S^m for the current block length m = 2^b
    sigma_block = C @ C.T  # Sigma(m)
    remaining = n_steps
    while remaining:
        if remaining & 1:
            total += S_prefix @ sigma_block @ S_prefix.T
            S_prefix = S_prefix @ S_block
        remaining >>= 1
        if remaining:
            sigma_block = sigma_block + S_block @ sigma_block @ S_block.T
            S_block = S_block @ S_block
    total = sigma2 * 0.5 * (total + total.T)
    if not np.isfinite(total).all():
        return np.full((n, 1), np.nan)
    eigenvalues, vectors = np.linalg.eigh(total)
    keep = eigenvalues > 1e-13 * max(eigenvalues.max(), 0.0)
    return np.ascontiguousarray(vectors[:, keep] * np.sqrt(eigenvalues[keep]))



def _nonempty_chunks(bounds: np.ndarray):
    """Indices of the chunks that hold at least one trial."""
    return np.flatnonzero(bounds[1:] > bounds[:-1])


def _readonly(a: np.ndarray) -> np.ndarray:
    a.flags.writeable = False
    return a
