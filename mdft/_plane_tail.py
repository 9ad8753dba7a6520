"""The extrapolated tail of the three-option chain (compiled helpers of :mod:`mdft._plane_step`).

Nothing here validates its input. Once the undecided mass is in the chain's
slowest mode, each step takes the same share ``h`` (the hazard) of it and
splits the choices in fixed proportions ``sigma``; the remaining rows of the
response-time distribution are then geometric. Before that mode is reached,
``h`` and ``sigma`` still drift, and their drift dies out geometrically at the
rate of the next mode. :func:`drift` estimates from three windows of the
recent history how far each still has to go; :func:`tail_error` turns those
distances into the change they would make to the probabilities and mean
response times if the tail were filled now. The chain stops propagating once
that change is within a budget, fills the tail with :func:`fill`, and adds the
change to its error estimate (``docs/threshold_exact.md``, section 5).
"""

from __future__ import annotations

from ._numba import njit

# Window (steps) over which the drift of the hazard and the shares is measured first.
WINDOW = 25
# A drift that is not geometric over WINDOW steps is measured again over windows doubled up
# to this many times: a slow next mode (a ratio per step near 1) shrinks by less than
# _MAX_RATIO over 25 steps, and would otherwise never let the tail be filled.
_DOUBLINGS = 5
# A drift that shrinks by less than this factor from one window to the next is not yet
# geometric: no estimate (the tail is not filled).
_MAX_RATIO = 0.95
# The remaining drift is taken as this many times its geometric estimate.
_SAFETY = 2.0


@njit
def drift(v0, v1, v2, v3):
    """Distance that a quantity seen at four times a window apart (``v3`` latest) still has
    to go, if its changes shrink geometrically; -1 when they do not (yet)."""
    d0 = v1 - v0
    d1 = v2 - v1
    d2 = v3 - v2
    scale = abs(v3)
    if abs(d2) <= 1e-14 * scale and abs(d1) <= 1e-14 * scale:
        return abs(d2) + abs(d1)
    if d0 * d1 <= 0.0 or d1 * d2 <= 0.0:
        return -1.0
    return _settling(abs(d0), abs(d1), abs(d2))


@njit
def _tail_sums(mass, h, n_rows, t):
    """Mass absorbed over rows ``t+1 .. t+n_rows`` at hazard ``h``, and its time-weighted sum
    (row ``u`` is decision step ``u + 1``)."""
    q = 1.0 - h
    f = mass * h
    absorbed = 0.0
    timed = 0.0
    for k in range(1, n_rows + 1):
        absorbed += f
        timed += f * (t + k + 1)
        f *= q
        if f < 1e-300:
            break
    return absorbed, timed


@njit
def tail_error(mass, h, dh, sigma, dsigma, done_p, done_w, n_rows, t, floor):
    """Change in the probabilities and the (weighted) relative change in the mean response
    times if the tail after row ``t`` (``mass`` undecided, ``n_rows`` rows left) were
    filled with hazard ``h +- dh`` and shares ``sigma +- dsigma`` instead of ``h`` and
    ``sigma``. ``done_p`` and ``done_w``: each option's probability and time-weighted
    probability up to row ``t``."""
    a_mid, s_mid = _tail_sums(mass, h, n_rows, t)
    a_lo, s_lo = _tail_sums(mass, max(h - dh, 0.0), n_rows, t)
    a_hi, s_hi = _tail_sums(mass, min(h + dh, 1.0), n_rows, t)
    da = max(abs(a_hi - a_mid), abs(a_lo - a_mid))
    err_p = da
    err_rt = 0.0
    for i in range(sigma.shape[0]):
        err_p = max(err_p, sigma[i] * da + dsigma[i] * a_mid)
        p = done_p[i] + sigma[i] * a_mid
        if p <= 0.0:
            continue
        rt = (done_w[i] + sigma[i] * s_mid) / p
        worst = 0.0
        for a, s in ((a_lo, s_lo), (a_hi, s_hi)):
            pp = done_p[i] + sigma[i] * a
            if pp > 0.0:
                worst = max(worst, abs((done_w[i] + sigma[i] * s) / pp - rt))
        for sg in (max(sigma[i] - dsigma[i], 0.0), sigma[i] + dsigma[i]):
            pp = done_p[i] + sg * a_mid
            if pp > 0.0:
                worst = max(worst, abs((done_w[i] + sg * s_mid) / pp - rt))
        err_rt = max(err_rt, min(1.0, p / floor) * 2.0 * worst / rt)
    return err_p, err_rt


@njit
def fill(rt_pmf, t, mass, h, sigma):
    """Fill the rows after ``t`` with ``mass`` decaying at hazard ``h`` and split by
    ``sigma``; returns the mass still undecided after the last row."""
    f = mass * h
    left = mass
    for u in range(t + 1, rt_pmf.shape[0]):
        for i in range(rt_pmf.shape[1]):
            rt_pmf[u, i] = f * sigma[i]
        left -= f
        f *= 1.0 - h
    return max(left, 0.0)


