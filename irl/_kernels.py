"""Compiled kernels of :mod:`irl`.

Every kernel works on the padded sparse layout of :class:`irl.mdp.MDP`:
``next_states[s, a, k]`` and ``probs[s, a, k]`` (``k < K``; padding entries
have probability zero). Terminal states are absorbing: they have value zero,
take no action and stop every visitation mass that enters them.

Kernels do no validation and have no defaults; the public layer
(:mod:`irl.planning`, :mod:`irl.mesc`, :mod:`irl.demonstrations`) checks every
argument once before calling them.
"""

from fractions import Fraction

import numpy as np
from llvmlite import ir
from numba import types
from numba.extending import intrinsic, overload

from ._numba import njit, njit_inline


# --------------------------------------------------------------------- helpers
@njit
def penalised_expected_rewards(next_states, probs, rewards, terminal, u_src, u_act, u_dst):
    """Expected reward of R - phi . omega where phi . omega = u_src[s] + u_act[a] + u_dst[s'].

    Zero at terminal states; zero penalties give the expected reward of R itself.
    """
    n_states, n_actions, n_succ = probs.shape
    out = np.zeros((n_states, n_actions))
    for s in range(n_states):
        if terminal[s]:
            continue
        for a in range(n_actions):
            acc = 0.0
            for k in range(n_succ):
                p = probs[s, a, k]
                if p != 0.0:
                    acc += p * (rewards[s, a, k] - u_dst[next_states[s, a, k]])
            out[s, a] = acc - u_src[s] - u_act[a]
    return out


@njit
def _bellman_q(next_states, probs, r_bar, terminal, discount, v_next, q):
    n_states, n_actions, n_succ = probs.shape
    for s in range(n_states):
        if terminal[s]:
            for a in range(n_actions):
                q[s, a] = 0.0
            continue
        for a in range(n_actions):
            acc = 0.0
            for k in range(n_succ):
                acc += probs[s, a, k] * v_next[next_states[s, a, k]]
            q[s, a] = r_bar[s, a] + discount * acc


# ------------------------------------------------------------------ fast exp
@intrinsic
def _bitcast_to_float(typingctx, bits):
    def codegen(context, builder, signature, args):
        return builder.bitcast(args[0], context.get_value_type(types.float64))

    return types.float64(types.int64), codegen


@intrinsic
def _bitcast_to_int(typingctx, x):
    def codegen(context, builder, signature, args):
        return builder.bitcast(args[0], context.get_value_type(types.int64))

    return types.int64(types.float64), codegen


def _bits_to_float(bits):
    """Reinterpret the 64 bits of an int64 as a float64 (NumPy here; one instruction when compiled)."""
    return np.int64(bits).view(np.float64)


def _float_to_bits(x):
    """Reinterpret the 64 bits of a float64 as an int64 (NumPy here; one instruction when compiled)."""
    return np.float64(x).view(np.int64)


@overload(_bits_to_float, inline="always")
def _bits_to_float_compiled(bits):
    return lambda bits: _bitcast_to_float(bits)


@overload(_float_to_bits, inline="always")
def _float_to_bits_compiled(x):
    return lambda x: _bitcast_to_int(x)


def _fma(a, b, c):
    """``a * b + c`` rounded once (exact through fractions here; one instruction when compiled)."""
    return float(Fraction(float(a)) * Fraction(float(b)) + Fraction(float(c)))


@intrinsic
def _fma_intrinsic(typingctx, a, b, c):
    def codegen(context, builder, signature, args):
        d = ir.DoubleType()
        fn = builder.module.declare_intrinsic("llvm.fma", [d], ir.FunctionType(d, [d, d, d]))
        return builder.call(fn, args)

    return types.float64(types.float64, types.float64, types.float64), codegen


@overload(_fma, inline="always")
def _fma_compiled(a, b, c):
    return lambda a, b, c: _fma_intrinsic(float(a), float(b), float(c))


