"""Two options whose summed preference moves on its own: a lattice with moving thresholds.

With the standard contrast (``1^T C = 0``) and a feedback matrix whose rows and columns all
sum to the same ``c`` (the parametric ``S`` of two options), the summed preference
``s = P_1 + P_2`` follows ``s(t + 1) = c s(t)`` on every walk, and the lattice coordinate
``z = (P_1 - P_2) / sqrt(2)`` moves independently of it. From a start ``P0`` that does not
sum to zero, only the thresholds of ``z``, ``+-sqrt(2) (theta - s(t) / 2)``, move, and they
move alike on every walk. So instead of levels of the sum (:mod:`mdft._lattice_chain`,
which splits each step between the two levels around the next sum and multiplies the
states), the lattice keeps one row of cells and steps the walks with each step's own
thresholds and absorption, until the sum has settled at 0 to within rounding; from there it
is the fixed lattice of the settled sum, solved as usual (:func:`mdft._threshold_solve.
solve_chain`, from the state and the choices of the steps before).
``docs/threshold_exact.md``, section 3.
"""

from __future__ import annotations

import logging
import math

import numpy as np
import scipy.sparse as sp

from . import _moving_kernels as kernels
from ._lattice_chain import _WIDTH, Chain, TooManyStates, _basis, _edges_on

logger = logging.getLogger(__name__)

# The sum has settled once it is within this share of theta of 0: the thresholds then stand
# where they will stay, to within rounding.
SETTLED = 1e-12
# Without a step limit (``method="solve"``), the steps while the sum moves are stepped one by
# one; beyond this many, the lattice with levels answers instead.
MAX_MOVING_STEPS = 100_000
# Most entries of the cells' stored spreads (cells x attributes x window; two arrays of
# doubles: 160 MB), and most work (entries stepped over all the steps while the sum moves,
# about a few seconds); beyond either, the pass is refused as too large (TooManyStates).
MAX_ENTRIES = 10_000_000
MAX_WORK = 3e9


def moving_sum_steps(model, theta):
    """The steps until the summed preference settles, where it moves on its own (two
    options, contrast columns summing to zero, every row and column of ``S`` summing to the
    same ``0 < c < 1``, a start that does not sum to zero); else None."""
    if model.n_options != 2:
        return None
    S = np.asarray(model.S, dtype=np.float64)
    c = float(S.sum(axis=0).mean())
    scale = max(1.0, float(np.abs(S).max()))
    if (np.ptp(S.sum(axis=0)) > 1e-12 * scale or np.abs(S.sum(axis=1) - c).max() > 1e-12 * scale
            or np.abs(np.asarray(model.C).sum(axis=0)).max() > 1e-12 or not 0.0 < c < 1.0):
        return None
    s0 = float(np.sum(model.P0))
    if abs(s0) <= SETTLED * theta:
        return None
    return max(1, int(math.ceil(math.log(SETTLED * theta / abs(s0)) / math.log(c))))


