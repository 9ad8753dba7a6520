"""Multi-start optimisation on the unit cube, checked against a coarse global screen.

:func:`multistart` minimises an objective over ``[0, 1]^k``:

1. a scrambled Sobol screen of the cube (the coarse global search) ranks candidate starts;
2. local optimisations (L-BFGS-B for smooth objectives, continued in small boxes where it
   stops on a slope; bounded Nelder-Mead otherwise) run from the given first start, the
   best screen point and the best, mutually distant other screen points;
3. the best optimum must be reached by at least two starts (within ``agree_tol``); if it is
   not, up to ``n_confirm`` further starts from the next best distant screen points try to
   reach it (or better). The best screen point is always a start, so no screened point is
   better than the optimum returned;
4. an optimum on a face of the cube is reported. A single start (``n_starts=1``) has no
   screen and nothing to agree with, so its optimum is never confirmed.

The outcome says whether the optimum is confirmed (:attr:`MultiStartOutcome.converged`);
the caller warns when it is not.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import optimize
from scipy.stats import qmc

from ._differences import ROUGH_MIN, gradient, hessian, rough_steps, room

__all__ = ["LocalRun", "MultiStartOutcome", "multistart"]

#: A coordinate within this distance of 0 or 1 is on a bound.
BOUND_TOL = 1e-3
#: Screen points closer than this (largest coordinate difference) to a chosen start are skipped.
_MIN_SPACING = 0.1
#: A smooth local run has stopped at an optimum where no component of its slope (the
#: gradient a move within the cube can follow) exceeds this times ``max(1, |f|)``.
_FLAT = 1e-3
#: Half-width of the first box a smooth run goes on in, the smallest, and the most boxes.
_BOX = 0.05
_MIN_BOX = 1e-3
_BOX_ROUNDS = 20
#: Finite-difference step of the gradient (unit-cube coordinates) on an objective that is
#: smooth only up to a relative noise (``noise > 0``): the default step of about 6e-6 would
#: difference the noise (``docs/fitting.md``, "Likelihoods smooth to a tolerance").
ROUGH_STEP = 3e-3
#: There, L-BFGS-B stops once the objective falls by less than this times the noise (of
#: itself): near the optimum the gradient, differenced over ROUGH_STEP, locates it better
#: than values within the noise can.
ROUGH_FTOL = 0.1
#: The Newton step's check of a rough run: values more than this above the run's end mean
#: the objective is not a bowl about it (see :func:`newton_gain`).
NEWTON_RISE = 100.0


@dataclass(frozen=True)
class LocalRun:
    """One local optimisation: start, optimum, value and the optimiser's report."""

    start: np.ndarray
    x: np.ndarray
    fun: float
    success: bool
    message: str
    n_iter: int


@dataclass(frozen=True)
class MultiStartOutcome:
    """What :func:`multistart` found and how far it can vouch for it."""

    best: LocalRun
    runs: tuple
    n_agree: int
    screen_best: float
    n_screen: int
    on_bound: tuple
    converged: bool
    problems: tuple


def _sobol(size, n, rng):
    m = max(1, math.ceil(math.log2(max(n, 2))))
    return qmc.Sobol(size, scramble=True, seed=rng).random_base2(m)[:n]


def _lbfgsb(objective, u0, lower, upper, max_iter, tol, noise=0.0):
    options = {"maxiter": max_iter, "ftol": max(tol, ROUGH_FTOL * noise), "gtol": 1e-7}
    if noise > 0.0:
        options["finite_diff_rel_step"] = ROUGH_STEP  # an absolute step: |u| <= 1
    return optimize.minimize(objective, u0, method="L-BFGS-B", jac="3-point",
                             bounds=list(zip(lower, upper)), options=options)