@njit
def snapshot(x, m, mass, snap_x, snap_m, dist):
    """Record the undecided distribution (``x`` and ``m`` over ``mass``) in ``snap_x`` and
    ``snap_m``; shift ``dist`` (``[k, 0]``: L1 change of ``x``, ``[k, 1]``: of ``m``, over
    the last windows, oldest first) and add the change since the last snapshot."""
    dx = 0.0
    dm = 0.0
    first = True
    scale = 1.0 / mass if mass > 0.0 else 0.0
    for r in range(x.shape[0]):
        vx = x[r] * scale
        vm = m[r] * scale
        if snap_x[r] != 0.0:
            first = False
        dx += abs(vx - snap_x[r])
        dm += abs(vm - snap_m[r])
        snap_x[r] = vx
        snap_m[r] = vm
    if first:
        # nothing recorded yet: no change to report
        dx = -1.0
        dm = -1.0
    for k in range(dist.shape[0] - 1):
        dist[k, 0] = dist[k + 1, 0]
        dist[k, 1] = dist[k + 1, 1]
    dist[dist.shape[0] - 1, 0] = dx
    dist[dist.shape[0] - 1, 1] = dm


@njit
def _settling(d0, d1, d2):
    """Remaining distance of a sequence whose successive window changes are ``d0, d1, d2``
    (non-negative), if they shrink geometrically; -1 otherwise."""
    if d2 == 0.0 and d1 == 0.0:
        return 0.0
    if not (d0 > 0.0 and d1 > 0.0):
        return -1.0
    r = max(d1 / d0, d2 / d1)
    if not r < _MAX_RATIO:
        return -1.0
    return _SAFETY * d2 * r / (1.0 - r)


@njit
def _share(rt_pmf, u, i):
    """Option ``i``'s share of the choices at row ``u`` (equal shares where there are none)."""
    n = rt_pmf.shape[1]
    total = 0.0
    for j in range(n):
        total += max(rt_pmf[u, j], 0.0)
    return max(rt_pmf[u, i], 0.0) / total if total > 0.0 else 1.0 / n


@njit
def _hazard_drift(hazard, t):
    """:func:`drift` of the hazard seen at ``t`` and three times a window before it, over
    the shortest window (``WINDOW`` doubled up to ``_DOUBLINGS`` times, within ``t``) over
    which its changes shrink geometrically; -1 when over none."""
    for k in range(_DOUBLINGS + 1):
        wk = WINDOW << k
        if t < 3 * wk + 1:
            break
        v0 = hazard[t - 3 * wk]
        v1 = hazard[t - 2 * wk]
        v2 = hazard[t - wk]
        # a hazard of 0 may be mass that has not reached the thresholds yet, and so may a
        # negative one: the moment closure's choices of mass that is nowhere near them
        # (rounding-sized and negative, they settled at -1e-10 over the first hundred steps
        # of a thousand-step deliberation, and a tail filled from there decided nothing)
        if v0 <= 0.0 or v1 <= 0.0 or v2 <= 0.0 or hazard[t] <= 0.0:
            return -1.0
        d = drift(v0, v1, v2, hazard[t])
        if d >= 0.0:
            return d
    return -1.0


@njit
def check(rt_pmf, hazard, t, mass, done_p, done_w, budget_p, budget_rt, floor, dist, reach,
          sigma, dsigma, errors):
    """Whether the tail after row ``t`` may be filled now: the drift of the hazard
    (``hazard[u]``: share of the undecided mass chosen at row ``u``) is geometric, or
    else the undecided distribution has settled (``dist``, see :func:`snapshot`; a
    change ``d`` in it moves the hazard by at most ``reach[0] d_x + reach[1] d_m``), and
    the change that the drift of the hazard and of each row's shares may still make is
    within ``budget_p`` and ``budget_rt``. Fills ``sigma``, ``dsigma`` and ``errors``
    (the estimated change) when it returns True."""
    w = WINDOW
    if t < 3 * w + 1:
        return False
    n = rt_pmf.shape[1]
    dh = _hazard_drift(hazard, t)
    if dh < 0.0:
        # the hazard is at the level of rounding, or still moving: has the mass settled?
        gx = _settling(dist[0, 0], dist[1, 0], dist[2, 0])
        gm = _settling(dist[0, 1], dist[1, 1], dist[2, 1])
        if gx < 0.0 or gm < 0.0:
            return False
        dh = reach[0] * gx + reach[1] * gm + abs(hazard[t])
    for i in range(n):
        sigma[i] = _share(rt_pmf, t, i)
        dsigma[i] = -1.0
    for k in range(_DOUBLINGS + 1):
        wk = w << k
        if t < 3 * wk + 1:
            break
        for i in range(n):
            if dsigma[i] < 0.0:
                dsigma[i] = drift(_share(rt_pmf, t - 3 * wk, i), _share(rt_pmf, t - 2 * wk, i),
                                  _share(rt_pmf, t - wk, i), sigma[i])
    for i in range(n):
        # a share that does not settle geometrically over any window may still be anything
        # in [0, 1]
        if dsigma[i] < 0.0:
            dsigma[i] = 1.0
    n_rows = rt_pmf.shape[0] - 1 - t
    err_p, err_rt = tail_error(mass, max(hazard[t], 0.0), dh, sigma, dsigma, done_p, done_w,
                               n_rows, t, floor)
    errors[0] = err_p
    errors[1] = err_rt
    return err_p <= budget_p and err_rt <= budget_rt
