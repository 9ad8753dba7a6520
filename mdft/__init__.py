"""pymdft's MDFT engine: Multi-alternative Decision Field Theory, compiled with numba.

The engine is standalone: it knows nothing of MDPs or of the orchestration
built on it. See ``docs/concepts.md`` for the equations and conventions.
"""

from ._version import __version__

from .model import (
    MDFTModel,
    UnstableFeedbackWarning,
    contrast_matrix,
    distance_matrix,
    feedback_matrix,
)
from .stopping import FixedTime, Threshold
from .simulation_result import SimulationResult
from .simulate import simulate
from .decide import decide
from .closed_form import (
    ClosedFormAccuracyWarning,
    MixtureProbabilities,
    choice_probabilities,
    mixture_choice_probabilities,
    preference_moments,
)
from .effects import (
    ATTRACTION,
    COMPROMISE,
    SIMILARITY,
    ContextEffect,
    ContextEffects,
    EffectResult,
    context_effects,
    default_stopping,
)
from .fit import ChoiceData, FitConvergenceWarning, FitResult, fit
from .fit_many import FitManyResult, fit_many
from .threshold_exact import (ThresholdProbabilities, ThresholdToleranceError,
                              threshold_probabilities)
from .warmup import WarmupReport, warmup

__all__ = [
    "FixedTime",
    "SimulationResult",
    "Threshold",
    "decide",
    "simulate",
    "ClosedFormAccuracyWarning",
    "choice_probabilities",
    "preference_moments",
    "MixtureProbabilities",
    "mixture_choice_probabilities",
    "ChoiceData",
    "FitConvergenceWarning",
    "FitResult",
    "fit",
    "FitManyResult",
    "fit_many",
    "MDFTModel",
    "UnstableFeedbackWarning",
    "contrast_matrix",
    "distance_matrix",
    "feedback_matrix",
    "ATTRACTION",
    "COMPROMISE",
    "SIMILARITY",
    "ContextEffect",
    "ContextEffects",
    "EffectResult",
    "context_effects",
    "default_stopping",
    "ThresholdProbabilities",
    "ThresholdToleranceError",
    "threshold_probabilities",
    "WarmupReport",
    "warmup",
]
