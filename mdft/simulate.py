"""Monte Carlo simulation of MDFT: stopping rules, :func:`simulate` and :func:`decide`.

The dynamics (``docs/concepts.md``, Roe, Busemeyer & Townsend 2001) is

    P(t) = S P(t-1) + C (M W(t) + eps(t)),   P(0) = P0,

with ``W(t)`` the unit vector of the attribute attended at step ``t``
(attribute ``j`` with probability ``w[j]``) and ``eps(t) ~ N(0, sigma2 I)``.
A deliberation stops after a fixed number of steps (:class:`FixedTime`) or as
soon as a preference reaches a threshold (:class:`Threshold`).

Randomness: every call resolves ``rng`` with :func:`numpy.random.default_rng`,
draws the states of a fixed number of independent streams from it (one per
chunk of trials, see ``docs/simulation.md``) and runs the chunks in parallel.
The result depends on the seed only, never on the number of threads.
"""

from __future__ import annotations

import math
import numbers
import os
from typing import Sequence
from dataclasses import dataclass

import numpy as np

from . import _control_kernels, _kernels
from ._typing import ArrayLike, SeedLike
from ._validation import (MAX_OPTIONS, MAX_SAMPLES, MAX_STEPS, MAX_THETA, as_count,
                          as_float_array, as_generator, as_scalar)
from .model import MDFTModel, warn_if_growing
from ._repr import compact_repr
from ._export import builtin, describe_stopping, fmt, labels_for, stopping_dict, table, to_json

__all__ = ["FixedTime", "Threshold", "SimulationResult", "simulate", "decide"]

#: Number of chunks (independent random streams) the trials are split into.
#: Fixed, so that the same seed gives the same result on any number of threads.
N_CHUNKS = 64

#: Largest number of decisions per chunk in :func:`decide`.
_DECISIONS_PER_CHUNK = 256

#: Below this many steps of work (trials x steps) the chunks run one after the
#: other in the calling thread: waking the thread pool would cost more than
#: it saves. The chunks and their streams are the same either way, and so is
#: the result.
_PARALLEL_WORK = 200_000

#: The same for :func:`decide`, whose steps cost far more (the feedback product and the
#: noise of every option at each step): a few hundred microseconds of work already pay
#: for waking the pool.
_PARALLEL_DECISION_WORK = 10_000

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

#: Sentinel of ``choices`` and ``decision_steps`` for an undecided trial.
UNDECIDED = -1


# ---------------------------------------------------------------- stopping rules
@dataclass(frozen=True)
class FixedTime:
    """Stop after a fixed number of deliberation steps and choose ``argmax P(n_steps)``.

    Parameters
    ----------
    n_steps : int
        Deliberation time ``T``, at least 1 and at most 10,000,000 (``MAX_STEPS``).

    Examples
    --------
    >>> FixedTime(100)
    FixedTime(n_steps=100)
    """

    n_steps: int

    def __post_init__(self):
        object.__setattr__(self, "n_steps", as_count("n_steps", self.n_steps, high=MAX_STEPS))


@dataclass(frozen=True)
class Threshold:
    """Stop as soon as some preference reaches ``theta``; give up after ``max_steps``.

    Parameters
    ----------
    theta : float
        Preference threshold, > 0 and at most 1e300 (``MAX_THETA``: the preference that
        first passes it is still finite, so the choice is made among numbers).
    max_steps : int, default 10_000
        Longest deliberation, at most 10,000,000 (``MAX_STEPS``). A trial that has not reached the threshold after
        ``max_steps`` steps is *undecided*: it is counted in
        ``SimulationResult.n_undecided``, never dropped.

    Notes
    -----
    The trial stops at the first step ``t >= 1`` with ``max_i P_i(t) >= theta``
    and chooses the option with the largest preference at that step (when
    several options cross in the same step, the one furthest past the
    threshold); exact ties are broken uniformly at random.

    Examples
    --------
    >>> Threshold(17.5)
    Threshold(theta=17.5, max_steps=10000)
    """

    theta: float
    max_steps: int = 10_000

    def __post_init__(self):
        object.__setattr__(self, "theta", as_scalar("theta", self.theta, low=0.0,
                                                    low_inclusive=False, high=MAX_THETA))
        object.__setattr__(self, "max_steps", as_count("max_steps", self.max_steps,
                                                       high=MAX_STEPS))


