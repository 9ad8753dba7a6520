"""Compiled kernels of the MDFT simulation engine.

Nothing here validates its input: :mod:`mdft.simulate` checks and converts
everything once and then calls these functions. Conventions:

* ``state`` is a ``uint64`` array of length 4, the state of one xoshiro256++
  stream, advanced in place. ``states`` stacks one such row per chunk. The
  helpers :func:`xoshiro`, :func:`normal_words` and :func:`attribute_words`
  take the four words and return them advanced, so that a kernel can hold
  them in local variables for a whole trial (:func:`small_trial`) and write
  them back with :func:`store_words`.
* ``cuts`` holds the cumulative attention weights ``cumw`` scaled to
  integers, ``cuts[j] = ceil(cumw[j] 2**53)``; attribute ``j`` is attended
  when ``cumw[j-1] <= u < cumw[j]`` for the uniform ``u`` in [0, 1) of one
  53-bit draw (no draw at all when there is a single attribute).
* ``bounds`` has ``n_chunks + 1`` entries: chunk ``c`` runs trials
  ``bounds[c] <= k < bounds[c + 1]`` with the stream ``states[c]``.

Random numbers
--------------
The kernels carry their own generator, xoshiro256++ (Blackman & Vigna), so
that a draw is a few inlined integer operations instead of an indirect call
into NumPy's bit generator, and so that a chunk's stream is just four words
that the public layer draws from the caller's ``numpy.random.Generator``.
Normal deviates come from a 256-layer ziggurat (Marsaglia & Tsang 2000) on
that stream. See ``docs/simulation.md`` for the reasons.
"""

from __future__ import annotations

import math

import numpy as np
from numba import prange

from ._numba import njit, njit_inline, njit_parallel

# ---------------------------------------------------------------- xoshiro256++
_SH11 = np.uint64(11)
_SH17 = np.uint64(17)
_ROT23_L = np.uint64(23)
_ROT23_R = np.uint64(41)
_ROT45_L = np.uint64(45)
_ROT45_R = np.uint64(19)
_SH8 = np.uint64(8)
_LOW8 = np.uint64(0xFF)
_BIT = np.uint64(1)
_TWO_M53 = 2.0**-53


@njit_inline
def xoshiro(s0, s1, s2, s3):
    """One step of xoshiro256++ on the four words of a stream held in local variables:
    ``(bits, s0, s1, s2, s3)``, 64 random bits and the words after the step."""
    t = s0 + s3
    result = ((t << _ROT23_L) | (t >> _ROT23_R)) + s0
    t = s1 << _SH17
    s2 ^= s0
    s3 ^= s1
    s1 ^= s2
    s0 ^= s3
    s2 ^= t
    s3 = (s3 << _ROT45_L) | (s3 >> _ROT45_R)
    return result, s0, s1, s2, s3


@njit_inline
def store_words(state, s0, s1, s2, s3):
    """Write a stream's four words, held in local variables, back to ``state``."""
    state[0] = s0
    state[1] = s1
    state[2] = s2
    state[3] = s3


@njit_inline
def load_words(state):
    """The four words of the stream ``state``, to be held in local variables."""
    return state[0], state[1], state[2], state[3]


@njit_inline
def next_u64(state):
    """Advance the xoshiro256++ stream ``state`` (uint64[4]) and return 64 random bits."""
    s0, s1, s2, s3 = load_words(state)
    result, s0, s1, s2, s3 = xoshiro(s0, s1, s2, s3)
    store_words(state, s0, s1, s2, s3)
    return result


@njit_inline
def _uniform(bits):
    """A uniform double in [0, 1) from the top 53 of 64 random bits."""
    return np.float64(bits >> _SH11) * _TWO_M53


@njit_inline
def next_double(state):
    """A uniform double in [0, 1) with 53 random bits."""
    return _uniform(next_u64(state))


# ---------------------------------------------------------------- ziggurat
def _ziggurat_tables(n_layers=256, r=3.6541528853610088, v=0.00492867323399):
    """Layer edges ``x`` and heights ``f(x) = exp(-x**2/2)`` of the normal ziggurat.

    Layer 0 is the base strip (the rectangle ``[0, r] x [0, f(r)]`` plus the
    tail beyond ``r``), given the width ``v / f(r)`` so that its area is
    ``v`` like every other layer. Layer ``i >= 1`` is the rectangle
    ``[0, x[i]] x [f(x[i]), f(x[i+1])]``; ``x[n_layers] = 0``.
    """
    x = np.empty(n_layers + 1)
    x[0] = v / math.exp(-0.5 * r * r)
    x[1] = r
    for i in range(1, n_layers - 1):
        x[i + 1] = math.sqrt(-2.0 * math.log(v / x[i] + math.exp(-0.5 * x[i] * x[i])))
    x[n_layers] = 0.0
    return x, np.exp(-0.5 * x * x)


