"""The outcome of :func:`mdft.simulate`: :class:`SimulationResult`."""

from __future__ import annotations

import numbers
import os
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from ._repr import compact_repr
from ._export import builtin, describe_stopping, fmt, labels_for, stopping_dict, table, to_json
from .stopping import FixedTime, Threshold

__all__ = ["SimulationResult"]

#: Sentinel of ``choices`` and ``decision_steps`` for an undecided trial.
UNDECIDED = -1


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
        choices, steps, _ = self._threshold_trials("response_times")
        option = _option_index(option, self.n_options)
        return steps[choices == option]

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
        choices, steps, stopping = self._threshold_trials("response_time_pmf")
        decided = choices >= 0
        pmf = np.zeros((stopping.max_steps, self.n_options))
        np.add.at(pmf, (steps[decided] - 1, choices[decided]), 1.0)
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
        rts = self.mean_response_times
        with_rt = rts is not None
        header = ["option", "P(choose)", "s.e.", "count"] + (["mean RT"] if with_rt else [])
        rows = []
        for i, name in enumerate(names):
            row = [name, fmt(self.probabilities[i]), fmt(self.standard_errors[i]),
                   int(self.counts[i])]
            rows.append(row + ([fmt(rts[i], ".1f")] if rts is not None else []))
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

    def _threshold_trials(self, what: str) -> tuple[np.ndarray, np.ndarray, Threshold]:
        """``(choices, decision_steps, stopping)`` of a result of threshold stopping; for
        any other, a clear error naming ``what`` needs them."""
        if (not isinstance(self.stopping, Threshold) or self.choices is None
                or self.decision_steps is None):
            raise ValueError(
                f"{what} needs a result of threshold stopping (got stopping={self.stopping!r})"
            )
        return self.choices, self.decision_steps, self.stopping


def _option_index(option, n_options: int) -> int:
    if isinstance(option, bool) or not isinstance(option, (numbers.Integral, np.integer)):
        raise TypeError(f"option must be an integer (got {option!r})")
    if not 0 <= int(option) < n_options:
        raise ValueError(f"option must lie in [0, {n_options - 1}] (got {option})")
    return int(option)