_LOG2E = 1.4426950408889634
_LN2_HI = 6.93147180369123816490e-01  # ln 2 split so that n * _LN2_HI is exact for |n| < 2**11
_LN2_LO = 1.90821492927058770002e-10
_ROUND = 6755399441055744.0  # 1.5 * 2**52: adding it rounds to an integer held in the low mantissa bits
_ROUND_BITS = 0x4338000000000000  # its bit pattern


@njit_inline
def _exp_nonpositive(x):
    """exp(x) for x <= 0 within 2 ulp, written so that loops over it vectorise.

    Range reduction ``x = n ln 2 + r`` with ``|r| <= ln 2 / 2`` and the Taylor
    polynomial of degree 12 (truncation error below 2e-16 relative) in
    Horner's form with fused multiply-adds (one rounding per step: fewer
    operations and a smaller error than a multiply and an add); 2**n is
    built from its bits. Results below exp(-708) (where 2**n leaves the normal
    range) are returned as 0, ``nan`` stays ``nan``. np.exp is a call into the C
    library that LLVM cannot vectorise, and the soft backward pass of MESC-IRL
    spends most of its time in it.
    """
    t = x * _LOG2E + _ROUND
    n = t - _ROUND
    r = x - n * _LN2_HI - n * _LN2_LO
    p = _fma(1.0 / 479001600.0, r, 1.0 / 39916800.0)
    p = _fma(p, r, 1.0 / 3628800.0)
    p = _fma(p, r, 1.0 / 362880.0)
    p = _fma(p, r, 1.0 / 40320.0)
    p = _fma(p, r, 1.0 / 5040.0)
    p = _fma(p, r, 1.0 / 720.0)
    p = _fma(p, r, 1.0 / 120.0)
    p = _fma(p, r, 1.0 / 24.0)
    p = _fma(p, r, 1.0 / 6.0)
    p = _fma(p, r, 0.5)
    p = _fma(p, r, 1.0)
    p = _fma(p, r, 1.0)
    y = p * _bits_to_float((_float_to_bits(t) - _ROUND_BITS + 1023) << 52)
    if x >= -708.0:
        return y
    return 0.0 if x == x else x


@njit
def _logsumexp_rows(q, terminal, v, policy):
    """v[s] = log sum_a exp(q[s, a]); policy[s, a] = exp(q[s, a] - v[s]) (uniform at terminals).

    All rows of :func:`_logsumexp_block`.
    """
    _logsumexp_block(q, terminal, v, policy, 0, q.shape[0], True)


@njit
def _logsumexp_block(q, terminal, v, policy, s0, s1, normalise):
    """:func:`_logsumexp_rows` for the rows ``s0 <= s < s1`` (``policy`` C-contiguous).

    With ``normalise`` False the rows of ``policy`` are left as ``exp(q - max(q))``
    (scratch of a pass that needs the values alone).

    The exponentials (of ``q - max(q)``) are :func:`_exp_nonpositive`'s, in one
    flat loop over the whole block so that it vectorises (a loop over a row's
    few actions does not): the soft backward passes spend most of their time
    here. ``v[s]`` holds the row maxima in between.
    """
    n_actions = q.shape[1]
    flat = policy[s0:s1].reshape(-1)  # indices from 0 (known non-negative: the loop below vectorises)
    for s in range(s0, s1):
        m = q[s, 0]
        for a in range(1, n_actions):
            x = q[s, a]
            m = x if x > m else m
        v[s] = m
        for a in range(n_actions):
            policy[s, a] = q[s, a] - m
    for i in range(flat.size):
        flat[i] = _exp_nonpositive(flat[i])
    for s in range(s0, s1):
        if terminal[s]:
            v[s] = 0.0
            for a in range(n_actions):
                policy[s, a] = 1.0 / n_actions
            continue
        acc = 0.0
        for a in range(n_actions):
            acc += policy[s, a]
        v[s] = v[s] + np.log(acc)
        if normalise:
            inv = 1.0 / acc
            for a in range(n_actions):
                policy[s, a] *= inv


