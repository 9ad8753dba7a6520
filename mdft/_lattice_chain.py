"""The lattice Markov chain of two-option threshold stopping (Diederich & Busemeyer 2003).

Python side of the compiled kernels in :mod:`mdft._lattice`: lays out the
lattice of the preference state and builds the transient matrix ``Q`` and the
absorbing matrix ``R``. Inputs are validated by
:func:`mdft.threshold_probabilities`. The summed-preference helpers are shared
with the three-option chain (:mod:`mdft._plane_chain`).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field

import numba
import numpy as np
import scipy.sparse as sp

from . import _lattice

logger = logging.getLogger(__name__)

_WIDTH = 5.5  # kernel windows reach this many noise standard deviations
MAX_STATES = 300_000


@dataclass(frozen=True)
class Chain:
    """An absorbing chain: ``Q`` (transient to transient, CSR), ``R`` (transient to
    options, dense), and the first step from the exact initial state; or, where ``prefix``
    holds the choices of steps before (:mod:`mdft._lattice_moving`), the step after them."""

    Q: sp.csr_matrix
    R: np.ndarray
    start_cols: np.ndarray
    start_vals: np.ndarray
    start_absorbed: np.ndarray
    n_levels: int
    prefix: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))


# ------------------------------------------------------------------ geometry
def _basis(model):
    """Orthonormal basis ``E`` (n x 2) of the zero-sum plane in which the noise is independent."""
    n = model.n_options
    if n == 2:
        return np.array([[1.0, 0.0], [-1.0, 0.0]]) / np.array([math.sqrt(2.0), 1.0])
    # orthonormal basis of {x : 1^T x = 0}
    B = np.linalg.qr(np.eye(n) - 1.0 / n)[0][:, : n - 1]
    cov = B.T @ (model.sigma2 * (model.C @ model.C.T)) @ B
    spread = np.linalg.eigvalsh(cov)
    if spread.max() - spread.min() <= 1e-12 * max(1.0, spread.max()):
        # isotropic noise (standard contrast): any rotation works; use the one
        # that diagonalises the feedback within the plane
        G = B.T @ model.S @ B
        U = np.linalg.eigh(0.5 * (G + G.T))[1]
    else:
        U = np.linalg.eigh(cov)[1]
    E = B @ U
    return np.ascontiguousarray(E)


class TooManyStates(ValueError):
    """The resolution asked for more states than the budget allows."""


class UnboundedSum(ValueError):
    """The chain's worst-case range of the summed preference holds no finite grid."""


def sum_bounds(S, theta, s0):
    """Smallest interval of summed preference ``1^T P`` that the chain can reach.

    ``s(t+1) = c^T P(t)`` with ``c = 1^T S``; over the transient region
    ``{P_i < theta, 1^T P = s}`` it is extreme at a vertex (every preference
    at ``theta`` but one), which gives linear bounds in ``s``; iterate them to
    their fixed point. Raises :class:`UnboundedSum` where they have none (a column
    sum above 1 lets the worst case fall without bound).
    """
    n = S.shape[0]
    c = S.sum(axis=0)
    total = c.sum()

    def images(s):
        return [theta * (total - ck) + ck * (s - (n - 1) * theta) for ck in c]

    if np.all((c >= 0.0) & (c < 1.0)):
        # increasing contractions b_k + c_k s: the interval's ends are their fixed points
        fixed = [(theta * (total - ck) - ck * (n - 1) * theta) / (1.0 - ck) for ck in c]
        return min(float(s0), min(fixed)), min(max(float(s0), max(fixed)), n * theta)

    lo = hi = float(s0)
    limit = 1e3 * theta + abs(s0)
    for _ in range(100_000):
        vals = images(lo) + images(hi)
        new_lo = min(lo, min(vals))
        new_hi = min(max(hi, max(vals)), n * theta)
        if new_lo < -limit:
            radius = float(np.abs(np.linalg.eigvals(S)).max())
            raise UnboundedSum(
                "the chain bounds the summed preference 1^T P by its worst case over the "
                "undecided states, and with a column sum of S above 1 (column sums "
                f"{np.round(c, 6).tolist()}) that worst case falls without bound, so no finite "
                f"grid holds every state the chain can reach (the spectral radius of S is "
                f"{radius:.4g}: the process itself "
                f"{'is stable' if radius < 1.0 else 'is not stable either'})"
            )
        if new_lo - lo > -1e-12 * (1 + abs(lo)) and new_hi - hi < 1e-12 * (1 + abs(hi)):
            return new_lo, new_hi
        lo, hi = new_lo, new_hi
    raise UnboundedSum(  # pragma: no cover - the bounds converge geometrically
        "the chain could not bound the summed preference 1^T P"
    )


