"""The moment chain of three-option threshold stopping.

Python side of the compiled kernels in :mod:`mdft._plane_moment` (the build) and
:mod:`mdft._plane_step` (the steps): chooses the grid of the zero-sum plane from the
model and a resolution ``kappa`` (cell size in per-step standard deviations), applies
the variance correction, builds and runs the chain, and fits the reference sums for the
next pass.
Inputs are validated by :func:`mdft.threshold_probabilities`;
``docs/threshold_exact.md`` describes the method.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numba
import numpy as np
import scipy.sparse as sp

from . import _plane_moment, _plane_step
from ._lattice_chain import (TooManyStates, chain_sum_bounds, pair_parameters,
                             sum_is_constant)
from ._plane_krylov import krylov_tail
from ._threads import configured_threads

logger = logging.getLogger(__name__)

# Each component's Gaussian keeps a standard deviation of at least this many cells.
_MIN_SD_CELLS = 0.5
# At least this many cells per theta along each axis (kappa = 1).
_MIN_CELLS_PER_THETA = 6.0
# Spacing (in finer cells) of the summed-preference levels that plane_geometry reports; the
# moment chain only uses their count (more than one: the feedback moves the sum).
_LEVEL_FACTOR = 1.0
# Largest index box (levels x cells x cells) the builder may allocate.
_MAX_BOX = 40_000_000
# With more than one numba thread, chains with at least this many nonzeros are propagated in
# parts (mdft._plane_step.PARTS of them whatever the number of threads, so that the sums are
# the same for any number above one); smaller ones, and all on one thread, serially: waking
# the threads costs more than it saves, and parts on one thread cost 10-30 % more.
_PARTS_MIN_NONZEROS = 20_000
# A finer pass gives rows only to the cells near the states the coarser pass occupied: summed
# over its steps, at least this much probability, within _NEAR_SD per-step standard deviations
# and one coarse cell (mdft.threshold_exact rebuilds with every row when more than
# _ESCAPE_MAX of the mass reaches a state without one).
_NEAR_OCCUPATION = 1e-14
_NEAR_SD = 2.0
# The closure's plane probe takes each cell's reference sum from the mean sum of the walks
# in it where the cell held at least this share of the occupation (mean_sums); elsewhere
# from the fitted plane.
_MAP_OCCUPATION = 1e-9
# Cells of work space (8 bytes each) the build's parallel parts may allocate together.
_PART_WORK_CELLS = 12_000_000
# Room for a source's cells in the build's first block (widened as it meets wider sources).
_FIRST_SLOT = 256
# A pass first tries the Krylov tail (mdft._plane_krylov) after this many steps, then after
# every doubling of them, with Krylov spaces capped at these dimensions in turn (grown past
# the cap only where that is predicted to cost less than the steps to the next try; a try
# that fails costs its dimensions; in between, the geometric tail goes on being checked).
# Where the pilots say the walks settle late (``early``), the first try comes after
# _KRYLOV_EARLY steps; the caps count from there (_KRYLOV_DIMS[0] for a try at
# _KRYLOV_EARLY, _KRYLOV_DIMS[1] at _KRYLOV_FIRST, and so on).
_KRYLOV_FIRST = 250
_KRYLOV_EARLY = 125
_KRYLOV_DIMS = (40, 60, 100, 120)
_KRYLOV_PARTS_MIN_NONZEROS = 1_000_000
# A pilot pass (``second``) checks every _PILOT_CHUNK steps that its moment closure is not
# running away: the signed sum of the choices so far and of the undecided mass is 1 by
# construction, but the linearised choices and masses may turn negative, and then the sum of
# their sizes exceeds 1. A pilot's crude reference sums make that common and passing (up to
# 0.15 on 40 random models, falling back within a few hundred steps); a closure that runs
# away grows it geometrically, past 1e3 by step 1,000. From the first chunk where it exceeds
# PILOT_RUNAWAY the pass stops, with the occupation of the chunks before.
_PILOT_CHUNK = 25
PILOT_RUNAWAY = 1.0


def narrow_axes(g):
    """The grid axes of ``plane_geometry`` output ``g`` along which the noise is narrower
    than the cells over ``sqrt(3)`` (where a pass is not trusted)."""
    return np.flatnonzero(g["sd_exact"] < np.array([g["h1"], g["h2"]]) / math.sqrt(3.0))


def plane_geometry(model, theta, kappa, margin=0.0):
    """Grid, corrected kernel and absorption parameters for resolution ``kappa``.

    The grid covers the transient region down to a summed preference ``margin``
    below its lower bound.
    """
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
        s_lo, s_hi, hs, n_levels = s0, s0, 1.0, 1
    else:
        s_lo, s_hi = chain_sum_bounds(S, theta, s0)
        hs = _LEVEL_FACTOR * h.min()
        n_levels = max(2, int(math.ceil((s_hi - s_lo) / hs)) + 1)
        hs = (s_hi - s_lo) / (n_levels - 1)
    verts = theta * np.ones((3, 3)) - (3 * theta - (s_lo - margin)) * np.eye(3)
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
        hs=float(hs), n_levels=int(n_levels), s_hi=float(s_hi), sd_opt=sd_opt, pair_sd=pair_sd,
        pair_rho=pair_rho,
    )


# ------------------------------------------------------------------ moment chain
@dataclass(frozen=True)
class MomentChain:
    """The moment chain (:mod:`mdft._plane_moment`): rows ``T0 + (s - sref) T1`` (CSR
    arrays), choices ``R0 + (s - sref) R1``, and the first step from the exact start."""

    row_ptr: np.ndarray
    cols: np.ndarray
    t0: np.ndarray
    t1: np.ndarray
    r0: np.ndarray
    r1: np.ndarray
    pos: np.ndarray
    sref: np.ndarray
    snext: np.ndarray
    b_sum: float
    start_cols: np.ndarray
    start_vals: np.ndarray
    start_absorbed: np.ndarray
    start_snext: float
    h: tuple
    moving: bool
    delta: float
    #: States without a row (outside ``build_moment_chain``'s ``near``): mass reaching one
    #: leaves the chain and is counted by :func:`propagate_moments`.
    frontier: np.ndarray
    #: Per-step standard deviation of the model's own Gaussian along the two grid axes.
    step_sd: tuple
    #: Centre of the grid's cell (0, 0) and the index box's size (cells along each axis).
    origin: tuple = (0.0, 0.0)
    box: tuple = (0, 0)
    #: The noise is narrower than the cell over sqrt(3) along either axis: the variance
    #: correction then takes width from the attention jumps along it, and answers at this
    #: grid are not trusted (``docs/threshold_exact.md``, section 8).
    narrow: bool = False

    @property
    def n_states(self):
        return self.pos.shape[0]


def _build_parts(box):
    """Parts the build evaluates its sources in: one per numba thread (at most 8), while
    their work space (three arrays the size of the index box each) stays within
    ``_PART_WORK_CELLS``. The chain does not depend on it."""
    return int(max(1, min(numba.get_num_threads(), 8, _PART_WORK_CELLS // (3 * box))))


def build_moment_chain(model, theta, kappa, ref, delta, max_states, near=None, ref_map=None,
                       edge=False):
    """The moment chain at resolution ``kappa`` with reference sums ``ref`` (see
    :func:`mdft._plane_moment.build`) and spread ``delta``.

    ``near = (points, (r1, r2))``: only the cells within ``r1`` and ``r2`` (along the grid
    axes) of one of ``points`` (rows ``(z1, z2)``) get rows; the other states reached are
    frontier states (:class:`MomentChain`). None: every state reached gets its row.
    ``ref_map``: :func:`mean_sums` of a pass (the closure's plane probe passes this grid's
    own), whose cells' mean sums replace the plane ``ref`` as the reference sums of the
    cells they cover (None: the plane everywhere). ``edge``: add the edge terms to the rows
    (:mod:`mdft._plane_boundary`).

    Raises TooManyStates when the reachable states exceed ``max_states`` or a
    step lands outside every cell.
    """
    g = plane_geometry(model, theta, kappa, margin=2.0 * delta + 1.0)
    moving = g["n_levels"] > 1
    if not moving:
        ref, delta = np.array([g["s_start"], 0.0, 0.0]), 0.0
    box = g["n1"] * g["n2"]
    if box > _MAX_BOX:
        raise TooManyStates(
            f"resolution {kappa:.3g} needs an index box of {box} cells (limit {_MAX_BOX})"
        )
    allowed = np.zeros((0, 0), dtype=np.bool_)
    if near is not None:
        allowed = np.zeros((g["n1"], g["n2"]), dtype=np.bool_)
        points, (r1, r2) = near
        _plane_moment.mark_near(allowed, np.ascontiguousarray(points, dtype=np.float64),
                                g["o1"], g["o2"], g["h1"], g["h2"], float(r1), float(r2))
    no_map = (np.zeros((0, 0)), (0.0, 0.0, 1.0, 1.0))
    cells_map, map_grid = no_map if ref_map is None else ref_map
    out = _plane_moment.build(
        g["z_start"], g["s_start"], g["S"], g["E"], g["CM"], g["w"], g["shrunk"], g["sd_cell"],
        g["exact"], g["sd_exact"], g["theta"], g["o1"], g["o2"], g["h1"], g["h2"], g["n1"],
        g["n2"], g["sd_opt"], g["pair_sd"], g["pair_rho"], np.asarray(ref, dtype=np.float64),
        g["s_lo"], g["s_hi"], float(delta), max_states, _build_parts(box), _FIRST_SLOT,
        allowed, np.ascontiguousarray(cells_map, dtype=np.float64),
        tuple(float(v) for v in map_grid), bool(edge),
    )
    (status, pos, sref, snext, row_ptr, cols, t0, t1, r0, r1, start_cols, start_vals,
     start_abs, start_snext, frontier) = out
    if status == _plane_moment.TOO_MANY_STATES:
        raise TooManyStates(f"resolution {kappa:.3g} reaches more than {max_states} states")
    if status == _plane_moment.LOST_MASS:
        raise TooManyStates(f"at resolution {kappa:.3g} some step lands outside every grid cell")
    b_sum = float(g["S"].sum()) / 3.0
    logger.debug("moment chain: kappa %.3g, %d states, %d nonzeros, delta %.3g",
                 kappa, pos.shape[0], cols.shape[0], delta)
    # the kernel writes 32-bit column indices: a quarter less memory traffic per propagated step
    narrow = narrow_axes(g).size > 0
    return MomentChain(row_ptr, cols, t0, t1, r0, r1, pos, sref, snext,
                       b_sum, start_cols, start_vals, start_abs, float(start_snext),
                       (g["h1"], g["h2"]), moving, float(delta), frontier,
                       (float(g["sd_exact"][0]), float(g["sd_exact"][1])),
                       (g["o1"], g["o2"]), (g["n1"], g["n2"]), narrow)


def tail_track(max_steps, n_states):
    """Fresh state of the tail's checks for :func:`mdft._plane_step.propagate` (its
    ``hazard``, ``done``, ``snaps`` and ``dist``), carried across a pass's pauses."""
    return (np.zeros(max_steps), np.zeros((2, 3)), np.zeros((2, n_states)),
            np.full((3, 2), -1.0))


