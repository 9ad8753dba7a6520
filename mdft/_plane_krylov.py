"""The Krylov tail of the moment chain: a long deliberation's remaining steps from a few.

After ``t`` steps, the undecided distribution ``v`` of a long deliberation is made of a few
slow modes of the chain (the fast ones have died out), so the steps still to come,
``G^k v`` for ``k`` up to the step limit, lie close to the Krylov space
``span(v, G v, ..., G^(d-1) v)`` of a small dimension ``d``. Arnoldi's process builds an
orthonormal basis ``V`` of that space with ``d`` steps of the chain and the small matrix
``H = V^T G V``; then ``G^k v ~ V H^k (|v| e_1)``, which is exact for ``k < d`` and gives
every later step (choices, undecided mass, occupation) at the cost of ``d x d`` products.

The dimensions of :data:`_DIMS` (up to a cap) are tried in turn until the estimated error is within the
budget: the larger of what may leave the space (the Arnoldi residual, weighted by the last
Krylov coefficients) and the change from the dimension tried before. Past the cap, the
space grows on only while the fall of the estimate over the last two dimensions predicts an
answer at a cost below that of the steps to the next try (:func:`_worth_growing`).
Otherwise the tail is not filled (None) and the chain goes on step by step.
``docs/threshold_exact.md``, section 5.
"""

from __future__ import annotations

import logging
import math

import numpy as np
from threadpoolctl import ThreadpoolController

from ._plane_step import PARTS, apply_step, krylov_powers

logger = logging.getLogger(__name__)

# Dimensions of the Krylov space tried in turn (each answer compared with the last); those
# past a try's cap only where _worth_growing says so.
_DIMS = (20, 30, 40, 60, 80, 100, 120, 140, 160, 200)


# made on the first tail (it scans the loaded libraries once)
_BLAS: list[ThreadpoolController] = []


def _blas_on_one_thread():
    """A context holding the BLAS libraries to one thread. The tail's vector products are
    short; between them, threaded BLAS leaves its threads spinning, and on a machine with
    as many cores as numba threads those slowed the chain's next build by half."""
    if not _BLAS:
        _BLAS.append(ThreadpoolController())
    return _BLAS[0].limit(limits=1, user_api="blas")


def _outputs(chain):
    """Linear functionals of a state vector ``(x, m)``: the three choices of its next step,
    the mass on frontier states (which leaves the chain) and the whole mass, as the rows of
    two ``(n_states, 5)`` matrices applied to ``x`` and ``m``."""
    n = chain.n_states
    on_x = np.zeros((n, 5))
    on_m = np.zeros((n, 5))
    inside = ~chain.frontier.astype(bool)
    on_x[inside, :3] = (chain.r0 - chain.r1 * chain.sref[:, None])[inside]
    on_m[inside, :3] = chain.r1[inside]
    on_x[~inside, 3] = 1.0
    on_x[:, 4] = 1.0
    return on_x, on_m


