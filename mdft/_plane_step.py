"""Compiled kernels that step the moment chain of :mod:`mdft._plane_moment`.

Nothing here validates its input. A state carries its probability ``x`` and the
first moment ``m`` of the summed preference (:mod:`mdft._plane_moment` says
what the rows ``T0`` and ``T1`` mean). :func:`propagate` applies the chain step
by step, records the choices of each step and, where the tail has settled,
fills it geometrically (:mod:`mdft._plane_tail`); :func:`apply_step` and
:func:`krylov_powers` are the products of the Krylov tail
(:mod:`mdft._plane_krylov`).

A large chain's step is scattered in a fixed number of parts on numba's
threads, into separate accumulators added in order, so the answer is the same
for any number of threads above one.
"""

from __future__ import annotations

import math

import numpy as np

from numba import prange

from ._numba import njit, njit_inline, njit_parallel
from ._plane_tail import WINDOW, check, fill, snapshot

# Propagation leaves out states holding less than this share of the undecided mass.
_SKIP = 1e-15

# Parallel propagation: the rows are dealt to this many parts, in blocks of _BLOCK rows in
# turn, and each part scatters into its own accumulators (summed in a fixed order after the
# step), so the sums do not depend on the number of threads.
PARTS = 4
_BLOCK = 16


@njit_inline
def _scatter_row(row_ptr, cols, t0, t1, r, xr, u, carry, cu, q0, second, y, ym, yq):
    """Add source ``r``'s step to ``y`` (``x``), ``ym`` (``m``) and, with ``second``, ``yq``
    (``q``). The indices are unsigned: numba then omits the negative-index wraparound on every
    access, which made this loop (the propagation's whole cost) about 1.5-2 times slower."""
    for k in range(np.uint64(row_ptr[r]), np.uint64(row_ptr[r + 1])):
        c = np.uint64(cols[k])
        a0 = t0[k]
        a1 = t1[k]
        y[c] += a0 * xr + a1 * u
        ym[c] += a0 * carry + a1 * cu
    if second:
        for k in range(np.uint64(row_ptr[r]), np.uint64(row_ptr[r + 1])):
            yq[np.uint64(cols[k])] += t0[k] * q0


@njit_parallel
def _scatter_parts(row_ptr, cols, t0, t1, src, q0s, acc, second):
    """One step of the chain in :data:`PARTS` parts run on numba's threads: part ``p``
    scatters the rows of its blocks (``src[r] = (x, u, carry, cu)``; a row whose terms are
    all zero adds nothing and is skipped, as in the serial scatter) into ``acc[p, 0]``
    (``x``), ``acc[p, 1]`` (``m``) and, with ``second``, ``acc[p, 2]`` (``q``)."""
    n = src.shape[0]
    n_blocks = (n + _BLOCK - 1) // _BLOCK
    for part in prange(PARTS):
        y = acc[part, 0]
        ym = acc[part, 1]
        yq = acc[part, 2]
        for blk in range(part, n_blocks, PARTS):
            for r in range(blk * _BLOCK, min((blk + 1) * _BLOCK, n)):
                xr = src[r, 0]
                u = src[r, 1]
                carry = src[r, 2]
                cu = src[r, 3]
                if xr == 0.0 and u == 0.0 and carry == 0.0 and cu == 0.0:
                    continue
                _scatter_row(row_ptr, cols, t0, t1, r, xr, u, carry, cu,
                             q0s[r] if second else 0.0, second, y, ym, yq)


@njit_parallel
def _sum_parts(acc, y, ym, yq, second):
    """``y``, ``ym`` (and ``yq``) = the parts' accumulators summed in order; those zeroed."""
    n_moments = 3 if second else 2
    for c in prange(y.shape[0]):
        for j in range(n_moments):
            v = 0.0
            for part in range(PARTS):
                v += acc[part, j, c]
                acc[part, j, c] = 0.0
            if j == 0:
                y[c] = v
            elif j == 1:
                ym[c] = v
            else:
                yq[c] = v


@njit_inline
def _source_terms(xr, mr, sr, sn, b_sum, dvar):
    """A source's deviation ``u = m - s_ref x`` and the terms its row scatters to the next
    first moment: ``carry`` (with ``T0``) and ``cu`` (with ``T1``); see the module
    docstring of :mod:`mdft._plane_moment`."""
    u = mr - sr * xr
    return u, sn * xr + b_sum * u, sn * u + b_sum * dvar * xr


@njit
def apply_step(row_ptr, cols, t0, t1, sref, snext, b_sum, dvar, x, m, y, ym, in_parts, src, acc):
    """``(y, ym)`` = one step of the chain applied to any ``(x, m)`` (a Krylov vector of
    :mod:`mdft._plane_krylov`): no state is skipped, and mass on a frontier state (no row)
    goes nowhere. ``src`` (n_states, 4) and ``acc`` (PARTS, 3, n_states) are work space for
    ``in_parts``, which adds the parts in the same fixed order as :func:`propagate`."""
    n_states = x.shape[0]
    for r in range(n_states):
        y[r] = 0.0
        ym[r] = 0.0
    for r in range(n_states):
        xr = x[r]
        u, carry, cu = _source_terms(xr, m[r], sref[r], snext[r], b_sum, dvar)
        if in_parts:
            src[r, 0] = xr
            src[r, 1] = u
            src[r, 2] = carry
            src[r, 3] = cu
        elif xr != 0.0 or u != 0.0:
            _scatter_row(row_ptr, cols, t0, t1, r, xr, u, carry, cu, 0.0, False, y, ym, y)
    if in_parts:
        _scatter_parts(row_ptr, cols, t0, t1, src, np.zeros(0), acc, False)
        _sum_parts(acc, y, ym, y, False)