def flat_slope(f, noise):
    """The largest slope (unit-cube coordinates) at which a smooth run at the value ``f``
    counts as flat: :data:`_FLAT` times ``max(1, |f|)``, or, on an objective smooth only
    to the relative ``noise``, the larger error that noise puts in a gradient differenced
    over :data:`ROUGH_STEP`."""
    return max(_FLAT, 2.0 * noise / ROUGH_STEP) * max(1.0, abs(f))


def _slope(x, gradient):
    """The largest component of the gradient that a move within the unit cube can follow
    downhill (0 for one pointing out of a face the point lies on); inf if not finite."""
    g = np.array(gradient, dtype=np.float64)
    if not np.all(np.isfinite(g)):
        return math.inf
    g[(x <= 0.0) & (g > 0.0)] = 0.0
    g[(x >= 1.0) & (g < 0.0)] = 0.0
    return float(np.max(np.abs(g))) if g.size else 0.0


def newton_gain(objective, x, f):
    """What a Newton step from ``x`` (value ``f``) of a rough objective would gain,
    ``g^T H^-1 g / 2`` over the coordinates at least :data:`mdft._differences.ROUGH_MIN`
    from the faces of the cube, with the gradient differenced over :data:`ROUGH_STEP` and
    the Hessian over about a standard error (:func:`mdft._differences.rough_steps`); None
    where no coordinate is that far in, where a value differenced rises more than
    :data:`NEWTON_RISE` above ``f`` (the steps of about a standard error rise by about 1/2:
    the objective is no bowl there, e.g. impossible beyond a wall), or where the Hessian is
    not positive definite."""
    idx = np.array([i for i in range(x.size) if room(x, i) >= ROUGH_MIN], dtype=np.intp)
    if not idx.size:
        return None
    values = []

    def logged(u):
        values.append(float(objective(u)))
        return values[-1]

    g = gradient(logged, x, idx, [min(ROUGH_STEP, room(x, i)) for i in idx])
    H = hessian(logged, x, idx, rough_steps(logged, x, idx, f), f)
    if not all(math.isfinite(v) and v - f <= NEWTON_RISE for v in values):
        return None  # not a bowl about x (an impossible value, a wall, a cliff)
    try:
        np.linalg.cholesky(H)
    except np.linalg.LinAlgError:
        return None
    gain = 0.5 * float(g @ np.linalg.solve(H, g))
    return gain if math.isfinite(gain) else None


def _band(noise, f):
    """Values within this of ``f`` are within the objective's relative ``noise`` of it."""
    return 2.0 * noise * max(1.0, abs(f))


def _agreement(agree_tol, noise, best):
    """How close to the best value ``best`` another start's value agrees with it."""
    return max(agree_tol, _band(noise, best))


def _within_noise(objective, x, f, noise):
    """Where ``noise > 0`` and a Newton step from ``x`` would gain at most the noise's
    band, ``2 noise max(1, |f|)``: the words saying so; otherwise an empty string."""
    if not noise > 0.0:
        return ""
    band = _band(noise, f)
    gain = newton_gain(objective, x, f)
    if gain is None or gain > band:
        return ""
    return (f"within the likelihood's noise of the optimum (a Newton step would gain "
            f"{gain:.2g}, at most {band:.2g})")