# ------------------------------------------------------------ value iteration
@njit
def value_iteration(next_states, probs, r_bar, terminal, discount, max_iter, tol):
    """Optimal values by repeated Bellman backups, v <- max_a (r_bar + discount * P v).

    Returns ``(v, q, n_iter, converged)``; stops when the largest change is <= tol.
    """
    n_states, n_actions, _ = probs.shape
    v = np.zeros(n_states)
    q = np.zeros((n_states, n_actions))
    converged = False
    n_iter = 0
    for it in range(max_iter):
        _bellman_q(next_states, probs, r_bar, terminal, discount, v, q)
        delta = 0.0
        for s in range(n_states):
            best = 0.0
            if not terminal[s]:
                best = q[s, 0]
                for a in range(1, n_actions):
                    if q[s, a] > best:
                        best = q[s, a]
            d = abs(best - v[s])
            if d > delta:
                delta = d
            v[s] = best
        n_iter = it + 1
        if delta <= tol:
            converged = True
            break
    _bellman_q(next_states, probs, r_bar, terminal, discount, v, q)
    return v, q, n_iter, converged


@njit
def soft_value_iteration(next_states, probs, r_bar, terminal, discount, max_iter, tol):
    """Stationary soft values v <- log sum_a exp(r_bar + discount * P v).

    Returns ``(v, q, policy, n_iter, converged)``.
    """
    n_states, n_actions, _ = probs.shape
    v = np.zeros(n_states)
    v_new = np.zeros(n_states)
    q = np.zeros((n_states, n_actions))
    policy = np.zeros((n_states, n_actions))
    converged = False
    n_iter = 0
    for it in range(max_iter):
        _bellman_q(next_states, probs, r_bar, terminal, discount, v, q)
        _logsumexp_rows(q, terminal, v_new, policy)
        delta = 0.0
        for s in range(n_states):
            d = abs(v_new[s] - v[s])
            if d > delta or d != d:
                delta = d if d == d else np.inf
            v[s] = v_new[s]
        n_iter = it + 1
        if delta <= tol:
            converged = True
            break
    _bellman_q(next_states, probs, r_bar, terminal, discount, v, q)
    _logsumexp_rows(q, terminal, v_new, policy)
    return v, q, policy, n_iter, converged


@njit
def soft_value_iteration_finite(next_states, probs, r_bar, terminal, discount, horizon):
    """Time-indexed soft values over ``horizon`` steps with V_horizon = 0.

    Returns ``(v, q, policy)`` with shapes (horizon + 1, S), (horizon, S, A),
    (horizon, S, A); ``v[t]`` is the soft value with ``horizon - t`` steps to go.
    """
    n_states, n_actions, _ = probs.shape
    v = np.zeros((horizon + 1, n_states))
    q = np.zeros((horizon, n_states, n_actions))
    policy = np.zeros((horizon, n_states, n_actions))
    for t in range(horizon - 1, -1, -1):
        _bellman_q(next_states, probs, r_bar, terminal, discount, v[t + 1], q[t])
        _logsumexp_rows(q[t], terminal, v[t], policy[t])
    return v, q, policy