@njit
def propagate(row_ptr, cols, t0, t1, ab0, ab1, sref, snext, b_sum, dvar, x, m, q, rt_pmf, occ,
              tol, second, budget_p, budget_rt, floor, errors, in_parts, frontier, pause,
              t_first, hazard, done, snaps, dist, escape_max):
    """Apply the moment chain step by step (see the module docstring of
    :mod:`mdft._plane_moment`).

    With ``in_parts``, each step's scatter runs in :data:`PARTS` parts on numba's threads
    (:func:`_scatter_parts`); otherwise serially. The parts' sums are added in a fixed
    order, so the answer does not depend on the number of threads (it differs from the
    serial scatter's by rounding).

    ``x`` and ``m`` (probability and first moment of the sum on each state)
    are updated in place; ``dvar`` is ``delta**2``, the spread of the sum
    within a state, which enters ``m`` through its covariance with the slope
    ``T1`` (``docs/threshold_exact.md``, section 2). With ``second``, so is
    ``q`` (second moment), which only estimates the spread of the sum (the next pass's ``delta``) and is
    carried by ``T0`` alone, which keeps it stable, and ``occ[:, 2]``
    accumulates the occupation of ``q`` over the steps (for the next pass's
    spread). ``snext[r]`` is the next sum
    from state ``r`` at its reference sum and ``b_sum`` its slope in the
    current sum. Stops once the undecided mass (of ``|x|``) is below ``tol``, or, with
    ``budget_p > 0``, once the tail may be filled geometrically with a change
    within ``budget_p`` and ``budget_rt`` (:func:`mdft._plane_tail.check`;
    the change is left in ``errors``). Mass that reaches a ``frontier`` state (no row:
    :func:`build`) leaves the chain; its sum is left in ``errors[2]``, and once it exceeds
    ``escape_max`` the run stops after that step (the pass is to be built again with every
    row, so the rest of its steps would be wasted). ``occ[:, 0]`` and ``occ[:, 1]``
    accumulate ``x`` and ``m`` over the steps (where the next, finer pass needs rows, and
    the walks' mean sums for the closure's plane probe: :func:`mdft._plane_chain.mean_sums`).
    With
    ``pause < rt_pmf.shape[0]``, returns after row ``pause - 1`` with ``x`` and ``m`` the
    distribution after ``pause`` steps (no tail filled), unless it stopped before; a
    later call with ``t_first = pause`` goes on from there. ``hazard`` (per row),
    ``done`` (each option's probability and time-weighted probability so far), ``snaps``
    and ``dist`` (:func:`mdft._plane_tail.snapshot`) carry the tail's checks across
    calls; the first call (``t_first = 1``) starts them. Returns
    ``(steps, tail_start, mass)``.
    """
    n_states = x.shape[0]
    n_steps = rt_pmf.shape[0]
    n_opt = rt_pmf.shape[1]
    y = np.zeros(n_states)
    ym = np.zeros(n_states)
    yq = np.zeros(n_states)
    # the sources' terms of a step, for the parts
    n_src = n_states if in_parts else 0
    src = np.zeros((n_src, 4))
    q0s = np.zeros(n_src if second else 0)
    acc = np.zeros((PARTS if in_parts else 0, 3, n_states))
    done_p = done[0]
    done_w = done[1]
    sigma = np.zeros(n_opt)
    dsigma = np.zeros(n_opt)
    snap_x = snaps[0]
    snap_m = snaps[1]
    # how far a change in the distribution can move the hazard (choices per unit of x, m)
    reach = np.zeros(2)
    for r in range(n_states):
        a0 = 0.0
        a1 = 0.0
        for i in range(n_opt):
            a0 += abs(ab0[r, i] - ab1[r, i] * sref[r])
            a1 += abs(ab1[r, i])
        reach[0] = max(reach[0], a0)
        reach[1] = max(reach[1], a1)
    if t_first == 1:
        for i in range(n_opt):
            done_p[i] = rt_pmf[0, i]
            done_w[i] = rt_pmf[0, i]
    errors[0] = 0.0
    errors[1] = 0.0
    errors[2] = 0.0
    escaped = 0.0
    mass = 0.0
    # the stop looks at |x|: where the moment closure lets x change sign, the signed mass can
    # pass below tol while the walks still choose
    size = 0.0
    for r in range(n_states):
        mass += x[r]
        size += abs(x[r])
    # states holding less than _SKIP of the undecided mass are left out of the step (their
    # mass, summed over the steps, is added to the probabilities' error)
    s_scale = 1.0
    for r in range(n_states):
        s_scale = max(s_scale, abs(sref[r]) + 1.0)
    dropped = 0.0
    steps = t_first
    bb = b_sum * b_sum
    for t in range(t_first, n_steps):
        if t >= pause:
            break
        if size < tol:
            errors[0] = dropped
            errors[1] = 0.0
            errors[2] = escaped
            return steps, n_steps, mass
        for i in range(n_opt):
            rt_pmf[t, i] = 0.0
        cut = _SKIP * mass
        for r in range(n_states):
            xr = x[r]
            mr = m[r]
            if in_parts:
                # an empty or skipped state adds nothing
                for i in range(4):
                    src[r, i] = 0.0
                if second:
                    q0s[r] = 0.0
            if xr == 0.0 and mr == 0.0:
                continue
            if frontier[r]:
                escaped += abs(xr)
                x[r] = 0.0
                m[r] = 0.0
                q[r] = 0.0
                continue
            if abs(xr) < cut and abs(mr) < cut * s_scale:
                dropped += abs(xr)
                x[r] = 0.0
                m[r] = 0.0
                q[r] = 0.0
                continue
            sr = sref[r]
            sn = snext[r]
            u, carry, cu = _source_terms(xr, mr, sr, sn, b_sum, dvar)
            for i in range(n_opt):
                rt_pmf[t, i] += ab0[r, i] * xr + ab1[r, i] * u
            q0 = 0.0
            occ[r, 0] += xr
            occ[r, 1] += mr
            if second:
                occ[r, 2] += q[r]
                v = q[r] - 2.0 * sr * mr + sr * sr * xr
                q0 = sn * sn * xr + 2.0 * sn * b_sum * u + bb * v
            if in_parts:
                src[r, 0] = xr
                src[r, 1] = u
                src[r, 2] = carry
                src[r, 3] = cu
                if second:
                    q0s[r] = q0
                continue
            _scatter_row(row_ptr, cols, t0, t1, r, xr, u, carry, cu, q0, second, y, ym, yq)
        if escaped > escape_max:
            steps = t + 1
            break  # no answer: the pass is built again
        if in_parts:
            _scatter_parts(row_ptr, cols, t0, t1, src, q0s, acc, second)
            _sum_parts(acc, y, ym, yq, second)
        new_mass = 0.0
        size = 0.0
        for r in range(n_states):
            x[r] = y[r]
            m[r] = ym[r]
            y[r] = 0.0
            ym[r] = 0.0
            new_mass += x[r]
            size += abs(x[r])
        if second:
            for r in range(n_states):
                q[r] = yq[r]
                yq[r] = 0.0
        total = 0.0
        for i in range(n_opt):
            total += rt_pmf[t, i]
            done_p[i] += rt_pmf[t, i]
            done_w[i] += (t + 1) * rt_pmf[t, i]
        hazard[t] = total / mass if mass > 0.0 else 0.0
        steps = t + 1
        mass = new_mass
        if budget_p > 0.0 and t % WINDOW == 0:
            snapshot(x, m, mass, snap_x, snap_m, dist)
        if budget_p > 0.0 and t % 4 == 0 and check(
                rt_pmf, hazard, t, mass, done_p, done_w, budget_p, budget_rt, floor, dist,
                reach, sigma, dsigma, errors):
            errors[0] += dropped
            errors[2] = escaped
            return steps, t + 1, fill(rt_pmf, t, mass, min(max(hazard[t], 0.0), 1.0), sigma)
    # no tail was filled (or the escape stopped the run): the last check's estimate does not
    # apply
    errors[0] = dropped
    errors[1] = 0.0
    errors[2] = escaped
    return steps, n_steps, mass


