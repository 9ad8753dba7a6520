"""MESC-IRL: maximum causal entropy learning of soft constraints (the paper's Section 3).

Given a nominal MDP with transition features phi and demonstrations from the
true constrained MDP, learn non-negative penalties omega (one per feature) so
that the constrained reward ``R_C = R_N - omega . phi`` makes the
demonstrations most likely under the maximum causal entropy (soft) policy of R_C.

The objective (maximised over omega >= 0)
------------------------------------------
With N demonstrations ``tau_i = (s_0, a_0, s_1, ..., s_{T_i})``, horizon H and
the MDP's discount gamma::

    L(omega) = 1/N sum_i sum_{t < min(T_i, H)} log pi_t(a_t | s_t)

where ``pi_t(a|s) = exp(Q_t(s, a) - V_t(s))`` is the time-indexed soft policy of
R_C over H steps (:func:`irl.soft_value_iteration` with ``horizon=H``:
``V_H = 0``, zero values at terminal states). The transition probabilities of
the demonstrations do not depend on omega and are left out.

The gradient is exact (docs/irl.md derives it)::

    dL/domega = -sum_t sum_{s,a} Lambda_t(s, a) psi(s, a),
    psi(s, a) = sum_s' P(s'|s, a) phi(s, a, s')

where Lambda is a forward pass of signed mass, with the same H and gamma as
the backward pass, started at every demonstrated step by
``c_t(s, a) - c_t(s) pi_t(a|s)`` (demonstrated minus model action counts).
Under deterministic dynamics it telescopes to the textbook form
``dL/domega = E_model[phi] - E_D[phi]`` (expected minus empirical discounted
feature counts, model started from the demonstrations' start states); under
stochastic dynamics the exact gradient replaces each realised next state of a
demonstration by the model's expectation over next states.
"""

from __future__ import annotations

import warnings
import weakref

import numpy as np
import scipy.sparse as sp

from . import _kernels, mesc_selection, mesc_solvers
from .demonstrations import Demonstrations
from .mdp import MDP, _as_float, _as_int, _as_real, _check_size, successor_patterns
from .mesc_result import LearnedConstraint, MESCResult, constraint_probability, feasible_reward_sd
from .mesc_selection import evidence_cost

__all__ = ["MESCObjective", "MESCResult", "LearnedConstraint", "mesc_irl", "constraint_probability"]