@njit
def soft_backward_into(next_states, probs, succ, pattern_of, patterns, split, r_bar, terminal, discount, shared,
                       policy, demo_ptr, demo_s, demo_a, block, block_first):
    """Finite-horizon soft recursion writing the time-indexed policy into ``policy`` (H, S, A).

    ``shared[s]`` says that every action of s lists the same successors in the same
    order (only the probabilities differ, as with slip); such a state reads its
    successors from ``succ[s]`` (int32, (S, K)) and the actions' probabilities of
    successor k side by side from ``patterns[pattern_of[s], k]`` (a table of the
    distinct (K, A) probability matrices, :func:`irl.mdp.successor_patterns`): a
    gridworld with slip has nine, so the pass reads a few bytes per state instead
    of ``probs``. Other states read ``next_states`` and ``probs``. ``split`` is
    :func:`irl.mesc._split_patterns` of the table: a pattern whose actions differ from its
    common part in one successor each (a gridworld's slip) costs K + A
    multiply-adds per state instead of K A.
    States are processed in blocks of ``block``; block b is computed at steps
    ``t >= block_first[b]`` only (its rows of ``policy`` and its values are left
    as they are before), which is exact for every quantity at (t, s) with
    ``t >= block_first[block of s]`` when no state of a block computed at t has a
    successor in a block not computed at t + 1 (:func:`first_needed_steps`).
    Demonstration transitions at step t are ``demo_s[demo_ptr[t]:demo_ptr[t + 1]]``
    (and ``demo_a``); their log-probabilities ``Q_t(s, a) - V_t(s)`` are summed
    without underflow. The horizon is ``demo_ptr.size - 1``; a ``policy`` of
    shape (1, S, A) is scratch space (the likelihood alone, each step
    overwriting the last, rows not normalised). Returns ``(v0, log_likelihood_sum)``.
    """
    n_states, n_actions, n_succ = probs.shape
    horizon = demo_ptr.size - 1
    keep = policy.shape[0] == horizon
    v_next = np.zeros(n_states)
    v = np.zeros(n_states)
    q = np.zeros((n_states, n_actions))
    g = np.zeros(n_succ)
    base, res_k, res_p, simple = split
    a4 = n_actions - n_actions % 4
    loglik = 0.0
    for t in range(horizon - 1, -1, -1):
        pol = policy[t if keep else 0]
        for b in range(block_first.size):
            if block_first[b] > t:
                continue
            s0 = b * block
            s1 = min(s0 + block, n_states)
            for s in range(s0, s1):
                if terminal[s]:
                    for a in range(n_actions):
                        q[s, a] = 0.0
                    continue
                pat = np.uint64(pattern_of[s])  # indices read from arrays as unsigned: no wraparound test
                if shared[s] and simple[pat]:
                    # (the sums over successors are fused multiply-adds, one rounding each) the common part
                    # once, then each action's one successor of its own
                    common = 0.0
                    for k in range(n_succ):
                        vk = v_next[np.uint64(succ[s, k])]
                        g[k] = vk
                        common = _fma(base[pat, k], vk, common)
                    for a in range(n_actions):
                        q[s, a] = _fma(discount, _fma(res_p[pat, a], g[np.uint64(res_k[pat, a])], common), r_bar[s, a])
                elif shared[s]:
                    # summed over k in order for each action; four actions at a time in registers (the
                    # compiler packs them into one vector), then the rest one by one
                    for a in range(0, a4, 4):
                        c0 = 0.0
                        c1 = 0.0
                        c2 = 0.0
                        c3 = 0.0
                        for k in range(n_succ):
                            vk = v_next[succ[s, k]]
                            c0 = _fma(patterns[pat, k, a], vk, c0)
                            c1 = _fma(patterns[pat, k, a + 1], vk, c1)
                            c2 = _fma(patterns[pat, k, a + 2], vk, c2)
                            c3 = _fma(patterns[pat, k, a + 3], vk, c3)
                        q[s, a] = _fma(discount, c0, r_bar[s, a])
                        q[s, a + 1] = _fma(discount, c1, r_bar[s, a + 1])
                        q[s, a + 2] = _fma(discount, c2, r_bar[s, a + 2])
                        q[s, a + 3] = _fma(discount, c3, r_bar[s, a + 3])
                    for a in range(a4, n_actions):
                        c0 = 0.0
                        for k in range(n_succ):
                            c0 = _fma(patterns[pat, k, a], v_next[succ[s, k]], c0)
                        q[s, a] = _fma(discount, c0, r_bar[s, a])
                else:
                    for a in range(n_actions):
                        acc = 0.0
                        for k in range(n_succ):
                            acc = _fma(probs[s, a, k], v_next[next_states[s, a, k]], acc)
                        q[s, a] = _fma(discount, acc, r_bar[s, a])
            _logsumexp_block(q, terminal, v, pol, s0, s1, keep)
        for i in range(demo_ptr[t], demo_ptr[t + 1]):
            loglik += q[demo_s[i], demo_a[i]] - v[demo_s[i]]
        for s in range(n_states):
            v_next[s] = v[s]
    return v, loglik


