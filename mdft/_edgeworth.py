"""Error estimate of the normal approximation of ``P(T)`` from the higher cumulants.

Conditionally on the attention sequence ``P(T)`` is normal; unconditionally it is the sum
of the Gaussian noise and the attention sum ``A = sum_{k<T} S^k C M (W(T-k) - w)`` (plus
its mean). Cumulants of a sum of independent terms add and the Gaussian part has none
beyond the second, so the third and fourth cumulant tensors of ``P(T)`` are exact sums
over the steps of those of one attention draw, mapped by ``S^k``:

    kappa_r(P(T)) = sum_{k<T} S^k . kappa_r(C M (W - w))      (r = 3, 4)

built by the same doubling as the mean and covariance (``O(log T)`` products).

For an option ``i`` with comparison vector ``Y = L_i P(T)`` and ``G(m) = Pr(m + Z > 0)``
(``Z`` normal with the covariance of ``Y``), the Edgeworth expansion of
``Pr(Y > 0) = E[1{m + (Y - m) > 0}]`` reads

    Pr(Y > 0) = G + K3.D^3 G / 6 + K4.D^4 G / 24 + (K3 (x) K3).D^6 G / 72 + ...

(``D`` the gradient with respect to ``m``, ``K3``, ``K4`` the cumulant tensors of ``Y``).
The three correction terms are computed exactly for one comparison (two options:
Hermite polynomials) and by finite differences of the exact bivariate normal orthant
(Owen's T) along a few directions for two comparisons (three options). Their absolute
values, summed, are the error estimate. For three or more comparisons the terms are
bounded instead: with ``h`` the Edgeworth density factor and ``p`` the normal
probability of the orthant, Cauchy-Schwarz gives ``|correction| <= sqrt(min(p, 1 - p))
||h||_2``, and ``||h||_2`` follows from the whitened cumulant tensors (a Hermite
polynomial of order ``r`` contracted with a tensor ``K`` has ``E[(K.H_r)^2] = r! |K|^2``).
"""

from __future__ import annotations

from functools import lru_cache
from math import comb

import numpy as np
from scipy import special

#: Step (in standard deviations of each comparison) of the finite differences.
_FD_STEP = 0.15
#: Correlation beyond which a pair of comparisons counts as singular.
_RHO_MAX = 1.0 - 1e-9


def _multilinear(A, K):
    """``K`` with the matrix ``A`` applied to every index (``K`` a symmetric tensor)."""
    order = K.ndim
    perm = (order - 1,) + tuple(range(order - 1))
    for _ in range(order):
        # map the last index and move it to the front: after `order` passes every index
        # has been mapped once and the order is restored
        K = (K @ A.T).transpose(perm)
    return K


def step_cumulants(CM, w):
    """Third and fourth cumulant tensors of one attention valence ``C M (W - w)``."""
    c = CM.T - CM @ w  # (J, n): centred valence of each attended attribute
    k2 = np.einsum("j,ja,jb->ab", w, c, c)
    k3 = np.einsum("j,ja,jb,jc->abc", w, c, c, c)
    m4 = np.einsum("j,ja,jb,jc,jd->abcd", w, c, c, c, c)
    k4 = (m4 - np.einsum("ab,cd->abcd", k2, k2) - np.einsum("ac,bd->abcd", k2, k2)
          - np.einsum("ad,bc->abcd", k2, k2))
    return k3, k4


def geometric_sums(S, terms, n_steps):
    """``(S^T, [sum_{k<T} S^k . K for K in terms])`` by repeated doubling.

    ``S^k . K`` applies ``S^k`` to every index of the symmetric tensor ``K`` (a vector:
    ``S^k K``; a matrix: ``S^k K S^kT``). A block of ``t`` steps joins one of ``t2`` steps
    after it as ``(A1 A2, K1 + A1 . K2)``: ``O(log T)`` products, no inverse of ``I - S``.
    """
    base = (S.copy(), list(terms))
    acc = None
    t = n_steps
    while t:
        if t & 1:
            if acc is None:
                acc = base
            else:
                A1, k1 = acc
                A2, k2 = base
                acc = (A1 @ A2, [a + _multilinear(A1, b) for a, b in zip(k1, k2)])
        t >>= 1
        if t:
            A, k = base
            base = (A @ A, [c + _multilinear(A, c) for c in k])
    return acc


