"""scipy's L-BFGS-B on ``0 <= x <= upper`` without ``scipy.optimize.minimize``'s layers (private).

:func:`minimize_box` drives scipy's reverse-communication routine
``scipy.optimize._lbfgsb.setulb`` directly, with the settings, stopping tests
and callback logic of ``scipy.optimize.minimize(method="L-BFGS-B")``
(written for scipy 1.17; memory ``maxcor``, ``factr = ftol / eps`` with scipy's
default ``ftol`` unless another is given, ``pgtol = 0``, at most 20 line-search steps, the iteration and
evaluation limits checked after each iteration). Given the same objective it
takes the same iterates, bit for bit, and returns the same point, iteration
count, success flag and message. What it leaves out is scipy's work around the
routine: the bounds' conversions, ``ScalarFunction`` and ``MemoizeJac`` (their
copies and comparisons per evaluation), an ``OptimizeResult`` per iteration and
the inverse-Hessian operator at the end. On the MESC-IRL selection, a call of
about 30 short fits, that work was a quarter to a third of the CPU time
without slip and a sixth with slip.

``setulb`` is private to scipy. :func:`available` therefore runs a small
known problem once per process, through this driver and through
``scipy.optimize.minimize``, and answers True only when both give the same
iterates bit for bit and the same result; otherwise (another signature,
another behaviour, an import error) callers use ``minimize``
(:func:`minimize_box_scipy`, same settings).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from scipy.optimize import Bounds, minimize

_log = logging.getLogger(__name__)

try:  # private to scipy: checked by available() before use
    from scipy.optimize import _lbfgsb as _routine
    from scipy.optimize._lbfgsb_py import status_messages as _STATUS
    from scipy.optimize._lbfgsb_py import task_messages as _TASK
except Exception:  # pragma: no cover - depends on the scipy release
    _routine = None
    _STATUS = _TASK = {}

FTOL = 2.2204460492503131e-09  # scipy's default ftol of L-BFGS-B
MAXLS = 20  # scipy's default line-search limit
FIXED_MESSAGE = "All independent variables were fixed by bounds."  # scipy's message when lb == ub everywhere
HALT_MESSAGE = "`callback` raised `StopIteration`."  # scipy.optimize.minimize's message after a halt
_FG, _NEW_X, _CONVERGENCE, _STOP = 3, 1, 4, 5  # setulb's task codes
_STATE: dict[str, bool] = {}  # "ok": result of the check, made on first use


@dataclass(frozen=True)
class BoxResult:
    """Outcome of one L-BFGS-B run (private)."""

    x: np.ndarray
    nit: int
    nfev: int
    success: bool
    message: str


def minimize_box(fun, x0, upper, *, maxcor, maxiter, maxfun, callback=None, ftol=FTOL):
    """Minimise ``fun`` on ``0 <= x <= upper`` with scipy's L-BFGS-B routine, driven directly.

    ``fun(x)`` returns ``(f, gradient)`` (a float and a float64 array); it
    must not modify ``x``, which it may keep; ``upper`` is a float64 array (``inf``: no
    bound); ``callback(x)`` is called after each iteration and returns True to
    stop. The settings and results are those of ``scipy.optimize.minimize(fun,
    x0, jac=True, method="L-BFGS-B", bounds=Bounds(0, upper), options={"maxiter":
    maxiter, "gtol": 0.0, "maxfun": maxfun, "maxcor": maxcor, "ftol": ftol})`` with a
    callback that raises StopIteration where ours returns True. ``ftol = 0``
    turns the relative reduction test off.
    """
    n = x0.size
    low = np.zeros(n)
    high = np.array(upper, dtype=np.float64)
    if np.array_equal(low, high):  # scipy evaluates once at the bounds and stops
        fun(low.copy())
        return BoxResult(low, 0, 1, True, FIXED_MESSAGE)
    m = int(maxcor)
    nbd = np.where(np.isinf(high), 1, 2).astype(np.int32)  # 1: lower bound only, 2: both
    high[np.isinf(high)] = 0.0
    x = np.clip(np.array(x0, dtype=np.float64), 0.0, upper)
    # the evaluation at the start point, as scipy's ScalarFunction makes it before the first call
    last_x = x.copy()
    f, g = fun(last_x)
    nfev = 1
    f_in = np.array(0.0)
    g_in = np.zeros(n)
    wa = np.zeros(2 * m * n + 5 * n + 11 * m * m + 8 * m)
    iwa = np.zeros(3 * n, dtype=np.int32)
    task = np.zeros(2, dtype=np.int32)
    ln_task = np.zeros(2, dtype=np.int32)
    lsave = np.zeros(4, dtype=np.int32)
    isave = np.zeros(44, dtype=np.int32)
    dsave = np.zeros(29)
    factr = ftol / np.finfo(float).eps
    nit = 0
    halted = False
    while True:
        _routine.setulb(m, x, low, high, nbd, f_in, g_in, factr, 0.0, wa, iwa, task, lsave, isave, dsave,
                        MAXLS, ln_task)
        if task[0] == _FG:
            if not np.array_equal(x, last_x):  # scipy's ScalarFunction re-evaluates only at a new point
                last_x = x.copy()
                f, g = fun(last_x)
                nfev += 1
            f_in = f
            g_in = np.array(g, dtype=np.float64)
        elif task[0] == _NEW_X:
            nit += 1
            if callback is not None and callback(x):
                halted = True
                task[0], task[1] = _STOP, 505
            if nit >= maxiter:
                task[0], task[1] = _STOP, 504
            elif nfev > maxfun:
                task[0], task[1] = _STOP, 502
        else:
            break
    if halted:  # minimize reports a halt by the callback this way, whatever the routine's task
        return BoxResult(x, nit, nfev, False, HALT_MESSAGE)
    message = _STATUS[int(task[0])] + ": " + _TASK[int(task[1])]
    return BoxResult(x, nit, nfev, bool(task[0] == _CONVERGENCE), message)


def minimize_box_scipy(fun, x0, upper, *, maxcor, maxiter, maxfun, callback=None, ftol=FTOL):
    """:func:`minimize_box` through ``scipy.optimize.minimize`` (the reference, and the fallback)."""

    def halt(intermediate_result):
        if callback is not None and callback(intermediate_result.x):
            raise StopIteration

    res = minimize(
        fun, x0, jac=True, method="L-BFGS-B", bounds=Bounds(np.zeros(x0.size), upper), callback=halt,
        options={"maxiter": maxiter, "gtol": 0.0, "maxfun": maxfun, "maxcor": maxcor, "ftol": ftol},
    )
    return BoxResult(res.x, int(res.get("nit", 0)), int(res.nfev), bool(res.success), str(res.message))


def _known_problem(solver):
    """A small bounded problem (a quadratic plus a quartic, some bounds active): iterates and result."""
    rng = np.random.default_rng(7)
    a = rng.normal(size=(6, 6))
    h = a @ a.T + np.eye(6)
    b = rng.normal(size=6) * 3.0
    upper = np.array([np.inf, 0.5, np.inf, 2.0, 0.0, np.inf])
    seen = []

    def fun(x):
        seen.append(x.copy())
        return float(0.5 * x @ h @ x - b @ x + 0.1 * np.sum(x**4)), h @ x - b + 0.4 * x**3

    res = solver(fun, np.full(6, 0.3), upper, maxcor=4, maxiter=50, maxfun=1000, callback=lambda x: False)
    stopped = []

    def stop_early(x):
        stopped.append(x.copy())
        return len(stopped) >= 3

    early = solver(fun, np.full(6, 0.3), upper, maxcor=4, maxiter=50, maxfun=1000, callback=stop_early)
    return seen, res, early


def available():
    """Whether :func:`minimize_box` reproduces ``scipy.optimize.minimize`` (checked once per process)."""
    if "ok" not in _STATE:
        ok = False
        try:
            if _routine is not None:
                mine = _known_problem(minimize_box)
                ref = _known_problem(minimize_box_scipy)
                ok = _same(mine, ref)
        except Exception as exc:  # a changed private routine: fall back
            _log.debug("direct L-BFGS-B driver unavailable: %r", exc)
        if not ok:
            _log.info("scipy's L-BFGS-B routine is not the expected one; using scipy.optimize.minimize")
        _STATE["ok"] = ok
    return _STATE["ok"]


def _same(mine, ref):
    seen, res, early = mine
    seen_ref, res_ref, early_ref = ref
    same_path = len(seen) == len(seen_ref) and all(np.array_equal(p, q) for p, q in zip(seen, seen_ref))
    return same_path and all(
        np.array_equal(r.x, s.x) and (r.nit, r.nfev, r.success, r.message) == (s.nit, s.nfev, s.success, s.message)
        for r, s in ((res, res_ref), (early, early_ref))
    )