_ZX, _ZF = _ziggurat_tables()
_ZR = 3.6541528853610088


@njit_inline
def normal_words(s0, s1, s2, s3):
    """A standard normal deviate (ziggurat method) from the stream's words held in local
    variables: ``(z, s0, s1, s2, s3)``.

    The first 64-bit word gives the layer (bits 0-7), the sign (bit 8) and a
    53-bit uniform (bits 11-63); about 99% of the calls use that word only.
    """
    # A rejection sampler: each pass accepts with probability > 0.98, so the
    # bound on the number of passes is never reached in practice.
    for _ in range(1_000_000):
        u, s0, s1, s2, s3 = xoshiro(s0, s1, s2, s3)
        i = np.intp(u & _LOW8)
        # +1.0 or -1.0, computed without a branch (the sign is unpredictable).
        sign = 1.0 - 2.0 * np.float64((u >> _SH8) & _BIT)
        z = _uniform(u) * _ZX[i]
        if z < _ZX[i + 1]:
            return sign * z, s0, s1, s2, s3
        if i == 0:
            # Tail beyond r (Marsaglia 1964): exponential proposals, accepted
            # with probability exp(-a**2 / 2).
            for _ in range(1_000_000):
                u, s0, s1, s2, s3 = xoshiro(s0, s1, s2, s3)
                a = -math.log(1.0 - _uniform(u)) / _ZR
                u, s0, s1, s2, s3 = xoshiro(s0, s1, s2, s3)
                b = -math.log(1.0 - _uniform(u))
                if b + b > a * a:
                    return sign * (_ZR + a), s0, s1, s2, s3
        else:
            u, s0, s1, s2, s3 = xoshiro(s0, s1, s2, s3)
            y = _ZF[i] + _uniform(u) * (_ZF[i + 1] - _ZF[i])
            if y < math.exp(-0.5 * z * z):
                return sign * z, s0, s1, s2, s3
    return 0.0, s0, s1, s2, s3


@njit_inline
def standard_normal(state):
    """A standard normal deviate from the stream ``state`` (:func:`normal_words`)."""
    s0, s1, s2, s3 = load_words(state)
    z, s0, s1, s2, s3 = normal_words(s0, s1, s2, s3)
    store_words(state, s0, s1, s2, s3)
    return z


# ---------------------------------------------------------------- small helpers
@njit_inline
def attribute_words(s0, s1, s2, s3, cuts):
    """Index of the attended attribute from the stream's words held in local variables:
    ``(j, s0, s1, s2, s3)``. No draw is made for a single attribute.

    One draw gives the uniform ``u = x 2**-53``, ``x`` the top 53 of its 64 bits.
    ``cuts[q] = ceil(cumw[q] 2**53)`` for the cumulative weights ``cumw``, so
    that ``x >= cuts[q]`` exactly when ``u >= cumw[q]``; the index is the
    number of such ``q < J - 1``, i.e. the first ``j`` with ``u < cumw[j]``.
    It is counted with integer arithmetic only (``1 + ((x - c) >> 63)`` is 1
    when ``x >= c`` and 0 otherwise): the outcome is random, and a branch or
    a floating-point comparison on it would be mispredicted half of the time.
    """
    if cuts.shape[0] == 1:
        return 0, s0, s1, s2, s3
    bits, s0, s1, s2, s3 = xoshiro(s0, s1, s2, s3)
    x = np.int64(bits >> _SH11)
    j = 0
    for q in range(cuts.shape[0] - 1):
        j += 1 + ((x - cuts[q]) >> 63)
    return j, s0, s1, s2, s3


@njit_inline
def draw_attribute(state, cuts):
    """Index of the attended attribute from the stream ``state`` (:func:`attribute_words`)."""
    s0, s1, s2, s3 = load_words(state)
    j, s0, s1, s2, s3 = attribute_words(s0, s1, s2, s3, cuts)
    store_words(state, s0, s1, s2, s3)
    return j


@njit_inline
def argmax_random_ties(P, state):
    """Index of the largest entry of ``P``; exact ties broken uniformly at random.

    A uniform is drawn only when there is a tie: among the ``k`` tied indices
    (in increasing order) the one at position ``floor(u * k)`` is returned.
    """
    n = P.shape[0]
    best = P[0]
    index = 0
    n_tied = 1
    for i in range(1, n):
        if P[i] > best:
            best = P[i]
            index = i
            n_tied = 1
        elif P[i] == best:
            n_tied += 1
    if n_tied == 1:
        return index
    pick = np.intp(next_double(state) * n_tied)
    seen = 0
    for i in range(n):
        if P[i] == best:
            if seen == pick:
                return i
            seen += 1
    return index