@njit
def first_needed_steps(next_states, probs, terminal, demo_ptr, demo_s, block):
    """First step at which each block of states matters to the demonstrations' likelihood.

    ``V_t(s)`` enters the likelihood only if s can be reached in at most
    ``t - t'`` moves from a state demonstrated at a step ``t' <= t``; the
    earliest such t per state (a breadth-first search seeded with the
    demonstrated steps) is minimised over each block of ``block`` states and
    capped at the horizon ``demo_ptr.size - 1`` (never needed). Every state of a
    block needed at t then has its successors in blocks needed at t + 1.
    """
    n_states, n_actions, n_succ = probs.shape
    horizon = demo_ptr.size - 1
    first = np.full(n_states, horizon, dtype=np.int64)
    for t in range(horizon):
        for i in range(demo_ptr[t], demo_ptr[t + 1]):
            if first[demo_s[i]] > t:
                first[demo_s[i]] = t
    # states by their label, relaxed in order of it (labels only grow by one per move)
    for t in range(horizon - 1):
        for s in range(n_states):
            if first[s] != t or terminal[s]:
                continue
            for a in range(n_actions):
                for k in range(n_succ):
                    if probs[s, a, k] > 0.0:
                        ns = next_states[s, a, k]
                        if first[ns] > t + 1:
                            first[ns] = t + 1
    n_blocks = (n_states + block - 1) // block
    out = np.full(n_blocks, horizon, dtype=np.int64)
    for s in range(n_states):
        b = s // block
        if first[s] < out[b]:
            out[b] = first[s]
    return out


