"""Finite differences of an objective on the optimiser's unit cube.

Central differences of a function ``f(u)``, ``u`` in ``[0, 1]^k``: its gradient and its
Hessian over some of the coordinates. A likelihood smooth only up to a noise (the exact
engine's on three options, ``docs/fitting.md``) is differenced with steps of about a
standard error (:func:`rough_steps`), so that the noise is small beside what they measure.
"""

from __future__ import annotations

import numpy as np

#: A rough objective's Hessian: the pilot step of each coordinate's curvature, and the
#: smallest and largest steps then taken (unit-cube coordinates, within the bounds).
ROUGH_PILOT = 1e-2
ROUGH_MIN = 1e-3
ROUGH_MAX = 0.1


def room(u, i):
    """Distance of coordinate ``i`` of ``u`` to the nearer face of the cube."""
    return min(float(u[i]), 1.0 - float(u[i]))


def gradient(f, u, idx, steps):
    """Central-difference gradient of ``f`` at ``u`` over the coordinates ``idx``, with
    the step ``steps[a]`` along coordinate ``idx[a]``."""
    g = np.empty(idx.size)
    for a, i in enumerate(idx):
        e = np.zeros_like(u)
        e[i] = steps[a]
        g[a] = (f(u + e) - f(u - e)) / (2.0 * steps[a])
    return g


def rough_steps(f, u, idx, f0=None):
    """Steps of about one standard error for the coordinates ``idx`` of a rough objective
    (a negative log-likelihood), each within the room to the bounds.

    A pilot second difference over :data:`ROUGH_PILOT` (or the room to the nearer bound)
    gives each coordinate's curvature ``d``; its step is then ``1 / sqrt(d)``, over which
    ``f`` rises by about 1/2, kept within :data:`ROUGH_MIN`, :data:`ROUGH_MAX` and the room
    (the pilot step where ``d <= 0``). A noise ``eps`` in ``f`` then puts an error of about
    ``4 eps`` in that coordinate's curvature relative to it, where a step of 1e-4 puts
    ``eps / (d * 1e-8)``."""
    f0 = f(u) if f0 is None else f0
    steps = np.empty(idx.size)
    for a, i in enumerate(idx):
        space = room(u, i)
        h = min(ROUGH_PILOT, space)
        e = np.zeros_like(u)
        e[i] = h
        d = (f(u + e) - 2.0 * f0 + f(u - e)) / h**2
        wanted = 1.0 / np.sqrt(d) if d > 0.0 else h
        steps[a] = min(max(wanted, min(ROUGH_MIN, space)), ROUGH_MAX, space)
    return steps


def hessian(f, u, idx, steps, f0=None):
    """Central-difference Hessian of ``f`` at ``u`` over the coordinates ``idx``, with the
    step ``steps[a]`` along coordinate ``idx[a]``."""
    k = idx.size
    H = np.empty((k, k))
    f0 = f(u) if f0 is None else f0
    for a in range(k):
        i = idx[a]
        e_i = np.zeros_like(u)
        e_i[i] = steps[a]
        fp, fm = f(u + e_i), f(u - e_i)
        H[a, a] = (fp - 2.0 * f0 + fm) / steps[a] ** 2
        for b in range(a + 1, k):
            j = idx[b]
            e_j = np.zeros_like(u)
            e_j[j] = steps[b]
            H[a, b] = H[b, a] = (
                f(u + e_i + e_j) - f(u + e_i - e_j) - f(u - e_i + e_j) + f(u - e_i - e_j)
            ) / (4.0 * steps[a] * steps[b])
    return 0.5 * (H + H.T)