# ---------------------------------------------------------------- plain dynamics
@njit
def plain_trial(state, S, CM, C, noise_sd, cuts, P0, n_steps, theta, use_threshold,
                P, P_next, eps, trajectory, record):
    """One trial of the step-by-step dynamics ``P(t) = S P(t-1) + C (M W(t) + eps(t))``.

    Per step the draws are: the attended attribute (one uniform, none for a
    single attribute), then ``n_options`` normals (none when ``noise_sd`` is
    0). With ``use_threshold`` the trial stops at the first step where some
    preference reaches ``theta`` and chooses the largest preference;
    otherwise it runs ``n_steps`` steps and chooses ``argmax P(n_steps)``.
    Ties are broken at random. Returns ``(choice, step)``; ``(-1, -1)`` for a
    threshold trial still undecided after ``n_steps`` steps. With ``record``
    the preferences ``P(0..)`` are written to the rows of ``trajectory``.
    """
    n = P0.shape[0]
    for i in range(n):
        P[i] = P0[i]
    if record:
        for i in range(n):
            trajectory[0, i] = P[i]
    for t in range(1, n_steps + 1):
        j = draw_attribute(state, cuts)
        if noise_sd > 0.0:
            for i in range(n):
                eps[i] = noise_sd * standard_normal(state)
        for i in range(n):
            acc = 0.0
            for k in range(n):
                acc += S[i, k] * P[k]
            acc += CM[i, j]
            if noise_sd > 0.0:
                for k in range(n):
                    acc += C[i, k] * eps[k]
            P_next[i] = acc
        reached = False
        for i in range(n):
            P[i] = P_next[i]
            if P[i] >= theta:
                reached = True
        if record:
            for i in range(n):
                trajectory[t, i] = P[i]
        if use_threshold and reached:
            return argmax_random_ties(P, state), t
    if use_threshold:
        return -1, -1
    return argmax_random_ties(P, state), n_steps


@njit_inline
def _corner(A):
    """The entries of the top-left 2 x 2 block of ``A``, row by row."""
    return A[0, 0], A[0, 1], A[1, 0], A[1, 1]


@njit_inline
def _third(A):
    """The entries of ``A``'s third column and row outside that block: ``A[0, 2], A[1, 2],
    A[2, 0], A[2, 1], A[2, 2]``."""
    return A[0, 2], A[1, 2], A[2, 0], A[2, 1], A[2, 2]


@njit
def small_trial(state, S, CM, C, noise_sd, cuts, P0, n_steps, theta, use_threshold, P):
    """:func:`plain_trial` for two or three options (not recorded), the state in scalars.

    The same draws in the same order and the same arithmetic in the same order, so
    the same choices and steps to the bit; about 1.7 times as fast (the generic loops
    keep the state in memory and cannot be unrolled). The stream's four words are held
    in local variables too, and written back to ``state`` before a tie is broken and at
    the end: in memory, every draw waited on the stores of the one before. With two
    options the third coordinate is carried as zero and never drawn for, tested or
    chosen.
    """
    three = P0.shape[0] == 3
    s00, s01, s10, s11 = _corner(S)
    c00, c01, c10, c11 = _corner(C)
    s02 = s12 = s20 = s21 = s22 = c02 = c12 = c20 = c21 = c22 = 0.0
    if three:
        s02, s12, s20, s21, s22 = _third(S)
        c02, c12, c20, c21, c22 = _third(C)
    noisy = noise_sd > 0.0
    w0, w1, w2, w3 = load_words(state)
    p0 = P0[0]
    p1 = P0[1]
    p2 = P0[2] if three else 0.0
    e0 = e1 = e2 = 0.0
    decided = False
    for t in range(1, n_steps + 1):
        j, w0, w1, w2, w3 = attribute_words(w0, w1, w2, w3, cuts)
        if noisy:
            e0, w0, w1, w2, w3 = normal_words(w0, w1, w2, w3)
            e1, w0, w1, w2, w3 = normal_words(w0, w1, w2, w3)
            e0 = noise_sd * e0
            e1 = noise_sd * e1
            if three:
                e2, w0, w1, w2, w3 = normal_words(w0, w1, w2, w3)
                e2 = noise_sd * e2
        if three:
            q0 = s00 * p0 + s01 * p1 + s02 * p2 + CM[0, j]
            q1 = s10 * p0 + s11 * p1 + s12 * p2 + CM[1, j]
            q2 = s20 * p0 + s21 * p1 + s22 * p2 + CM[2, j]
            if noisy:
                q0 = q0 + c00 * e0 + c01 * e1 + c02 * e2
                q1 = q1 + c10 * e0 + c11 * e1 + c12 * e2
                q2 = q2 + c20 * e0 + c21 * e1 + c22 * e2
        else:
            q0 = s00 * p0 + s01 * p1 + CM[0, j]
            q1 = s10 * p0 + s11 * p1 + CM[1, j]
            q2 = 0.0
            if noisy:
                q0 = q0 + c00 * e0 + c01 * e1
                q1 = q1 + c10 * e0 + c11 * e1
        p0 = q0
        p1 = q1
        p2 = q2
        if use_threshold and (p0 >= theta or p1 >= theta or (three and p2 >= theta)):
            decided = True
            break
    store_words(state, w0, w1, w2, w3)
    if use_threshold and not decided:
        return -1, -1
    P[0] = p0
    P[1] = p1
    if three:
        P[2] = p2
    return argmax_random_ties(P, state), t


