"""The result of MESC-IRL: :class:`MESCResult`, its :class:`LearnedConstraint` rows, and the
paper's map from a penalty to the probability that its feature is a constraint (zeta)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .mdp import MDP, _as_float, _as_real
from ._repr import compact_repr, iterations

__all__ = ["MESCResult", "LearnedConstraint", "constraint_probability"]


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
        Probability that each feature is a constraint. With
        ``zeta_method == "evidence"`` (the default of :func:`mesc_irl`)
        ``sigmoid((penalty - sigma_nominal) / sigma_nominal) *
        sigmoid(evidence - evidence_cost)``; with ``"penalty"`` the
        paper's map ``penalty_zeta``.
    horizon, n_demonstrations, n_iter, n_evaluations : int
    converged : bool
    message : str
        The optimiser's message.
    penalty_zeta : ndarray, shape (n_features,)
        The paper's map ``sigmoid((penalty - sigma_pooled) / sigma_pooled)``.
    evidence : ndarray of shape (n_features,) or None
        Log-likelihood (nats, summed over the demonstrations) lost when the
        feature's penalty is set to zero and the other selected penalties are
        refitted (the other features at zero); zero for features outside the
        selected model, which ``evidence > 0`` marks; None when no
        selection was made.
    evidence_cost : float or None
        Cost in nats of one more feature (see :func:`mesc_irl`); None with ``evidence``.
    zeta_method : str
        ``"evidence"`` or ``"penalty"``.
    selection : str
        How the penalised features were chosen: ``"evidence"``, ``"l1"`` or ``"none"``.

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
    penalty_zeta: np.ndarray | None = None
    evidence: np.ndarray | None = None
    evidence_cost: float | None = None
    zeta_method: str = "penalty"
    selection: str = "none"

    @classmethod
    def from_penalties(cls, nominal, penalties, *, evidence=None, evidence_cost=None, selection="none", **info):
        """Build a result (zeta, learned MDP, ...) from penalties; ``info`` fills the fit diagnostics.

        With ``evidence`` (nats per feature) and ``evidence_cost`` (nats),
        ``zeta = sigmoid((penalty - sigma_nominal) / sigma_nominal) *
        sigmoid(evidence - evidence_cost)``; otherwise zeta is the paper's
        map of the penalties.
        """
        if not isinstance(nominal, MDP) or nominal.features is None:
            raise TypeError("nominal must be an irl.MDP with features")
        w = nominal.features.check_weights(penalties, "penalties")
        if w.min() < 0:
            raise ValueError(f"penalties must be non-negative (got {w.min():.4g})")
        constrained = nominal.penalised(w)
        s_n, s_c = feasible_reward_sd(nominal), feasible_reward_sd(constrained)
        s_p = float(np.sqrt((s_n**2 + s_c**2) / 2))
        penalty_zeta = constraint_probability(w, s_p) if s_p > 0 else (w > 0).astype(float)
        if (evidence is None) != (evidence_cost is None):
            raise ValueError("evidence and evidence_cost must be given together (got one of them)")
        if evidence is not None:
            evidence = _as_float("evidence", evidence, ndim=1, shape=(w.size,))
            if evidence.min() < 0:
                raise ValueError(f"evidence must be non-negative log-likelihood losses (got {evidence.min():.4g})")
            evidence_cost = _as_real("evidence_cost", evidence_cost, low=0.0)
            size = constraint_probability(w, s_n) if s_n > 0 else (w > 0).astype(float)
            zeta = size / (1.0 + np.exp(-(evidence - evidence_cost)))
            evidence.flags.writeable = False
        else:
            zeta = penalty_zeta.copy()
        for arr in (w, zeta, penalty_zeta):
            arr.flags.writeable = False
        defaults = dict(
            objective=float("nan"), gradient=np.full(w.size, np.nan),
            horizon=0, n_demonstrations=0, n_iter=0, n_evaluations=0, converged=False, message="",
        )
        defaults.update(info)
        return cls(
            penalties=w, feature_names=nominal.features.names, nominal=nominal, constrained=constrained,
            sigma_nominal=s_n, sigma_constrained=s_c, sigma_pooled=s_p, zeta=zeta, penalty_zeta=penalty_zeta,
            evidence=evidence, evidence_cost=evidence_cost,
            zeta_method="penalty" if evidence is None else "evidence", selection=selection, **defaults,
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
            ``zeta`` of each feature in f (see ``zeta_method``).
        """
        idx = slice(None) if features is None else features
        return np.array(self.zeta[idx], copy=True)

    def transition_zeta(self, features=None):
        """zeta of every padded transition, shape (S, A, K), from the penalty of the features in ``features``.

        ``sigmoid((omega_f . phi_f(s, a, s') - sigma_pooled) / sigma_pooled)``;
        with ``features=None`` all features count (the paper's per-transition
        zeta). This is always the paper's penalty map, whatever ``zeta_method``.
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

    def summary(self, *, min_zeta: float = 0.5) -> str:
        """The fit and the constraints with ``zeta >= min_zeta``, as text.

        Examples
        --------
        >>> import irl
        >>> world = irl.GridWorld(4, 0, 15, constrained_states=[5, 10], p_slip=0.0)
        >>> demos = irl.generate_demonstrations(world.constrained_mdp, 50, rng=0)
        >>> print(irl.mesc_irl(world.nominal_mdp, demos).summary(min_zeta=0.6))
        ... # doctest: +ELLIPSIS
        MESC-IRL: 27 features, 2 with zeta >= 0.6, selection evidence, converged after ...
        log-likelihood per demonstration -3.0... (50 demonstrations, horizon 9)
          #  constraint                 penalty     zeta
          1  state ...                    7.2...   0.91...
          2  state ...                    7.2...   0.91...
        """
        ranked = self.ranked_constraints(min_zeta=min_zeta)
        rows = [f"{'#':>3s}  {'constraint':<24s} {'penalty':>9s} {'zeta':>8s}"]
        rows += [f"{k + 1:3d}  {c.name:<24s} {c.penalty:9.4f} {c.zeta:8.4f}"
                 for k, c in enumerate(ranked)]
        return (f"MESC-IRL: {self.penalties.size} features, {len(ranked)} with zeta >= "
                f"{min_zeta:g}, selection {self.selection}, "
                f"{iterations(self.n_iter, self.converged)}\n"
                + (f"log-likelihood per demonstration {self.objective:.4f} "
                   f"({self.n_demonstrations} demonstrations, horizon {self.horizon})\n"
                   if self.n_demonstrations else "no demonstrations (penalties given)\n")
                + "\n".join(rows))

    def save(self, path):
        """Write the result to JSON (see :func:`irl.io.save_mesc_result`)."""
        from .io import save_mesc_result

        save_mesc_result(self, path)
