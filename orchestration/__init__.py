"""Orchestrators that trade a nominal goal off against learned constraints.

Greedy, weighted-average and MDFT orchestrators, rollouts, the paper's
experiments and the ``mdft`` command line. Uses :mod:`mdft` and :mod:`irl`
through their public APIs only.
"""

from .preferences import ActionPreferences, action_preferences
from .orchestrators import (
    GreedyOrchestrator,
    MDFTOrchestrator,
    Orchestrator,
    WeightedAverageOrchestrator,
)
from .rollout import rollout
from .agent import Episode, OrchestratorAgent, run_episode
from .expressiveness import MDFTvsWAInstance, MDFTvsWAResult, mdft_vs_wa, mdft_vs_wa_instance
from .guided_tour import TourResult, tour

__all__ = [
    "ActionPreferences",
    "action_preferences",
    "Orchestrator",
    "GreedyOrchestrator",
    "WeightedAverageOrchestrator",
    "MDFTOrchestrator",
    "rollout",
    "Episode",
    "OrchestratorAgent",
    "run_episode",
    "MDFTvsWAInstance",
    "MDFTvsWAResult",
    "mdft_vs_wa_instance",
    "mdft_vs_wa",
    "TourResult",
    "tour",
]

from mdft import __version__  # one version for the whole pymdft distribution