@njit
def krylov_powers(H, beta, n, negligible):
    """Rows ``k = 0 .. n - 1``: ``H^k (beta e_1)`` (:mod:`mdft._plane_krylov`), up to the
    first whose norm is below ``negligible`` (the rest are zero); returns the rows and how
    many were computed."""
    d = H.shape[0]
    # H by columns: the product is taken a column at a time (H c = sum_j c_j H[:, j]), each
    # an independent update of every row, which vectorises; a row at a time it would be a
    # sum into one number, which without reordering cannot (3-4 times slower at d = 60-200;
    # the terms of each row are added in the same order either way)
    cols = np.ascontiguousarray(H.T)
    out = np.zeros((n, d))
    c = np.zeros(d)
    nxt = np.zeros(d)
    c[0] = beta
    for k in range(n):
        norm = 0.0
        for i in range(d):
            out[k, i] = c[i]
            norm += c[i] * c[i]
        if math.sqrt(norm) < negligible:
            return out, k + 1
        for i in range(d):
            nxt[i] = 0.0
        for j in range(d):
            cj = c[j]
            col = cols[j]
            # H is upper Hessenberg: column j ends at row j + 1
            for i in range(min(j + 2, d)):
                nxt[i] += col[i] * cj
        for i in range(d):
            c[i] = nxt[i]
    return out, n
