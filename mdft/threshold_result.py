"""The result of :func:`mdft.threshold_probabilities`."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ._export import builtin

__all__ = ["ThresholdProbabilities", "ThresholdToleranceError"]


class ThresholdToleranceError(ValueError):
    """:func:`mdft.threshold_probabilities` could not meet ``atol`` and ``rt_rtol`` with the
    chain and was told not to simulate (``fallback="raise"``, or ``method="solve"``).

    A ``ValueError``, raised where the chain ran and refused: its error estimate (the grid's
    or the moment closure's term) stayed beyond the tolerances within ``max_states``. Looser
    tolerances may be met where these were not; the likelihood of :func:`mdft.fit` asks for
    them then (``docs/fitting.md``, "Where the exact engine cannot vouch"). A model that no
    chain can answer (more than three options, no noise, ...) raises a plain ``ValueError``.

    Examples
    --------
    >>> import mdft
    >>> model = mdft.MDFTModel([[1, 3], [3, 1], [2, 2]], [0.5, 0.5],
    ...                        phi1=0.022, phi2=0.05, beta=12.0)
    >>> try:
    ...     mdft.threshold_probabilities(model, 17.5, max_states=10, fallback="raise")
    ... except mdft.ThresholdToleranceError as exc:
    ...     print("refused:", "max_states=10" in str(exc))
    refused: True
    """


@dataclass(frozen=True)
class ThresholdProbabilities:
    """Choice and response-time distributions of threshold stopping.

    Attributes
    ----------
    probabilities : ndarray, shape (n_options,)
        Probability that option ``i`` is chosen within ``max_steps`` steps
        (``method="solve"``: ever).
    p_undecided : float
        Probability that no option has been chosen after ``max_steps`` steps,
        so ``probabilities.sum() + p_undecided`` is 1 up to the mass a chain
        leaves out as negligible and its tail's extrapolation (at most 5.3e-9
        on 158 random three-option models), far inside
        ``error_probabilities`` (0 for ``method="solve"``, which has no step
        limit).
    rt_pmf : ndarray, shape (max_steps, n_options), or None
        ``rt_pmf[t, i]``: probability of choosing option ``i`` at step
        ``t + 1``. None for ``method="solve"``.
    mean_response_times : ndarray, shape (n_options,)
        Mean decision step given that option ``i`` is chosen (within
        ``max_steps`` for ``"propagate"``); NaN for an option never chosen,
        or chosen so rarely (probabilities near the rounding of the chain)
        that its mean comes out below one step.
    theta : float
        The threshold.
    max_steps : int or None
        The step limit (None for ``method="solve"``).
    n_cells : int
        Cells per ``theta`` along the finest grid axis.
    spacing : float
        Finest cell size in preference units.
    n_levels : int
        Two options: levels of the summed preference ``1^T P`` that hold
        states (1 when the feedback keeps the sum at its initial value).
        Three options: 1 (the chain carries the sum as moments).
    n_states : int
        Number of transient states of the chain.
    method : str
        ``"propagate"``, ``"solve"``, ``"simulation"`` (the fallback) or
        ``"bound"`` (no option can be chosen within ``max_steps`` steps but
        with a probability that the tolerances neglect).
    n_iter : int
        Steps propagated, iterations of the linear solver (0 for a direct
        solve), or trials simulated by the fallback.
    converged : bool
        ``"propagate"``: True. ``"solve"``: whether the iterative solver met
        ``tol``.
    tail_start : int or None
        First row of ``rt_pmf`` filled in geometrically (see ``tail_tol``),
        or None when every step was propagated.
    engine : str
        ``"lattice"`` (two options), ``"plane"`` (three options),
        ``"simulation"`` (the chain refused and ``fallback="simulation"``
        answered; ``n_states`` is then 0) or ``"bound"`` (every trial ends
        undecided but for at most ``error_probabilities``; no chain built).
    resolution : float
        Two options: the lattice spacing in per-step standard deviations of
        the preference difference; three options: the cell size in per-step
        standard deviations along each grid axis (``kappa`` in the docs).
    error_probabilities : float
        Estimated error of ``probabilities`` and ``p_undecided``: the largest
        change against the same computation at a coarser resolution (the
        simulation fallback: three standard errors; ``"bound"``: the bound on
        the probability of deciding at all).
    error_mean_rt : float
        Estimated relative error of ``mean_response_times``, measured the
        same way; options chosen with probability ``p < 0.01`` weigh in with
        ``p / 0.01``.
    """

    probabilities: np.ndarray
    p_undecided: float
    rt_pmf: np.ndarray | None
    mean_response_times: np.ndarray
    theta: float
    max_steps: int | None
    n_cells: int
    spacing: float
    n_levels: int
    n_states: int
    method: str
    n_iter: int
    converged: bool
    tail_start: int | None = None
    engine: str = "lattice"
    resolution: float = math.nan
    error_probabilities: float = math.nan
    error_mean_rt: float = math.nan

    def __repr__(self):
        p = np.array2string(np.asarray(self.probabilities), precision=4, separator=", ")
        rt = np.array2string(np.asarray(self.mean_response_times), precision=1, separator=", ")
        return (f"ThresholdProbabilities(probabilities={p}, p_undecided={self.p_undecided:.3g}, "
                f"mean_response_times={rt}, theta={self.theta:g}, engine={self.engine!r}, "
                f"error_probabilities={self.error_probabilities:.2g}, "
                f"error_mean_rt={self.error_mean_rt:.2g})")

    def summary(self) -> str:
        """A small text table: each option's probability and mean response time, and the errors.

        Examples
        --------
        >>> import mdft
        >>> model = mdft.MDFTModel([[1, 3], [3, 1]], [0.5, 0.5],
        ...                        phi1=0.022, phi2=0.05, beta=12.0)
        >>> print(mdft.threshold_probabilities(model, 10.0).summary())  # doctest: +ELLIPSIS
        Threshold stopping, theta = 10 (lattice, ... states)
        option  probability  mean RT (steps)
             0       0.5000             27.6
             1       0.5000             27.6
        undecided   0.0000
        estimated error: probabilities ..., mean RT ... %
        """
        size = {"simulation": f"{self.n_iter} trials",
                "bound": f"no decision within {self.max_steps} steps"}.get(
                    self.engine, f"{self.n_states} states")
        lines = [f"Threshold stopping, theta = {self.theta:g} ({self.engine}, {size})",
                 f"{'option':>6}  {'probability':>11}  {'mean RT (steps)':>15}"]
        for i, (p, rt) in enumerate(zip(self.probabilities, self.mean_response_times)):
            lines.append(f"{i:>6}  {p:>11.4f}  {rt:>15.1f}")
        lines.append(f"{'undecided':<9} {self.p_undecided:>8.4f}")
        lines.append(f"estimated error: probabilities {self.error_probabilities:.1e}, "
                     f"mean RT {100 * self.error_mean_rt:.2f} %")
        return "\n".join(lines)

    def to_dict(self) -> dict:
        """The result as JSON-serialisable builtins (``rt_pmf`` as nested lists, NaN as None).

        Examples
        --------
        >>> import json, mdft
        >>> model = mdft.MDFTModel([[1, 3], [3, 1]], [0.5, 0.5],
        ...                        phi1=0.022, phi2=0.05, beta=12.0)
        >>> d = mdft.threshold_probabilities(model, 5.0, max_steps=200).to_dict()
        >>> sorted(d)[:4]
        ['converged', 'engine', 'error_mean_rt', 'error_probabilities']
        >>> len(json.dumps(d)) > 0
        True
        """
        names = ("probabilities", "p_undecided", "rt_pmf", "mean_response_times", "theta",
                 "max_steps", "n_cells", "spacing", "n_levels", "n_states", "method", "n_iter",
                 "converged", "tail_start", "engine", "resolution", "error_probabilities",
                 "error_mean_rt")
        return {name: builtin(getattr(self, name)) for name in names}

