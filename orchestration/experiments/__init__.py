"""The paper's experiments, run as independent work units (``mdft reproduce``).

- :mod:`.runner`: units, seeds, executors, atomic saving and resuming.
- :mod:`.base`: :class:`Experiment`, :class:`Report` and :func:`reproduce`.
- One module per experiment: :mod:`.orchestrators`, :mod:`.mdft_vs_wa`,
  :mod:`.hard_constraints`, :mod:`.soft_constraints`, :mod:`.transfer`.
- :mod:`.plot`: their figures, drawn on given Axes.
"""

from .base import EXPERIMENTS, Experiment, Report, get_experiment, reproduce
from .runner import (
    RunMismatchError,
    RunResult,
    Unit,
    child_seed,
    dask_executor,
    local_executor,
    run_units,
    unit_seed,
)

__all__ = [
    "EXPERIMENTS",
    "Experiment",
    "Report",
    "RunMismatchError",
    "RunResult",
    "Unit",
    "child_seed",
    "dask_executor",
    "get_experiment",
    "local_executor",
    "reproduce",
    "run_units",
    "unit_seed",
]