class _Arnoldi:
    """Arnoldi's process on the chain's step, in the scaled coordinates ``(x, m / scale)``
    (the first moment of the sum is ``scale`` times larger than the probability)."""

    def __init__(self, chain, x, m, in_parts, max_dim):
        n = chain.n_states
        self.chain = chain
        self.n = n
        self.scale = float(max(1.0, np.max(np.abs(chain.sref)) + 1.0)) if n else 1.0
        self.V = np.zeros((max_dim + 1, 2 * n))
        self.H = np.zeros((max_dim + 1, max_dim))
        self.n_vec = 2 * n
        v = np.concatenate([x, m / self.scale])
        self.beta = float(np.linalg.norm(v))
        self.V[0] = v / self.beta if self.beta > 0.0 else v
        self.dim = 0
        self.in_parts = in_parts
        self.src = np.zeros((n if in_parts else 0, 4))
        self.acc = np.zeros((PARTS if in_parts else 0, 3, n))
        self.y = np.zeros(n)
        self.ym = np.zeros(n)
        self.broke = False

    def _apply(self, v):
        c = self.chain
        n = self.n
        apply_step(c.row_ptr, c.cols, c.t0, c.t1, c.sref, c.snext, c.b_sum, c.delta**2,
                   np.ascontiguousarray(v[:n]), v[n:] * self.scale, self.y, self.ym,
                   self.in_parts, self.src, self.acc)
        return np.concatenate([self.y, self.ym / self.scale])

    def grow(self, dim):
        """Extend the basis to ``dim`` vectors (fewer if the space closes: it is then
        invariant and every later step is exact)."""
        if dim >= self.V.shape[0]:  # room for the basis past the first cap
            V = np.zeros((dim + 1, self.V.shape[1]))
            V[:self.V.shape[0]] = self.V
            H = np.zeros((dim + 1, dim))
            H[:self.H.shape[0], :self.H.shape[1]] = self.H
            self.V, self.H = V, H
        V, H = self.V, self.H
        for j in range(self.dim, dim):
            if self.broke:
                break
            w = self._apply(V[j])
            norm0 = np.linalg.norm(w)
            for _ in range(2):  # classical Gram-Schmidt, twice
                h = V[:j + 1] @ w
                w -= h @ V[:j + 1]
                H[:j + 1, j] += h
            H[j + 1, j] = np.linalg.norm(w)
            self.dim = j + 1
            if H[j + 1, j] <= 1e-14 * max(norm0, 1e-300):
                self.broke = True
                break
            V[j + 1] = w / H[j + 1, j]

    def steps(self, dim, n_rows, on_x, on_m, negligible):
        """The chain's next ``n_rows + 1`` steps from dimension ``dim``: the functionals of
        :func:`_outputs` at each, ``(n_rows + 1, 5)`` (zero after the first whose Krylov
        coefficients have a norm below ``negligible``), and the coefficients."""
        n = self.n
        coef, _ = krylov_powers(np.ascontiguousarray(self.H[:dim, :dim]), self.beta,
                                n_rows + 1, negligible)
        basis = self.V[:dim]
        out_basis = basis[:, :n] @ on_x + (basis[:, n:] * self.scale) @ on_m
        return coef @ out_basis, coef

    def residual(self, dim):
        """``h_{d+1,d}`` times the l1 norm of the next basis vector (0 if the space closed):
        what one unit of the last Krylov coefficient leaves out of the space."""
        if self.broke and dim >= self.dim:
            return 0.0
        return float(self.H[dim, dim - 1] * np.sum(np.abs(self.V[dim])))

    def occupation(self, coef, n_rows):
        """``x`` and ``m`` summed over the first ``n_rows`` steps, ``(n, 2)``, with the states
        whose ``x`` is within the rounding of the basis (Gram-Schmidt spreads it over every
        state the basis reaches) set to zero."""
        n = self.n
        d = coef.shape[1]
        summed = coef[:n_rows].sum(axis=0)
        basis_x = self.V[:d, :n]
        occ = np.empty((n, 2))
        occ[:, 0] = summed @ basis_x
        occ[:, 1] = (summed @ self.V[:d, n:]) * self.scale
        noise = 64.0 * np.finfo(float).eps * (np.abs(summed) @ np.abs(basis_x))
        occ[occ[:, 0] <= noise] = 0.0
        return occ


def _answers(rows, start, done_p, done_w):
    """Each option's probability and time-weighted probability: ``done_p`` and ``done_w``
    (up to row ``start``) plus the rows from ``start`` on."""
    hazards = rows[:-1, :3]
    steps = np.arange(start + 1, start + 1 + hazards.shape[0], dtype=np.float64)
    return done_p + hazards.sum(axis=0), done_w + steps @ hazards


def _rt_change(p, w, p0, w0, floor):
    """Largest relative change of the mean times from ``(p0, w0)`` to ``(p, w)``, weighted
    by ``min(1, p / floor)``."""
    change = 0.0
    for i in range(p.shape[0]):
        if p[i] > 0.0 and p0[i] > 0.0 and w[i] > 0.0:
            rt = w[i] / p[i]
            change = max(change, min(1.0, p[i] / floor) * abs(rt - w0[i] / p0[i]) / rt)
    return change


def _worth_growing(last, now, dim, wait, nonzeros, n_vec):
    """Whether a Krylov space past its try's cap should grow on to ``dim``.

    ``last`` and ``now`` are the last two dimensions tried with their estimated errors over
    the budget (the larger of the two ratios). Where the estimate falls, it is taken to go
    on falling geometrically at that rate, which is cautious: on the long deliberations of
    the benchmark's draws it fell faster and faster with the dimension. The space grows on
    if that reaches the budget within :data:`_DIMS` at a cost below that of the ``wait``
    steps of the chain to the next try: a step of the chain per dimension (``nonzeros``
    units) and Gram-Schmidt's products with the basis (``n_vec`` units per vector), which
    take about as long per unit on this machine as the chain's scatter."""
    (d0, g0), (d1, g1) = last, now
    if wait <= 0 or not 1.0 < g1 < g0:
        return False
    need = max(d1 + math.log(g1) * (d1 - d0) / math.log(g0 / g1), dim)
    if need > _DIMS[-1]:
        return False
    cost = (need - d1) * nonzeros + 0.5 * n_vec * (need * need - d1 * d1)
    return cost <= wait * nonzeros


def krylov_tail(chain, x, m, start, rt_pmf, budget, floor, in_parts, max_dim=_DIMS[-1],
                wait=0):
    """:func:`_krylov_tail` with BLAS on one thread. A space whose products overflow (a
    moment closure that runs away) gives rows that are not finite, and no tail: numpy's
    warnings on the way there are not the caller's business."""
    with _blas_on_one_thread(), np.errstate(over="ignore", invalid="ignore"):
        return _krylov_tail(chain, x, m, start, rt_pmf, budget, floor, in_parts, max_dim,
                            wait)


