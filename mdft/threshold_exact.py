"""Exact threshold stopping: choice and response-time distributions without Monte Carlo noise.

The preference process ``P(t+1) = S P(t) + C (M W(t+1) + eps(t+1))`` stopped
when some ``P_i`` reaches ``theta`` is approximated by a Markov chain on a
lattice (Diederich & Busemeyer 2003): the transient states are lattice cells
of the region where every preference is below ``theta``, the absorbing
states are the options. The transition probabilities integrate the
per-step Gaussian mixture over the cells, and the probability of stopping
at a step is computed exactly from the state, so every row of the chain sums
to one. Choice probabilities and the response-time distribution then follow
from sparse matrix products (step by step) or a sparse linear solve (the
long run). See ``docs/threshold_exact.md`` for the method, its error and
its limits.
"""

from __future__ import annotations

import logging
import math
import warnings
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from . import _lattice
from ._validation import as_count, as_scalar
from .model import MDFTModel
from ._repr import compact_repr

__all__ = ["ThresholdProbabilities", "threshold_probabilities"]

logger = logging.getLogger(__name__)

_MAX_OPTIONS = 3
_WIDTH = 5.5  # kernel windows reach this many noise standard deviations
_MAX_STATES = 300_000
_DIRECT_SOLVE_MAX_STATES = 2_000
_METHODS = ("propagate", "solve")
_COARSE = 1.6  # warn when the spacing exceeds this many noise sds
_DEFAULT_CELLS = {1: 100, 2: 25, 3: 8}  # default n_cells by lattice dimension


@dataclass(frozen=True)
class ThresholdProbabilities:
    """Choice and response-time distributions of threshold stopping (lattice method).

    Attributes
    ----------
    probabilities : ndarray, shape (n_options,)
        Probability that option ``i`` is chosen within ``max_steps`` steps
        (``method="solve"``: ever).
    p_undecided : float
        Probability that no option has been chosen after ``max_steps`` steps,
        so ``probabilities.sum() + p_undecided == 1`` up to rounding
        (0 for ``method="solve"``, which has no step limit).
    rt_pmf : ndarray, shape (max_steps, n_options), or None
        ``rt_pmf[t, i]``: probability of choosing option ``i`` at step
        ``t + 1``. None for ``method="solve"``.
    mean_response_times : ndarray, shape (n_options,)
        Mean decision step given that option ``i`` is chosen (within
        ``max_steps`` for ``"propagate"``); NaN for an option never chosen.
    theta : float
        The threshold.
    max_steps : int or None
        The step limit (None for ``method="solve"``).
    n_cells : int
        Lattice cells per ``theta`` along each lattice axis.
    spacing : float
        Lattice spacing ``theta / n_cells`` in preference units.
    n_levels : int
        Levels of the summed preference ``1^T P`` (1 when the feedback keeps
        the sum at its initial value, so the lattice is (n_options - 1)-dimensional).
    n_states : int
        Number of transient lattice states.
    method : str
        ``"propagate"`` or ``"solve"``.
    n_iter : int
        Steps propagated, or iterations of the linear solver (0 for a direct solve).
    converged : bool
        ``"propagate"``: True. ``"solve"``: whether the iterative solver met ``tol``.
    tail_start : int or None
        First row of ``rt_pmf`` filled in geometrically (see ``tail_tol``),
        or None when every step was propagated.
    """

    __repr__ = compact_repr

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


@dataclass(frozen=True)
class _Chain:
    """The lattice chain: ``Q`` (transient to transient), ``R`` (transient to options),
    and the first step from the exact initial state."""

    Q: sp.csr_matrix
    R: sp.csr_matrix
    start_cols: np.ndarray
    start_vals: np.ndarray
    start_absorbed: np.ndarray
    spacing: float
    n_levels: int