@njit_inline
def reduced_coefficients(S, L, three):
    """The entries of ``S`` (row by row, zero beyond a 2 x 2 ``S``) and of ``L`` (row by
    row, zero beyond its ``r`` columns), a 15-tuple for the kernels to unpack into scalars."""
    r = L.shape[1]
    s00, s01, s10, s11 = _corner(S)
    s02 = s12 = s20 = s21 = s22 = 0.0
    if three:
        s02, s12, s20, s21, s22 = _third(S)
    l00 = l01 = l10 = l11 = l20 = l21 = 0.0
    if r >= 1:
        l00 = L[0, 0]
        l10 = L[1, 0]
        if three:
            l20 = L[2, 0]
    if r >= 2:
        l01 = L[0, 1]
        l11 = L[1, 1]
        if three:
            l21 = L[2, 1]
    return (s00, s01, s02, s10, s11, s12, s20, s21, s22, l00, l01, l10, l11, l20, l21)


@njit_inline
def reduced_draws(w0, w1, w2, w3, cuts, r):
    """A step's attended attribute and ``r <= 2`` normals from the stream's words held in
    local variables: ``(j, z0, z1, w0, w1, w2, w3)`` (``z`` zero beyond ``r``)."""
    z0 = z1 = 0.0
    j, w0, w1, w2, w3 = attribute_words(w0, w1, w2, w3, cuts)
    if r >= 1:
        z0, w0, w1, w2, w3 = normal_words(w0, w1, w2, w3)
    if r >= 2:
        z1, w0, w1, w2, w3 = normal_words(w0, w1, w2, w3)
    return j, z0, z1, w0, w1, w2, w3


@njit_inline
def reduced_choice(state, P, p0, p1, p2, three):
    """The option chosen by the preferences ``(p0, p1, p2)`` that reached the threshold
    (:func:`argmax_random_ties`, after the stream's words are stored)."""
    P[0] = p0
    P[1] = p1
    if three:
        P[2] = p2
    return argmax_random_ties(P, state)


@njit
def reduced_trial(state, S, CM, L, cuts, P0, n_steps, theta, P):
    """A threshold trial of two or three options whose noise ``C eps`` is drawn as ``L z``
    from ``r = L.shape[1] <= 2`` normals, ``L L^T = sigma2 C C^T``
    (:func:`mdft.simulate._noise_factor` over one step). With the contrast matrix
    ``C eps`` lies in the ``n - 1`` dimensions orthogonal to the ones vector, so this
    draws one normal fewer per step than :func:`small_trial`: the same distribution of
    choices and steps, about 1.3 times as fast with three options, but not the same trials
    from the same stream (the simulation fallback of ``threshold_probabilities`` runs it;
    ``simulate`` keeps :func:`small_trial`). ``(choice, step)``, ``(-1, -1)`` undecided.
    """
    three = P0.shape[0] == 3
    r = L.shape[1]
    (s00, s01, s02, s10, s11, s12, s20, s21, s22,
     l00, l01, l10, l11, l20, l21) = reduced_coefficients(S, L, three)
    w0, w1, w2, w3 = load_words(state)
    p0 = P0[0]
    p1 = P0[1]
    p2 = P0[2] if three else 0.0
    for t in range(1, n_steps + 1):
        j, z0, z1, w0, w1, w2, w3 = reduced_draws(w0, w1, w2, w3, cuts, r)
        # written out here and in mdft._control_kernels.controlled_trial: a helper taking
        # the coefficients as a tuple made this kernel 1.35 times slower
        q0 = s00 * p0 + s01 * p1 + s02 * p2 + CM[0, j] + l00 * z0 + l01 * z1
        q1 = s10 * p0 + s11 * p1 + s12 * p2 + CM[1, j] + l10 * z0 + l11 * z1
        if three:
            p2 = s20 * p0 + s21 * p1 + s22 * p2 + CM[2, j] + l20 * z0 + l21 * z1
        p0, p1 = q0, q1
        if p0 >= theta or p1 >= theta or (three and p2 >= theta):
            store_words(state, w0, w1, w2, w3)
            return reduced_choice(state, P, p0, p1, p2, three), t
    store_words(state, w0, w1, w2, w3)
    return -1, -1