@njit
def likelihood_adjoint(next_states, probs, succ, pattern_of, patterns_ak, split, terminal, discount, shared, policy,
                       demo_ptr, demo_s, demo_a, weight):
    """Adjoint (forward) pass of the demonstrations' log-likelihood.

    With c_t(s, a) the weighted count of demonstration transitions at step t,
    the signed mass ``L_t(s, a) = c_t(s, a) + pi_t(a|s) (m_t(s) - c_t(s))`` with
    ``m_{t+1}(s') = discount * sum_{s,a} L_t(s, a) P(s'|s, a)`` and ``m_0 = 0``
    gives ``d loglik = sum_t sum_{s,a} L_t(s, a) d r_bar(s, a)``. Returns
    ``sum_t L_t``, shape (S, A).
    ``shared``, ``succ`` and ``pattern_of`` as in :func:`soft_backward_into`;
    ``patterns_ak`` is its table of patterns transposed, (P, A, K), so that
    the probabilities of one action's successors lie side by side, and ``split``
    is as there.
    """
    n_states, n_actions, n_succ = probs.shape
    horizon = policy.shape[0]
    sa = np.zeros((n_states, n_actions))
    m = np.zeros(n_states)
    m_next = np.zeros(n_states)
    acc = np.zeros(n_succ)
    mass = np.zeros(n_actions)
    base, res_k, res_p, simple = split
    k4 = n_succ - n_succ % 4
    for t in range(horizon):
        for i in range(demo_ptr[t], demo_ptr[t + 1]):
            m[demo_s[i]] -= weight
        for s in range(n_states):
            m_next[s] = 0.0
        for s in range(n_states):
            ms = m[s]
            if ms == 0.0 or terminal[s]:
                continue
            pat = np.uint64(pattern_of[s])  # indices read from arrays as unsigned: no wraparound test
            if shared[s] and simple[pat]:
                # the common part times the total mass, then each action's one successor of its own
                total = 0.0
                for a in range(n_actions):
                    la = ms * policy[t, s, a]
                    mass[a] = la
                    sa[s, a] += la
                    total += la
                for k in range(n_succ):
                    acc[k] = base[pat, k] * total
                for a in range(n_actions):
                    k = np.uint64(res_k[pat, a])
                    acc[k] = _fma(mass[a], res_p[pat, a], acc[k])
                for k in range(n_succ):
                    m_next[np.uint64(succ[s, k])] += discount * acc[k]
            elif shared[s]:
                # acc[k] summed over a in order; four successors at a time in registers, then the rest
                for a in range(n_actions):
                    la = ms * policy[t, s, a]
                    mass[a] = la
                    sa[s, a] += la
                for k in range(0, k4, 4):
                    c0 = 0.0
                    c1 = 0.0
                    c2 = 0.0
                    c3 = 0.0
                    for a in range(n_actions):
                        la = mass[a]
                        c0 = _fma(la, patterns_ak[pat, a, k], c0)
                        c1 = _fma(la, patterns_ak[pat, a, k + 1], c1)
                        c2 = _fma(la, patterns_ak[pat, a, k + 2], c2)
                        c3 = _fma(la, patterns_ak[pat, a, k + 3], c3)
                    acc[k] = c0
                    acc[k + 1] = c1
                    acc[k + 2] = c2
                    acc[k + 3] = c3
                for k in range(k4, n_succ):
                    c0 = 0.0
                    for a in range(n_actions):
                        c0 = _fma(mass[a], patterns_ak[pat, a, k], c0)
                    acc[k] = c0
                for k in range(n_succ):
                    m_next[succ[s, k]] += discount * acc[k]
            else:
                for a in range(n_actions):
                    la = ms * policy[t, s, a]
                    sa[s, a] += la
                    for k in range(n_succ):
                        p = probs[s, a, k]
                        if p != 0.0:
                            m_next[next_states[s, a, k]] += discount * la * p
        for i in range(demo_ptr[t], demo_ptr[t + 1]):
            s = demo_s[i]
            a = demo_a[i]
            sa[s, a] += weight
            for k in range(n_succ):
                p = probs[s, a, k]
                if p != 0.0:
                    m_next[next_states[s, a, k]] += discount * weight * p
        for s in range(n_states):
            m[s] = m_next[s]
    return sa


@njit
def affine_rewards(r0, indptr, indices, data, w, out):
    """``out = r0 - G w`` for G in CSR form (``indptr``, ``indices``, ``data``), one row per entry of ``r0``.

    ``r0`` and ``out`` are C-contiguous of any shape with ``indptr.size - 1``
    entries; each row's product is summed in the order of its entries.
    """
    flat_r0 = r0.reshape(-1)
    flat_out = out.reshape(-1)
    for i in range(indptr.size - 1):
        acc = 0.0
        for j in range(indptr[i], indptr[i + 1]):
            acc = _fma(data[j], w[indices[j]], acc)
        flat_out[i] = flat_r0[i] - acc


@njit
def transposed_product(indptr, indices, data, x, n_cols):
    """``G.T x`` for G in CSR form with ``n_cols`` columns (rows taken in order)."""
    out = np.zeros(n_cols)
    for i in range(indptr.size - 1):
        xi = x[i]
        if xi == 0.0:
            continue
        for j in range(indptr[i], indptr[i + 1]):
            out[indices[j]] += data[j] * xi
    return out


