"""Tabular MDPs, gridworlds, planning, demonstrations and constraint learning (MESC-IRL).

``irl`` supplies the attributes that an MDFT orchestrator deliberates over: the
Q-values and policies of a nominal MDP and of one whose soft constraints were
learned from demonstrations. It does not depend on :mod:`mdft`.
"""

from ._version import __version__

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
from .metrics import (
    HardConstraintScores,
    SoftConstraintErrors,
    false_discovery_rate,
    false_positive_rate,
    hard_constraint_scores,
    js_divergence,
    kl_divergence,
    precision,
    recall,
    soft_constraint_errors,
    visitation_counts,
    visitation_js_divergence,
    visitation_kl_divergence,
)
from .gym import from_gymnasium
from .demonstrations import Demonstrations, generate_demonstrations, sample_trajectories
from .mesc import MESCObjective, mesc_irl
from .mesc_result import LearnedConstraint, MESCResult, constraint_probability
from .io import (
    load_demonstrations,
    load_mdp,
    load_mesc_result,
    load_paper_demonstrations,
    load_paper_worlds,
    save_demonstrations,
    save_mdp,
    save_mesc_result,
)
from .scobee import HardConstraintResult, infer_hard_constraints
from .warmup import WarmupReport, warmup

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
    "Demonstrations",
    "generate_demonstrations",
    "sample_trajectories",
    "LearnedConstraint",
    "MESCObjective",
    "MESCResult",
    "constraint_probability",
    "mesc_irl",
    "load_demonstrations",
    "load_mdp",
    "load_mesc_result",
    "load_paper_demonstrations",
    "load_paper_worlds",
    "save_demonstrations",
    "save_mdp",
    "save_mesc_result",
    "HardConstraintScores",
    "SoftConstraintErrors",
    "false_discovery_rate",
    "false_positive_rate",
    "hard_constraint_scores",
    "js_divergence",
    "kl_divergence",
    "precision",
    "recall",
    "soft_constraint_errors",
    "visitation_counts",
    "visitation_js_divergence",
    "visitation_kl_divergence",
    "from_gymnasium",
    "HardConstraintResult",
    "infer_hard_constraints",
    "WarmupReport",
    "warmup",
]