# ---------------------------------------------------------------- result
@dataclass(frozen=True)
class SimulationResult:
    """Outcome of :func:`simulate`.

    Attributes
    ----------
    probabilities : ndarray, shape (n_options,)
        ``counts / n_samples``. With undecided trials these sum to
        ``1 - p_undecided``.
    counts : ndarray of int, shape (n_options,)
        Number of trials that chose each option.
    standard_errors : ndarray, shape (n_options,)
        Binomial standard errors ``sqrt(p (1 - p) / n_samples)``.
    n_samples : int
        Number of simulated trials.
    n_undecided : int
        Trials that had not decided after ``max_steps`` (always 0 for
        :class:`FixedTime`).
    p_undecided : float
        ``n_undecided / n_samples``.
    stopping : FixedTime or Threshold
        The stopping rule used.
    method : str
        ``"shortcut"`` (fixed time, exact linear decomposition of ``P(T)``) or
        ``"step-by-step"``.
    choices : ndarray of int, shape (n_samples,), or None
        Threshold stopping only: the option chosen in each trial, ``-1`` for
        an undecided trial.
    decision_steps : ndarray of int, shape (n_samples,), or None
        Threshold stopping only: the step ``1 <= t <= max_steps`` at which each
        trial decided (its response time), ``-1`` for an undecided trial.
    mean_response_times : ndarray, shape (n_options,), or None
        Threshold stopping only: mean decision step of the trials that chose
        each option (NaN for an option never chosen).
    trajectories : ndarray, shape (n_trajectories, n_recorded + 1, n_options), or None
        Preferences ``P(0), P(1), ...`` of the first ``n_trajectories`` trials.
        For fixed time ``n_recorded = n_steps``; for threshold stopping it is the
        longest of the recorded deliberations, and the rows after a trial's
        decision are NaN.
    trajectory_choices : ndarray of int, shape (n_trajectories,), or None
        The options chosen in the recorded trials (``-1``: undecided).

    Examples
    --------
    >>> import mdft
    >>> model = mdft.MDFTModel([[1, 3], [3, 1]], [0.5, 0.5],
    ...                        phi1=0.022, phi2=0.05, beta=12.0)
    >>> res = mdft.simulate(model, 1000, stopping=mdft.Threshold(30.0, max_steps=50),
    ...                     rng=0, n_trajectories=2)
    >>> int(res.counts.sum() + res.n_undecided)
    1000
    >>> res.trajectories.shape[0], res.trajectories.shape[2]
    (2, 2)
    """

    __repr__ = compact_repr

    probabilities: np.ndarray
    counts: np.ndarray
    standard_errors: np.ndarray
    n_samples: int
    n_undecided: int
    p_undecided: float
    stopping: FixedTime | Threshold
    method: str
    choices: np.ndarray | None = None
    decision_steps: np.ndarray | None = None
    mean_response_times: np.ndarray | None = None
    trajectories: np.ndarray | None = None
    trajectory_choices: np.ndarray | None = None

    @property
    def n_options(self) -> int:
        """Number of options of the simulated model."""
        return self.counts.shape[0]

    def response_times(self, option: int) -> np.ndarray:
        """Decision steps of the trials that chose ``option`` (threshold stopping).

        Examples
        --------
        >>> import mdft
        >>> model = mdft.MDFTModel([[1, 3], [3, 1]], [0.5, 0.5],
        ...                        phi1=0.022, phi2=0.05, beta=12.0)
        >>> res = mdft.simulate(model, 200, stopping=mdft.Threshold(5.0), rng=0)
        >>> bool(res.response_times(0).min() >= 1)
        True
        """
        self._need_threshold("response_times")
        option = _option_index(option, self.n_options)
        return self.decision_steps[self.choices == option]

    def response_time_pmf(self) -> np.ndarray:
        """Empirical ``pmf[t, i]``: fraction of trials that chose option ``i`` at step ``t + 1``.

        Shape (max_steps, n_options); the entries sum to ``1 - p_undecided``.

        Examples
        --------
        >>> import mdft
        >>> model = mdft.MDFTModel([[1, 3], [3, 1]], [0.5, 0.5],
        ...                        phi1=0.022, phi2=0.05, beta=12.0)
        >>> res = mdft.simulate(model, 200, stopping=mdft.Threshold(5.0, max_steps=500),
        ...                     rng=0)
        >>> pmf = res.response_time_pmf()
        >>> pmf.shape
        (500, 2)
        >>> bool(abs(pmf.sum(axis=0) - res.probabilities).max() < 1e-12)
        True
        """
        self._need_threshold("response_time_pmf")
        decided = self.choices >= 0
        pmf = np.zeros((self.stopping.max_steps, self.n_options))
        np.add.at(pmf, (self.decision_steps[decided] - 1, self.choices[decided]), 1.0)
        return pmf / self.n_samples

    def summary(self, labels: Sequence[str] | None = None) -> str:
        """A text table: each option's share, standard error, count (and mean response time).

        Parameters
        ----------
        labels : sequence of str, optional
            One name per option; ``0, 1, ...`` by default.

        Examples
        --------
        >>> import mdft
        >>> model = mdft.MDFTModel([[1, 3], [3, 1]], [0.5, 0.5],
        ...                        phi1=0.022, phi2=0.05, beta=12.0)
        >>> res = mdft.simulate(model, 1000, stopping=mdft.FixedTime(50), rng=0)
        >>> print(res.summary(labels=["A", "B"]))  # doctest: +NORMALIZE_WHITESPACE
        1,000 trials, fixed time, 50 steps (shortcut)
        option     P(choose)    s.e.  count
        A             0.5250  0.0158    525
        B             0.4750  0.0158    475
        undecided     0.0000              0
        """
        names = labels_for(labels, self.n_options)
        with_rt = self.mean_response_times is not None
        header = ["option", "P(choose)", "s.e.", "count"] + (["mean RT"] if with_rt else [])
        rows = []
        for i, name in enumerate(names):
            row = [name, fmt(self.probabilities[i]), fmt(self.standard_errors[i]),
                   int(self.counts[i])]
            rows.append(row + ([fmt(self.mean_response_times[i], ".1f")] if with_rt else []))
        rows.append(["undecided", fmt(self.p_undecided), "", self.n_undecided]
                    + ([""] if with_rt else []))
        title = f"{self.n_samples:,} trials, {describe_stopping(self.stopping)} ({self.method})"
        return title + "\n" + table(header, rows)

    def to_dict(self, *, trials: bool = False) -> dict:
        """The result as JSON-ready builtins (NaN, e.g. the mean response time of an option
        never chosen, becomes None).

        Parameters
        ----------
        trials : bool, default False
            Also export the per-trial arrays (``choices``, ``decision_steps``) and the
            recorded trajectories, which can be large.

        Examples
        --------
        >>> import mdft
        >>> model = mdft.MDFTModel([[1, 3], [3, 1]], [0.5, 0.5],
        ...                        phi1=0.022, phi2=0.05, beta=12.0)
        >>> d = mdft.simulate(model, 100, stopping=mdft.FixedTime(10), rng=0).to_dict()
        >>> d["stopping"], d["counts"], d["n_undecided"]
        ({'rule': 'fixed_time', 'n_steps': 10}, [45, 55], 0)
        """
        out = {
            "n_options": self.n_options, "n_samples": self.n_samples,
            "stopping": stopping_dict(self.stopping), "method": self.method,
            "probabilities": self.probabilities, "standard_errors": self.standard_errors,
            "counts": self.counts, "n_undecided": self.n_undecided,
            "p_undecided": self.p_undecided, "mean_response_times": self.mean_response_times,
        }
        if trials:
            out.update(choices=self.choices, decision_steps=self.decision_steps,
                       trajectories=self.trajectories,
                       trajectory_choices=self.trajectory_choices)
        return builtin(out)

    def to_json(self, path: str | os.PathLike | None = None, *, trials: bool = False) -> str:
        """:meth:`to_dict` as JSON text, also written to ``path`` if given."""
        return to_json(self.to_dict(trials=trials), path)

    def _need_threshold(self, what: str) -> None:
        if not isinstance(self.stopping, Threshold):
            raise ValueError(
                f"{what} needs a result of threshold stopping (got stopping={self.stopping!r})"
            )


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
                       generator: np.random.Generator, time_scale: float
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """:func:`_fallback_trials` with control variates (:mod:`mdft._control_kernels`):
    ``(choices, steps, grams)``, ``grams`` (2, size, size) the two folds' sums of ``v v^T``
    (:func:`mdft._control_kernels.gram_size`, made symmetric); None for the models
    :func:`_fallback_trials` hands to :func:`simulate` (more than three options, or noise of
    rank above two).

    The position is measured from the start in units of ``theta``, and the step in units of
    ``time_scale``, so that the sums are of order one. (The monomials span the same functions
    from any origin; an origin far from the walks, such as the mean path's fixed point where
    ``S`` nearly keeps the preferences, only makes their fit ill-conditioned.)
    """
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
    states, bounds, choices, steps = _chunk_layout(generator, n_samples)
    size = _control_kernels.gram_size(n)
    grams = np.zeros((N_CHUNKS, 2, size, size))
    _run_chunks(_control_kernels.controlled_chunks, _control_kernels.controlled_chunk, states,
                bounds, (*args, plane), choices, steps, n_samples * max_steps, (grams,))
    upper = grams.sum(axis=0)
    lower = np.transpose(np.triu(upper, 1), (0, 2, 1))
    return choices, steps, upper + lower


# ---------------------------------------------------------------- decide
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


def _nonempty_chunks(bounds: np.ndarray):
    """Indices of the chunks that hold at least one trial."""
    return np.flatnonzero(bounds[1:] > bounds[:-1])


def _option_index(option, n_options: int) -> int:
    if isinstance(option, bool) or not isinstance(option, (numbers.Integral, np.integer)):
        raise TypeError(f"option must be an integer (got {option!r})")
    if not 0 <= int(option) < n_options:
        raise ValueError(f"option must lie in [0, {n_options - 1}] (got {option})")
    return int(option)


def _readonly(a: np.ndarray) -> np.ndarray:
    a.flags.writeable = False
    return a
