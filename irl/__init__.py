"""Tabular MDPs, gridworlds, planning, demonstrations and constraint learning (MESC-IRL).

``irl`` supplies the attributes that an MDFT orchestrator deliberates over: the
Q-values and policies of a nominal MDP and of one whose soft constraints were
learned from demonstrations. It does not depend on :mod:`mdft`.
"""

from .mdp import MDP, TransitionFeatures
from .gridworld import ACTIONS, ACTION_MOVES, COLOURS, GridWorld
from .planning import (
    PlanningResult,
    SoftPlanningResult,
    VisitationResult,
    greedy_policy,
    soft_value_iteration,
    state_action_visitation,
    value_iteration,
)

__all__ = [
    "MDP",
    "TransitionFeatures",
    "ACTIONS",
    "ACTION_MOVES",
    "COLOURS",
    "GridWorld",
    "PlanningResult",
    "SoftPlanningResult",
    "VisitationResult",
    "greedy_policy",
    "soft_value_iteration",
    "state_action_visitation",
    "value_iteration",
]
