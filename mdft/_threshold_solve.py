"""Solving a threshold chain, and comparing two answers (``docs/threshold_exact.md``,
sections 4 and 5).

Two options: the lattice chain (:mod:`mdft._lattice_chain`) step by step with its
geometric tail, or as a linear system (``method="solve"``); the linear solver is shared
with the three-option moment chain. The comparison of two answers is the error estimate of
section 4.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from . import _lattice
from ._threshold_fallback import RT_WEIGHT_FLOOR
from .threshold_result import ThresholdProbabilities

#: ``method="solve"``: a direct factorisation up to this many states, iterative beyond.
DIRECT_SOLVE_MAX_STATES = 3_000


def mean_rt(weighted, probs):
    """Mean decision steps ``weighted / probs``; NaN for an option never chosen, and for one
    chosen so rarely that its mean comes out below one step (a mean the chain's rounding
    does not resolve: every decision takes at least one step)."""
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = weighted / np.where(probs > 0, probs, 1.0)
    return np.where((probs > 0) & (mean >= 1.0), mean, np.nan)


def solve_chain(chain, theta, spacing, spec, *, method, max_steps, tol, tail_tol, max_iter):
    common = dict(theta=theta, n_cells=int(spec.get("n_cells", math.ceil(theta / spacing))),
                  spacing=float(spacing), n_levels=chain.n_levels, n_states=chain.Q.shape[0],
                  engine=spec["engine"], resolution=float(spec["resolution"]))
    if method == "propagate":
        return _propagate(chain, max_steps, tol, tail_tol, common)
    return _solve(chain, tol, max_iter, common)


def _propagate(chain, max_steps, tol, tail_tol, common):
    n = chain.R.shape[1]
    Q = chain.Q
    x = np.zeros(Q.shape[0])
    np.add.at(x, chain.start_cols, chain.start_vals)
    rt_pmf = np.zeros((max_steps, n))
    # the steps before the chain's start (a lattice whose thresholds moved), then the chain's
    o = chain.prefix.shape[0]
    if o:
        rt_pmf[:o] = chain.prefix
    rt_pmf[o] = chain.start_absorbed
    steps, tail_start, mass = _lattice.propagate(
        Q.indptr.astype(np.int64), Q.indices.astype(np.int64), Q.data,
        np.ascontiguousarray(chain.R), x, rt_pmf[o:], tol, tail_tol)
    steps, tail_start = steps + o, tail_start + o
    probs = rt_pmf.sum(axis=0)
    times = np.arange(1, max_steps + 1, dtype=np.float64)
    return ThresholdProbabilities(
        probabilities=probs, p_undecided=float(max(mass, 0.0)), rt_pmf=rt_pmf,
        mean_response_times=mean_rt(times @ rt_pmf, probs), max_steps=max_steps,
        method="propagate", n_iter=int(steps), converged=True,
        tail_start=int(tail_start) if tail_start < max_steps else None, **common,
    )


def krylov(A, rhs, tol, max_iter):
    """Solve ``A y = rhs`` by BiCGSTAB, then restarted GMRES if that fails; ``(y, ok, iters)``."""
    counter = [0]

    def callback(*_):
        counter[0] += 1

    y, info = spla.bicgstab(A, rhs, rtol=tol, atol=0.0, maxiter=max_iter, callback=callback)
    if info == 0 and np.all(np.isfinite(y)):
        return y, True, counter[0]
    restart = min(50, max_iter)
    y, info = spla.gmres(A, rhs, rtol=tol, atol=0.0, restart=restart,
                         maxiter=-(-max_iter // restart), callback=callback,
                         callback_type="pr_norm")
    return y, info == 0 and bool(np.all(np.isfinite(y))), counter[0]


#: Beyond this, a long run whose choices do not sum to one (or go negative) is refused; below
#: it, what they miss is added to the answer's error.
LONG_RUN_SUM_TOL = 0.01


def _solve(chain, tol, max_iter, common):
    n_states = chain.Q.shape[0]
    b = np.zeros(n_states)
    np.add.at(b, chain.start_cols, chain.start_vals)
    converged = True
    n_iter = 0
    if n_states <= DIRECT_SOLVE_MAX_STATES:
        lu = spla.splu((sp.identity(n_states, format="csc") - chain.Q.T).tocsc())
        y = lu.solve(b)
        y2 = lu.solve(y)
    else:
        A = (sp.identity(n_states, format="csr") - chain.Q.T).tocsr()
        y, ok1, it1 = krylov(A, b, tol, max_iter)
        y2, ok2, it2 = krylov(A, y, tol, max_iter)
        n_iter = it1 + it2
        converged = ok1 and ok2
        if not converged:
            raise ValueError(
                f"the iterative solver did not reach tol={tol:g} within max_iter={max_iter} "
                f"on {n_states} states; raise max_iter or tol, or use method='propagate'"
            )
    R = chain.R
    # the choices of the steps before the chain's start (at step o + 1), if any
    o = chain.prefix.shape[0]
    before = chain.prefix.sum(axis=0) if o else 0.0
    probs = before + chain.start_absorbed + R.T @ y
    # every walk decides in the long run, so the choices sum to one: what they miss (the
    # rounding of a system near singular, where walks almost never decide, and any mass the
    # lattice's rows lose, summed over a long deliberation) is an error of this answer
    total = float(probs.sum())
    missing = abs(total - 1.0) + float(np.clip(-probs, 0.0, None).sum())
    if missing > LONG_RUN_SUM_TOL:
        raise ValueError(
            f"the long run cannot be solved for this model: the choice probabilities of the "
            f"solved chain sum to {total:.6g} and range down to {probs.min():.3g}, so the walks "
            "almost never decide and the linear system is too close to singular; use "
            "method='propagate' with a step limit (max_steps)"
        )
    # a choice k steps after the start is made at step o + 1 + k
    weighted = (o + 1) * (chain.start_absorbed + R.T @ y) + R.T @ y2
    if o:
        weighted = weighted + np.arange(1, o + 1) @ chain.prefix
    return ThresholdProbabilities(
        probabilities=probs, p_undecided=0.0, rt_pmf=None,
        mean_response_times=mean_rt(weighted, probs), max_steps=None, method="solve",
        n_iter=n_iter, converged=bool(converged), tail_start=None,
        error_probabilities=missing, error_mean_rt=0.0, **common,
    )



def error_estimate(fine, coarse):
    """Largest change in the probabilities and weighted relative change in the mean times."""
    err_p = float(max(np.max(np.abs(fine.probabilities - coarse.probabilities)),
                      abs(fine.p_undecided - coarse.p_undecided)))
    err_rt = 0.0
    for i, p in enumerate(fine.probabilities):
        a, b = fine.mean_response_times[i], coarse.mean_response_times[i]
        if p <= 0.0:
            continue
        weight = min(1.0, p / RT_WEIGHT_FLOOR)
        # a mean time only one side resolves (mean_rt) counts as wrong by 100 %
        change = abs(a - b) / a if np.isfinite(a) and np.isfinite(b) else 1.0
        err_rt = max(err_rt, weight * change)
    return err_p, float(err_rt)


def own_error(value):
    return float(value) if math.isfinite(value) else 0.0


def with_errors(result, err_p, err_rt):
    return replace(result, error_probabilities=err_p, error_mean_rt=err_rt)