@njit
def projected_gradient_max(w, grad, upper, free):
    """Largest violation of the first-order conditions of ``max grad . w`` on ``0 <= w <= upper``.

    Over the coordinates with ``free`` True: ``|grad|`` inside the box,
    ``max(grad, 0)`` at zero and ``max(-grad, 0)`` at ``upper`` (the latter
    where both hold); 0 when none is free, nan when a free gradient is nan.
    """
    out = 0.0
    for f in range(w.size):
        if not free[f]:
            continue
        g = grad[f]
        if g != g:
            return g
        if w[f] >= upper[f]:
            x = -g if g < 0.0 else 0.0
        elif w[f] <= 0.0:
            x = g if g > 0.0 else 0.0
        else:
            x = abs(g)
        if x > out:
            out = x
    return out


@njit
def shared_successors(next_states):
    """Mask of states whose actions all list the same successors in the same order."""
    n_states, n_actions, n_succ = next_states.shape
    out = np.ones(n_states, dtype=np.bool_)
    for s in range(n_states):
        for a in range(1, n_actions):
            for k in range(n_succ):
                if next_states[s, a, k] != next_states[s, 0, k]:
                    out[s] = False
                    break
            if not out[s]:
                break
    return out


# ------------------------------------------------------------------ visitation
@njit
def _propagate(next_states, probs, terminal, pol, d, weight, sa, dst, d_next):
    n_states, n_actions, n_succ = probs.shape
    for s in range(n_states):
        d_next[s] = 0.0
    for s in range(n_states):
        ds = d[s]
        if ds == 0.0 or terminal[s]:
            continue
        for a in range(n_actions):
            m = ds * pol[s, a]
            if m == 0.0:
                continue
            sa[s, a] += weight * m
            for k in range(n_succ):
                p = probs[s, a, k]
                if p != 0.0:
                    ns = next_states[s, a, k]
                    d_next[ns] += m * p
                    dst[ns] += weight * m * p


@njit
def visitation_finite(next_states, probs, terminal, discount, policy, d0):
    """Discounted visitation over ``policy.shape[0]`` steps of a time-indexed policy.

    Returns ``(sa, dst)``: ``sa[s, a] = sum_t discount**t Pr(s_t = s, a_t = a)`` and
    ``dst[s'] = sum_t discount**t Pr(s_t non-terminal, s_{t+1} = s')``.
    """
    n_states, n_actions, _ = probs.shape
    horizon = policy.shape[0]
    sa = np.zeros((n_states, n_actions))
    dst = np.zeros(n_states)
    d = d0.copy()
    d_next = np.zeros(n_states)
    weight = 1.0
    for t in range(horizon):
        _propagate(next_states, probs, terminal, policy[t], d, weight, sa, dst, d_next)
        for s in range(n_states):
            d[s] = d_next[s]
        weight *= discount
    return sa, dst


@njit
def visitation_stationary(next_states, probs, terminal, discount, policy, d0, max_iter, tol):
    """Discounted visitation of a stationary policy, summed until the mass left is <= tol.

    Returns ``(sa, dst, n_iter, converged)``; converged means the discounted mass
    still in non-terminal states after ``n_iter`` steps is at most ``tol``.
    """
    n_states, n_actions, _ = probs.shape
    sa = np.zeros((n_states, n_actions))
    dst = np.zeros(n_states)
    d = d0.copy()
    d_next = np.zeros(n_states)
    weight = 1.0
    converged = False
    n_iter = 0
    for it in range(max_iter):
        _propagate(next_states, probs, terminal, policy, d, weight, sa, dst, d_next)
        weight *= discount
        left = 0.0
        for s in range(n_states):
            d[s] = d_next[s]
            if not terminal[s]:
                left += d_next[s]
        n_iter = it + 1
        if weight * left <= tol:
            converged = True
            break
    return sa, dst, n_iter, converged


# -------------------------------------------------------------------- sampling
@njit
def _draw(cdf_row_probs, u):
    acc = 0.0
    n = cdf_row_probs.shape[0]
    for i in range(n):
        acc += cdf_row_probs[i]
        if u < acc:
            return i
    # round-off: return the last entry with positive probability
    for i in range(n - 1, -1, -1):
        if cdf_row_probs[i] > 0.0:
            return i
    return n - 1