def _smooth_local(objective, u0, max_iter, tol, noise=0.0):
    """L-BFGS-B on the unit cube, continued in boxes around its end while the likelihood
    still falls there.

    L-BFGS-B's first step follows the gradient as far as the cube allows; where that lands
    in a region the model cannot reach (the objective's impossible value), the line search
    can end back at the start and report convergence by "relative reduction" without having
    moved. Where the run ends with a slope above :data:`_FLAT` (times ``max(1, |f|)``), it
    goes on from there within a box of half-width :data:`_BOX` (doubled when the run ends on
    the box's edge, quartered when it gains nothing), for at most :data:`_BOX_ROUNDS` runs;
    the run is reported as converged only if it ends where the slope is flat. The boxes
    share the run's ``max_iter`` iterations.

    On an objective smooth only up to the relative ``noise`` (``noise > 0``), the gradient
    is differenced over :data:`ROUGH_STEP`, L-BFGS-B stops once the objective falls by
    less than :data:`ROUGH_FTOL` times ``noise`` of itself, and the slope is flat within
    :func:`flat_slope`. Values within the noise of each other do not tell which point is
    better, so a run can stop near the optimum on a point whose noise happens to be low,
    with a slope still above that: there the run counts as converged where a Newton step
    (:func:`newton_gain`) would gain no more than the noise's band, ``2 noise |f|``, before
    and after the boxes."""
    zeros, ones = np.zeros(u0.size), np.ones(u0.size)
    res = _lbfgsb(objective, u0, zeros, ones, max_iter, tol, noise)
    x, f = np.clip(res.x, 0.0, 1.0), float(res.fun)
    slope, n_iter = _slope(x, res.jac), int(res.nit)
    if slope <= flat_slope(f, noise):
        return x, bool(res.success), str(res.message), n_iter
    within = _within_noise(objective, x, f, noise)
    if within:
        return x, True, f"{res.message}; {within}", n_iter
    half, rounds, moved = _BOX, 0, False
    while (slope > flat_slope(f, noise) and rounds < _BOX_ROUNDS and half >= _MIN_BOX
           and n_iter < max_iter):
        rounds += 1
        lower, upper = np.maximum(x - half, 0.0), np.minimum(x + half, 1.0)
        sub = _lbfgsb(objective, x, lower, upper, max_iter - n_iter, tol, noise)
        n_iter += int(sub.nit)
        if not float(sub.fun) < f:
            half /= 4.0
            continue
        x, f, moved = np.clip(sub.x, lower, upper), float(sub.fun), True
        slope = _slope(x, sub.jac)
        edge = ((x <= lower) & (lower > 0.0)) | ((x >= upper) & (upper < 1.0))
        if np.any(edge):
            half = min(2.0 * half, 0.5)
    if slope <= flat_slope(f, noise):
        return x, True, f"{res.message}; continued in {rounds} boxes to a flat slope", n_iter
    # where no box gained, the Newton step's check before them stands (its 2 k^2 + 4 k
    # evaluations are not made again at the same point)
    within = _within_noise(objective, x, f, noise) if moved else ""
    if within:
        return x, True, f"{res.message}; continued in {rounds} boxes; {within}", n_iter
    if n_iter >= max_iter:
        return x, False, f"{max_iter} iterations (max_iter) reached", n_iter
    return x, False, (f"the local search stopped where the likelihood still changes along "
                      f"the cube (slope {slope:.3g} in unit-cube coordinates, after "
                      f"{rounds} boxes)"), n_iter


def _local(objective, u0, *, smooth, max_iter, tol, fatol, noise=0.0):
    if smooth:
        x, success, message, n_iter = _smooth_local(objective, u0, max_iter, tol, noise)
    else:
        bounds = [(0.0, 1.0)] * u0.size
        res = optimize.minimize(objective, u0, method="Nelder-Mead", bounds=bounds,
                                options={"maxiter": max_iter * u0.size, "xatol": 1e-4,
                                         "fatol": fatol, "adaptive": u0.size > 3})
        x = np.clip(res.x, 0.0, 1.0)
        success, message, n_iter = bool(res.success), str(res.message), int(getattr(res, "nit", 0))
    return LocalRun(start=np.array(u0), x=x, fun=float(objective(x)), success=success,
                    message=message, n_iter=n_iter)


def _spread(points, taken, k):
    """Up to ``k`` of ``points`` (best first) at least ``_MIN_SPACING`` from ``taken`` and
    from each other; filled up with the closest ones if too few are far enough."""
    chosen, rest = [], []
    anchors = list(taken)
    for i, x in enumerate(points):
        if len(chosen) == k:
            break
        if all(np.max(np.abs(x - a)) >= _MIN_SPACING for a in anchors):
            chosen.append(i)
            anchors.append(x)
        else:
            rest.append(i)
    return chosen + rest[: k - len(chosen)]


