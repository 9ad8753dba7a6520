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
from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize

from . import _kernels
from .demonstrations import Demonstrations
from .mdp import MDP, _as_float, _as_int, _as_real
from ._repr import compact_repr

__all__ = ["MESCObjective", "MESCResult", "LearnedConstraint", "mesc_irl", "constraint_probability"]


def constraint_probability(penalty, sigma):
    """The paper's map from penalty to probability, ``sigmoid((penalty - sigma) / sigma)``.

    Parameters
    ----------
    penalty : array_like
    sigma : float
        The pooled standard deviation sigma_pooled (> 0).

    Examples
    --------
    >>> round(float(constraint_probability(10.0, 5.0)), 4)
    0.7311
    """
    sigma = _as_real("sigma", sigma, low=0.0, low_open=True)
    p = np.asarray(penalty, dtype=np.float64)
    return 1.0 / (1.0 + np.exp(-(p - sigma) / sigma))


def feasible_reward_sd(mdp):
    """Population standard deviation of R(s, a, s') over the MDP's feasible transitions.

    The set is every padded transition ``(s, a, k)`` with ``s`` non-terminal and
    ``probs[s, a, k] > 0``, each counted once (unweighted).

    Examples
    --------
    >>> from irl import GridWorld
    >>> round(feasible_reward_sd(GridWorld(3, 0, 8, p_slip=0.0).nominal_mdp), 3)
    2.762
    """
    mask = (mdp.probs > 0) & ~mdp.terminal[:, None, None]
    return float(np.std(mdp.rewards[mask]))


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
    keeps one (H, S, A) policy buffer.

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
        if not isinstance(demonstrations, Demonstrations):
            raise TypeError(f"demonstrations must be an irl.Demonstrations (got {type(demonstrations).__name__})")
        slots = demonstrations.check(nominal)
        if horizon is None:
            longest = int(demonstrations.lengths.max())
            horizon = longest + (longest + 1) // 2
        self.horizon = H = _as_int("horizon", horizon)
        self.nominal = nominal
        self.features = nominal.features
        self.n_demonstrations = n = len(demonstrations)
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
        self._shared = _kernels.shared_successors(nominal.next_states)
        self.n_evaluations = 0

    @property
    def n_features(self) -> int:
        """Number of penalties."""
        return self.features.n_features

    def _backward(self, w):
        nom = self.nominal
        u_src, u_act, u_dst = self.features._projections(w)
        r_bar = _kernels.penalised_expected_rewards(
            nom.next_states, nom.probs, nom.rewards, nom.terminal, u_src, u_act, u_dst
        )
        return _kernels.soft_backward_into(
            nom.next_states, nom.probs, r_bar, nom.terminal, nom.discount, self._shared, self._policy,
            self._demo_ptr, self._demo_s, self._demo_a,
        )

    def __call__(self, penalties):
        """``(L(omega), dL/domega)`` at ``penalties`` (shape (n_features,))."""
        w = self.features.check_weights(penalties, "penalties")
        return self._evaluate(w)

    def _evaluate(self, w):
        nom = self.nominal
        _, loglik = self._backward(w)
        sa, dst = _kernels.likelihood_adjoint(
            nom.next_states, nom.probs, nom.terminal, nom.discount, self._shared, self._policy,
            self._demo_ptr, self._demo_s, self._demo_a, self._weight,
        )
        self.n_evaluations += 1
        # d r_bar / d omega = -psi, so dL/domega = -(Lambda counts of phi)
        return loglik * self._weight, -self.features.counts(sa.sum(axis=1), sa.sum(axis=0), dst)

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
        self._backward(w)
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
        self._backward(w)
        return self._policy.copy()


@dataclass(frozen=True)
class LearnedConstraint:
    """One learned constraint: feature index and name, penalty and zeta.

    Examples
    --------
    >>> LearnedConstraint(31, "state 31", 48.0, 0.9).name
    'state 31'
    """

    feature: int
    name: str
    penalty: float
    zeta: float