def _krylov_tail(chain, x, m, start, rt_pmf, budget, floor, in_parts, max_dim, wait):
    """Fill ``rt_pmf[start:]`` from the distribution ``(x, m)`` after ``start`` steps, if
    the Krylov tail's estimated error is within ``budget = (atol, rtol)`` at a dimension
    of :data:`_DIMS` up to ``max_dim``, or past it where :func:`_worth_growing` says so
    (``wait``: the steps of the chain before its next try; 0: none past ``max_dim``).

    The error estimate is the larger of two: the change from the dimension tried before,
    and what the Arnoldi residual may add (``h_{d+1,d} |v_{d+1}|_1`` times the summed last
    Krylov coefficients: the mass that leaves the space, each unit of which is taken to
    change the choices by at most one unit and the time-weighted sums by at most the step
    limit).

    Returns None, or ``(mass, occupation, escaped, errors, matvecs)``: the mass undecided
    after the last row, ``x`` summed over the rows filled, the mass that reached frontier
    states, the estimated error of the probabilities and (relative, weighted as in
    :func:`mdft._plane_tail.tail_error`) of the mean response times, and the steps of the
    chain it took.
    """
    n_steps = rt_pmf.shape[0]
    n_rows = n_steps - start
    done_p = rt_pmf[:start].sum(axis=0)
    done_w = np.arange(1, start + 1, dtype=np.float64) @ rt_pmf[:start]
    on_x, on_m = _outputs(chain)
    dims = [d for d in _DIMS if d <= max_dim]
    arnoldi = _Arnoldi(chain, x, m, in_parts, min(dims[-1], n_rows))
    dims += [d for d in _DIMS if d > max_dim]
    tried = []  # (dimension, estimated error over the budget)
    if arnoldi.beta == 0.0:
        return None
    # the rows stop once the Krylov coefficients' norm is below ``negligible``: what is left
    # holds at most ``left`` (the l1 norm is at most sqrt(2 n) times the l2 norm), which
    # changes the probabilities by as much and the time-weighted sums by ``n_steps`` times
    # as much (so a mean time of at least one step by a thousandth of the budget)
    left = 1e-3 * min(budget[0], budget[1] * floor / n_steps)
    negligible = left / np.sqrt(2.0 * max(chain.n_states, 1))
    previous = None
    for dim in dims:
        if dim > max_dim and not _worth_growing(tried[-2], tried[-1], dim, wait,
                                                chain.cols.shape[0], arnoldi.n_vec):
            return None
        arnoldi.grow(min(dim, n_rows))
        d = arnoldi.dim
        rows, coef = arnoldi.steps(d, n_rows, on_x, on_m, negligible)
        if not np.all(np.isfinite(rows)):
            return None
        p, w = _answers(rows, start, done_p, done_w)
        leak = arnoldi.residual(d) * float(np.sum(np.abs(coef[:n_rows, d - 1]))) + left
        err_p = leak
        err_rt = 0.0
        for i in range(3):
            if p[i] > 0.0 and w[i] > 0.0:
                rt = w[i] / p[i]
                # (w + dw) / (p + dp) - w / p with |dp| <= leak and |dw| <= n_steps leak,
                # relative, weighted by min(1, p / floor)
                err_rt = max(err_rt, leak * (n_steps / rt + 1.0) / max(p[i] - leak, floor))
        if previous is not None:
            err_p = max(err_p, float(np.max(np.abs(p - previous[0]))))
            err_rt = max(err_rt, _rt_change(p, w, previous[0], previous[1], floor))
        logger.debug("Krylov tail from step %d, dimension %d: estimated error %.2g "
                     "(residual %.2g), %.2g relative in the mean times", start, d, err_p,
                     leak, err_rt)
        if (previous is not None or arnoldi.broke) and err_p <= budget[0] \
                and err_rt <= budget[1]:
            rt_pmf[start:] = rows[:-1, :3]
            escaped = float(np.sum(np.abs(rows[:-1, 3])))
            return (float(rows[-1, 4]), arnoldi.occupation(coef, n_rows), escaped,
                    (err_p, err_rt), d)
        if arnoldi.broke or d < dim:
            return None
        previous = (p, w)
        tried.append((d, max(err_p / budget[0], err_rt / budget[1])))
    return None


def compile_kernels():
    """Compile (or load) the Krylov tail's kernels on a two-state chain (mdft.warmup):
    threshold calls short enough to warm the rest never reach a Krylov tail."""
    row_ptr = np.array([0, 1, 1])
    cols = np.array([1], dtype=np.int32)
    x, m, y, ym = np.array([1.0, 0.0]), np.zeros(2), np.zeros(2), np.zeros(2)
    apply_step(row_ptr, cols, np.array([0.5]), np.zeros(1), np.zeros(2), np.zeros(2), 1.0,
               0.0, x, m, y, ym, False, np.zeros((0, 4)), np.zeros((0, 3, 2)))
    krylov_powers(np.eye(2), 1.0, 2, 0.0)
    return y