def chain_sum_bounds(S, theta, s0):
    """:func:`sum_bounds` for a chain of ``n`` options, which also needs the summed
    preference to stay below ``n * theta`` for three options (where every preference could
    cross at once, which the chains do not represent): raises :class:`UnboundedSum` if not."""
    n = S.shape[0]
    s_lo, s_hi = sum_bounds(S, theta, s0)
    if n == 3 and s_hi >= n * theta - 1e-9:
        raise UnboundedSum(
            "the worst case of the summed preference 1^T P under S reaches 3 * theta (column "
            f"sums of S {np.round(S.sum(axis=0), 6).tolist()}), where every preference can "
            "cross the threshold at once, which the chain does not represent"
        )
    return s_lo, s_hi


def _settled_sum(model):
    """The summed preference of the mean path's fixed point, ``1^T (I - S)^-1 C M w`` (where
    the sum of walks that have not decided settles; 0 when ``I - S`` is singular)."""
    drive = np.asarray(model.C) @ np.asarray(model.M) @ np.asarray(model.w)
    try:
        return float(np.linalg.solve(np.eye(model.n_options) - model.S, drive).sum())
    except np.linalg.LinAlgError:
        return 0.0


def _edges_on(edge, half_width, h):
    """Cell edges covering ``[-half_width, half_width]``, about ``h`` apart, with ``-edge``
    and ``edge`` among them."""
    inner = max(1, int(round(2.0 * edge / h)))
    step = 2.0 * edge / inner
    first = -edge - math.ceil((half_width - edge) / step - 1e-9) * step
    count = int(math.ceil((half_width - first) / step - 1e-9))
    return first + step * np.arange(count + 1)


def pair_parameters(cov, sd_opt):
    """``pair_sd[i, k]``: sd of ``P_k - P_i``; ``pair_rho[i, k]``: its correlation with ``P_i``."""
    n = cov.shape[0]
    pair_sd = np.zeros((n, n))
    pair_rho = np.zeros((n, n))
    for i in range(n):
        for k in range(n):
            if i == k:
                continue
            var_y = cov[k, k] + cov[i, i] - 2 * cov[i, k]
            pair_sd[i, k] = math.sqrt(max(var_y, 0.0))
            if pair_sd[i, k] > 0 and sd_opt[i] > 0:
                rho = (cov[i, k] - cov[i, i]) / (pair_sd[i, k] * sd_opt[i])
                pair_rho[i, k] = min(max(rho, -1 + 1e-12), 1 - 1e-12)
    return pair_sd, pair_rho


def sum_is_constant(S, s0):
    """True when ``1^T S P = 1^T P`` along every path from a start with sum ``s0``."""
    c = S.sum(axis=0)
    return bool(np.ptp(c) <= 1e-12 and abs(c[0] * s0 - s0) <= 1e-12 * max(1.0, abs(s0)))


def _check_box(n_cells, n_box):
    """Refuse a lattice whose bounding box holds more than four times the states allowed
    (about half the box lies inside the region)."""
    if not n_box <= 4 * MAX_STATES:
        raise TooManyStates(
            f"n_cells={n_cells} gives about {int(n_box) // 2} lattice states (the lattice's "
            f"limit is {MAX_STATES})"
        )


