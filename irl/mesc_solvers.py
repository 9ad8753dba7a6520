"""Optimisers of the MESC-IRL objective (private to :mod:`irl.mesc`).

Two solvers act on an :class:`irl.mesc.MESCObjective` (its ``_evaluate``
returns ``(L, dL/domega)`` without validation):

* :func:`lbfgsb` maximises ``L(omega) - l1 * sum(omega) - l2 / 2 * |omega|**2``
  over ``0 <= omega <= upper`` with some penalties held at zero (``free``),
  with scipy's L-BFGS-B (its routine driven by :mod:`irl._lbfgsb`) and an
  optional diagonal scaling. On the non-negative
  orthant the L1 term is linear, so the objective stays smooth.
* :func:`exponentiated_gradient` is the optimiser of the paper's public code:
  multiplicative ascent ``omega <- omega * exp(lr * g)`` with the gradient g
  clipped to norm ``clip``, from ``omega = init`` for at most ``steps`` steps.

Callers run them inside :func:`single_blas_thread`: L-BFGS-B's many tiny
vector operations otherwise wait on idle BLAS threads, which on a busy
machine made one iteration 100 times slower.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from threadpoolctl import ThreadpoolController

from . import _kernels, _lbfgsb

MAX_RESTARTS = 3  # restarts of L-BFGS-B stopped by its own tests above the tolerance (see lbfgsb)
_CONTROLLER: list[ThreadpoolController] = []  # one ThreadpoolController, made on first use (it scans the loaded libraries)


def single_blas_thread():
    """Context manager limiting BLAS libraries to one thread inside the block (restored on exit)."""
    if not _CONTROLLER:
        _CONTROLLER.append(ThreadpoolController())
    return _CONTROLLER[0].limit(limits=1, user_api="blas")


@dataclass(frozen=True)
class Fit:
    """Outcome of one solver run (private)."""

    penalties: np.ndarray
    value: float  # L at the penalties (the likelihood, without l1/l2 terms)
    gradient: np.ndarray  # dL/domega at the penalties
    n_iter: int
    converged: bool
    message: str


def _box(n, upper, free):
    """``upper`` and ``free`` as float and bool arrays of length n (inf: no bound; all free by default)."""
    high = np.full(n, np.inf) if upper is None else np.array(np.broadcast_to(upper, (n,)), dtype=np.float64)
    return high, np.ones(n, dtype=bool) if free is None else np.asarray(free, dtype=bool)


def projected_gradient_norm(w, grad, upper, free):
    """Largest violation of the first-order conditions of max grad . w on the box (free coordinates)."""
    return float(_kernels.projected_gradient_max(w, grad, *_box(w.size, upper, free)))


def lbfgsb(obj, w0, *, l1=0.0, l2=0.0, upper=None, free=None, scale=None, tol=1e-3, max_iter=1000, maxcor=40,
           tol_at=None):
    """Maximise the (penalised) likelihood with L-BFGS-B; see the module docstring.

    ``upper`` is None, a number or an array (``inf`` for no bound); ``free``
    (bool mask) holds the other penalties at zero; ``scale`` runs the
    solver on ``theta = omega / scale``. Converged means the projected gradient
    of the penalised objective is <= tol on the free coordinates, and
    nothing else; a start (clipped to the bounds) that meets the tolerance
    is returned as it is (``n_iter`` 0). ``tol_at``, if given, maps L at an
    iterate to the tolerance there (never below ``tol``).
    When L-BFGS-B stops by its own tests above the tolerance (the relative
    reduction of the objective below ``ftol``, or a line search that finds no
    decrease), it is restarted from its iterate with a fresh memory and the
    reduction test off, at most ``MAX_RESTARTS`` times and within
    ``max_iter`` iterations in all; a run that still ends above the
    tolerance is reported as not converged, its message saying where it
    stopped.
    scipy's routine is driven by
    :func:`irl._lbfgsb.minimize_box` (same iterates as
    ``scipy.optimize.minimize``, which is used when that driver is not
    available).
    """
    F = w0.size
    scaled = scale is not None
    scale = scale if scaled else np.ones(F)
    w0 = np.where(free, w0, 0.0) if free is not None else w0
    last = {}
    box = _box(F, upper, free)

    def violation(w, grad):
        return _kernels.projected_gradient_max(w, grad, *box)

    def penalised(w, value, grad):
        if l1:
            value -= l1 * float(w.sum())
            grad = grad - l1
        if l2:
            value -= 0.5 * l2 * float(w @ w)
            grad = grad - l2 * w
        return value, grad

    def fun(theta):
        # theta is the solver's own copy (neither solver path changes it later); with no scaling
        # theta * 1.0 and -grad * 1.0 would be theta and -grad bit for bit, so they are skipped
        w = theta * scale if scaled else theta
        loglik, grad = obj._evaluate(w)
        value, grad = penalised(w, loglik, grad)
        last["theta"], last["grad"], last["loglik"] = theta, grad, loglik
        return -value, (-grad * scale if scaled else -grad)

    done = {"converged": False}

    def tolerance(loglik):
        return tol if tol_at is None else max(tol, tol_at(loglik))

    def callback(theta):
        if "theta" in last and np.array_equal(theta, last["theta"]):
            if violation(theta * scale if scaled else theta, last["grad"]) <= tolerance(last["loglik"]):
                done["converged"] = True
                return True
        return False

    high = np.where(box[1], box[0] / scale, 0.0)  # the bounds of the solver's theta = omega / scale
    # a start that already meets the tolerance is the answer (L-BFGS-B would take one step first);
    # the solver's own first evaluation is this one, served from the objective's cache
    theta0 = np.clip(w0 / scale, 0.0, high)
    start = theta0 * scale if scaled else theta0
    value, grad = obj._evaluate(start)
    _, grad_pen = penalised(start, value, grad)
    if violation(start, grad_pen) <= tolerance(value):
        return Fit(start, float(value), grad, 0, True, "projected gradient <= tol at the start")
    solve = _lbfgsb.minimize_box if _lbfgsb.available() else _lbfgsb.minimize_box_scipy
    theta, nit, nfev, restarts, ftol = theta0, 0, 0, 0, _lbfgsb.FTOL
    while True:
        res = solve(fun, theta, high, maxcor=maxcor, maxiter=max_iter - nit, maxfun=20 * max_iter - nfev,
                    callback=callback, ftol=ftol)
        nit, nfev = nit + res.nit, nfev + res.nfev
        w = np.clip(res.x * scale, 0.0, upper)
        if free is not None:
            w[~free] = 0.0
        value, grad = obj._evaluate(w)  # the last iterate: usually served from the objective's cache
        _, grad_pen = penalised(w, value, grad)
        pg = violation(w, grad_pen)
        converged = done["converged"] or pg <= tolerance(value)
        limited = nit >= max_iter or nfev > 20 * max_iter
        if converged or limited or restarts >= MAX_RESTARTS or (restarts and np.array_equal(res.x, theta)):
            break
        # stopped by the routine's own tests above the tolerance: again from here, fresh memory, no reduction test
        theta, restarts, ftol = res.x, restarts + 1, 0.0
    if converged:
        message = "projected gradient <= tol"
    else:
        message = (f"projected gradient {pg:.3g} > tol {tolerance(value):.3g} after {restarts} restart"
                   f"{'' if restarts == 1 else 's'} ({res.message})")
    return Fit(w, float(value), grad, nit, bool(converged), message)


def exponentiated_gradient(obj, n_features, *, steps=500, lr=0.3, clip=10.0, init=1e-6, burn_in=50,
                           tol_step=1e-4, tol_gradient=1e-2, cap=200.0, l1=0.0):
    """The paper's optimiser: clipped exponentiated-gradient ascent of L.

    Each step computes g = dL/domega (minus ``l1``), rescales it to norm
    ``clip`` when longer, and sets ``omega <- omega * exp(lr * g)``; when the
    largest penalty exceeds ``cap`` all penalties are scaled down so that it
    equals ``cap``. After ``burn_in`` steps the run stops as soon as the
    largest change of a penalty is <= ``tol_step`` or the mean absolute
    gradient is <= ``tol_gradient``, and at ``steps`` steps in any case. It
    returns the iterate of smallest mean absolute gradient seen after
    ``burn_in`` steps. This is the rule of the paper's public code, with its
    defaults (steps 500, lr 0.3, clip 10, init 1e-6, burn-in 50, cap 200).
    """
    w = np.full(n_features, float(init))
    best, best_err = None, np.inf
    step = 0
    stopped = False
    if True:
        while step < steps:
            _, g = obj._evaluate(w)
            g = g - l1
            err = float(np.abs(g).mean())
            if step >= burn_in and err < best_err:
                best, best_err = w.copy(), err
            norm = float(np.linalg.norm(g))
            if clip is not None and norm > clip:
                g = g * (clip / norm)
            w_new = w * np.exp(lr * g)
            if cap is not None and w_new.max() > cap:
                w_new = w_new * (cap / w_new.max())
            delta = float(np.abs(w_new - w).max())
            w = w_new
            step += 1
            if step > burn_in and (delta <= tol_step or err <= tol_gradient):
                stopped = True
                break
    if best is None:
        best = w
    value, grad = obj._evaluate(best)
    message = "paper's stopping rule met" if stopped else f"{steps} steps done"
    return Fit(best, float(value), grad, step, stopped, message)

