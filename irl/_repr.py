"""A short ``repr`` for result and model dataclasses that hold large arrays.

The default dataclass ``repr`` prints every array and every nested model in
full, thousands of lines for a gridworld; this one prints small arrays and
scalars as they are and summarises the rest by type and shape.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import scipy.sparse as sp

_SMALL = 8


def _short(value) -> str:
    if isinstance(value, np.ndarray):
        if value.size <= _SMALL:
            return np.array2string(value, precision=6, separator=", ")
        return f"<array shape={value.shape} dtype={value.dtype}>"
    if sp.issparse(value):
        return f"<sparse shape={value.shape} nnz={value.nnz}>"
    if isinstance(value, (tuple, list)) and len(value) > _SMALL:
        return f"<{type(value).__name__} of {len(value)}>"
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return repr(value) if len(repr(value)) <= 200 else f"<{type(value).__name__}>"
    if isinstance(value, float):
        return f"{value:.6g}"
    return repr(value)


def spread(values) -> str:
    """``"min a, mean b, max c"`` of the finite entries of an array (``"none finite"`` if none)."""
    arr = np.asarray(values, dtype=float)
    arr = arr[np.isfinite(arr)]
    if arr.size == 0:
        return "none finite"
    return f"min {arr.min():.4g}, mean {arr.mean():.4g}, max {arr.max():.4g}"


def iterations(n_iter: int, converged: bool) -> str:
    """``"converged after 12 iterations"`` or ``"NOT converged after 12 iterations"``."""
    return f"{'converged' if converged else 'NOT converged'} after {n_iter} iterations"


def compact_repr(self) -> str:
    """``ClassName(field=value, ...)`` with large arrays summarised by shape."""
    parts = [
        f"{f.name}={_short(getattr(self, f.name))}"
        for f in dataclasses.fields(self)
        if f.repr
    ]
    return f"{type(self).__name__}({', '.join(parts)})"