def threshold_probabilities(model, theta, *, max_steps=10_000, n_cells=None,
                            method="propagate", tol=1e-10, tail_tol=1e-7,
                            variance_correction=True, max_iter=2_000):
    """Choice probabilities and response-time distribution of threshold stopping.

    The preference state is put on a lattice and the stopped MDFT process
    becomes an absorbing Markov chain (Diederich & Busemeyer 2003), solved
    without Monte Carlo noise. Works for two and three options.

    Parameters
    ----------
    model : MDFTModel
        The model; two or three options, a contrast ``C`` whose columns sum
        to zero (the standard one does).
    theta : float
        Threshold, > 0: option ``i`` is chosen at the first step where
        ``P_i >= theta``; if several preferences reach it at the same step,
        the largest is chosen (as :func:`mdft.simulate` does).
    max_steps : int, default 10_000
        Step limit of ``method="propagate"``; mass not absorbed by then is
        ``p_undecided``. Ignored by ``method="solve"``.
    n_cells : int, optional
        Lattice resolution: cells per ``theta`` along each axis (spacing
        ``theta / n_cells``), at least 4. The default depends on the number
        of lattice dimensions: 100 for two options whose summed preference
        stays constant (one dimension), 25 for two options otherwise, 8 for
        three options (errors below 1e-4 and about 2e-3 in the choice
        probabilities of the canonical sets). The error falls roughly with the square of the spacing
        (``docs/threshold_exact.md`` has a measured table).
    method : {"propagate", "solve"}, default "propagate"
        ``"propagate"`` applies the chain step by step and returns the
        response-time distribution; it stops early once the undecided mass is
        below ``tol``. ``"solve"`` solves ``(I - Q) x = b`` with
        scipy.sparse.linalg (LU up to 2,000 states, GMRES above) for the
        long-run (unlimited time) probabilities and mean response times.
    tol : float, default 1e-10
        ``"propagate"``: undecided mass at which propagation stops.
        ``"solve"``: relative residual of the iterative solver (GMRES).
    tail_tol : float, default 1e-7
        ``"propagate"``: once the undecided mass decays by a constant factor
        per step and the options' shares of each step's choices stay fixed
        (relative changes below ``tail_tol`` for 20 steps in a row), the chain
        is in its slowest mode and the rest of ``rt_pmf`` is geometric; it is
        filled in without further steps. 0 propagates every step.
    variance_correction : bool, default True
        Integrate each Gaussian over the cells with its variance reduced by
        ``spacing**2 / 12`` (Sheppard's correction), so that the chain's step
        variance matches the model's instead of exceeding it by the spread of
        a uniform cell. Lowers the error at a given spacing (see the docs).
    max_iter : int, default 2000
        Iteration limit of GMRES (``"solve"`` on lattices above 2,000 states),
        per right-hand side.

    Returns
    -------
    ThresholdProbabilities
        Frozen dataclass with ``probabilities``, ``p_undecided``, ``rt_pmf``,
        ``mean_response_times`` and the lattice used.

    Raises
    ------
    ValueError
        Bad ``theta``, ``max_steps``, ``n_cells``, ``method``, ``tol``; a model
        with more than three options (use :func:`mdft.simulate`); a contrast
        whose columns do not sum to zero; an initial preference at or above
        ``theta``; a feedback matrix under which the summed preference is not
        bounded.

    Notes
    -----
    State space. Every valence ``C (M W + eps)`` sums to zero, so only the
    feedback ``S`` changes the summed preference ``s = 1^T P``, and it does so
    deterministically: ``s(t+1) = 1^T S P(t)``. The lattice holds the zero-sum
    part of ``P`` (``n_options - 1`` axes, along which the noise is
    independent) and, unless ``S`` keeps ``s`` at its start value (equal
    column sums and ``1^T P0 = 0``, as for two options with the parametric
    ``S``), a few levels of ``s`` between rigorous bounds, so no preference
    needs a lower truncation: the transient region is bounded.

    Transitions. From a cell centre, ``P(t+1)`` given the attended attribute
    ``j`` is Gaussian with mean ``S P + C M e_j``. The probability of choosing
    each option at the step is computed exactly (normal and bivariate normal
    tails); the rest is spread over the lattice cells inside the region in
    proportion to the Gaussian's integral over each cell (products of normal
    CDF differences), and ``s(t+1)`` is split linearly between two levels.
    The first step starts from ``P0`` exactly.

    Examples
    --------
    >>> import mdft
    >>> model = mdft.MDFTModel([[1, 3], [3, 1]], [0.5, 0.5],
    ...                        phi1=0.022, phi2=0.05, beta=12.0)
    >>> res = mdft.threshold_probabilities(model, 17.5)
    >>> res.probabilities.round(3)
    array([0.5, 0.5])
    >>> round(float(res.mean_response_times[0]))
    143
    >>> res.rt_pmf.shape
    (10000, 2)
    """
    if not isinstance(model, MDFTModel):
        raise TypeError(f"model must be an MDFTModel (got {type(model).__name__})")
    n = model.n_options
    if n > _MAX_OPTIONS:
        raise ValueError(
            f"model has {n} options; the lattice method handles at most {_MAX_OPTIONS} "
            f"(its state space has n_options dimensions and grows as n_cells**n_options); "
            "estimate threshold stopping for more options with mdft.simulate(model, n_samples, "
            "stopping=mdft.Threshold(theta))"
        )
    theta = as_scalar("theta", theta, low=0.0, low_inclusive=False)
    if method not in _METHODS:
        raise ValueError(f"method must be one of {_METHODS} (got {method!r})")
    max_steps = as_count("max_steps", max_steps, low=1)
    if n_cells is None:
        # by the number of lattice dimensions: the zero-sum plane, plus the sum if it moves
        dims = n - 1 + (0 if _sum_is_constant(np.asarray(model.S), float(np.sum(model.P0))) else 1)
        n_cells = _DEFAULT_CELLS[dims]
    n_cells = as_count("n_cells", n_cells, low=4)
    tol = as_scalar("tol", tol, low=0.0, low_inclusive=False, high=0.1)
    max_iter = as_count("max_iter", max_iter, low=1)
    tail_tol = as_scalar("tail_tol", tail_tol, low=0.0, high=0.1)
    if not isinstance(variance_correction, (bool, np.bool_)):
        raise TypeError(f"variance_correction must be True or False (got {variance_correction!r})")
    C = np.asarray(model.C)
    col = np.abs(C.sum(axis=0)).max()
    if col > 1e-9 * max(1.0, np.abs(C).max()):
        raise ValueError(
            f"the contrast C must have columns summing to zero (largest column sum {col:.3g}); "
            "the lattice method relies on valences that leave the summed preference unchanged"
        )
    P0 = np.asarray(model.P0)
    if np.any(P0 >= theta):
        raise ValueError(
            f"the initial preference P0 must lie below theta={theta:g} for every option "
            f"(got P0={P0.tolist()})"
        )

    chain = _build_chain(model, theta, n_cells, bool(variance_correction))
    if method == "propagate":
        return _propagate(chain, n, theta, max_steps, n_cells, tol, tail_tol)
    return _solve(chain, n, theta, n_cells, tol, max_iter)


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


