"""Orthant probabilities of a multivariate normal: which option has the largest preference.

``probabilities_from_moments(mean, cov)`` gives ``Pr(argmax P = i)`` for ``P ~ N(mean, cov)``
with ties split equally. Two and three options are exact (normal CDF, Owen's T); four or
more use Genz's separation of variables on scrambled Sobol points. Singular covariances
are handled exactly (classes of tied options, zero-variance comparisons, low-rank
factors). Used by :mod:`mdft.closed_form`; ``docs/closed_form.md`` describes the method.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from scipy import special

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


class _OrthantSumError(ValueError):
    """The orthant probabilities miss a sum of one by more than the method's error."""



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


def sov_orthants_many(m, L, u):
    """Unbiased estimates of ``Pr(m[s] + L z > 0)``, ``z ~ N(0, I)``, for many means.

    ``m`` (N, q) are the means, ``L`` (q, q) a lower-triangular factor with a positive
    diagonal, ``u`` (N, K, q - 1) independent uniforms on (0, 1): ``K`` randomised points
    of Genz's separation of variables per mean. Row ``k`` bounds ``z_k`` from below given
    the earlier ``z``; the estimate multiplies the probabilities of the bounds and draws
    each ``z_k`` from its truncated normal by inversion. Returns the (N,) mean over the
    points of each row, an unbiased estimate (its randomness averages out over rows).
    """
    q = L.shape[0]
    N, K = u.shape[0], u.shape[1]
    z = np.zeros((N, K, q))
    weight = np.ones((N, K))
    for k in range(q):
        bound = -(m[:, None, k] + z[..., :k] @ L[k, :k]) / L[k, k]
        tail = special.ndtr(-bound)  # Pr(z_k > bound)
        weight *= tail
        if k < q - 1:
            # Phi(-z_k) is uniform on (0, tail) when z_k is normal truncated to (bound, inf)
            z[..., k] = -special.ndtri(np.clip(tail * u[..., k], 1e-300, 1.0))
    return weight.mean(axis=1)