@njit
def reduced_chunk(state, first, stop, S, CM, L, cuts, P0, n_steps, theta, choices, steps):
    """Trials ``first <= k < stop`` with :func:`reduced_trial` on one stream; writes
    ``choices[k - first]`` and ``steps[k - first]``."""
    P = np.empty(P0.shape[0])
    for k in range(first, stop):
        choice, step = reduced_trial(state, S, CM, L, cuts, P0, n_steps, theta, P)
        choices[k - first] = choice
        steps[k - first] = step


@njit_parallel
def reduced_chunks(states, bounds, S, CM, L, cuts, P0, n_steps, theta, choices, steps):
    """:func:`reduced_chunk` for every chunk ``c`` (stream ``states[c]``), in parallel.

    The loop is :func:`plain_chunks`' own. One parallel kernel taking the chunk kernel as
    an argument would serve both, but numba's disk cache misses for a kernel with a
    function argument in every new process (it compiles again each time), which
    :func:`mdft.warmup` could not then save."""
    n_chunks = bounds.shape[0] - 1
    origin = bounds[0]
    for c in prange(n_chunks):
        lo = bounds[c] - origin
        hi = bounds[c + 1] - origin
        reduced_chunk(states[c], bounds[c], bounds[c + 1], S, CM, L, cuts, P0, n_steps,
                      theta, choices[lo:hi], steps[lo:hi])


@njit_inline
def _row4(A, i):
    """Row ``i`` of the 4 x 4 matrix ``A`` as four scalars."""
    return A[i, 0], A[i, 1], A[i, 2], A[i, 3]


@njit_inline
def _four_normals(sd, w0, w1, w2, w3):
    """Four normal deviates of standard deviation ``sd``, in order, from the stream's words
    held in local variables: ``(e0, e1, e2, e3, w0, w1, w2, w3)``."""
    z0, w0, w1, w2, w3 = normal_words(w0, w1, w2, w3)
    z1, w0, w1, w2, w3 = normal_words(w0, w1, w2, w3)
    z2, w0, w1, w2, w3 = normal_words(w0, w1, w2, w3)
    z3, w0, w1, w2, w3 = normal_words(w0, w1, w2, w3)
    return sd * z0, sd * z1, sd * z2, sd * z3, w0, w1, w2, w3


@njit
def quad_trial(state, S, CM, C, noise_sd, cuts, P0, n_steps, theta, use_threshold, P):
    """:func:`small_trial` for four options: :func:`plain_trial`'s draws and arithmetic in
    the same order, so the same choices and steps to the bit, with the state, ``S``, ``C``
    and the stream's words in scalars (a kernel of its own, so that the two- and
    three-option kernel keeps its registers)."""
    s00, s01, s02, s03 = _row4(S, 0)
    s10, s11, s12, s13 = _row4(S, 1)
    s20, s21, s22, s23 = _row4(S, 2)
    s30, s31, s32, s33 = _row4(S, 3)
    c00, c01, c02, c03 = _row4(C, 0)
    c10, c11, c12, c13 = _row4(C, 1)
    c20, c21, c22, c23 = _row4(C, 2)
    c30, c31, c32, c33 = _row4(C, 3)
    noisy = noise_sd > 0.0
    w0, w1, w2, w3 = load_words(state)
    p0, p1, p2, p3 = P0[0], P0[1], P0[2], P0[3]
    e0 = e1 = e2 = e3 = 0.0
    decided = False
    for t in range(1, n_steps + 1):
        j, w0, w1, w2, w3 = attribute_words(w0, w1, w2, w3, cuts)
        if noisy:
            e0, e1, e2, e3, w0, w1, w2, w3 = _four_normals(noise_sd, w0, w1, w2, w3)
        q0 = s00 * p0 + s01 * p1 + s02 * p2 + s03 * p3 + CM[0, j]
        q1 = s10 * p0 + s11 * p1 + s12 * p2 + s13 * p3 + CM[1, j]
        q2 = s20 * p0 + s21 * p1 + s22 * p2 + s23 * p3 + CM[2, j]
        q3 = s30 * p0 + s31 * p1 + s32 * p2 + s33 * p3 + CM[3, j]
        if noisy:
            q0 = q0 + c00 * e0 + c01 * e1 + c02 * e2 + c03 * e3
            q1 = q1 + c10 * e0 + c11 * e1 + c12 * e2 + c13 * e3
            q2 = q2 + c20 * e0 + c21 * e1 + c22 * e2 + c23 * e3
            q3 = q3 + c30 * e0 + c31 * e1 + c32 * e2 + c33 * e3
        p0, p1, p2, p3 = q0, q1, q2, q3
        if use_threshold and (p0 >= theta or p1 >= theta or p2 >= theta or p3 >= theta):
            decided = True
            break
    store_words(state, w0, w1, w2, w3)
    if use_threshold and not decided:
        return -1, -1
    P[0], P[1], P[2], P[3] = p0, p1, p2, p3
    return argmax_random_ties(P, state), t


