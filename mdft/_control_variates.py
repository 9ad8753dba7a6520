"""Control-variate estimates of the simulation fallback (:mod:`mdft._threshold_fallback`).

Each trial of :func:`mdft.simulate._controlled_trials` records, besides its choice and
decision step, ``K`` control sums ``x`` of expectation zero (:mod:`mdft._control_kernels`).
The quantities the fallback estimates are means of per-trial targets ``y``: the indicators of
each option and of ending undecided, and each option's indicator times the decision step.
For a matrix ``B``, ``mean(y - B^T x)`` estimates ``E y`` without bias whatever ``B`` is, and
its variance is least for the regression coefficients of ``y`` on ``x``. The sums move with
the walk's position and its decision, so this removes much of the trials' variance.

The coefficients are estimated, so that fitting and applying them on the same trials would
bias the answer by a term of order ``K / n``. Instead the trials are split into two folds (even
and odd trials); each fold's coefficients apply to the other fold
(cross-fitting), which keeps every estimate unbiased, and the variance of the answer is that of
the applied residuals.

Everything is computed from each fold's sums of ``v v^T``, ``v = (1, x, y)``, which the
kernels accumulate, so that the trials' control sums need not be kept.
"""

from __future__ import annotations

import numpy as np

#: Regressors whose standardised Gram matrix has eigenvalues below this many times its
#: largest are left out of the fit (a control that is zero or a combination of others).
RCOND = 1e-10


class ControlledSums:
    """Running sums of ``v v^T`` over two folds of trials, for ``n_options`` options and
    ``n_controls`` controls.

    The targets ``y`` are, in order: the indicators of the options, the indicator of ending
    undecided, and each option's indicator times the decision step.
    """

    def __init__(self, n_options: int, n_controls: int):
        self.n_options = n_options
        self.n_controls = n_controls
        self.n_targets = 2 * n_options + 1
        size = 1 + n_controls + self.n_targets
        self.gram = np.zeros((2, size, size))

    def add(self, grams: np.ndarray) -> None:
        """Add the two folds' sums of a run of trials
        (:func:`mdft.simulate._controlled_trials`); sums with more controls than these
        (trials that recorded every control, added to the monomials') add their first
        ones."""
        size = self.gram.shape[-1]
        if grams.shape[-1] > size:
            grams = restricted(grams, self.n_controls, self.n_targets)
        self.gram += grams

    def restricted(self, n_controls: int) -> "ControlledSums":
        """The same sums with the first ``n_controls`` controls only."""
        out = ControlledSums(self.n_options, n_controls)
        out.gram = restricted(self.gram, n_controls, self.n_targets)
        return out

    def estimate(self) -> tuple[np.ndarray, np.ndarray]:
        """``(means, cov)``: the cross-fitted estimates of the targets' expectations and
        their covariance (that of the estimates, not of one trial)."""
        K = self.n_controls
        x = slice(1, 1 + K)
        y = slice(1 + K, None)
        moments = []
        for g in self.gram:
            count = g[0, 0]
            mean = g[0] / count
            cov = g / count - np.outer(mean, mean)
            moments.append((count, mean, cov))
        total = sum(m[0] for m in moments)
        means = 0.0
        cov_means = 0.0
        for fold in (0, 1):
            count, mean, cov = moments[fold]
            B = _coefficients(moments[1 - fold][2], x, y)
            means = means + count / total * (mean[y] - B.T @ mean[x])
            residual = (cov[y, y] - B.T @ cov[x, y] - cov[y, x] @ B + B.T @ cov[x, x] @ B)
            cov_means = cov_means + count / total**2 * residual * count / (count - 1)
        return np.asarray(means), np.asarray(cov_means)


def restricted(grams: np.ndarray, n_controls: int, n_targets: int) -> np.ndarray:
    """Sums of ``v v^T`` (the last two axes) with only the first ``n_controls`` controls of
    ``v = (1, controls, targets)`` and the last ``n_targets`` entries (the targets) kept:
    the sums of the same trials with fewer controls."""
    size = grams.shape[-1]
    keep = np.r_[0:1 + n_controls, size - n_targets:size]
    return grams[..., keep[:, None], keep]


def _coefficients(cov: np.ndarray, x: slice, y: slice) -> np.ndarray:
    """Least-squares coefficients of the targets on the controls from their covariance,
    on standardised controls, leaving out directions without variance (:data:`RCOND`)."""
    sxx = cov[x, x]
    sxy = cov[x, y]
    scale = np.sqrt(np.maximum(np.diag(sxx), 0.0))
    live = scale > 0
    B = np.zeros(sxy.shape)
    if not live.any():
        return B
    s = scale[live]
    corr = sxx[np.ix_(live, live)] / np.outer(s, s)
    values, vectors = np.linalg.eigh(corr)
    keep = values > RCOND * values.max()
    inverse = (vectors[:, keep] / values[keep]) @ vectors[:, keep].T
    B[live] = (inverse @ (sxy[live] / s[:, None])) / s[:, None]
    return B