@dataclass(frozen=True, eq=False)
class MESCResult:
    """Result of :func:`mesc_irl`.

    Attributes
    ----------
    penalties : ndarray, shape (n_features,)
        Learned omega_R >= 0; ``R_C = R_N - penalties . phi``.
    feature_names : tuple of str
    nominal : MDP
        The nominal MDP the penalties apply to.
    constrained : MDP
        The learned constrained MDP (``nominal.penalised(penalties)``).
    objective : float
        L at the penalties: the demonstrations' mean log-likelihood (see :mod:`irl.mesc`).
    gradient : ndarray, shape (n_features,)
        dL/domega at the penalties.
    sigma_nominal, sigma_constrained, sigma_pooled : float
        Standard deviations of R_N and R_C over the feasible transitions
        (:func:`feasible_reward_sd`) and ``sqrt((sigma_N**2 + sigma_C**2) / 2)``.
    zeta : ndarray, shape (n_features,)
        ``sigmoid((penalty - sigma_pooled) / sigma_pooled)`` per feature.
    horizon, n_demonstrations, n_iter, n_evaluations : int
    converged : bool
    message : str
        The optimiser's message.

    Examples
    --------
    >>> from irl import GridWorld
    >>> world = GridWorld(4, 0, 15, constrained_states=[5], constrained_actions=["left"])
    >>> res = MESCResult.from_penalties(world.nominal_mdp, world.true_penalties)
    >>> [c.name for c in res.ranked_constraints(min_zeta=0.6)]
    ['state 5', 'action left']
    >>> res.feature_zeta(world.feature_slices["colour"]).round(3).tolist()
    [0.269, 0.269, 0.269]
    >>> res.transition_zeta().shape
    (16, 8, 8)
    """

    __repr__ = compact_repr

    penalties: np.ndarray
    feature_names: tuple
    nominal: MDP
    constrained: MDP
    objective: float
    gradient: np.ndarray
    sigma_nominal: float
    sigma_constrained: float
    sigma_pooled: float
    zeta: np.ndarray
    horizon: int
    n_demonstrations: int
    n_iter: int
    n_evaluations: int
    converged: bool
    message: str

    @classmethod
    def from_penalties(cls, nominal, penalties, **info):
        """Build a result (zeta, learned MDP, ...) from penalties; ``info`` fills the fit diagnostics."""
        if not isinstance(nominal, MDP) or nominal.features is None:
            raise TypeError("nominal must be an irl.MDP with features")
        w = nominal.features.check_weights(penalties, "penalties")
        if w.min() < 0:
            raise ValueError(f"penalties must be non-negative (got {w.min():.4g})")
        constrained = nominal.penalised(w)
        s_n, s_c = feasible_reward_sd(nominal), feasible_reward_sd(constrained)
        s_p = float(np.sqrt((s_n**2 + s_c**2) / 2))
        zeta = constraint_probability(w, s_p) if s_p > 0 else (w > 0).astype(float)
        w.flags.writeable = False
        zeta.flags.writeable = False
        defaults = dict(
            objective=float("nan"), gradient=np.full(w.size, np.nan),
            horizon=0, n_demonstrations=0, n_iter=0, n_evaluations=0, converged=False, message="",
        )
        defaults.update(info)
        return cls(
            penalties=w, feature_names=nominal.features.names, nominal=nominal, constrained=constrained,
            sigma_nominal=s_n, sigma_constrained=s_c, sigma_pooled=s_p, zeta=zeta, **defaults,
        )

    def feature_zeta(self, features=None):
        """zeta_f of the paper's Section 3.2 for a subset of features.

        Parameters
        ----------
        features : slice, sequence of int or bool mask, optional
            The subset f (default all features).

        Returns
        -------
        ndarray
            ``sigmoid((omega_f - sigma_pooled) / sigma_pooled)`` for each feature in f.
        """
        idx = slice(None) if features is None else features
        return np.array(self.zeta[idx], copy=True)

    def transition_zeta(self, features=None):
        """zeta of every padded transition, shape (S, A, K), from the penalty of the features in ``features``.

        ``sigmoid((omega_f . phi_f(s, a, s') - sigma_pooled) / sigma_pooled)``;
        with ``features=None`` all features count (the paper's per-transition zeta).
        """
        w = np.zeros_like(self.penalties)
        sel = slice(None) if features is None else features
        w[sel] = self.penalties[sel]
        vals = self.nominal.features.transition_values(w, self.nominal.next_states)
        return constraint_probability(vals, self.sigma_pooled) if self.sigma_pooled > 0 else (vals > 0).astype(float)

    def ranked_constraints(self, *, min_zeta=0.5, features=None):
        """Learned constraints with zeta >= ``min_zeta``, largest penalty first.

        Parameters
        ----------
        min_zeta : float
        features : slice or sequence of int, optional
            Restrict to these features.

        Returns
        -------
        tuple of LearnedConstraint
        """
        min_zeta = _as_real("min_zeta", min_zeta, low=0.0, high=1.0)
        idx = np.arange(self.penalties.size)
        if features is not None:
            idx = idx[features]
        idx = idx[self.zeta[idx] >= min_zeta]
        idx = idx[np.argsort(-self.penalties[idx], kind="stable")]
        return tuple(
            LearnedConstraint(int(i), self.feature_names[i], float(self.penalties[i]), float(self.zeta[i])) for i in idx
        )

    def save(self, path):
        """Write the result to JSON (see :func:`irl.io.save_mesc_result`)."""
        from .io import save_mesc_result

        save_mesc_result(self, path)


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


