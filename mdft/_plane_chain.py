"""The plane chain of three-option threshold stopping.

Python side of the compiled kernels in :mod:`mdft._plane`: chooses the grid
from the model and a resolution ``kappa`` (cell size in per-step standard
deviations), applies the variance correction, and builds the chain. Inputs are
validated by :func:`mdft.threshold_probabilities`; ``docs/threshold_exact.md``
describes the method.
"""

from __future__ import annotations

import logging
import math

import numpy as np
import scipy.sparse as sp

from . import _lattice, _plane
from ._lattice_chain import Chain, pair_parameters, sum_bounds, sum_is_constant

logger = logging.getLogger(__name__)

# Each component's Gaussian keeps a standard deviation of at least this many cells.
_MIN_SD_CELLS = 0.5
# At least this many cells per theta along each axis (kappa = 1).
_MIN_CELLS_PER_THETA = 6.0
# Levels of the summed preference are this many times the finer cell size. Splitting a step
# between two levels adds spurious spread to the sum (and so to every threshold); at 3 cells
# it biased mean response times by 0.3-0.5 % (compromise set), at 1 cell it is below 0.1 %.
_LEVEL_FACTOR = 1.0
# Largest index box (levels x cells x cells) the builder may allocate.
_MAX_BOX = 40_000_000


class TooManyStates(ValueError):
    """The resolution asked for more states than the budget allows."""


def plane_geometry(model, theta, kappa):
    """Grid, corrected kernel and absorption parameters for resolution ``kappa``."""
    C = np.asarray(model.C, dtype=np.float64)
    S = np.ascontiguousarray(model.S, dtype=np.float64)
    B = np.linalg.qr(np.eye(3) - 1.0 / 3.0)[0][:, :2]
    cov3 = model.sigma2 * (C @ C.T)
    noise = B.T @ cov3 @ B
    CM = np.ascontiguousarray(C @ np.asarray(model.M, dtype=np.float64))
    w = np.ascontiguousarray(model.w, dtype=np.float64)
    A = B.T @ CM
    abar = A @ w
    dev = A - abar[:, None]
    att = (dev * w) @ dev.T
    ev = np.linalg.eigvalsh(noise)
    if ev.max() - ev.min() <= 1e-9 * ev.max():
        # isotropic noise (standard contrast): axes along the total per-step spread
        U = np.linalg.eigh(noise + att)[1]
    else:
        U = np.linalg.eigh(noise)[1]
    E = np.ascontiguousarray(B @ U)
    v = np.clip(np.diag(U.T @ noise @ U), 0.0, None)
    a = np.clip(np.diag(U.T @ att @ U), 0.0, None)
    tot = v + a
    h = np.minimum(kappa * np.sqrt(tot), kappa * theta / _MIN_CELLS_PER_THETA)
    # variance correction: the jump to a cell adds h^2/12 along each axis; take it from the
    # Gaussian, keeping at least half a cell of width, and the rest from the attention spread
    need = h**2 / 12.0
    v_cell = np.maximum(v - need, (_MIN_SD_CELLS * h) ** 2)
    deficit = v_cell + need - v
    with np.errstate(invalid="ignore", divide="ignore"):
        gam = np.where(a > 0, np.sqrt(np.clip((a - deficit) / np.where(a > 0, a, 1.0), 0, None)),
                       1.0)
    A_ax = U.T @ A
    abar_ax = U.T @ abar
    shrunk = np.ascontiguousarray(abar_ax[:, None] + gam[:, None] * (A_ax - abar_ax[:, None]))
    s0 = float(np.sum(model.P0))
    if sum_is_constant(S, s0):
        s_lo, hs, n_levels = s0, 1.0, 1
    else:
        s_lo, s_hi = sum_bounds(S, theta, s0)
        if s_hi >= 3 * theta - 1e-9:
            raise ValueError(
                "the feedback matrix S lets the summed preference reach 3 * theta, where all "
                "preferences can cross together; use mdft.simulate for this model"
            )
        hs = _LEVEL_FACTOR * h.min()
        n_levels = max(2, int(math.ceil((s_hi - s_lo) / hs)) + 1)
        hs = (s_hi - s_lo) / (n_levels - 1)
    verts = theta * np.ones((3, 3)) - (3 * theta - s_lo) * np.eye(3)
    zv = verts @ E
    first = np.floor(zv.min(axis=0) / h)
    o = first * h
    nn = (np.ceil(zv.max(axis=0) / h) - first + 1).astype(np.int64)
    sd_opt = np.sqrt(np.clip(np.diag(cov3), 0.0, None))
    pair_sd, pair_rho = pair_parameters(cov3, sd_opt)
    P0 = np.asarray(model.P0, dtype=np.float64)
    return dict(
        z_start=np.ascontiguousarray(E.T @ P0), s_start=s0, S=S, E=E, CM=CM, w=w,
        shrunk=shrunk, sd_cell=np.sqrt(v_cell), exact=np.ascontiguousarray(A_ax),
        sd_exact=np.sqrt(v), theta=float(theta), o1=float(o[0]), o2=float(o[1]),
        h1=float(h[0]), h2=float(h[1]), n1=int(nn[0]), n2=int(nn[1]), s_lo=float(s_lo),
        hs=float(hs), n_levels=int(n_levels), sd_opt=sd_opt, pair_sd=pair_sd,
        pair_rho=pair_rho,
    )


def build_plane_chain(model, theta, kappa, max_states):
    """The plane chain at resolution ``kappa``; ``(chain, spacing, max_gap)``.

    Raises TooManyStates when the reachable states exceed ``max_states``.
    """
    g = plane_geometry(model, theta, kappa)
    box = g["n_levels"] * g["n1"] * g["n2"]
    if box > _MAX_BOX:
        raise TooManyStates(
            f"resolution {kappa:.3g} needs an index box of {box} cells (limit {_MAX_BOX})"
        )
    out = _plane.build(
        g["z_start"], g["s_start"], g["S"], g["E"], g["CM"], g["w"], g["shrunk"], g["sd_cell"],
        g["exact"], g["sd_exact"], g["theta"], g["o1"], g["o2"], g["h1"], g["h2"], g["n1"],
        g["n2"], g["s_lo"], g["hs"], g["n_levels"], g["sd_opt"], g["pair_sd"], g["pair_rho"],
        _lattice._GL_X, _lattice._GL_W, max_states,
    )
    (status, pos, lev, row_ptr, cols, vals, absorb, start_cols, start_vals, start_abs,
     max_gap, n_fallback) = out
    if status == _plane.TOO_MANY_STATES:
        raise TooManyStates(
            f"resolution {kappa:.3g} reaches more than {max_states} states"
        )
    n_states = pos.shape[0]
    Q = sp.csr_matrix((vals, cols, row_ptr), shape=(n_states, n_states))
    chain = Chain(Q, absorb, start_cols, start_vals, start_abs,
                  int(np.unique(lev).size) if n_states else 0)
    lost = status == _plane.LOST_MASS
    logger.debug("plane chain: kappa %.3g, %d states, %d nonzeros, %d levels, %d fallbacks, "
                 "lost mass %s", kappa, n_states, Q.nnz, g["n_levels"], n_fallback, lost)
    return chain, (g["h1"], g["h2"]), lost
