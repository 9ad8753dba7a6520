"""Type aliases of the public signatures (annotations only; nothing here runs)."""

from __future__ import annotations

import os
from typing import TypeAlias

import numpy as np
from numpy.typing import ArrayLike

__all__ = ["ArrayLike", "PathLike", "SeedLike"]

#: What ``rng=`` accepts: anything :func:`numpy.random.default_rng` accepts.
SeedLike: TypeAlias = (
    int | np.random.SeedSequence | np.random.BitGenerator | np.random.Generator | None
)

#: A file name: a string or a path object.
PathLike: TypeAlias = str | os.PathLike[str]