@njit
def plain_chunk(state, first, stop, S, CM, C, noise_sd, cuts, P0, n_steps, theta,
                use_threshold, choices, steps):
    """Trials ``first <= k < stop`` with :func:`plain_trial` on one stream
    (:func:`small_trial` for two or three options, :func:`quad_trial` for four).

    Writes ``choices[k - first]`` and ``steps[k - first]``.
    """
    n = P0.shape[0]
    P = np.empty(n)
    P_next = np.empty(n)
    eps = np.empty(n)
    dummy = np.empty((1, n))
    small = n == 2 or n == 3
    for k in range(first, stop):
        if small:
            choice, step = small_trial(state, S, CM, C, noise_sd, cuts, P0, n_steps, theta,
                                       use_threshold, P)
        elif n == 4:
            choice, step = quad_trial(state, S, CM, C, noise_sd, cuts, P0, n_steps, theta,
                                      use_threshold, P)
        else:
            choice, step = plain_trial(state, S, CM, C, noise_sd, cuts, P0, n_steps, theta,
                                       use_threshold, P, P_next, eps, dummy, False)
        choices[k - first] = choice
        steps[k - first] = step


@njit_parallel
def plain_chunks(states, bounds, S, CM, C, noise_sd, cuts, P0, n_steps, theta,
                 use_threshold, choices, steps):
    """:func:`plain_chunk` for every chunk ``c`` (stream ``states[c]``), chunks in parallel.

    Trial ``k`` writes ``choices[k - bounds[0]]`` and ``steps[k - bounds[0]]``.
    """
    n_chunks = bounds.shape[0] - 1
    origin = bounds[0]
    for c in prange(n_chunks):
        lo = bounds[c] - origin
        hi = bounds[c + 1] - origin
        plain_chunk(states[c], bounds[c], bounds[c + 1], S, CM, C, noise_sd, cuts, P0,
                    n_steps, theta, use_threshold, choices[lo:hi], steps[lo:hi])


@njit
def plain_recorded(state, S, CM, C, noise_sd, cuts, P0, n_steps, theta, use_threshold,
                   trajectories, choices, steps):
    """Run ``trajectories.shape[0]`` trials serially on one stream, recording each one."""
    n = P0.shape[0]
    P = np.empty(n)
    P_next = np.empty(n)
    eps = np.empty(n)
    for k in range(trajectories.shape[0]):
        choice, step = plain_trial(state, S, CM, C, noise_sd, cuts, P0, n_steps, theta,
                                   use_threshold, P, P_next, eps, trajectories[k], True)
        choices[k] = choice
        steps[k] = step


# ---------------------------------------------------------------- fixed-time shortcut
@njit
def attention_table(S, CM, n_steps):
    """``table[k, j, :] = S^k C M e_j`` for ``k < n_steps``: shape (n_steps, J, n)."""
    n, J = CM.shape
    table = np.empty((n_steps, J, n))
    for j in range(J):
        for i in range(n):
            table[0, j, i] = CM[i, j]
    for k in range(1, n_steps):
        for j in range(J):
            for i in range(n):
                acc = 0.0
                for q in range(n):
                    acc += S[i, q] * table[k - 1, j, q]
                table[k, j, i] = acc
    return table


@njit
def block_table(table, block_size):
    """Sums of ``table`` rows over blocks of steps, one per attention pattern.

    Steps ``t = 0 .. T-1`` (step ``t + 1`` of the deliberation) are grouped in
    blocks of ``block_size`` consecutive steps (the last block may be
    shorter). For block ``m`` and the attributes ``j_0, j_1, ...`` attended in
    its steps, the pattern index is ``p = (((j_0) J + j_1) J + ...)`` and

        blocks[m, p] = sum_s table[T - 1 - t_s, j_s],

    the contribution of those steps to ``P(T)``, summed from the block's last
    step back to its first. Shape (n_blocks, J**block_size, n). The patterns
    are built by prepending one step at a time, so the cost is about twice
    the size of the result.
    """
    n_steps, J, n = table.shape
    n_blocks = (n_steps + block_size - 1) // block_size
    n_patterns = J**block_size
    blocks = np.zeros((n_blocks, n_patterns, n))
    for m in range(n_blocks):
        first = m * block_size
        size = min(block_size, n_steps - first)
        # The block's last step alone: its attribute is the lowest digit.
        lag = n_steps - 1 - (first + size - 1)
        for j in range(J):
            for i in range(n):
                blocks[m, j, i] = table[lag, j, i]
        count = J
        for s in range(size - 2, -1, -1):
            lag = n_steps - 1 - (first + s)
            # Prepend step s as the highest digit: new index j * count + p. The
            # slots of j = 0 are the old ones, so they are updated last.
            for j in range(J - 1, -1, -1):
                for p in range(count):
                    for i in range(n):
                        blocks[m, j * count + p, i] = blocks[m, p, i] + table[lag, j, i]
            count *= J
    return blocks