def pilot_pass(chain, max_steps, tol, budget=(0.0, 0.0), floor=0.01):
    """A pilot pass (:func:`propagate_moments` with ``second``) and whether it was cut
    because its moment closure ran away: ``(answer, cut)``. A cut pass's occupation is that
    of its first ``answer[2]`` steps (which may be none); the rest of its answer is not one.
    """
    return _propagate(chain, max_steps, tol, budget, True, floor, None, False)


def propagate_moments(chain, max_steps, tol, budget=(0.0, 0.0), second=False, floor=0.01,
                      in_parts=None, krylov=True, krylov_from=None, escape_max=math.inf,
                      early=False):
    """Run the moment chain; ``(rt_pmf, p_undecided, steps, tail_start, occupation,
    tail_errors, escaped)``.

    ``budget = (atol, rtol)``: the change that filling the tail (geometrically, or from a
    Krylov space: :mod:`mdft._plane_krylov`) may make to the probabilities and (relative)
    to the mean response times (0: no tail; :mod:`mdft._plane_tail`); ``tail_errors`` is
    the change estimated where it was filled, and (third) the size of the negative choices
    and undecided mass clipped (:func:`_clip_negative`). ``occupation[:, 0]`` is each state's
    probability summed over the steps; ``second`` also carries the second moment of the
    sum and its occupation (``occupation[:, 1:]``, a pilot pass, which fills no Krylov
    tail, and stops at the first of its chunks of ``_PILOT_CHUNK`` steps where the sizes of
    the choices and of the undecided mass sum to more than ``1 + PILOT_RUNAWAY``: the
    occupation is then that of the chunks before, and ``steps`` their number of steps).
    ``escaped``: the mass that reached frontier states and left the chain
    (:func:`build_moment_chain`'s ``near``). ``floor``: mean response times of options
    chosen less often weigh in proportionally. ``in_parts``: run each step in parts on
    numba's threads (None: with more than one thread configured, for chains of at least
    ``_PARTS_MIN_NONZEROS`` nonzeros; on a busy machine the parts run on one thread,
    :mod:`mdft._threads`); in parts the answer is the same whatever the
    number of threads, and differs from the serial one by rounding (the parts' sums are
    added in another order). ``krylov``: try the Krylov tail after ``_KRYLOV_FIRST`` steps,
    and after every doubling of them, until it is within the budget; ``krylov_from``: the
    step where a coarser pass of the same model filled its tail (None: none did), whose
    failed tries are left out (:func:`krylov_start`); ``early``: the first try comes after
    ``_KRYLOV_EARLY`` steps instead (where a coarser pass filled no tail or one before
    that). ``escape_max``: once more mass than
    this has reached frontier states the run stops there, its answer incomplete (``escaped``
    above ``escape_max`` says so; the caller builds the pass again with every row).
    """
    return _propagate(chain, max_steps, tol, budget, second, floor, in_parts, krylov,
                      krylov_from, escape_max, early)[0]


