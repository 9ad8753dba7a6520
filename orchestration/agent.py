"""An orchestrator inside a Gymnasium-style agent loop.

Any environment with discrete states and actions and the Gymnasium API
(``reset(seed=...) -> (observation, info)``, ``step(action) -> (observation, reward,
terminated, truncated, info)``) can be driven by an orchestrator: FrozenLake, CliffWalking
and Taxi read with :func:`irl.from_gymnasium`, or a hand-made environment. The observation
is mapped to the orchestrator's state index (by default it *is* the index).
"""

from __future__ import annotations

import numbers
from dataclasses import dataclass

import numpy as np

import irl

from .orchestrators import Orchestrator

__all__ = ["OrchestratorAgent", "Episode", "run_episode"]


def _identity_state(observation):
    return observation


class OrchestratorAgent:
    """An agent that chooses each action by one decision of an orchestrator.

    Parameters
    ----------
    orchestrator : Orchestrator
        Built on an MDP of the environment (e.g. from :func:`irl.from_gymnasium`).
    observation_to_state : callable, optional
        Maps an observation to a state index in ``[0, orchestrator.n_states)``; by default
        the observation is the state index (as in FrozenLake, CliffWalking and Taxi).
    rng : None, int or numpy.random.Generator
        Source of the agent's randomness.

    Examples
    --------
    >>> import irl, orchestration
    >>> world = irl.GridWorld(3, 0, 8, p_slip=0.0)
    >>> orch = orchestration.WeightedAverageOrchestrator(
    ...     world.nominal_mdp, world.constrained_mdp, weights=(0.5, 0.5))
    >>> agent = orchestration.OrchestratorAgent(orch, rng=0)
    >>> agent.act(0) in range(8)
    True
    """

    def __init__(self, orchestrator, *, observation_to_state=None, rng=None):
        if not isinstance(orchestrator, Orchestrator):
            raise TypeError(
                f"orchestrator must be an orchestration.Orchestrator (got {type(orchestrator).__name__})"
            )
        if observation_to_state is not None and not callable(observation_to_state):
            raise TypeError(f"observation_to_state must be callable or None (got {observation_to_state!r})")
        self.orchestrator = orchestrator
        self.observation_to_state = observation_to_state or _identity_state
        self.rng = np.random.default_rng(rng)

    def state(self, observation) -> int:
        """The state index of ``observation`` (validated)."""
        s = self.observation_to_state(observation)
        if isinstance(s, np.ndarray) and s.ndim == 0:
            s = s.item()
        if isinstance(s, bool) or not isinstance(s, (numbers.Integral, np.integer)):
            raise TypeError(
                f"the observation must map to an integer state index (got {s!r} from observation "
                f"{observation!r}); pass observation_to_state="
            )
        if not 0 <= int(s) < self.orchestrator.n_states:
            raise ValueError(
                f"the observation maps to state {int(s)}, outside [0, {self.orchestrator.n_states}) "
                "of the orchestrator's MDP"
            )
        return int(s)

    def act(self, observation) -> int:
        """One decision of the orchestrator in the state of ``observation``."""
        return self.orchestrator.act(self.state(observation), self.rng)


@dataclass(frozen=True, eq=False)
class Episode:
    """One episode of an agent in an environment.

    Attributes
    ----------
    states : ndarray of int, shape (n_steps + 1,)
        State indices visited, from the reset state to the last one.
    actions : ndarray of int, shape (n_steps,)
    rewards : ndarray, shape (n_steps,)
    total_reward : float
    terminated : bool
        The environment ended the episode (goal, hole, ...).
    truncated : bool
        The environment truncated it (its time limit) or ``max_steps`` was reached.

    Examples
    --------
    >>> import numpy as np
    >>> ep = Episode(np.array([0, 1, 2]), np.array([1, 1]), np.array([-1.0, -1.0]), -2.0,
    ...              True, False)
    >>> ep.n_steps, ep.to_demonstrations().trajectory(0)
    (2, ([0, 1, 2], [1, 1]))
    """

    states: np.ndarray
    actions: np.ndarray
    rewards: np.ndarray
    total_reward: float
    terminated: bool
    truncated: bool

    def __repr__(self) -> str:
        return (f"Episode(n_steps={self.n_steps}, total_reward={self.total_reward:.6g}, "
                f"terminated={self.terminated}, truncated={self.truncated})")

    def summary(self) -> str:
        """The episode's length, return and ending, and its path of states, as text.

        Examples
        --------
        >>> import numpy as np
        >>> print(Episode(np.array([0, 1, 2]), np.array([1, 1]), np.array([-1.0, -1.0]), -2.0,
        ...               True, False).summary())
        2 steps, total reward -2, terminated
        states: 0 -> 1 -> 2
        """
        ending = ("terminated" if self.terminated else "truncated" if self.truncated
                  else "still running")
        path = " -> ".join(str(int(s)) for s in self.states[:21])
        more = f" -> ... ({self.states.size - 21} more)" if self.states.size > 21 else ""
        return (f"{self.n_steps} steps, total reward {self.total_reward:g}, {ending}\n"
                f"states: {path}{more}")

    @property
    def n_steps(self) -> int:
        """Number of actions taken."""
        return int(self.actions.size)

    def to_demonstrations(self) -> irl.Demonstrations:
        """The episode as a one-trajectory :class:`irl.Demonstrations`."""
        if self.n_steps == 0:
            raise ValueError("the episode has no transition (it ended at reset)")
        demos = irl.Demonstrations.from_sequences([self.states.tolist()], [self.actions.tolist()])
        return irl.Demonstrations(demos.offsets, demos.states, demos.actions, demos.next_states,
                                  [self.terminated])