def build_moving_chain(model, theta, n_cells, variance_correction, n_moving, max_steps=None,
                       tol=0.0):
    """The lattice of ``n_cells`` cells per ``theta`` for a sum that moves on its own,
    settling in ``n_moving`` steps (:func:`moving_sum_steps`), stepped while it moves (at
    most ``max_steps`` steps in all, fewer once the undecided mass is below ``tol``): a
    :class:`mdft._lattice_chain.Chain` of the settled sum whose start is the state after
    those steps and whose ``prefix`` holds the choices of the steps before. Raises
    :class:`mdft._lattice_chain.TooManyStates` where the lattice would be too large."""
    S = np.ascontiguousarray(model.S, dtype=np.float64)
    C = np.asarray(model.C)
    E = _basis(model)
    c = float(S.sum(axis=0).mean())
    s0 = float(np.sum(model.P0))
    n_prefix = n_moving if max_steps is None else min(n_moving, max_steps)
    sums = s0 * c ** np.arange(n_prefix + 1)
    sums[-1] = 0.0 if n_prefix == n_moving else sums[-1]
    # cells of the settled thresholds, extended by whole cells to the widest of the steps
    h = theta / n_cells
    edge = math.sqrt(2.0) * theta
    half_width = math.sqrt(2.0) * (theta - min(s0, 0.0) / 2.0)
    cov = model.sigma2 * (C @ C.T)
    sd_axis = math.sqrt(max(float(E[:, 0] @ cov @ E[:, 0]), 0.0))
    w = np.ascontiguousarray(model.w, dtype=np.float64)
    # the lattice's size, counted before any of it is stored (a start far below a small
    # theta asks for more than memory holds)
    approx_cells = 2.0 * half_width / h + 2.0
    entries = approx_cells * w.shape[0] * (2.0 * _WIDTH * sd_axis / h + 4.0)
    if not (entries <= MAX_ENTRIES and entries * n_prefix <= MAX_WORK):
        raise TooManyStates(
            f"n_cells={n_cells} gives about {int(approx_cells)} lattice cells whose spreads "
            f"hold about {entries:.3g} entries, stepped for {n_prefix} steps while the sum "
            f"moves (the moving lattice's limits are {MAX_ENTRIES:.3g} entries and "
            f"{MAX_WORK:.3g} entry-steps)")
    edges = _edges_on(edge, half_width, h)
    n_total = edges.size - 1
    centres = 0.5 * (edges[1:] + edges[:-1])
    step = float(edges[1] - edges[0])

    sd_opt = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    sd_cell = math.sqrt(max(sd_axis**2 - step**2 / 12.0, 0.0)) if variance_correction else sd_axis
    CM = np.ascontiguousarray(C @ model.M)
    slope = float(E[:, 0] @ S @ E[:, 0])
    shift = np.ascontiguousarray(E[:, 0] @ CM)
    max_count = int(math.ceil(2.0 * _WIDTH * sd_axis / step)) + 3
    spreads = kernels.spreads(centres, slope, shift, sd_cell, _WIDTH, edges, max_count)
    lattice = (centres, spreads, sd_cell, sd_axis, bool(variance_correction), _WIDTH, slope,
               shift, S, CM, w, theta, edges, sd_opt)

    # step 1, from the exact start (its spread as a source of its own)
    z0 = float(E[:, 0] @ np.asarray(model.P0, dtype=np.float64))
    start = kernels.spreads(np.array([z0]), slope, shift, sd_cell, _WIDTH, edges,
                            max_count + 2)
    x = np.zeros(n_total)
    rt = np.zeros((n_prefix, 2))
    reg = kernels.region_at(edges, theta, sums[1])
    kernels.add_row(z0, sums[0], sums[1], 1.0, 0, *start, sd_cell, slope, shift, S, CM, w, theta,
                    edges, reg, sd_opt, x, rt[0])
    done = kernels.run_steps(x, sums, *lattice, rt, tol)

    # the fixed chain of the settled sum: the cells of its region
    indptr, cols, vals, absorbing, lo = kernels.settled_rows(float(sums[-1]), *lattice)
    n_states = indptr.size - 1
    hi = lo + n_states
    outside = float(x[:lo].sum() + x[hi:].sum())
    if outside > 0.0:
        # stopped early (everything but less than tol decided) while the region was still
        # wider than the settled one: that mass joins the nearest settled cell, where it
        # counts as undecided (the chain does not step a mass below tol further)
        if not (done < n_prefix and outside < tol):  # pragma: no cover - by construction
            raise AssertionError(f"mass {outside:.3g} outside the settled lattice")
        x[lo] += x[:lo].sum()
        x[hi - 1] += x[hi:].sum()
        x[:lo] = 0.0
        x[hi:] = 0.0
    Q = sp.csr_matrix((vals, cols, indptr), shape=(n_states, n_states))
    occupied = np.flatnonzero(x[lo:hi])
    logger.debug("moving lattice: %d cells, %d steps while the sum moves, %d states, "
                 "%d nonzeros", n_total, n_prefix, n_states, Q.nnz)
    return Chain(Q, absorbing, occupied, x[lo:hi][occupied], rt[-1], 1, prefix=rt[:-1])