def _sum_bounds(S, theta, s0):
    """Smallest interval of summed preference ``1^T P`` that the chain can reach.

    ``s(t+1) = c^T P(t)`` with ``c = 1^T S``; over the transient region
    ``{P_i < theta, 1^T P = s}`` it is extreme at a vertex (every preference
    at ``theta`` but one), which gives linear bounds in ``s``; iterate them to
    their fixed point.
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
            raise ValueError(
                "the feedback matrix S lets the summed preference 1^T P grow without bound "
                f"(column sums of S: {np.round(c, 6).tolist()}), so no finite lattice holds "
                "the preference state; use mdft.simulate for this model"
            )
        if new_lo - lo > -1e-12 * (1 + abs(lo)) and new_hi - hi < 1e-12 * (1 + abs(hi)):
            return new_lo, new_hi
        lo, hi = new_lo, new_hi
    raise ValueError(  # pragma: no cover - the bounds converge geometrically
        "could not bound the summed preference 1^T P; use mdft.simulate for this model"
    )


def _sum_is_constant(S, s0):
    """True when ``1^T S P = 1^T P`` along every path from a start with sum ``s0``."""
    c = S.sum(axis=0)
    return bool(np.ptp(c) <= 1e-12 and abs(c[0] * s0 - s0) <= 1e-12 * max(1.0, abs(s0)))


def _build_chain(model, theta, n_cells, variance_correction):
    n = model.n_options
    S = np.ascontiguousarray(model.S, dtype=np.float64)
    C = np.asarray(model.C)
    E = _basis(model)
    h = theta / n_cells
    s0 = float(np.sum(model.P0))
    if _sum_is_constant(S, s0):
        s_lo = s_hi = s0
    else:
        s_lo, s_hi = _sum_bounds(S, theta, s0)
        if n == 3 and s_hi >= n * theta - 1e-9:
            raise ValueError(
                "the feedback matrix S lets the summed preference reach n_options * theta, "
                "where all preferences can cross together; use mdft.simulate for this model"
            )
    if s_hi - s_lo > 0.0:
        n_levels = max(2, int(math.ceil((s_hi - s_lo) / h)) + 1)
        levels = np.linspace(s_lo, s_hi, n_levels)
    else:
        n_levels = 1
        levels = np.array([s_lo])
    # bounding box of the largest transient region, at the lowest summed preference
    R = theta - s_lo / n
    verts = np.full((n, n), R) - n * R * np.eye(n)  # row k: every option at R but k
    zv = verts @ E
    edges = []
    for k in range(2):
        lo, hi = zv[:, k].min(), zv[:, k].max()
        if k == 1 and n == 2:
            edges.append(np.array([-0.5, 0.5]))
            continue
        m = max(1, int(math.ceil((hi - lo) / h - 1e-9)))
        edges.append(np.linspace(lo, hi, m + 1))
    edges1, edges2 = edges
    n_box = (edges1.size - 1) * (edges2.size - 1) * n_levels
    if n_box > 4 * _MAX_STATES:
        raise ValueError(
            f"n_cells={n_cells} gives about {n_box // 2} lattice states (limit "
            f"{_MAX_STATES}); use a smaller n_cells"
        )
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
    if n_states > _MAX_STATES:
        raise ValueError(
            f"n_cells={n_cells} gives {n_states} lattice states (limit {_MAX_STATES}); "
            "use a smaller n_cells"
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
    if np.any(sd_axis[: n - 1] == 0.0):
        warnings.warn(
            "the preference noise is zero along a lattice axis (sigma2 = 0): nothing smooths "
            "the rounding of each step to a cell centre, so the result is exact only when every "
            "reachable preference lies on a cell centre and is otherwise approximate; "
            "check it against mdft.simulate",
            RuntimeWarning, stacklevel=3,
        )
    positive = sd_axis[sd_axis > 0]
    if positive.size and h > _COARSE * positive.min():
        warnings.warn(
            f"the lattice spacing theta / n_cells = {h:.3g} exceeds {_COARSE} times the "
            f"per-step noise sd {positive.min():.3g}: choice probabilities can be off by "
            f"0.01 or more; raise n_cells above {math.ceil(theta / (_COARSE * positive.min()))}",
            RuntimeWarning, stacklevel=3,
        )
    if variance_correction:
        sd_cell = np.sqrt(np.clip(sd_axis**2 - spac**2 / 12.0, 0.0, None))
    else:
        sd_cell = sd_axis.copy()
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
    CM = np.ascontiguousarray(C @ model.M)
    A = np.ascontiguousarray(E.T @ CM)
    w = np.ascontiguousarray(model.w, dtype=np.float64)
    args = (S, E, CM, A, w, theta, edges1, edges2, top, levels, index, sd_opt, sd_cell,
            pair_sd, pair_rho, _WIDTH, _lattice._GL_X, _lattice._GL_W)
    n_chunks = 64
    counts = _lattice.count_rows(states, *args, n_chunks)
    indptr = np.zeros(n_states + 1, dtype=np.int64)
    np.cumsum(counts, out=indptr[1:])
    cols = np.empty(indptr[-1], dtype=np.int64)
    vals = np.empty(indptr[-1])
    absorbing = np.zeros((n_states, n))
    _lattice.fill_rows(states, indptr, *args, n_chunks, cols, vals, absorbing)
    Q = sp.csr_matrix((vals, cols, indptr), shape=(n_states, n_states))
    Rm = sp.csr_matrix(absorbing)
    z0 = E.T @ (np.asarray(model.P0) - s0 / n)
    start_abs = np.zeros(n)
    start_cols, start_vals = _lattice.first_row(z0[0], z0[1], s0, *args, start_abs)
    logger.debug("lattice: %d states, %d levels, %d nonzeros", n_states, n_levels, Q.nnz)
    return _Chain(Q, Rm, start_cols, start_vals, start_abs, h, n_levels)


# ------------------------------------------------------------------ solvers
def _mean_rt(weighted, probs):
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(probs > 0, weighted / np.where(probs > 0, probs, 1.0), np.nan)


def _propagate(chain, n, theta, max_steps, n_cells, tol, tail_tol):
    QT = chain.Q.T.tocsr()
    RT = chain.R.T.tocsr()
    n_states = chain.Q.shape[0]
    x = np.zeros(n_states)
    np.add.at(x, chain.start_cols, chain.start_vals)
    rt_pmf = np.zeros((max_steps, n))
    rt_pmf[0] = chain.start_absorbed
    steps, tail_start, mass = _lattice.propagate(
        QT.indptr.astype(np.int64), QT.indices.astype(np.int32), QT.data,
        RT.indptr.astype(np.int64), RT.indices.astype(np.int32), RT.data, x, rt_pmf, tol,
        tail_tol)
    probs = rt_pmf.sum(axis=0)
    p_undecided = float(max(mass, 0.0))
    times = np.arange(1, max_steps + 1, dtype=np.float64)
    mean_rt = _mean_rt(times @ rt_pmf, probs)
    return ThresholdProbabilities(
        probabilities=probs, p_undecided=p_undecided, rt_pmf=rt_pmf,
        mean_response_times=mean_rt, theta=theta, max_steps=max_steps, n_cells=n_cells,
        spacing=chain.spacing, n_levels=chain.n_levels, n_states=n_states, method="propagate",
        n_iter=steps, converged=True,
        tail_start=int(tail_start) if tail_start < max_steps else None,
    )


def _solve(chain, n, theta, n_cells, tol, max_iter):
    n_states = chain.Q.shape[0]
    A = (sp.identity(n_states, format="csc") - chain.Q.T).tocsc()
    b = np.zeros(n_states)
    np.add.at(b, chain.start_cols, chain.start_vals)
    converged = True
    n_iter = 0
    if n_states <= _DIRECT_SOLVE_MAX_STATES:
        lu = spla.splu(A)
        y = lu.solve(b)
        y2 = lu.solve(y)
    else:
        ys = []
        for rhs in (b, None):
            rhs = b if rhs is not None else ys[0]
            counter = [0]

            def callback(_, counter=counter):
                counter[0] += 1

            restart = min(50, max_iter)
            sol, info = spla.gmres(A, rhs, rtol=tol, atol=0.0, restart=restart,
                                   maxiter=-(-max_iter // restart), callback=callback,
                                   callback_type="pr_norm")
            n_iter += counter[0]
            converged = converged and info == 0
            ys.append(sol)
        y, y2 = ys
        if not converged:
            warnings.warn(
                f"the iterative solver did not reach tol={tol:g} within max_iter={max_iter}; "
                "raise max_iter or tol, or use method='propagate'",
                RuntimeWarning, stacklevel=3,
            )
    RT = chain.R.T.tocsr()
    probs = chain.start_absorbed + RT @ y
    weighted = chain.start_absorbed + RT @ (y + y2)
    mean_rt = _mean_rt(weighted, probs)
    return ThresholdProbabilities(
        probabilities=probs, p_undecided=0.0, rt_pmf=None, mean_response_times=mean_rt,
        theta=theta, max_steps=None, n_cells=n_cells, spacing=chain.spacing,
        n_levels=chain.n_levels, n_states=n_states, method="solve", n_iter=n_iter,
        converged=bool(converged), tail_start=None,
    )