def run_episode(env, orchestrator, *, rng=None, max_steps=1000, observation_to_state=None) -> Episode:
    """Run one episode of an orchestrator in a Gymnasium-style environment.

    Parameters
    ----------
    env : object
        An environment with ``reset(seed=...)`` and ``step(action)`` in the Gymnasium API
        (five-tuple from ``step``), discrete observations and actions.
    orchestrator : Orchestrator
        Built on an MDP with the environment's states and actions, e.g. from
        ``irl.from_gymnasium(env)``.
    rng : None, int or numpy.random.Generator
        Seeds the environment's reset (one integer drawn from it) and the agent's
        decisions: the same seed gives the same episode.
    max_steps : int, default 1000
        Steps after which the episode is cut (reported as ``truncated``).
    observation_to_state : callable, optional
        As in :class:`OrchestratorAgent`.

    Returns
    -------
    Episode

    Examples
    --------
    A three-cell corridor with the Gymnasium interface:

    >>> import irl, orchestration
    >>> class Corridor:
    ...     P = {s: {0: [(1.0, max(s - 1, 0), -1.0, False)],
    ...              1: [(1.0, s + 1, -1.0, s + 1 == 2)]} for s in range(2)}
    ...     P[2] = {0: [(1.0, 2, 0.0, True)], 1: [(1.0, 2, 0.0, True)]}
    ...     initial_state_distrib = [1.0, 0.0, 0.0]
    ...     def reset(self, *, seed=None):
    ...         self.s = 0
    ...         return 0, {}
    ...     def step(self, a):
    ...         _, self.s, r, done = self.P[self.s][a][0]
    ...         return self.s, r, done, False, {}
    >>> env = Corridor()
    >>> mdp = irl.from_gymnasium(env)
    >>> greedy = orchestration.GreedyOrchestrator(mdp, mdp)
    >>> ep = orchestration.run_episode(env, greedy, rng=0)
    >>> ep.states.tolist(), ep.total_reward, ep.terminated
    ([0, 1, 2], -2.0, True)
    """
    agent = OrchestratorAgent(orchestrator, observation_to_state=observation_to_state, rng=rng)
    if isinstance(max_steps, bool) or not isinstance(max_steps, (numbers.Integral, np.integer)) \
            or max_steps < 1:
        raise ValueError(f"max_steps must be an integer >= 1 (got {max_steps!r})")
    for name in ("reset", "step"):
        if not callable(getattr(env, name, None)):
            raise TypeError(f"env must have a {name}() method in the Gymnasium API (got {type(env).__name__})")
    seed = int(agent.rng.integers(2**31))
    reset = env.reset(seed=seed)
    if not (isinstance(reset, tuple) and len(reset) == 2):
        raise TypeError("env.reset must return (observation, info) as in the Gymnasium API")
    observation = reset[0]
    states = [agent.state(observation)]
    actions, rewards = [], []
    terminated = truncated = False
    for _ in range(int(max_steps)):
        action = agent.act(observation)
        result = env.step(action)
        if not (isinstance(result, tuple) and len(result) == 5):
            raise TypeError(
                "env.step must return (observation, reward, terminated, truncated, info) as in "
                "the Gymnasium API"
            )
        observation, reward, terminated, truncated, _ = result
        actions.append(action)
        rewards.append(float(reward))
        states.append(agent.state(observation))
        if terminated or truncated:
            break
    else:
        truncated = True
    rewards_arr = np.asarray(rewards, dtype=np.float64)
    return Episode(
        states=np.asarray(states, dtype=np.int64),
        actions=np.asarray(actions, dtype=np.int64),
        rewards=rewards_arr,
        total_reward=float(rewards_arr.sum()),
        terminated=bool(terminated),
        truncated=bool(truncated and not terminated),
    )