def mesc_irl(
    nominal,
    demonstrations,
    *,
    horizon=None,
    init=None,
    max_penalty=None,
    l2=0.0,
    max_iter=1000,
    tol=1e-3,
    precondition=False,
    maxcor=40,
):
    """Learn soft constraints from demonstrations (MESC-IRL).

    Maximises the log-likelihood L(omega) of :mod:`irl.mesc` (minus
    ``l2 / 2 * |omega|**2``) over ``0 <= omega <= max_penalty`` with
    L-BFGS-B and the exact gradient.

    Parameters
    ----------
    nominal : MDP
        The nominal MDP, with features (e.g. ``GridWorld.nominal_mdp``).
    demonstrations : Demonstrations
        Trajectories in the (unknown) constrained MDP; checked against ``nominal``.
    horizon : int, optional
        Horizon H of the backward and forward passes (default: one and a
        half times the longest demonstration, rounded up).
    init : array_like of shape (n_features,) or MESCResult, optional
        Warm start, e.g. penalties learned on another world with the same
        feature layout (transfer). Default zeros.
    max_penalty : float, optional
        Upper bound on every penalty (default none).
    l2 : float
        Ridge weight on the penalties (default 0, the paper's objective).
    max_iter : int
        L-BFGS-B iterations.
    tol : float
        Stop when the largest component of the projected gradient of L with
        respect to omega is <= tol (expected feature visits per demonstration),
        or when L-BFGS-B's relative change of L falls below its ``ftol``.
    maxcor : int
        Number of correction pairs L-BFGS-B keeps (its memory).
    precondition : bool
        Run L-BFGS-B on ``theta = omega * sqrt(c + 0.01)``, c the expected plus
        empirical feature counts at the start point (a diagonal scaling that
        evens out the curvature of frequent and rare features). It speeds up
        large problems (thousands of features); where features are collinear
        (a colour and the cells of that colour) the likelihood cannot tell
        them apart and the scaling changes how the penalty is split among them.

    Returns
    -------
    MESCResult

    Warns
    -----
    RuntimeWarning
        When L-BFGS-B stops without meeting its convergence criteria.

    Examples
    --------
    >>> from irl import GridWorld, generate_demonstrations
    >>> world = GridWorld(5, 0, 24, constrained_states=[12], p_slip=0.0)
    >>> demos = generate_demonstrations(world.constrained_mdp, 50, rng=0)
    >>> res = mesc_irl(world.nominal_mdp, demos)
    >>> res.converged, res.ranked_constraints()[0].name
    (True, 'state 12')
    """
    obj = MESCObjective(nominal, demonstrations, horizon=horizon)
    F = obj.n_features
    w0 = _initial(init, F, nominal.features.names)
    l2 = _as_real("l2", l2, low=0.0)
    max_iter = _as_int("max_iter", max_iter)
    maxcor = _as_int("maxcor", maxcor)
    tol = _as_real("tol", tol, low=0.0, low_open=True)
    if max_penalty is not None:
        max_penalty = _as_real("max_penalty", max_penalty, low=0.0, low_open=True)
        w0 = np.minimum(w0, max_penalty)

    # Diagonal preconditioning: optimise theta = omega / scale, with scale_f =
    # 1 / sqrt(c_f + 0.01) and c_f the expected plus empirical counts of feature f
    # at the start point, so that frequent and rare features have similar curvature.
    if precondition:
        expected, empirical = obj.feature_counts(w0)
        scale = 1.0 / np.sqrt(np.abs(expected) + empirical + 1e-2)
    else:
        scale = np.ones(F)
    upper = None if max_penalty is None else max_penalty / scale
    last = {}

    def fun(theta):
        w = theta * scale
        value, grad = obj._evaluate(w)
        if l2:
            value -= 0.5 * l2 * float(w @ w)
            grad = grad - l2 * w
        last.update(theta=theta.copy(), value=value, grad=grad)
        return -value, -grad * scale

    def projected_gradient(w, grad):
        pg = np.abs(grad)
        at_low = w <= 0.0
        pg[at_low] = np.maximum(grad[at_low], 0.0)
        if max_penalty is not None:
            at_high = w >= max_penalty
            pg[at_high] = np.maximum(-grad[at_high], 0.0)
        return float(pg.max()) if pg.size else 0.0

    done = {"converged": False}

    def callback(intermediate_result):
        theta = intermediate_result.x
        if "theta" in last and np.array_equal(theta, last["theta"]):
            if projected_gradient(theta * scale, last["grad"]) <= tol:
                done["converged"] = True
                raise StopIteration

    bounds = [(0.0, None if upper is None else float(u)) for u in (upper if upper is not None else [None] * F)]
    res = minimize(
        fun, w0 / scale, jac=True, method="L-BFGS-B", bounds=bounds, callback=callback,
        options={"maxiter": max_iter, "gtol": 0.0, "maxfun": 20 * max_iter, "maxcor": maxcor},
    )
    w = np.clip(res.x * scale, 0.0, max_penalty)
    value, grad = obj._evaluate(w)
    if l2:
        grad_pen = grad - l2 * w
    else:
        grad_pen = grad
    converged = done["converged"] or projected_gradient(w, grad_pen) <= tol or bool(res.success)
    message = "projected gradient <= tol" if done["converged"] else str(res.message)
    if not converged:
        warnings.warn(f"mesc_irl: L-BFGS-B did not converge ({message}); raise max_iter", RuntimeWarning, stacklevel=2)
    return MESCResult.from_penalties(
        nominal, w, objective=value, gradient=grad,
        horizon=obj.horizon, n_demonstrations=obj.n_demonstrations, n_iter=int(res.nit),
        n_evaluations=obj.n_evaluations, converged=converged, message=message,
    )