def attention_cumulants(S, CM, w, n_steps):
    """``(kappa_3, kappa_4)`` of the attention sum over ``n_steps`` steps."""
    return tuple(geometric_sums(S, step_cumulants(CM, w), n_steps)[1])


def lumpiness(cov, CM, w):
    """How far the last attention draw alone moves a comparison, in standard deviations.

    ``P(T)`` is the mixture, over the attribute attended at the last step, of the law of
    everything else shifted by ``C M e_j``. Where those shifts are large against the spread
    of the rest, the mixture has separate modes and no short Edgeworth expansion describes
    it. Returns the largest shift between two attended attributes along a pairwise
    difference ``P_a - P_b``, divided by the standard deviation of the rest along it.
    """
    keep = w > 0
    c = CM[:, keep]
    wk = w[keep]
    rest = cov - c @ (np.diag(wk) - np.outer(wk, wk)) @ c.T
    n = cov.shape[0]
    a, b = np.triu_indices(n, 1)
    var = rest[a, a] + rest[b, b] - 2.0 * rest[a, b]
    shift = c[a] - c[b]  # (pairs, J)
    spread = shift.max(axis=1) - shift.min(axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        d = np.where(spread > 0, spread / np.sqrt(np.clip(var, 0.0, None)), 0.0)
    return float(np.nan_to_num(d, nan=np.inf).max()) if d.size else 0.0


def lattice_terms(mean, cov, noise_cov, CM, w):
    """Per-option size of the lattice (continuity) error the Edgeworth terms miss.

    With weak decay the attention sum moves on a lattice whose span along a comparison
    ``l`` is at most ``h = max_j l.C M e_j - min_j l.C M e_j``; the normal approximation of
    a lattice variable errs by up to ``h / (2 sd) phi(x)`` (Esseen's continuity term), and
    noise of standard deviation ``s`` along ``l`` damps that by ``exp(-2 pi^2 s^2 / h^2)``
    (the first Fourier coefficient of the sawtooth). Summed over an option's comparisons;
    conservative where decay breaks the lattice.
    """
    n = mean.size
    keep = w > 0
    c = CM[:, keep]
    out = np.zeros(n)
    for i in range(n):
        L = _comparison(n, i)
        proj = L @ c
        h = proj.max(axis=1) - proj.min(axis=1)
        sd = np.sqrt(np.clip(np.einsum("ij,jk,ik->i", L, cov, L), 0.0, None))
        sn2 = np.clip(np.einsum("ij,jk,ik->i", L, noise_cov, L), 0.0, None)
        ok = (h > 0) & (sd > 0)
        if not ok.any():
            continue
        x = (L @ mean)[ok] / sd[ok]
        damp = np.exp(-2.0 * np.pi**2 * sn2[ok] / h[ok] ** 2)
        phi = np.exp(-0.5 * x * x) / np.sqrt(2.0 * np.pi)
        out[i] = float(np.sum(h[ok] / (2.0 * sd[ok]) * phi * damp))
    return out


def _comparison(n, i):
    L = -np.eye(n)[np.arange(n) != i]
    L[:, i] = 1.0
    return L


def _hermite(r, x):
    """Probabilists' Hermite polynomial ``He_r(x)``."""
    return special.eval_hermitenorm(r, x)


def _terms_1d(x, k3, k4):
    """Edgeworth terms of ``Pr(x + e > 0)``, standardised ``e`` with cumulants ``k3``, ``k4``.

    ``G(x) = Phi(x)`` has ``G^(r) = (-1)^(r-1) He_{r-1}(x) phi(x)``.
    """
    phi = np.exp(-0.5 * x * x) / np.sqrt(2.0 * np.pi)
    t3 = k3 / 6.0 * _hermite(2, x) * phi
    t4 = -k4 / 24.0 * _hermite(3, x) * phi
    t33 = -k3 * k3 / 72.0 * _hermite(5, x) * phi
    return np.array([t3, t4, t33])


def _stencil(r):
    """Finite-difference plan for ``K . D^r G`` in two dimensions.

    Any homogeneous operator ``sum_a p[a] d1^a d2^(r-a)`` is a combination of ``r + 1``
    directional derivatives ``(u_k . D)^r`` (angles ``pi k / (r + 1)``); each of those is
    the central difference ``sum_j (-1)^j C(r, j) G(x + (r/2 - j) h u_k) / h^r``.
    Returns the matrix turning ``p`` into direction weights, the point offsets (one row
    per direction and difference point) and the difference weights.
    """
    theta = np.pi * np.arange(r + 1) / (r + 1)
    a = np.arange(r + 1)[:, None]
    binom = np.array([comb(r, k) for k in range(r + 1)], dtype=float)
    V = binom[:, None] * np.cos(theta)[None, :] ** a * np.sin(theta)[None, :] ** (r - a)
    u = np.stack([np.cos(theta), np.sin(theta)], axis=1)
    offs = (r / 2.0 - np.arange(r + 1)) * _FD_STEP
    points = (u[:, None, :] * offs[None, :, None]).reshape(-1, 2)
    diff = np.array([(-1) ** j * comb(r, j) for j in range(r + 1)], dtype=float) / _FD_STEP**r
    return np.linalg.inv(V), points, diff


_ORDERS = (3, 4, 6)
_STENCILS = [_stencil(r) for r in _ORDERS]
_OFFSETS = np.concatenate([s[1] for s in _STENCILS])
_SPLITS = np.cumsum([s[1].shape[0] for s in _STENCILS])[:-1]
#: Edgeworth coefficients of the K3, K4 and K3 (x) K3 terms.
_COEF = np.array([1.0 / 6.0, 1.0 / 24.0, 1.0 / 72.0])


def _operator(K):
    """Coefficients ``p[a]`` of ``K . D^r`` as a polynomial in ``(d1, d2)``: ``d1^a d2^(r-a)``."""
    r = K.ndim
    return np.array([comb(r, a) * K[(0,) * a + (1,) * (r - a)] for a in range(r + 1)])


def bivariate_cdf(h, k, rho):
    """``Pr(Z1 < h, Z2 < k)`` for standard bivariate normals with correlation ``rho``.

    Owen's T function; ``h``, ``k``, ``rho`` arrays of one shape, ``|rho| < 1``.
    """
    root = np.sqrt(1.0 - rho * rho)
    with np.errstate(divide="ignore", invalid="ignore"):
        a_h = np.where(h != 0.0, (k - rho * h) / (h * root), np.copysign(np.inf, k - rho * h))
        a_k = np.where(k != 0.0, (h - rho * k) / (k * root), np.copysign(np.inf, h - rho * k))
    corr = np.where((h * k > 0.0) | ((h * k == 0.0) & (h + k >= 0.0)), 0.0, 0.5)
    p = (0.5 * (special.ndtr(h) + special.ndtr(k)) - special.owens_t(h, a_h)
         - special.owens_t(k, a_k) - corr)
    both0 = (h == 0.0) & (k == 0.0)
    return np.where(both0, 0.25 + np.arcsin(rho) / (2.0 * np.pi), p)


def _terms_2d(x, rho, k3, k4):
    """Edgeworth terms of ``Pr(x + e > 0)`` for two standardised comparisons.

    ``x`` (m, 2) standardised means, ``rho`` (m,) correlations, ``k3``, ``k4`` (m, ...)
    standardised cumulant tensors of ``m`` options; returns (m, 3).
    """
    pts = x[:, None, :] + _OFFSETS[None, :, :]
    G = bivariate_cdf(pts[..., 0], pts[..., 1], np.broadcast_to(rho[:, None], pts.shape[:2]))
    out = np.empty((x.shape[0], 3))
    for i in range(x.shape[0]):
        p3 = _operator(k3[i])
        ops = (p3, _operator(k4[i]), np.convolve(p3, p3))
        for t, (Vinv, _, diff), g, p in zip(range(3), _STENCILS, np.split(G[i], _SPLITS), ops):
            r = p.size - 1
            out[i, t] = (Vinv @ p) @ (g.reshape(r + 1, r + 1) @ diff)
    return out * _COEF


def _bound_norm(L, cov, k3, k4, var_tol):
    """``||h||_2`` of the Edgeworth factor of ``L P`` over the support of its covariance."""
    lam, U = np.linalg.eigh(L @ cov @ L.T)
    keep = lam > var_tol
    if not keep.any():
        return 0.0
    Wi = (U[:, keep] / np.sqrt(lam[keep])).T @ L  # whitened comparisons on the support
    n3 = float(np.sum(_multilinear(Wi, k3) ** 2))
    n4 = float(np.sum(_multilinear(Wi, k4) ** 2))
    # E[(K.H_r)^2] = r! |K|^2 and |sym(K3 (x) K3)| <= |K3|^2
    return np.sqrt(n3 / 6.0) + np.sqrt(n4 / 24.0) + np.sqrt(720.0) * n3 / 72.0


#: Scrambled Sobol sets of the quasi-Monte Carlo Edgeworth terms (four or more options).
_QMC_SHIFTS = 8
_QMC_POINTS = 1024
_QMC_SEED = 70_001


@lru_cache(maxsize=32)
def _normal_points(dim):
    from scipy.stats import qmc

    pts = np.empty((_QMC_SHIFTS, _QMC_POINTS, dim))
    for s in range(_QMC_SHIFTS):
        u = qmc.Sobol(d=dim, scramble=True, rng=np.random.default_rng(_QMC_SEED + s)).random(
            _QMC_POINTS)
        pts[s] = special.ndtri(np.clip(u, 1e-12, 1.0 - 1e-12))
    pts.flags.writeable = False
    return pts


def _edgeworth_factor(z, k3, k4):
    """``h(z)``: the Edgeworth density factor minus one, whitened coordinates ``z`` (N, r).

    ``K3.H3 / 6 + K4.H4 / 24 + (K3 (x) K3).H6 / 72`` with the Hermite tensors contracted
    in closed form; the last by the product rule of Wick powers,
    ``(K3.H3)^2 = (K3 (x) K3).H6 + 9 Q.H4 + 18 R.H2 + 6 |K3|^2`` with
    ``Q_abde = K_abx K_dex`` and ``R_ad = K_axy K_dxy``.
    """
    r = z.shape[1]
    zz = (z[:, :, None] * z[:, None, :]).reshape(-1, r * r)
    u = zz @ k3.reshape(r * r, r)  # u_x = K3(z, z, e_x)
    Mz = z @ k3.reshape(r, r * r)  # M_ax = K3(z, e_a, e_x), flattened
    v = np.einsum("aax->x", k3)
    cubic = np.einsum("nx,nx->n", u, z)
    kh3 = cubic - 3.0 * z @ v
    m2 = np.einsum("nk,nk->n", Mz, Mz)
    k3sq = float(np.sum(k3 * k3))
    qh4 = np.einsum("nx,nx->n", u, u) - 2.0 * u @ v - 4.0 * m2 + v @ v + 2.0 * k3sq
    rh2 = m2 - k3sq
    h33 = (kh3 * kh3 - 9.0 * qh4 - 18.0 * rh2 - 6.0 * k3sq) / 72.0
    U = np.einsum("aacd->cd", k4)
    quartic = np.einsum("nk,nk->n", zz @ k4.reshape(r * r, r * r), zz)
    kh4 = quartic - 6.0 * np.einsum("na,ab,nb->n", z, U, z) + 3.0 * np.trace(U)
    return kh3 / 6.0 + kh4 / 24.0 + h33


def _qmc_terms(mean, cov, k3, k4, p, var_tol):
    """Edgeworth terms of every option at once, by quasi-Monte Carlo; (value, std. error).

    ``E[1{option i wins} h(Z)]`` with ``Z`` standard normal in whitened coordinates of the
    differences ``P_j - P_n``, on fixed scrambled Sobol sets. The exact normal probability
    ``p_i`` is a control variate for the indicator's own sampling error.
    """
    n = mean.size
    L = np.hstack([np.eye(n - 1), -np.ones((n - 1, 1))])
    lam, U = np.linalg.eigh(L @ cov @ L.T)
    keep = lam > var_tol
    B = U[:, keep] * np.sqrt(lam[keep])  # D = m + B z
    Binv = (U[:, keep] / np.sqrt(lam[keep])).T @ L  # z = Binv (P - mean)
    c3 = _multilinear(Binv, k3)
    c4 = _multilinear(Binv, k4)
    z = _normal_points(int(keep.sum()))
    shifts, pts, r = z.shape
    z = z.reshape(-1, r)
    d = L @ mean + z @ B.T
    scores = np.hstack([d, np.zeros((d.shape[0], 1))])
    win = np.zeros((d.shape[0], n))
    win[np.arange(d.shape[0]), scores.argmax(axis=1)] = 1.0
    h = _edgeworth_factor(z, c3, c4)
    wh = win * h[:, None]
    # control variate: the indicator's mean is known exactly (the normal probability)
    wc = win - win.mean(axis=0)
    beta = np.einsum("ni,ni->i", wh - wh.mean(axis=0), wc) / np.maximum(
        np.einsum("ni,ni->i", wc, wc), 1e-300)
    adj = (wh - beta * (win - p)).reshape(shifts, pts, n).mean(axis=1)
    return adj.mean(axis=0), adj.std(axis=0, ddof=1) / np.sqrt(shifts)


def error_estimate(mean, cov, k3, k4, p, enough=0.0):
    """Per-option estimate of ``|Pr(choose i) - normal approximation|``.

    ``mean``, ``cov``: moments of ``P(T)``; ``k3``, ``k4``: its third and fourth cumulant
    tensors; ``p``: the normal-approximation probabilities. Returns non-negative numbers.
    For four or more options the cheap bound is returned as it is where every option's
    bound is at most ``enough``; otherwise the terms are computed by quasi-Monte Carlo.

    A comparison with zero variance is constant (all its cumulants vanish), hence decided
    exactly; the estimate concerns the others: one left, the Edgeworth terms in closed
    form; two with a regular correlation, by finite differences; otherwise the
    Cauchy-Schwarz bound.
    """
    n = mean.size
    est = np.zeros(n)
    if not (np.any(k3) or np.any(k4)):
        return est  # no attention randomness: P(T) is exactly normal
    mean_scale = float(np.abs(mean).max())
    var_tol = 1e-12 * max(float(np.abs(np.diag(cov)).max()), mean_scale**2)
    ones, twos = [], []
    shared = None
    for i in range(n):
        L = _comparison(n, i)
        m = L @ mean
        v = np.einsum("ij,jk,ik->i", L, cov, L)
        det = v <= var_tol
        if np.any(det & (m < -1e-9 * mean_scale)):
            continue  # loses a comparison for certain: exactly zero in both
        L, m, v = L[~det], m[~det], v[~det]
        sd = np.sqrt(v)
        if L.shape[0] == 1:
            ones.append((i, m[0] / sd[0], L[0] / sd[0]))
            continue
        if L.shape[0] == 2:
            rho = float(L[0] @ cov @ L[1]) / (sd[0] * sd[1])
            if abs(rho) < _RHO_MAX:
                twos.append((i, m / sd, rho, L / sd[:, None]))
                continue
        if L.shape[0] == 0:
            continue
        if L.shape[0] == n - 1:
            # all comparisons random (n >= 4): the terms of every option by quasi-Monte
            # Carlo, capped by the bound (affine invariant: one norm for all options)
            if shared is None:
                bound = np.sqrt(np.clip(np.minimum(p, 1.0 - p), 0.0, None)) * _bound_norm(
                    L, cov, k3, k4, var_tol)
                if bound.max() <= enough:
                    shared = bound
                else:
                    t, se = _qmc_terms(mean, cov, k3, k4, p, var_tol)
                    shared = np.minimum(np.abs(t) + 2.0 * se, bound)
            est[i] = shared[i]
            continue
        norm = _bound_norm(L, cov, k3, k4, var_tol)
        est[i] = np.sqrt(max(min(p[i], 1.0 - p[i]), 0.0)) * norm
    if ones:
        idx = [o[0] for o in ones]
        D = np.array([o[2] for o in ones])
        terms = _terms_1d(np.array([o[1] for o in ones]),
                          np.einsum("abc,ia,ib,ic->i", k3, D, D, D),
                          np.einsum("abcd,ia,ib,ic,id->i", k4, D, D, D, D))
        est[idx] = np.abs(terms).sum(axis=0)
    if twos:
        idx = [t[0] for t in twos]
        terms = _terms_2d(np.array([t[1] for t in twos]), np.array([t[2] for t in twos]),
                          np.array([_multilinear(t[3], k3) for t in twos]),
                          np.array([_multilinear(t[3], k4) for t in twos]))
        est[idx] = np.abs(terms).sum(axis=1)
    return est