@njit_inline
def draw_pattern(state, cuts, size):
    """Attention pattern of ``size`` consecutive steps, ``p = ((j_0 J + j_1) J + ...)``.

    Draws ``size`` attributes exactly as :func:`draw_attribute` does.
    """
    J = cuts.shape[0]
    p = 0
    for _s in range(size):
        p = p * J + draw_attribute(state, cuts)
    return p


@njit_inline
def draw_pattern2(state, cut0, size):
    """:func:`draw_pattern` for two attributes, the single cut ``cut0`` held in a register.

    Same draws and same result as ``draw_pattern(state, cuts, size)`` with
    ``cuts[0] == cut0``; written out because, read from the array at every
    step, the cut is reloaded after each store to the stream state.
    """
    p = 0
    for _s in range(size):
        x = np.int64(next_u64(state) >> _SH11)
        p = 2 * p + 1 + ((x - cut0) >> 63)
    return p


@njit_inline
def add_block(P, blocks, m, p):
    """``P += blocks[m, p]``."""
    for i in range(P.shape[0]):
        P[i] += blocks[m, p, i]


@njit_inline
def add_row4(a0, a1, a2, a3, blocks, m, p):
    """``(a0, a1, a2, a3) + blocks[m, p]`` for rows of width 4."""
    return (a0 + blocks[m, p, 0], a1 + blocks[m, p, 1], a2 + blocks[m, p, 2],
            a3 + blocks[m, p, 3])


@njit_inline
def attention_sum2x4(state, blocks, base, block_size, n_full, rest, cut0):
    """Attention part of ``P(T)`` for two attributes and rows of width 4, in registers.

    Same draws and same additions, in the same order, as the general path of
    :func:`fixed_time_chunk`; the four sums live in local variables, so no
    store to memory interrupts the stream of draws.
    """
    a0 = base[0]
    a1 = base[1]
    a2 = base[2]
    a3 = base[3]
    if block_size == 8:
        for m in range(n_full):
            a0, a1, a2, a3 = add_row4(a0, a1, a2, a3, blocks, m,
                                      draw_pattern2(state, cut0, 8))
    else:
        for m in range(n_full):
            a0, a1, a2, a3 = add_row4(a0, a1, a2, a3, blocks, m,
                                      draw_pattern2(state, cut0, block_size))
    if rest > 0:
        a0, a1, a2, a3 = add_row4(a0, a1, a2, a3, blocks, n_full,
                                  draw_pattern2(state, cut0, rest))
    return a0, a1, a2, a3


@njit
def fixed_time_chunk(state, first, stop, blocks, block_size, n_steps, base, L, cuts, counts):
    """Fixed-time trials ``first <= k < stop`` through the exact decomposition of ``P(T)``.

    With up to 4 options, ``blocks``, ``base`` and ``L`` may be padded with
    zeros to width 4 (the choice is taken among the first
    ``counts.shape[0]`` entries); with two attributes the sums are then kept
    in registers (:func:`attention_sum2x4`).

    ``P(T) = base + sum_t S^(T-t) C M e_(j_t) + L z`` with ``base = S^T P0``,
    ``j_t`` the attribute attended at step ``t`` and ``z`` a standard normal
    vector of length ``L.shape[1]`` (``L L^T`` is the covariance of the
    accumulated noise). The attention sum is read from :func:`block_table`,
    one lookup per block of steps. Per trial the draws are: ``n_steps``
    attention uniforms in step order (none for one attribute), then
    ``L.shape[1]`` normals, then one uniform only for a tie. Adds each
    choice to ``counts`` (n_options,).

    Two attributes with blocks of 8 steps (the common case) get a loop of
    constant length, which the compiler unrolls; a loop whose length is only
    known at run time costs a mispredicted branch per block.
    """
    n = base.shape[0]
    n_options = counts.shape[0]
    rank = L.shape[1]
    n_full = n_steps // block_size
    rest = n_steps - n_full * block_size
    two = cuts.shape[0] == 2
    width4 = n == 4 and blocks.shape[2] == 4
    cut0 = cuts[0]
    P = np.empty(n)
    for _k in range(first, stop):
        for i in range(n):
            P[i] = base[i]
        if two and width4:
            P[0], P[1], P[2], P[3] = attention_sum2x4(state, blocks, base, block_size, n_full,
                                                      rest, cut0)
        elif two:
            if block_size == 8:
                for m in range(n_full):
                    add_block(P, blocks, m, draw_pattern2(state, cut0, 8))
            else:
                for m in range(n_full):
                    add_block(P, blocks, m, draw_pattern2(state, cut0, block_size))
            if rest > 0:
                add_block(P, blocks, n_full, draw_pattern2(state, cut0, rest))
        else:
            for m in range(n_full):
                add_block(P, blocks, m, draw_pattern(state, cuts, block_size))
            if rest > 0:
                add_block(P, blocks, n_full, draw_pattern(state, cuts, rest))
        for q in range(rank):
            z = standard_normal(state)
            for i in range(n):
                P[i] += L[i, q] * z
        counts[argmax_random_ties(P[:n_options], state)] += 1