def multistart(objective, first, *, n_starts, n_screen, rng, smooth, max_iter, tol, fatol,
               agree_tol, n_confirm=2, noise=0.0):
    """Minimise ``objective`` over the unit cube from several starts; see the module docs.

    Parameters
    ----------
    objective : callable
        ``f(u) -> float`` for ``u`` in ``[0, 1]^k``.
    first : ndarray, shape (k,)
        The first start.
    n_starts : int
        Local optimisations (the first start and ``n_starts - 1`` screened ones).
    n_screen : int
        Sobol points of the screen (0: no screen; then no further starts).
    rng : numpy.random.Generator
        Scrambles the Sobol sequence.
    smooth : bool
        L-BFGS-B with finite-difference gradients if True, else bounded Nelder-Mead.
    max_iter, tol, fatol : optimiser settings.
    agree_tol : float
        Two optima agree when their objective values differ by at most this, or by at
        most the noise's band ``2 noise |f|`` of the best value where that is larger.
    n_confirm : int
        Extra starts when the best optimum was reached only once.
    noise : float
        Relative noise up to which a smooth objective is smooth (0: smooth to rounding);
        see :func:`_smooth_local`.

    Returns
    -------
    MultiStartOutcome
    """
    first = np.asarray(first, dtype=np.float64)
    size = first.size
    kw = dict(smooth=smooth, max_iter=max_iter, tol=tol, fatol=fatol, noise=noise)
    screen = np.empty((0, size))
    values = np.empty(0)
    if n_screen and n_starts > 1:
        screen = _sobol(size, n_screen, rng)
        values = np.array([objective(u) for u in screen])
        order = np.argsort(values, kind="stable")
        screen, values = screen[order], values[order]
    screen_best = float(values[0]) if values.size else math.inf
    used = set()
    if values.size and n_starts > 1:
        # the best screen point is always a start, even near the first one (which may lie
        # in another basin); the others are spread out from both
        used = {0, *(i + 1 for i in _spread(screen[1:], [first, screen[0]], n_starts - 2))}
    runs = [_local(objective, first, **kw)]
    runs += [_local(objective, screen[i], **kw) for i in sorted(used)]

    def agreeing():
        best = min(r.fun for r in runs)
        return sum(r.fun <= best + _agreement(agree_tol, noise, best) for r in runs)

    extra = 0
    while n_starts > 1 and agreeing() < 2 and extra < n_confirm and len(used) < len(screen):
        nxt = [i for i in _spread(screen, [screen[i] for i in used] + [first], len(screen))
               if i not in used][:1]
        if not nxt:
            break
        used.add(nxt[0])
        runs.append(_local(objective, screen[nxt[0]], **kw))
        extra += 1

    best = min(runs, key=lambda r: r.fun)
    n_agree = agreeing()
    on_bound = tuple(int(i) for i in np.flatnonzero((best.x < BOUND_TOL) |
                                                     (best.x > 1.0 - BOUND_TOL)))
    problems = []
    # a run that reached the best value and met its criterion vouches for the best one (an
    # L-BFGS-B line search can end "abnormally" a rounding error away from the optimum)
    agree_tol = _agreement(agree_tol, noise, best.fun)
    if not any(r.success for r in runs if r.fun <= best.fun + agree_tol):
        problems.append(f"the best start did not converge ({best.message})")
    if n_starts == 1:
        problems.append("a single start: its optimum was not checked against a screen or "
                        "other starts (n_starts >= 2 checks it)")
    elif n_agree < 2:
        problems.append(
            f"the starts disagree: only one of {len(runs)} reached the best log-likelihood "
            f"(within {agree_tol:g})"
        )
    converged = not problems and not on_bound
    return MultiStartOutcome(best=best, runs=tuple(runs), n_agree=int(n_agree),
                             screen_best=screen_best, n_screen=int(values.size),
                             on_bound=on_bound, converged=converged, problems=tuple(problems))
