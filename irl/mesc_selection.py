"""Sparse identification of constraints for MESC-IRL (private to :mod:`irl.mesc`).

The unregularised likelihood has no reason to prefer a sparse explanation:
every feature that the demonstrations avoid gains a little likelihood from a
penalty, and a fully converged maximum-likelihood fit penalises them all. This
module selects the constraints the demonstrations give evidence for:

1. **L1 path (screening).** The L1-penalised likelihood
   ``L(omega) - lam * sum(omega)`` (on ``omega >= 0`` the L1 norm is linear) is
   maximised on a geometric grid of ``n_lambda`` strengths from
   ``lam_max = max_f dL/domega_f(0)`` (the smallest strength at which no
   feature is penalised) down to ``min(cost / (4 N), lam_max / 1000)``, each
   fit warm-started from the last, with a tolerance thirty times looser than
   the final fits' (the path only has to find supports). Each new support S
   is refitted by plain maximum likelihood on S ("relaxed" lasso) and scored
   by ``N L_S - |S|`` (Akaike's cost, one nat per feature: a generous
   screen). The path stops at the first support that does not improve the
   score.
2. **Backward elimination (evidence).** From the union of the best screened
   support and the one the path visited after it (Akaike's score of a
   support is a sum over all its features, so a feature with evidence above
   ``cost`` can enter in the same step as many without; the elimination
   removes those again),
   features whose removal costs fewer than ``cost`` nats of log-likelihood
   are removed until none is left. The cost with the other penalties held is
   an upper bound of the cost with them refitted, so a feature whose held
   cost is below ``cost`` is removed at once; the cheapest features are
   removed together when dropping them all at once (others held) costs less
   than one feature (they are worth less than one feature, so one-at-a-time
   removal would take them all). Between such removals a held cost measured
   ``a`` rounds before and at least ``HELD_GROWTH**a * cost`` (4, 16, ...
   times the cost) is reused rather than measured again (on 48 fits, one
   round of removals lowered a held cost of at least 2 cost by at most a
   factor 2.7); before the elimination leaves the removals, every held cost
   is measured. When no held cost is below ``cost``, the
   features are dropped in turn, in the order of their held costs, with the
   others refitted (which reveals redundant features, such as a colour and
   the cells of that colour); the first whose refitted cost is below
   ``cost`` is removed. When none is, their refitted costs are their evidence
   ``e_f = N (L_S - L_{S without f})`` (nats, over all demonstrations).
   These refits run at the screening tolerance, and at ``FAR_TOL`` (3) times
   it while the loss is at least ``FAR_LOSS`` (100) times ``cost``: such
   evidence is a looser upper bound, where zeta no longer depends on it
   (``sigmoid(e - cost)`` is 1 to double precision from ``e - cost`` = 37).
3. **Probability** (in :class:`irl.mesc_result.MESCResult`).
   ``sigmoid(e_f - cost)`` is the posterior probability that f belongs to
   the model in the Laplace (BIC-type) approximation of the posterior odds of
   the models with and without f; ``zeta_f`` multiplies it by the paper's
   size map of the penalty measured against the nominal reward's spread,
   the probability that a penalty of that size is a constraint rather than a
   mild preference. A feature outside the selected model has no evidence.
4. **Penalties of the features without evidence** (:func:`fit_unselected`).
   Setting them to zero discards what the demonstrations say about where
   they do not go, and the selected model then predicts held-out behaviour
   worse than plain maximum likelihood with few demonstrations. The
   penalties of the learned model therefore maximise
   ``L(omega) - strength / 2 * sum_{f not selected} omega_f**2`` over the
   features outside the selected model, the selected penalties held
   (``strength`` per demonstration, as ``L`` is a mean): mild penalties,
   bounded on the scale of the nominal reward, that shape the policy but
   carry no evidence and leave ``zeta`` as it was.

**Tolerances.** The fits above meet ``min(tol, TOTAL_TOL / N)`` (the
screening ones ``SCREEN_FACTOR`` (30) times it): ``tol`` bounds the projected
gradient of the mean log-likelihood per demonstration, but every decision
compares ``N L`` (nats summed over the demonstrations) with ``cost``, and a
fit's shortfall in ``N L`` at a fixed gradient per demonstration grows with
N. Capping the gradient of ``N L`` at ``TOTAL_TOL`` (0.1) nats per unit
penalty keeps that shortfall in proportion to ``cost`` whatever N; with the
default ``tol`` (1e-3) the cap binds above 100 demonstrations. Without it, refits
that met the screening tolerance after no iteration dropped true constraints
and kept proxies of them, and evidence measured between under-fitted refits
was off in either direction (docs/irl.md, section 4.1).

``cost`` is ``max(log(n) / 2, log(F))`` nats per feature (n demonstrated
decisions, F candidate features): the larger of the Bayesian information
criterion's cost and that of the risk inflation criterion (Foster & George
1994), which is what the extended BIC of Chen & Chen (2008) reduces to at
its smallest consistent gamma, ``1 - log(n) / (2 log(F))``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import mesc_solvers

SUPPORT_EPS = 1e-8  # a penalty above this counts as selected by an L1 fit
# a held cost measured a rounds of removals ago is reused while it is at least HELD_GROWTH**a * cost
# (module docstring, step 2)
HELD_GROWTH = 4.0
# a refit without a feature stops at FAR_TOL times its tolerance while the loss is FAR_LOSS * cost or more
FAR_LOSS = 100.0
FAR_TOL = 3.0
# the selection compares log-likelihoods summed over the N demonstrations with ``cost`` (nats), so the
# tolerance of its fits is capped in those units: a projected gradient of N L of at most TOTAL_TOL nats
# per unit penalty (tol <= TOTAL_TOL / N; module docstring, "Tolerances")
TOTAL_TOL = 0.1
SCREEN_FACTOR = 30.0  # the screening fits (L1 path, refits of the elimination) stop at this times the tolerance


def evidence_cost(n_decisions, n_features):
    """Cost in nats of one more penalised feature: ``max(log(n)/2, log(F))``."""
    return float(max(0.5 * np.log(max(n_decisions, 1)), np.log(max(n_features, 1))))


@dataclass(frozen=True)
class Selection:
    """Outcome of :func:`select` (private)."""

    fit: mesc_solvers.Fit  # plain maximum likelihood on the support kept by the elimination
    support: np.ndarray  # bool (F,)
    evidence: np.ndarray  # nats (F,), zero outside the support
    cost: float
    path_lambdas: np.ndarray  # L1 strengths visited (per demonstration)
    path_sizes: np.ndarray  # support size at each
    n_fits: int
    unconverged: tuple  # messages of the other fits (of n_fits, not fit) that did not meet their tolerance


def _held(obj, fit, features):
    """Cost in nats of dropping each of ``features`` with the other penalties held (one evaluation each)."""
    costs = np.empty(len(features))
    for j, f in enumerate(features):
        w = fit.penalties.copy()
        w[f] = 0.0
        costs[j] = obj.n_demonstrations * (fit.value - obj._value(w))
    return costs


def _held_round(obj, fit, idx, cost, known):
    """Held costs of ``idx`` for one round of the elimination, reusing the far ones of earlier rounds.

    ``known`` maps a feature to ``(held cost, age)`` from the rounds of
    removals since the held costs were last all measured. A held cost of at
    least ``HELD_GROWTH**age * cost`` is taken as still above ``cost`` and
    reused; the others are measured (one evaluation each). When none of the
    measured ones is below ``cost`` (the elimination would leave the
    removals), the reused ones are measured too, so that every decision to
    refit without each feature rests on fresh held costs. Returns the held
    costs and the ``known`` of the next round, should this round remove a run.
    """
    reuse = np.array([f in known and known[f][0] >= HELD_GROWTH ** known[f][1] * cost for f in idx], dtype=bool)
    held = np.empty(len(idx))
    held[reuse] = [known[f][0] for f in idx[reuse]]
    held[~reuse] = _held(obj, fit, idx[~reuse])
    if reuse.any() and not (held[~reuse] < cost).any():
        held[reuse] = _held(obj, fit, idx[reuse])
        reuse[:] = False
    following = {}
    for f, h, r in zip(idx, held, reuse):
        following[f] = (known[f][0], known[f][1] + 1) if r else (h, 1)
    return held, following


def _cheap_run(obj, fit, idx, held, cost):
    """The features to drop together: the longest run of the cheapest that costs less than one feature.

    Sorted by their held costs, the first m features are dropped together if
    dropping all m at once, the others held, costs fewer than ``cost`` nats:
    together they are worth less than one feature, so one-at-a-time removal
    would remove them all (in some order), each step costing less than
    ``cost``. m is found by halving from the number of features below
    ``cost`` (one evaluation each); m = 1 is the cheapest feature alone.
    """
    order = idx[np.argsort(held, kind="stable")]
    m = int(np.count_nonzero(held < cost))
    while m > 1:
        w = fit.penalties.copy()
        w[order[:m]] = 0.0
        if obj.n_demonstrations * (fit.value - obj._value(w)) < cost:
            break
        m //= 2
    return order[:m]


def _refit(obj, w0, support, opts):
    return mesc_solvers.lbfgsb(obj, np.where(support, w0, 0.0), free=support, **opts)


def _refit_without(obj, fit, support, cost, opts):
    """Refit on ``support`` (``fit``'s without one feature), looser while the loss is far above ``cost``.

    While ``N (L_fit - L)`` at an iterate is at least ``FAR_LOSS * cost``, the
    refit stops at ``FAR_TOL`` times the tolerance. The loss only falls as the
    refit proceeds, so a loss measured this way is an upper bound of the one
    at the tolerance; the decision it serves (below ``cost`` or not) would
    change only if the rest of the refit took off 99% of it.
    """
    n, far, loose = obj.n_demonstrations, FAR_LOSS * cost, FAR_TOL * opts["tol"]

    def tol_at(value):
        return loose if n * (fit.value - value) >= far else opts["tol"]

    return _refit(obj, fit.penalties, support, dict(opts, tol_at=tol_at))


def path_strengths(lam_max, lam_cost, n_lambda):
    """Geometric grid of L1 strengths below ``lam_max`` down to a quarter of ``lam_cost``.

    ``lam_cost = cost / N`` is the strength at which a feature whose expected
    visits per demonstration stay below it cannot earn its cost; the path goes
    a factor 4 beyond it (and at least a factor 4 below ``lam_max``).
    """
    low = min(0.25 * lam_cost, 1e-3 * lam_max)
    return lam_max * np.geomspace(1.0, low / lam_max, n_lambda + 1)[1:]


def select(obj, *, cost, n_lambda=8, patience=1, opts):
    """Run the L1 path, the relaxed refits and the backward elimination (module docstring)."""
    F = obj.n_features
    N = obj.n_demonstrations
    opts = dict(opts, tol=min(opts["tol"], TOTAL_TOL / N))
    path_opts = dict(opts, tol=SCREEN_FACTOR * opts["tol"])
    zeros = np.zeros(F)
    value0, grad0 = obj._evaluate(zeros)
    lam_max = float(grad0.max()) if F else 0.0
    ran = []  # every fit made, in order
    empty = mesc_solvers.Fit(zeros, float(value0), grad0, 0, True, "no feature has evidence")
    best = (N * value0, np.zeros(F, dtype=bool), empty)
    lambdas, sizes = [], []
    beyond = np.zeros(F, dtype=bool)  # features of the supports visited after the best one
    last = zeros
    if lam_max > 0.0:
        w = zeros
        seen = set()
        since_best = 0
        for lam in path_strengths(lam_max, cost / N, n_lambda):
            l1_fit = mesc_solvers.lbfgsb(obj, w, l1=float(lam), **path_opts)
            ran.append(l1_fit)
            w = l1_fit.penalties
            support = w > SUPPORT_EPS
            lambdas.append(lam)
            sizes.append(int(support.sum()))
            key = support.tobytes()
            if key in seen or not support.any():
                continue
            seen.add(key)
            refit = _refit(obj, w, support, path_opts)
            ran.append(refit)
            score = N * refit.value - support.sum()
            if score > best[0]:
                best = (score, support, refit)
                since_best = 0
                beyond = np.zeros(F, dtype=bool)
            else:
                since_best += 1
                beyond |= support
                last = refit.penalties
                if since_best >= patience:
                    break
    _, support, fit = best
    support = support.copy()
    if (beyond & ~support).any():
        # a feature with evidence can enter the path in the same step as several without any
        # (Akaike's score sums over the support): the elimination starts from the union
        support |= beyond
        fit = _refit(obj, np.where(best[1], fit.penalties, last), support, path_opts)
        ran.append(fit)
    evidence = np.zeros(F)
    tight = False  # fit is a refit at the final tolerance
    known = {}  # held costs of the rounds of removals since they were last all measured
    while support.any():
        idx = np.flatnonzero(support)
        # the cost of dropping f with the others held: an upper bound of the refitted cost
        held, following = _held_round(obj, fit, idx, cost, known)
        if held.min() < cost:
            support[_cheap_run(obj, fit, idx, held, cost)] = False
            fit = _refit(obj, fit.penalties, support, path_opts)
            ran.append(fit)
            tight = False
            known = following
            continue
        known = {}
        if not tight:
            fit = _refit(obj, fit.penalties, support, opts)
            ran.append(fit)
            tight = True
        # every feature survives with the others held: refit without each to see redundancy
        drops = []
        for f in idx[np.argsort(held, kind="stable")]:
            s2 = support.copy()
            s2[f] = False
            r = _refit_without(obj, fit, s2, cost, path_opts)
            ran.append(r)
            drops.append((N * (fit.value - r.value), f, s2, r))
            if drops[-1][0] < cost:  # rejected: the others need no refit this round
                break
        gain, f, s2, r = min(drops, key=lambda d: d[0])
        if gain < cost:
            support, fit, tight = s2, r, False
            continue
        for g, f, _, _ in drops:
            evidence[f] = max(g, 0.0)
        break
    if support.any() and not tight:
        fit = _refit(obj, fit.penalties, support, opts)
        ran.append(fit)
    unconverged = [run.message for run in ran if not run.converged and run is not fit]
    return Selection(fit, support, evidence, cost, np.array(lambdas), np.array(sizes, dtype=np.int64), len(ran),
                     tuple(unconverged))


def held_evidence(obj, fit, min_penalty=0.0):
    """Evidence of each penalised feature with the others held: ``N (L(omega) - L(omega with omega_f = 0))``.

    One evaluation per feature with a penalty of at least ``min_penalty``
    (and above zero); an upper bound of the refitted evidence of
    :func:`select`, used where refits are too costly. Features below
    ``min_penalty`` get no evidence (0).
    """
    evidence = np.zeros(obj.n_features)
    idx = np.flatnonzero((fit.penalties > 0.0) & (fit.penalties >= min_penalty))
    evidence[idx] = np.maximum(_held(obj, fit, idx), 0.0)
    return evidence


class _Shifted:
    """The objective at ``base + x``: penalties ``x`` of the features outside a selected model on top of
    the selected model's penalties ``base`` (zero outside it)."""

    def __init__(self, obj, base):
        self.obj, self.base = obj, base
        self.n_demonstrations = obj.n_demonstrations

    def _evaluate(self, x):
        return self.obj._evaluate(self.base + x)


def fit_unselected(obj, fit, support, strength, opts):
    """Penalties of the features outside ``support`` by a ridge fit, the selected ones held (module docstring, step 4).

    Maximises ``L(base + x) - strength / 2 * |x|**2`` over ``x >= 0``, zero
    on ``support`` (``base``: the penalties of ``fit``, zero outside it;
    ``strength`` per demonstration, as ``L`` is a mean), from ``x = 0`` at
    the tolerance in ``opts``. Returns the :class:`Fit` of ``base + x``, whose
    value and gradient are those of ``L``.
    """
    base = np.where(support, fit.penalties, 0.0)
    r = mesc_solvers.lbfgsb(_Shifted(obj, base), np.zeros(obj.n_features), l2=strength, free=~support, **opts)
    return mesc_solvers.Fit(base + r.penalties, r.value, r.gradient, r.n_iter, r.converged, r.message)