def build_chain(model, theta, n_cells, variance_correction):
    """The lattice chain of a two-option model with ``n_cells`` cells per ``theta``.

    Where the summed preference moves (levels), two options get cell edges on the
    thresholds of the sum where the walks settle (:func:`_settled_sum`); otherwise the edges
    lie on the thresholds of the lowest level.
    """
    n = model.n_options
    S = np.ascontiguousarray(model.S, dtype=np.float64)
    C = np.asarray(model.C)
    E = _basis(model)
    h = theta / n_cells
    s0 = float(np.sum(model.P0))
    if sum_is_constant(S, s0):
        s_lo = s_hi = s0
    else:
        s_lo, s_hi = chain_sum_bounds(S, theta, s0)
    # bounding box of the largest transient region, at the lowest summed preference
    R = theta - s_lo / n
    verts = np.full((n, n), R) - n * R * np.eye(n)  # row k: every option at R but k
    zv = verts @ E
    # the box's cells and levels are counted before any is stored: a start far below a
    # small theta asks for more than memory holds
    spans = [float(zv[:, k].max() - zv[:, k].min()) for k in range(n - 1)]
    counts = [max(1.0, math.ceil(span / h - 1e-9)) for span in spans]
    counts.append(max(2.0, math.ceil((s_hi - s_lo) / h) + 1.0) if s_hi - s_lo > 0.0 else 1.0)
    _check_box(n_cells, math.prod(counts))
    n_levels = int(counts[-1])
    levels = np.linspace(s_lo, s_hi, n_levels) if n_levels > 1 else np.array([s_lo])
    edges = []
    for k in range(2):
        lo, hi = zv[:, k].min(), zv[:, k].max()
        if k == 1 and n == 2:
            edges.append(np.array([-0.5, 0.5]))
            continue
        edges.append(np.linspace(lo, hi, int(counts[k]) + 1))
    edges1, edges2 = edges
    if n == 2 and n_levels > 1:
        settled = min(max(_settled_sum(model), s_lo), s_hi)
        edge = math.sqrt(2.0) * (theta - settled / n)
        if edge >= h:
            edges1 = _edges_on(edge, math.sqrt(2.0) * R, h)
    _check_box(n_cells, (edges1.size - 1) * (edges2.size - 1) * n_levels)
    c1 = 0.5 * (edges1[1:] + edges1[:-1])
    c2 = 0.5 * (edges2[1:] + edges2[:-1])
    if n == 2:
        c2 = np.zeros(1)
    top = (E[:, 0][None, None, :] * c1[:, None, None]
           + E[:, 1][None, None, :] * c2[None, :, None]).max(axis=2)
    # level l holds the cells inside the region of level l - 1 (the larger one),
    # so that a step split between two levels always lands on existing states
    lower = np.concatenate([[levels[0]], levels[:-1]])
    mask = top[None, :, :] + lower[:, None, None] / n < theta
    n_states = int(mask.sum())
    if n_states > MAX_STATES:
        raise TooManyStates(
            f"n_cells={n_cells} gives {n_states} lattice states (the lattice's limit is "
            f"{MAX_STATES})"
        )
    if n_states == 0:
        raise ValueError(f"n_cells={n_cells} leaves no lattice cell below theta; raise n_cells")
    index = np.full(mask.shape, -1, dtype=np.int64)
    index[mask] = np.arange(n_states)
    states = np.argwhere(mask).astype(np.int64)  # (level, i1, i2), in state order

    cov = model.sigma2 * (C @ C.T)
    sd_opt = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    cov_z = E.T @ cov @ E
    sd_axis = np.sqrt(np.clip(np.diag(cov_z), 0.0, None))
    sd_axis[1] = sd_axis[1] if n > 2 else 0.0
    spac = np.array([edges1[1] - edges1[0], edges2[1] - edges2[0] if n > 2 else 0.0])
    if variance_correction:
        sd_cell = np.sqrt(np.clip(sd_axis**2 - spac**2 / 12.0, 0.0, None))
    else:
        sd_cell = sd_axis.copy()
    pair_sd, pair_rho = pair_parameters(cov, sd_opt)
    CM = np.ascontiguousarray(C @ model.M)
    A = np.ascontiguousarray(E.T @ CM)
    w = np.ascontiguousarray(model.w, dtype=np.float64)
    args = (S, E, CM, A, w, theta, edges1, edges2, top, levels, index, sd_opt, sd_cell,
            pair_sd, pair_rho, _WIDTH, _lattice._GL_X, _lattice._GL_W)
    n_chunks = int(min(64, max(1, n_states // 2_000)))  # small chains: no thread overhead
    threads = numba.get_num_threads()
    if n_chunks == 1:
        numba.set_num_threads(1)  # a small chain: waking the thread pool costs more than it saves
    try:
        counts = _lattice.count_rows(states, *args, n_chunks)
        indptr = np.zeros(n_states + 1, dtype=np.int64)
        np.cumsum(counts, out=indptr[1:])
        cols = np.empty(indptr[-1], dtype=np.int64)
        vals = np.empty(indptr[-1])
        absorbing = np.zeros((n_states, n))
        _lattice.fill_rows(states, indptr, *args, n_chunks, cols, vals, absorbing)
    finally:
        numba.set_num_threads(threads)
    Q = sp.csr_matrix((vals, cols, indptr), shape=(n_states, n_states))
    z0 = E.T @ (np.asarray(model.P0) - s0 / n)
    start_abs = np.zeros(n)
    start_cols, start_vals = _lattice.first_row(z0[0], z0[1], s0, *args, start_abs)
    logger.debug("lattice: %d states, %d levels, %d nonzeros", n_states, n_levels, Q.nnz)
    return Chain(Q, absorbing, start_cols, start_vals, start_abs, n_levels)