@njit_parallel
def fixed_time_chunks(states, bounds, blocks, block_size, n_steps, base, L, cuts, counts):
    """:func:`fixed_time_chunk` for every chunk ``c``, in parallel, counting in ``counts[c]``."""
    n_chunks = bounds.shape[0] - 1
    for c in prange(n_chunks):
        fixed_time_chunk(states[c], bounds[c], bounds[c + 1], blocks, block_size, n_steps,
                         base, L, cuts, counts[c])


# ---------------------------------------------------------------- decisions for agents
@njit
def _one_decision(state, M, cuts, phi1, phi2, beta, noise_sd, n_steps, S, CM, P, P_next, eps):
    n, J = M.shape
    # Hotaling distance and feedback matrix S = I - phi2 exp(-phi1 D^2).
    for a in range(n):
        for b in range(n):
            sq = 0.0
            along = 0.0
            for q in range(J):
                d = M[a, q] - M[b, q]
                sq += d * d
                along += d
            dist = sq + (beta - 1.0) * along * along / J
            S[a, b] = (1.0 if a == b else 0.0) - phi2 * math.exp(-phi1 * dist * dist)
    # Standard contrast: (C x)_i = (n x_i - sum x) / (n - 1).
    scale = n / (n - 1.0)
    for q in range(J):
        mean = 0.0
        for i in range(n):
            mean += M[i, q]
        mean /= n
        for i in range(n):
            CM[i, q] = scale * (M[i, q] - mean)
    for i in range(n):
        P[i] = 0.0
    for _t in range(n_steps):
        j = draw_attribute(state, cuts)
        noise_mean = 0.0
        if noise_sd > 0.0:
            for i in range(n):
                eps[i] = noise_sd * standard_normal(state)
                noise_mean += eps[i]
            noise_mean /= n
        for i in range(n):
            acc = CM[i, j]
            for k in range(n):
                acc += S[i, k] * P[k]
            if noise_sd > 0.0:
                acc += scale * (eps[i] - noise_mean)
            P_next[i] = acc
        for i in range(n):
            P[i] = P_next[i]
    for i in range(n):
        if not np.isfinite(P[i]):
            return -1  # the preferences overflowed: no choice (the wrapper raises)
    return argmax_random_ties(P, state)


@njit
def decide_chunk(state, first, stop, M, cuts, phi1, phi2, beta, noise_sd, n_steps, out):
    """One fixed-time deliberation for each decision ``first <= d < stop``: ``out[d]``.

    ``M`` has shape (n_decisions, n_options, n_attributes) and ``cuts`` shape
    (n_decisions, n_attributes) or (1, n_attributes) (shared). The feedback
    matrix is built from ``M[d]`` inside the kernel; ``P(0) = 0`` and the
    contrast is the standard one.
    """
    n = M.shape[1]
    J = M.shape[2]
    shared = cuts.shape[0] == 1
    S = np.empty((n, n))
    CM = np.empty((n, J))
    P = np.empty(n)
    P_next = np.empty(n)
    eps = np.empty(n)
    for d in range(first, stop):
        cw = cuts[0] if shared else cuts[d]
        out[d] = _one_decision(state, M[d], cw, phi1, phi2, beta, noise_sd, n_steps,
                               S, CM, P, P_next, eps)


@njit_parallel
def decide_chunks(states, bounds, M, cuts, phi1, phi2, beta, noise_sd, n_steps, out):
    """:func:`decide_chunk` for every chunk ``c`` (stream ``states[c]``), in parallel."""
    n_chunks = bounds.shape[0] - 1
    for c in prange(n_chunks):
        decide_chunk(states[c], bounds[c], bounds[c + 1], M, cuts, phi1, phi2, beta, noise_sd,
                     n_steps, out)