@njit
def sample_trajectories(next_states, probs, terminal, policy, time_indexed, start, n, max_steps, rng):
    """Sample ``n`` trajectories; each stops on entering a terminal state or after max_steps.

    Returns flat arrays ``(offsets, states, actions, succ, reached)``: trajectory i
    has transitions ``offsets[i]:offsets[i + 1]``.
    """
    n_policy_steps = policy.shape[0]
    cap = n * 16
    states = np.empty(cap, dtype=np.int64)
    actions = np.empty(cap, dtype=np.int64)
    succ = np.empty(cap, dtype=np.int64)
    offsets = np.zeros(n + 1, dtype=np.int64)
    reached = np.zeros(n, dtype=np.bool_)
    pos = 0
    for i in range(n):
        s = _draw(start, rng.random())
        t = 0
        while t < max_steps and not terminal[s]:
            if time_indexed:
                row = policy[min(t, n_policy_steps - 1), s]
            else:
                row = policy[0, s]
            a = _draw(row, rng.random())
            k = _draw(probs[s, a], rng.random())
            ns = next_states[s, a, k]
            if pos == cap:
                cap *= 2
                grown = np.empty(cap, dtype=np.int64)
                grown[:pos] = states[:pos]
                states = grown
                grown = np.empty(cap, dtype=np.int64)
                grown[:pos] = actions[:pos]
                actions = grown
                grown = np.empty(cap, dtype=np.int64)
                grown[:pos] = succ[:pos]
                succ = grown
            states[pos] = s
            actions[pos] = a
            succ[pos] = ns
            pos += 1
            s = ns
            t += 1
        reached[i] = terminal[s]
        offsets[i + 1] = pos
    return offsets, states[:pos].copy(), actions[:pos].copy(), succ[:pos].copy(), reached


# ---------------------------------------------------------------- utilities
@njit
def reaches_terminal(next_states, probs, terminal):
    """Mask of states from which some policy reaches a terminal state with positive probability."""
    n_states, n_actions, n_succ = probs.shape
    # reverse adjacency by repeated sweeps (bounded by n_states passes)
    ok = terminal.copy()
    for _ in range(n_states):
        changed = False
        for s in range(n_states):
            if ok[s]:
                continue
            found = False
            for a in range(n_actions):
                for k in range(n_succ):
                    if probs[s, a, k] > 0.0 and ok[next_states[s, a, k]]:
                        found = True
                        break
                if found:
                    break
            if found:
                ok[s] = True
                changed = True
        if not changed:
            break
    return ok


@njit
def merge_successors(dest, prob):
    """Merge duplicate successors of each (s, a); returns padded (next_states, probs).

    ``dest`` and ``prob`` have shape (S, A, M); the result has K = the largest number
    of distinct positive-probability successors, padded with the state itself and 0.
    """
    n_states, n_actions, m = dest.shape
    out_d = np.empty((n_states, n_actions, m), dtype=np.int64)
    out_p = np.zeros((n_states, n_actions, m))
    width = 1
    for s in range(n_states):
        for a in range(n_actions):
            cnt = 0
            for j in range(m):
                p = prob[s, a, j]
                if p <= 0.0:
                    continue
                d = dest[s, a, j]
                found = -1
                for i in range(cnt):
                    if out_d[s, a, i] == d:
                        found = i
                        break
                if found >= 0:
                    out_p[s, a, found] += p
                else:
                    out_d[s, a, cnt] = d
                    out_p[s, a, cnt] = p
                    cnt += 1
            for i in range(cnt, m):
                out_d[s, a, i] = s
                out_p[s, a, i] = 0.0
            if cnt > width:
                width = cnt
    return out_d[:, :, :width].copy(), out_p[:, :, :width].copy()
