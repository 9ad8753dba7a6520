"""Rollouts: trajectories of an orchestrator in the world's true dynamics.

All trajectories advance in lockstep: at every time step the active ones make their
decisions in one batched call (:meth:`Orchestrator.decide_many`; for MDFT one compiled
:func:`mdft.decide` over a stack of ``M`` matrices), then their successors are drawn from
the transitions of the nominal MDP.
"""

from __future__ import annotations

import numbers
import warnings

import numpy as np

import irl

from .orchestrators import Orchestrator

__all__ = ["rollout"]

#: Default cut-off of a trajectory that has not entered a terminal state.
DEFAULT_MAX_LENGTH = 1000


def _start_distribution(start, mdp) -> np.ndarray:
    if start is None:
        return np.asarray(mdp.start, dtype=np.float64)
    if isinstance(start, (numbers.Integral, np.integer)) and not isinstance(start, bool):
        s = int(start)
        if not 0 <= s < mdp.n_states:
            raise ValueError(f"start must be a state in [0, {mdp.n_states}) or a distribution (got {s})")
        p0 = np.zeros(mdp.n_states)
        p0[s] = 1.0
        return p0
    try:
        p0 = np.array(start, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise TypeError(f"start must be a state index or a distribution over states (got {start!r})") from exc
    if p0.shape != (mdp.n_states,) or not np.all(np.isfinite(p0)) or p0.min() < 0 \
            or abs(p0.sum() - 1.0) > 1e-8:
        raise ValueError(
            f"start must be a state index or a probability distribution of shape ({mdp.n_states},) "
            f"(got shape {p0.shape})"
        )
    return p0 / p0.sum()


def rollout(orchestrator, n_trajectories, *, rng=None, max_length=None, start=None,
            mdp=None) -> irl.Demonstrations:
    """Trajectories of an orchestrator, one decision per step, in the nominal MDP's dynamics.

    Parameters
    ----------
    orchestrator : Orchestrator
        A :class:`GreedyOrchestrator`, :class:`WeightedAverageOrchestrator` or
        :class:`MDFTOrchestrator`.
    n_trajectories : int
        Number of trajectories, at least 1.
    rng : None, int or numpy.random.Generator
        Source of randomness (start states, decisions, transitions). The same seed gives
        the same trajectories.
    max_length : int, optional
        Transitions after which a trajectory that has not entered a terminal state is
        cut (default 1000). Cut trajectories are kept, flagged ``False`` in
        ``reached_terminal`` and counted in a ``RuntimeWarning``.
    start : int or array_like, shape (n_states,), optional
        A start state or a start distribution (default: the MDP's).
    mdp : irl.MDP, optional
        The world whose transitions are sampled (default: the nominal MDP the
        orchestrator was built from, ``orchestrator.preferences.nominal``). It must have
        the orchestrator's states and actions.

    Returns
    -------
    irl.Demonstrations
        The trajectories, in order; ``reached_terminal`` says which entered a terminal
        state.

    Notes
    -----
    At step ``t`` every active trajectory in state ``s_t`` takes ``a_t`` from one call of
    ``orchestrator.decide_many`` on all active states, then moves to
    ``s_{t+1} ~ P(. | s_t, a_t)`` of ``mdp``; a trajectory stops on entering a terminal
    state. The cost per decision of an MDFT orchestrator is that of the compiled
    deliberation (``benchmarks/bench_rollout.py``).

    Examples
    --------
    >>> import irl, orchestration
    >>> world = irl.GridWorld(3, 0, 8, constrained_states=(4,))
    >>> orch = orchestration.MDFTOrchestrator(
    ...     world.nominal_mdp, world.constrained_mdp, weights=(0.2, 0.8))
    >>> demos = orchestration.rollout(orch, 50, rng=0)
    >>> len(demos), bool(demos.reached_terminal.all())
    (50, True)
    >>> orchestration.rollout(orch, 50, rng=0).actions.tolist() == demos.actions.tolist()
    True
    """
    if not isinstance(orchestrator, Orchestrator):
        raise TypeError(
            "orchestrator must be an orchestration.Orchestrator (Greedy, WeightedAverage or "
            f"MDFT) (got {type(orchestrator).__name__})"
        )
    if isinstance(n_trajectories, bool) or not isinstance(n_trajectories, (numbers.Integral, np.integer)):
        raise TypeError(f"n_trajectories must be an integer (got {n_trajectories!r})")
    n = int(n_trajectories)
    if n < 1:
        raise ValueError(f"n_trajectories must be an integer >= 1 (got {n})")
    if max_length is None:
        max_length = DEFAULT_MAX_LENGTH
    if isinstance(max_length, bool) or not isinstance(max_length, (numbers.Integral, np.integer)) \
            or max_length < 1:
        raise ValueError(f"max_length must be an integer >= 1 (got {max_length!r})")
    max_length = int(max_length)
    if mdp is None:
        mdp = orchestrator.preferences.nominal
        if mdp is None:
            raise ValueError(
                "mdp is required: the orchestrator's preferences hold no nominal MDP; pass the "
                "world's MDP as mdp="
            )
    elif not isinstance(mdp, irl.MDP):
        raise TypeError(f"mdp must be an irl.MDP (got {type(mdp).__name__})")
    if (mdp.n_states, mdp.n_actions) != (orchestrator.n_states, orchestrator.n_actions):
        raise ValueError(
            f"mdp must have the orchestrator's {orchestrator.n_states} states and "
            f"{orchestrator.n_actions} actions (got {mdp.n_states} and {mdp.n_actions})"
        )
    if not np.array_equal(mdp.terminal, orchestrator.preferences.terminal):
        raise ValueError(
            "mdp must have the terminal states of the orchestrator's MDPs (they differ): the "
            "orchestrator takes no decision in a terminal state"
        )
    p0 = _start_distribution(start, mdp)
    if np.any((p0 > 0) & mdp.terminal):
        raise ValueError("start must put no mass on terminal states: a trajectory would be empty")

    generator = np.random.default_rng(rng)
    cum0 = np.cumsum(p0)
    states = np.minimum(np.searchsorted(cum0, generator.random(n) * cum0[-1], side="right"),
                        mdp.n_states - 1)
    active = np.arange(n)
    reached = np.zeros(n, dtype=bool)
    next_states, probs, terminal = mdp.next_states, mdp.probs, mdp.terminal
    K = probs.shape[2]
    rec_traj, rec_s, rec_a, rec_ns = [], [], [], []
    for _ in range(max_length):
        actions = orchestrator.decide_many(states, generator)
        cum = np.cumsum(probs[states, actions], axis=1)
        u = generator.random(states.size) * cum[:, -1]
        slot = np.minimum((cum <= u[:, None]).sum(axis=1), K - 1)
        successors = next_states[states, actions, slot]
        rec_traj.append(active)
        rec_s.append(states)
        rec_a.append(actions)
        rec_ns.append(successors)
        done = terminal[successors]
        reached[active[done]] = True
        active = active[~done]
        states = successors[~done]
        if active.size == 0:
            break

    traj = np.concatenate(rec_traj)
    order = np.argsort(traj, kind="stable")  # per trajectory, in time order
    lengths = np.bincount(traj, minlength=n)
    offsets = np.concatenate([[0], np.cumsum(lengths)])
    if terminal.any() and not reached.all():
        warnings.warn(
            f"{int((~reached).sum())} of {n} trajectories did not reach a terminal state within "
            f"max_length={max_length}; they are kept and flagged in reached_terminal",
            RuntimeWarning,
            stacklevel=2,
        )
    return irl.Demonstrations(
        offsets,
        np.concatenate(rec_s)[order],
        np.concatenate(rec_a)[order],
        np.concatenate(rec_ns)[order],
        reached,
    )