def _expected_features(mdp):
    """``psi(s, a) = sum_s' P(s'|s, a) phi(s, a, s')`` as a CSR matrix of shape (S * A, F), row ``s * A + a``.

    Rows of terminal states are zero (they take no action). ``r_bar = r0 - psi @ omega``
    is the expected penalised reward, and ``-psi.T @ Lambda`` the gradient of L.
    """
    S, A, K = mdp.probs.shape
    feats = mdp.features
    rows = np.arange(S * A)
    live = np.repeat(~mdp.terminal, A).astype(np.float64)
    moves = sp.csr_array((mdp.probs.reshape(-1), (np.repeat(rows, K), mdp.next_states.reshape(-1))), shape=(S * A, S))
    ones = np.ones(S * A)
    psi = (moves @ feats.destination
           + sp.csr_array((ones, (rows, rows // A)), shape=(S * A, S)) @ feats.source
           + sp.csr_array((ones, (rows, rows % A)), shape=(S * A, A)) @ feats.action)
    psi = sp.csr_array(sp.diags_array(live) @ psi, dtype=np.float64)
    psi.eliminate_zeros()
    psi.sum_duplicates()
    psi.sort_indices()
    return psi


def _split_patterns(patterns):
    """Each transition pattern as a common part plus at most one successor of its own per action.

    ``patterns`` is the (P, K, A) table of :func:`irl.mdp.successor_patterns`.
    Returns ``(base, res_k, res_p, simple)``: ``base[p, k]`` the smallest
    probability of successor k over the actions, and for a ``simple`` pattern
    (every action's probabilities exceed ``base`` at one successor at most)
    ``P[p, k, a] = base[p, k] + res_p[p, a] [k == res_k[p, a]]`` up to rounding;
    other patterns keep their full matrix (``simple`` False).
    """
    base = patterns.min(axis=2)
    excess = patterns - base[:, :, None]
    simple = (np.count_nonzero(excess > 0.0, axis=1) <= 1).all(axis=1)
    res_k = excess.argmax(axis=1).astype(np.int64)
    res_p = np.take_along_axis(excess, res_k[:, None, :], axis=1)[:, 0, :]
    return np.ascontiguousarray(base), res_k, np.ascontiguousarray(res_p), simple


_TABLES: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()  # MDP -> its tables for the passes


def _pass_tables(mdp):
    """``(r0, psi's CSR arrays, successor_patterns, _split_patterns)`` of an MDP, made once per MDP object
    (its arrays are read-only).

    ``r_bar = r0 - psi @ omega`` is the expected penalised reward of every (s, a).
    """
    hit = _TABLES.get(mdp)
    if hit is None:
        S, A = mdp.n_states, mdp.n_actions
        zeros = np.zeros(S)
        r0 = _kernels.penalised_expected_rewards(mdp.next_states, mdp.probs, mdp.rewards, mdp.terminal, zeros,
                                                 np.zeros(A), zeros)
        psi = _expected_features(mdp)
        compact = successor_patterns(mdp.next_states, mdp.probs)
        hit = (r0, (psi.indptr.astype(np.int64), psi.indices.astype(np.int64), psi.data), compact,
               _split_patterns(compact[3]))
        _TABLES[mdp] = hit
    return hit


PASS_BLOCK = 128  # states per block of the backward pass (its soft maximum runs over a block at a time)
RECENT_EVALUATIONS = 64  # evaluations MESCObjective keeps (each: omega's bytes and the gradient, 2 F floats)


class MESCObjective:
    """The MESC-IRL objective L(omega) and its exact gradient on fixed data.

    Parameters
    ----------
    nominal : MDP
        Nominal MDP with ``features``.
    demonstrations : Demonstrations
        Checked against ``nominal`` (states, actions, feasible transitions).
    horizon : int, optional
        H of the backward and forward passes; default one and a half times
        the longest demonstration, rounded up. Transitions at steps t >= H do not count.

    Notes
    -----
    See the module docstring for L. ``objective(omega)`` returns
    ``(L, dL/domega)``, L being the mean log-likelihood per demonstration. One
    evaluation costs one backward and one forward pass (``O(H S A K)``) and
    keeps one (H, S, A) policy buffer. The optimisers often return to a point
    they have just evaluated; the last 64 evaluations are kept (keyed by the
    exact bytes of omega, so a repeated point gets the identical answer) and
    ``n_evaluations`` counts only those computed.

    Examples
    --------
    >>> from irl import GridWorld, generate_demonstrations
    >>> world = GridWorld(5, 0, 24, constrained_states=[12])
    >>> demos = generate_demonstrations(world.constrained_mdp, 20, rng=0)
    >>> obj = MESCObjective(world.nominal_mdp, demos)
    >>> value, grad = obj(world.true_penalties)
    >>> grad.shape, bool(value < 0)
    ((36,), True)
    """

    def __init__(self, nominal, demonstrations, *, horizon=None):
        if not isinstance(nominal, MDP):
            raise TypeError(f"nominal must be an irl.MDP (got {type(nominal).__name__})")
        if nominal.features is None:
            raise ValueError("nominal must have features (got features=None); MESC-IRL learns one penalty per feature")
        if nominal.features.n_features == 0:
            raise ValueError("nominal must have at least one feature (got features with n_features=0); "
                             "MESC-IRL learns one penalty per feature")
        if not isinstance(demonstrations, Demonstrations):
            raise TypeError(f"demonstrations must be an irl.Demonstrations (got {type(demonstrations).__name__})")
        slots = demonstrations.check(nominal)
        if horizon is None:
            longest = int(demonstrations.lengths.max())
            horizon = longest + (longest + 1) // 2
        self.horizon = H = _as_int("horizon", horizon)
        _check_size(f"horizon={H} x {nominal.n_states} states x {nominal.n_actions} actions (the policy buffer)",
                    H * nominal.n_states * nominal.n_actions)
        self.nominal = nominal
        self.features = nominal.features
        self.n_demonstrations = n = len(demonstrations)
        self.n_decisions = int(np.count_nonzero(demonstrations.time_steps < H))
        S, A = nominal.n_states, nominal.n_actions
        t = demonstrations.time_steps
        keep = np.flatnonzero(t < H)
        order = keep[np.argsort(t[keep], kind="stable")]
        self._demo_s = np.ascontiguousarray(demonstrations.states[order])
        self._demo_a = np.ascontiguousarray(demonstrations.actions[order])
        self._demo_ns = np.ascontiguousarray(demonstrations.next_states[order])
        self._demo_t = np.ascontiguousarray(t[order])
        self._demo_k = slots[order]
        self._demo_ptr = np.concatenate([[0], np.cumsum(np.bincount(self._demo_t, minlength=H))]).astype(np.int64)
        self._weight = 1.0 / n
        self.start = np.bincount(demonstrations.start_states, minlength=S).astype(np.float64) / n
        self._policy = np.empty((H, S, A))
        self._scratch = np.empty((1, S, A))  # policy rows of a likelihood-only backward pass
        self._compact = _pass_tables(nominal)[2]  # shared, succ, pattern_of, patterns
        self._patterns_ak = np.ascontiguousarray(self._compact[3].transpose(0, 2, 1))  # the adjoint's layout
        # the passes skip blocks of states that no demonstrated state can reach by then (exact for L and its
        # gradient); a full pass (the policy handed out) computes every block at every step
        self._block_first = _kernels.first_needed_steps(
            nominal.next_states, nominal.probs, nominal.terminal, self._demo_ptr, self._demo_s, PASS_BLOCK)
        self._block_all = np.zeros_like(self._block_first)
        # r_bar = r0 - psi omega; the gradient is -psi.T Lambda (psi: expected features of each (s, a))
        self._r0, self._psi, _, self._split = _pass_tables(nominal)
        self._r_bar = np.empty((S, A))
        self.n_evaluations = 0
        self._recent = {}  # exact bytes of omega -> (L, dL/domega) of the last few evaluations

    @property
    def n_features(self) -> int:
        """Number of penalties."""
        return self.features.n_features

    def _backward(self, w, policy=None, full=False):
        nom = self.nominal
        r_bar = self._r_bar
        _kernels.affine_rewards(self._r0, *self._psi, w, r_bar)
        shared, succ, pattern_of, patterns = self._compact
        return _kernels.soft_backward_into(
            nom.next_states, nom.probs, succ, pattern_of, patterns, self._split, r_bar, nom.terminal, nom.discount,
            shared,
            self._policy if policy is None else policy, self._demo_ptr, self._demo_s, self._demo_a, PASS_BLOCK,
            self._block_all if full else self._block_first,
        )

    def __call__(self, penalties):
        """``(L(omega), dL/domega)`` at ``penalties`` (shape (n_features,))."""
        w = self.features.check_weights(penalties, "penalties")
        return self._evaluate(w)

    def _evaluate(self, w):
        # the optimisers often ask again for a point just evaluated (a solver's last iterate, the
        # warm start of the next refit, often a point of the held costs): the last results are kept,
        # keyed by the exact bytes
        key = w.tobytes()
        hit = self._recent.get(key)
        if hit is not None and hit[1] is not None:
            return hit[0], hit[1].copy()
        value, grad = self._compute(w)
        self._keep(key, value, grad.copy())
        return value, grad

    def _value(self, w):
        """L alone (the backward pass, without the adjoint pass of the gradient); same caching."""
        key = w.tobytes()
        hit = self._recent.get(key)
        if hit is not None:
            return hit[0]
        _, loglik = self._backward(w, self._scratch)
        self.n_evaluations += 1
        value = loglik * self._weight
        self._keep(key, value, None)
        return value

    def _keep(self, key, value, grad):
        self._recent.pop(key, None)
        if len(self._recent) >= RECENT_EVALUATIONS:
            self._recent.pop(next(iter(self._recent)))
        self._recent[key] = (value, grad)

    def _compute(self, w):
        nom = self.nominal
        _, loglik = self._backward(w)
        shared, succ, pattern_of, _ = self._compact
        sa = _kernels.likelihood_adjoint(
            nom.next_states, nom.probs, succ, pattern_of, self._patterns_ak, self._split, nom.terminal, nom.discount,
            shared,
            self._policy,
            self._demo_ptr, self._demo_s, self._demo_a, self._weight,
        )
        self.n_evaluations += 1
        # d r_bar / d omega = -psi, so dL/domega = -psi.T Lambda
        grad = _kernels.transposed_product(*self._psi, sa.reshape(-1), self.n_features)
        np.negative(grad, out=grad)
        return loglik * self._weight, grad

    def feature_counts(self, penalties):
        """Expected and empirical discounted feature counts per demonstration.

        Returns ``(expected, empirical)``, each of shape (n_features,):
        ``expected`` from the soft policy of R_C over H steps started at the
        demonstrations' start states, ``empirical`` from the demonstrations'
        transitions at steps t < H, both weighted by ``gamma**t``. Under
        deterministic dynamics ``dL/domega = expected - empirical``.
        """
        w = self.features.check_weights(penalties, "penalties")
        nom = self.nominal
        self._backward(w, full=True)
        sa, dst = _kernels.visitation_finite(nom.next_states, nom.probs, nom.terminal, nom.discount, self._policy, self.start)
        expected = self.features.counts(sa.sum(axis=1), sa.sum(axis=0), dst)
        S, A = nom.n_states, nom.n_actions
        wt = nom.discount ** self._demo_t.astype(np.float64) * self._weight
        empirical = self.features.counts(
            np.bincount(self._demo_s, weights=wt, minlength=S),
            np.bincount(self._demo_a, weights=wt, minlength=A),
            np.bincount(self._demo_ns, weights=wt, minlength=S),
        )
        return expected, empirical

    def policy(self, penalties):
        """The time-indexed soft policy of R_C, a new array of shape (H, S, A)."""
        w = self.features.check_weights(penalties, "penalties")
        self._backward(w, full=True)
        return self._policy.copy()


def _initial(init, n_features, names):
    if init is None:
        return np.zeros(n_features)
    if isinstance(init, MESCResult):
        if init.penalties.size != n_features:
            raise ValueError(
                f"init must have one penalty per feature ({n_features}) (got a result with {init.penalties.size})"
            )
        if tuple(init.feature_names) != tuple(names):
            bad = next(i for i, (a, b) in enumerate(zip(init.feature_names, names)) if a != b)
            raise ValueError(
                f"init was learned on other features (feature {bad} is {init.feature_names[bad]!r}, "
                f"here {names[bad]!r}); transfer needs the same feature layout"
            )
        w = np.array(init.penalties, dtype=np.float64)
    else:
        w = _as_float("init", init, ndim=1, shape=(n_features,))
    if w.min() < 0:
        raise ValueError(f"init must be non-negative penalties (got {w.min():.4g})")
    return w


SELECTIONS = ("auto", "evidence", "l1", "none")
OPTIMIZERS = ("lbfgsb", "eg")
# "auto" runs the evidence selection (L1 path and backward elimination) when one
# evaluation visits at most this many (step, state, action, successor) entries and
# there are at most EVIDENCE_MAX_FEATURES features; above either, one L1 fit.
EVIDENCE_MAX_WORK = 4_000_000
EVIDENCE_MAX_FEATURES = 1000
# ridge on the penalties of the features outside the evidence selection's model: weight per demonstration
# 1 / (UNSELECTED_SCALE * sigma_nominal)**2 (docs/irl.md, section 4.1, "Penalties")
UNSELECTED_SCALE = 6.0
# "auto" preconditioning: on above this many features
PRECONDITION_MIN_FEATURES = 1000
EG_DEFAULTS = dict(steps=500, lr=0.3, clip=10.0, init=1e-6, burn_in=50, tol_step=1e-4, tol_gradient=1e-2, cap=200.0)


def _choice(name, value, allowed):
    if not isinstance(value, str) or value not in allowed:
        raise ValueError(f"{name} must be one of {', '.join(map(repr, allowed))} (got {value!r})")
    return value


def _eg_options(eg_options):
    opts = dict(EG_DEFAULTS)
    if eg_options is None:
        return opts
    if not isinstance(eg_options, dict):
        raise TypeError(f"eg_options must be a dict (got {type(eg_options).__name__})")
    unknown = sorted(set(eg_options) - set(EG_DEFAULTS))
    if unknown:
        raise ValueError(f"eg_options has unknown keys {unknown}; allowed: {sorted(EG_DEFAULTS)}")
    for key, val in eg_options.items():
        if key in ("steps", "burn_in"):
            opts[key] = _as_int(f"eg_options[{key!r}]", val, low=0 if key == "burn_in" else 1)
        elif key in ("clip", "cap") and val is None:
            opts[key] = None
        else:
            opts[key] = _as_real(f"eg_options[{key!r}]", val, low=0.0, low_open=key in ("lr", "init", "clip", "cap"))
    return opts


def _fit(obj, selection, optimizer, w0, l1, l2, cost, eg, max_penalty, opts, unselected_scale):
    """Run the chosen optimiser and selection.

    Returns ``(fit, evidence or None, number of fits, messages of the other fits that did not converge)``.
    """
    if optimizer == "eg":
        if max_penalty is not None:
            eg = dict(eg, cap=max_penalty)
        return mesc_solvers.exponentiated_gradient(obj, obj.n_features, l1=l1 or 0.0, **eg), None, 1, ()
    if selection == "evidence":
        sel = mesc_selection.select(obj, cost=cost, opts=opts)
        if not unselected_scale or sel.support.all():
            return sel.fit, sel.evidence, sel.n_fits, sel.unconverged
        # the features without evidence keep mild penalties (docs/irl.md, section 4.1, "Penalties")
        strength = 1.0 / (unselected_scale * feasible_reward_sd(obj.nominal)) ** 2
        fit = mesc_selection.fit_unselected(obj, sel.fit, sel.support, strength, opts)
        earlier = sel.unconverged + (() if sel.fit.converged else (sel.fit.message,))
        return fit, sel.evidence, sel.n_fits + 1, earlier
    if selection == "l1":
        strength = cost / obj.n_demonstrations if l1 is None else l1
        fit = mesc_solvers.lbfgsb(obj, w0, l1=strength, **opts)
        # a penalty below sigma_N has a size factor below 1/2, so its zeta stays below 1/2 whatever its
        # evidence: its evidence is not measured (one evaluation each)
        return fit, mesc_selection.held_evidence(obj, fit, min_penalty=feasible_reward_sd(obj.nominal)), 1, ()
    return mesc_solvers.lbfgsb(obj, w0, l1=l1 or 0.0, l2=l2, **opts), None, 1, ()


def mesc_irl(
    nominal,
    demonstrations,
    *,
    selection="auto",
    optimizer="lbfgsb",
    horizon=None,
    init=None,
    max_penalty=None,
    l1=None,
    l2=0.0,
    max_iter=1000,
    tol=1e-3,
    precondition="auto",
    maxcor=40,
    eg_options=None,
    unselected_scale=None,
):
    """Learn soft constraints from demonstrations (MESC-IRL).

    By default the penalties are those of the sparsest explanation the
    demonstrations give evidence for, and ``zeta`` is the probability of each
    feature being a constraint given that evidence (``selection="evidence"``,
    see Notes). ``selection="none"`` is the plain maximum-likelihood fit of
    :mod:`irl.mesc` with the paper's penalty-to-probability map, and
    ``optimizer="eg"`` the paper's own optimiser.

    Parameters
    ----------
    nominal : MDP
        The nominal MDP, with features (e.g. ``GridWorld.nominal_mdp``).
    demonstrations : Demonstrations
        Trajectories in the (unknown) constrained MDP; checked against ``nominal``.
    selection : {"auto", "evidence", "l1", "none"}
        ``"evidence"``: L1 path, relaxed refits and backward elimination
        (Notes); ``zeta = sigmoid(evidence - evidence_cost)``.
        ``"l1"``: one fit of ``L(omega) - l1 * sum(omega)`` (default strength
        ``evidence_cost / N``); ``evidence`` is the log-likelihood lost when a
        penalty is set to zero with the others held (one evaluation per
        feature with a penalty of at least ``sigma_nominal``, no refits;
        smaller penalties have a size factor below 1/2, so zeta < 1/2
        whatever the evidence, and get evidence 0), zeta as for ``"evidence"``.
        ``"none"``: maximise ``L`` (minus ``l1`` and ``l2`` terms if given);
        the paper's map. ``"auto"`` (default): ``"none"`` with
        ``optimizer="eg"``, ``l2 > 0`` or ``init``, ``"l1"`` when ``l1`` is given,
        otherwise ``"evidence"`` when one evaluation of the objective is
        small (at most 4e6 step-state-action-successor entries and 1,000
        features) and ``"l1"`` above.
    optimizer : {"lbfgsb", "eg"}
        ``"lbfgsb"``: scipy's L-BFGS-B with the exact gradient (default).
        ``"eg"``: the paper's clipped exponentiated gradient (500 steps,
        learning rate 0.3, gradient norm clipped at 10, start 1e-6, its
        stopping rule and best iterate; ``eg_options`` overrides them).
        Only with ``selection="none"`` or ``"auto"``.
    horizon : int, optional
        Horizon H of the backward and forward passes (default: one and a
        half times the longest demonstration, rounded up).
    init : array_like of shape (n_features,) or MESCResult, optional
        Warm start of L-BFGS-B, e.g. penalties learned on another world with
        the same feature layout (transfer). Default zeros. Only the fits of
        ``selection="none"`` and ``"l1"`` start from it (``"auto"`` takes
        ``"none"`` when it is given); the evidence selection's L1 path starts
        from zero and the paper's optimiser from ``eg_options["init"]``, so
        ``init`` with either raises ValueError.
    max_penalty : float, optional
        Upper bound on every penalty (default none).
    l1 : float, optional
        L1 weight per demonstration (``selection="l1"`` or ``"none"``).
    l2 : float
        Ridge weight on the penalties (default 0, the paper's objective;
        ``selection="none"`` only).
    max_iter : int
        L-BFGS-B iterations of each fit.
    tol : float
        A fit converges when the largest component of the projected gradient
        of its objective is <= tol (expected feature visits per
        demonstration; the evidence selection's fits meet ``min(tol, 0.1 / N)``
        for N demonstrations, as it compares log-likelihoods summed over them).
        When L-BFGS-B stops by its relative reduction test
        (``ftol``) or a failed line search above tol, it is restarted from
        its iterate (fresh memory, at most 3 times); a fit that still ends
        above tol is reported as not converged.
    precondition : bool or "auto"
        Run L-BFGS-B on ``theta = omega * sqrt(c + 0.01)``, c the expected plus
        empirical feature counts at the start point (a diagonal scaling that
        evens out the curvature of frequent and rare features). ``"auto"``
        (default) turns it on above 1,000 features, where it halves the
        number of evaluations; below, collinear features (a colour and the
        cells of that colour) would have their penalty split differently.
    maxcor : int
        Number of correction pairs L-BFGS-B keeps (its memory).
    eg_options : dict, optional
        Overrides of ``steps``, ``lr``, ``clip``, ``init``, ``burn_in``,
        ``tol_step``, ``tol_gradient``, ``cap`` of the paper's optimiser.
    unselected_scale : float, optional
        Evidence selection only: the penalties of the features outside the
        selected model are fitted with a ridge of weight
        ``1 / (unselected_scale * sigma_nominal)**2`` per demonstration (the
        selected ones held), so that the learned model keeps mild penalties
        where the demonstrations do not go (Notes). Default 6; 0 leaves them
        at zero (the selected model alone). Neither ``evidence`` nor ``zeta``
        depends on it.

    Returns
    -------
    MESCResult

    Warns
    -----
    RuntimeWarning
        When an L-BFGS-B fit ends above its tolerance (then ``converged`` is
        False and ``message`` says which fits and where they stopped).

    Notes
    -----
    The evidence selection (docs/irl.md, section 4) maximises the
    L1-penalised likelihood ``L(omega) - lam * sum(omega)`` along a geometric
    path of ``lam`` (warm starts, from the strength at which no feature is
    penalised), refits every new support by plain maximum likelihood and
    keeps the support with the best ``N L - |S|``; then it removes, one at a
    time, the feature whose removal (others refitted) costs fewer than
    ``evidence_cost = max(log(n) / 2, log(F))`` nats of log-likelihood
    (n demonstrated decisions, F features). ``evidence`` is that cost for
    the features kept and 0 for the others; ``sigmoid(evidence -
    evidence_cost)`` approximates the posterior probability that the feature
    belongs to the model, and ``zeta`` multiplies it by the paper's size map
    of the penalty measured against the nominal reward's spread
    (``sigma_nominal``), so that a proven but mild preference is not called
    a constraint. ``evidence > 0`` marks the selected features.

    The penalties (and ``constrained``, the learned model) maximise
    ``L(omega) - sum_{f not selected} omega_f**2 / (2 (unselected_scale
    sigma_nominal)**2)`` over the features outside the selected model, the
    selected features' maximum-likelihood penalties held: the features
    without evidence keep mild penalties. On the
    paper's Figure 1 world and random worlds this model's trajectories are
    closer to held-out demonstrations than those of plain maximum likelihood
    and of the selected model alone with few demonstrations, and as close as
    plain maximum likelihood's with many (docs/irl.md, section 4.1).

    Examples
    --------
    >>> from irl import GridWorld, generate_demonstrations
    >>> world = GridWorld(5, 0, 24, constrained_states=[12], p_slip=0.0)
    >>> demos = generate_demonstrations(world.constrained_mdp, 50, rng=0)
    >>> res = mesc_irl(world.nominal_mdp, demos)
    >>> res.converged, [c.name for c in res.ranked_constraints(min_zeta=0.6)]
    (True, ['state 12'])
    >>> plain = mesc_irl(world.nominal_mdp, demos, selection="none")
    >>> plain.zeta_method, res.zeta_method
    ('penalty', 'evidence')
    """
    obj = MESCObjective(nominal, demonstrations, horizon=horizon)
    F = obj.n_features
    selection = _choice("selection", selection, SELECTIONS)
    optimizer = _choice("optimizer", optimizer, OPTIMIZERS)
    w0 = _initial(init, F, nominal.features.names)
    l2 = _as_real("l2", l2, low=0.0)
    if l1 is not None:
        l1 = _as_real("l1", l1, low=0.0)
    max_iter = _as_int("max_iter", max_iter)
    maxcor = _as_int("maxcor", maxcor)
    tol = _as_real("tol", tol, low=0.0, low_open=True)
    if not (isinstance(precondition, bool) or precondition == "auto"):
        raise ValueError(f"precondition must be True, False or 'auto' (got {precondition!r})")
    if max_penalty is not None:
        max_penalty = _as_real("max_penalty", max_penalty, low=0.0, low_open=True)
        w0 = np.minimum(w0, max_penalty)
    eg = _eg_options(eg_options)
    if init is not None and optimizer == "eg":
        raise ValueError("init is a start of L-BFGS-B; the paper's optimiser starts every penalty at "
                         "eg_options['init'] (got init with optimizer='eg')")
    if selection == "auto":
        if optimizer == "eg" or l2 or init is not None:
            selection = "none"
        elif l1 is not None:
            selection = "l1"
        else:
            nom = nominal
            work = obj.horizon * nom.n_states * nom.n_actions * nom.n_successors
            small = work <= EVIDENCE_MAX_WORK and F <= EVIDENCE_MAX_FEATURES
            selection = "evidence" if small else "l1"
    if optimizer == "eg" and selection != "none":
        raise ValueError(f"optimizer='eg' fits all penalties at once; use selection='none' (got {selection!r})")
    if selection == "evidence" and (l1 is not None or l2):
        raise ValueError("l1 and l2 apply to selection='l1' or 'none'; the evidence selection sets its own L1 path")
    if selection == "evidence" and init is not None:
        raise ValueError("init applies to selection='l1' or 'none'; the evidence selection's L1 path starts from zero "
                         "(got init with selection='evidence')")
    if selection == "l1" and l2:
        raise ValueError(f"l2 applies to selection='none' (got l2={l2} with selection='l1')")
    if unselected_scale is None:
        unselected_scale = UNSELECTED_SCALE
    else:
        unselected_scale = _as_real("unselected_scale", unselected_scale, low=0.0)
        if selection != "evidence":
            raise ValueError("unselected_scale applies to the evidence selection "
                             f"(got unselected_scale={unselected_scale} with selection={selection!r})")
    cost = evidence_cost(obj.n_decisions, F)

    if precondition == "auto":
        precondition = F > PRECONDITION_MIN_FEATURES
    if precondition and optimizer == "lbfgsb":
        expected, empirical = obj.feature_counts(w0)
        scale = 1.0 / np.sqrt(np.abs(expected) + empirical + 1e-2)
    else:
        scale = None
    upper = max_penalty
    opts = dict(upper=upper, scale=scale, tol=tol, max_iter=max_iter, maxcor=maxcor)

    with mesc_solvers.single_blas_thread():
        fit, evidence, n_fits, earlier = _fit(obj, selection, optimizer, w0, l1, l2, cost, eg, max_penalty, opts,
                                              unselected_scale)
    message = fit.message if n_fits == 1 else f"{n_fits} fits; last: {fit.message}"
    if earlier:
        message += f"; {len(earlier)} other fit{'s' if len(earlier) > 1 else ''} above tol (first: {earlier[0]})"
    converged = fit.converged and not earlier
    if optimizer == "lbfgsb" and not converged:
        warnings.warn(f"mesc_irl: L-BFGS-B did not converge ({message}); raise max_iter or tol", RuntimeWarning,
                      stacklevel=2)
    return MESCResult.from_penalties(
        nominal, fit.penalties, objective=fit.value, gradient=fit.gradient,
        horizon=obj.horizon, n_demonstrations=obj.n_demonstrations, n_iter=fit.n_iter,
        n_evaluations=obj.n_evaluations, converged=converged, message=message,
        evidence=evidence, evidence_cost=None if evidence is None else cost, selection=selection,
    )