def krylov_start(tail_start, early=False):
    """The first step at which a finer pass tries the Krylov tail, given where a coarser
    pass of the same model filled its tail (``tail_start``; None: it filled none), so that
    the finer pass leaves out the tries that failed on the coarser grid: a tail filled at a
    point of the tries' schedule (``_KRYLOV_FIRST``, doubled) is a Krylov tail, and the
    finer pass tries first there; a tail filled between two points is a geometric one,
    after the try at the first of them failed, and the finer pass tries first at the
    second. A finer grid's walks settle no earlier (on seed 8383 of the benchmark's draws,
    the tries that failed took 7 % of the time of all calls, 15-17 % of the slowest).
    ``early``: the schedule starts at ``_KRYLOV_EARLY`` instead of ``_KRYLOV_FIRST``."""
    first = _KRYLOV_EARLY if early else _KRYLOV_FIRST
    while tail_start is not None and 2 * first <= tail_start:
        first *= 2
    if tail_start is not None and tail_start > first:
        first *= 2  # the try at first failed: the tail that followed is geometric
    return first


def _propagate(chain, max_steps, tol, budget, second, floor, in_parts, krylov,
               krylov_from=None, escape_max=math.inf, early=False):
    """:func:`propagate_moments`'s answer, and whether a pilot pass was cut short."""
    n = chain.n_states
    x = np.zeros(n)
    np.add.at(x, chain.start_cols, chain.start_vals)
    m = x * chain.start_snext
    q = x * chain.start_snext**2
    rt_pmf = np.zeros((max_steps, 3))
    rt_pmf[0] = chain.start_absorbed
    occ = np.zeros((n, 3))
    errors = np.zeros(3)
    if in_parts is None:
        in_parts = configured_threads() > 1 and chain.cols.shape[0] >= _PARTS_MIN_NONZEROS
    use_krylov = krylov and not second and budget[0] > 0.0
    pause = min(krylov_start(krylov_from, early), max_steps) if use_krylov else max_steps
    # the tries left out count as made: the dimensions go on from there
    tries = (pause // _KRYLOV_EARLY).bit_length() - 1 if use_krylov else 0
    if second:
        pause = min(_PILOT_CHUNK, max_steps)
        kept = occ.copy()
    cut = False
    track = tail_track(max_steps, n)
    t_first = 1
    dropped = escaped = 0.0
    while True:
        steps, tail_start, mass = _plane_step.propagate(
            chain.row_ptr, chain.cols, chain.t0, chain.t1, chain.r0, chain.r1, chain.sref,
            chain.snext, chain.b_sum, chain.delta**2, x, m, q, rt_pmf, occ, tol,
            bool(second), float(budget[0]), float(budget[1]), float(floor), errors,
            bool(in_parts), chain.frontier, pause, t_first, *track, escape_max - escaped)
        escaped += errors[2]
        if escaped > escape_max:
            break  # stopped where the escaped mass passed escape_max: no answer
        dropped += errors[0]  # with the geometric tail's change, if it was filled
        if second:
            balance = float(np.abs(rt_pmf[:steps]).sum() + np.abs(x).sum() + escaped) - 1.0
            if not balance <= PILOT_RUNAWAY:
                kept_steps = t_first if t_first > 1 else 0  # the chunks before this one
                logger.debug("pilot pass: the sizes of the choices and of the undecided mass "
                             "sum to 1 %+.2g after %d steps; the occupation of the first %d "
                             "steps is kept", balance, steps, kept_steps)
                occ[:] = kept
                steps = kept_steps
                errors[0] = dropped
                cut = True
                break
            kept[:] = occ
        if tail_start < max_steps or steps != pause or pause >= max_steps:
            errors[0] = dropped  # a tail filled, decided, or at the step limit
            break
        if second:
            t_first, pause = pause, min(pause + _PILOT_CHUNK, max_steps)
            continue
        # between the Krylov steps the threads go idle, and waking them costs more than
        # running the parts saves below _KRYLOV_PARTS_MIN_NONZEROS
        tail = krylov_tail(chain, x, m, pause, rt_pmf, budget, floor,
                           in_parts and chain.cols.shape[0] >= _KRYLOV_PARTS_MIN_NONZEROS,
                           _KRYLOV_DIMS[min(tries, len(_KRYLOV_DIMS) - 1)],
                           min(2 * pause, max_steps) - pause)
        if tail is not None:
            mass, occupation, lost, (err_p, err_rt), dim = tail
            occ[:, :2] += occupation
            escaped += lost
            errors[:2] = (dropped + err_p, err_rt)
            steps, tail_start = pause + dim, pause
            break
        t_first, pause, tries = pause, min(2 * pause, max_steps), tries + 1
    errors[2] = escaped
    mass, clipped = _clip_negative(rt_pmf, float(mass))
    return (rt_pmf, mass, int(steps), int(tail_start), occ,
            (float(errors[0]), float(errors[1]), clipped), float(errors[2])), cut


def _clip_negative(rt_pmf, mass):
    """Clip the negative choices and undecided mass of a moment chain's answer (in place)
    and scale what is left back to a distribution; returns ``(mass, clipped)``.

    Where a state's mean sum lies far from its reference, the linearised choices
    ``R0 + (s - sref) R1`` can turn negative: the signed answer still sums to 1, and the
    walks counted on the other options make up for the negative part. A probability is
    never negative, so the negative part is set to zero, the rest scaled to sum to 1 with
    the undecided mass (the mean times do not change), and the size of the negative part
    (``clipped``) is part of the answer's error: it is the closure's error made visible.
    """
    negative = rt_pmf < 0.0
    clipped = float(-rt_pmf[negative].sum()) + max(-mass, 0.0)
    if clipped == 0.0:
        return mass, 0.0
    rt_pmf[negative] = 0.0
    mass = max(mass, 0.0)
    total = float(rt_pmf.sum()) + mass
    if total > 0.0:
        rt_pmf /= total
        mass /= total
    return mass, clipped


def near_occupied(chain, occ):
    """``near`` for the next, finer pass (:func:`build_moment_chain`): the states of
    ``chain`` whose summed probability over the steps (``occ[:, 0]``) reaches
    ``_NEAR_OCCUPATION``, and a reach of ``_NEAR_SD`` per-step standard deviations plus
    one of this chain's cells along each axis."""
    points = chain.pos[occ[:, 0] >= _NEAR_OCCUPATION]
    reach = tuple(_NEAR_SD * sd + h for sd, h in zip(chain.step_sd, chain.h))
    return points, reach


def mean_sums(chain, occ):
    """``ref_map`` (:func:`build_moment_chain`) of the closure's plane probe: the mean sum
    of the walks in each cell of ``chain`` over the steps (``occ[:, 1] / occ[:, 0]``) where
    the cell held at least ``_MAP_OCCUPATION`` of the summed occupation, NaN elsewhere,
    and the grid ``(o1, o2, h1, h2)``; None when the sum does not move. A plane through
    the mean sums leaves the walks' sums several units away from their reference where
    the sum depends on the path (seed 1313 model 5 of the benchmark's draws: 1.8 in rms,
    and the probability of an option chosen 2 % of the time 0.0015 low); each cell's own
    mean sum brings them within 0.3, and the change that makes to the answer is the
    probe's term (``docs/threshold_exact.md``, section 4)."""
    if not chain.moving:
        return None
    held = occ[:, 0]
    total = float(held[held > 0.0].sum())
    good = held > _MAP_OCCUPATION * total
    n1, n2 = chain.box
    grid = np.full((n1, n2), np.nan)
    a = np.floor((chain.pos[good, 0] - chain.origin[0]) / chain.h[0] + 0.5).astype(np.int64)
    b = np.floor((chain.pos[good, 1] - chain.origin[1]) / chain.h[1] + 0.5).astype(np.int64)
    inside = (a >= 0) & (a < n1) & (b >= 0) & (b < n2)
    grid[a[inside], b[inside]] = occ[good, 1][inside] / held[good][inside]
    return grid, (chain.origin[0], chain.origin[1], chain.h[0], chain.h[1])


#: A spread of the states' mean sums that moves the thresholds by at most this share of a
#: cell is immaterial (:func:`reference_sums`).
_SUM_SPREAD_FLOOR = 0.01


def reference_sums(chain, occ):
    """Reference-sum map ``(r0, r1, r2)``, spread ``delta`` for the next pass, and whether
    the spread could be measured.

    A weighted least-squares fit of the states' mean sums on their positions
    (weights: occupation), and the root of the occupation-weighted mean of the
    sum's variance within the states. That variance comes from the second moment the
    pilot carries with ``T0`` alone, and is clipped at 0 where it comes out negative.
    Where the walks' sums stray far from the reference sums (a starting preference whose
    sum lies far from the sums the walks settle to) it can come out negative in every
    state. Where the states' mean sums then still differ (their weighted standard
    deviation, over 3, above :data:`_SUM_SPREAD_FLOOR` of the smaller cell size: the sum
    moves the thresholds), the spread is not measured (False), as ``delta = 0`` would
    leave the chain no slope in the sum to follow.
    """
    wx = occ[:, 0]
    good = wx > 1e-12 * max(wx.sum(), 1e-300)
    if not chain.moving or good.sum() < 3:
        return np.array([chain.start_snext if chain.moving else 0.0, 0.0, 0.0]), 0.0, True
    W = wx[good]
    mean = occ[good, 1] / W
    raw = occ[good, 2] / W - mean**2
    X = np.c_[np.ones(W.size), chain.pos[good]]
    root = np.sqrt(W)
    coef = np.linalg.lstsq(X * root[:, None], mean * root, rcond=None)[0]
    delta = float(np.sqrt(np.sum(W * np.clip(raw, 0.0, None)) / W.sum()))
    if delta > 0.0:
        return coef, delta, True
    centre = np.sum(W * mean) / W.sum()
    moves = math.sqrt(np.sum(W * (mean - centre) ** 2) / W.sum()) / 3.0
    return coef, delta, bool(moves <= _SUM_SPREAD_FLOOR * min(chain.h))


def solve_moments(chain, tol, max_iter, krylov):
    """Long-run probabilities and weighted times of the moment chain (linear solves):
    ``(probabilities, weighted, n_iter, converged, clipped, occupation)``; ``occupation``
    (n_states, 2) holds ``x`` and ``m`` summed over every step, as
    :func:`propagate_moments`'s first two columns (the first solve's answer)."""
    n = chain.n_states
    T0 = sp.csr_matrix((chain.t0, chain.cols, chain.row_ptr), shape=(n, n))
    T1 = sp.csr_matrix((chain.t1, chain.cols, chain.row_ptr), shape=(n, n))
    Dr = sp.diags(chain.sref)
    Dn = sp.diags(chain.snext)
    b = chain.b_sum
    # new (x, m) = G (x, m): see the module docstring of mdft._plane_moment
    G = sp.bmat([[T0.T - T1.T @ Dr, T1.T],
                 [T0.T @ (Dn - b * Dr) - T1.T @ (Dn @ Dr - b * chain.delta**2 * sp.identity(n)),
                  b * T0.T + T1.T @ Dn]]).tocsr()
    A = (sp.identity(2 * n, format="csr") - G).tocsr()
    x1 = np.zeros(n)
    np.add.at(x1, chain.start_cols, chain.start_vals)
    rhs = np.concatenate([x1, x1 * chain.start_snext])
    y, ok1, it1 = krylov(A, rhs, tol, max_iter)
    y2, ok2, it2 = krylov(A, y, tol, max_iter)
    Rx = chain.r0 - chain.r1 * chain.sref[:, None]
    Rm = chain.r1

    def absorbed(v):
        return Rx.T @ v[:n] + Rm.T @ v[n:]

    probs = chain.start_absorbed + absorbed(y)
    weighted = chain.start_absorbed + absorbed(y + y2)
    # as _clip_negative: an option whose linearised probability is negative is never chosen;
    # the rest is scaled back to 1, and the negative part counts as error
    clipped = float(-probs[probs < 0.0].sum())
    weighted = np.where(probs > 0.0, np.maximum(weighted, 0.0), 0.0)
    probs = np.maximum(probs, 0.0)
    if clipped > 0.0 and probs.sum() > 0.0:
        scale = 1.0 / max(float(probs.sum()), 1.0)
        probs, weighted = probs * scale, weighted * scale
    return probs, weighted, it1 + it2, ok1 and ok2, clipped, np.c_[y[:n], y[n:]]
