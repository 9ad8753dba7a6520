"""Plain-data export of models and results: JSON-ready builtins, JSON files, text tables.

``to_dict`` methods return only ``dict``, ``list``, ``str``, ``int``, ``float``, ``bool``
and ``None``; a NaN or infinite number becomes ``None`` (JSON has no such numbers), which
is stated in each method's docstring. JSON files are written whole or not at all: to a
temporary file beside the target, then moved over it.
"""

from __future__ import annotations

import json
import math
import os
import tempfile
from pathlib import Path

import numpy as np


def builtin(value):
    """``value`` with NumPy arrays and scalars turned into lists and Python numbers.

    Tuples become lists, NaN and infinities become ``None``; dicts are converted
    recursively (their keys must already be strings).
    """
    if isinstance(value, dict):
        return {str(k): builtin(v) for k, v in value.items()}
    if isinstance(value, np.ndarray):
        return builtin(value.tolist())
    if isinstance(value, (list, tuple)):
        return [builtin(v) for v in value]
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        value = float(value)
        return value if math.isfinite(value) else None
    if value is None or isinstance(value, str):
        return value
    raise TypeError(f"cannot export a {type(value).__name__} to JSON")


def to_json(data: dict, path=None) -> str:
    """Return ``data`` as indented JSON text; with ``path``, also write it there (atomically)."""
    text = json.dumps(data, indent=2, allow_nan=False) + "\n"
    if path is None:
        return text
    if not isinstance(path, (str, os.PathLike)):
        raise TypeError(f"path must be a str or os.PathLike (got {type(path).__name__})")
    target = Path(path)
    if not target.parent.is_dir():
        raise ValueError(f"path {str(path)!r}: folder {str(target.parent)!r} does not exist")
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write(text)
        os.replace(tmp, target)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return text


def stopping_dict(stopping) -> dict:
    """``{"rule": "fixed_time", "n_steps": T}`` or ``{"rule": "threshold", "theta", "max_steps"}``."""
    if hasattr(stopping, "theta"):
        return {"rule": "threshold", "theta": float(stopping.theta),
                "max_steps": int(stopping.max_steps)}
    return {"rule": "fixed_time", "n_steps": int(stopping.n_steps)}


def describe_stopping(stopping) -> str:
    """``"fixed time, 100 steps"`` or ``"threshold 17.5 (at most 10,000 steps)"``."""
    if hasattr(stopping, "theta"):
        return f"threshold {stopping.theta:g} (at most {stopping.max_steps:,} steps)"
    return f"fixed time, {stopping.n_steps:,} steps"


def table(header: list, rows: list, *, left: int = 1) -> str:
    """Columns of text, the first ``left`` left-aligned and the others right-aligned."""
    cells = [list(map(str, header))] + [list(map(str, r)) for r in rows]
    widths = [max(len(r[i]) for r in cells) for i in range(len(header))]
    lines = []
    for r in cells:
        parts = [c.ljust(w) if i < left else c.rjust(w)
                 for i, (c, w) in enumerate(zip(r, widths))]
        lines.append("  ".join(parts).rstrip())
    return "\n".join(lines)


def labels_for(labels, n: int, name: str = "labels") -> list:
    """``labels`` checked to hold ``n`` entries, or ``["0", "1", ...]``.

    Any sized iterable is accepted, a string of ``n`` characters too (as in
    :func:`mdft.plot.plot_trajectories`).
    """
    if labels is None:
        return [str(i) for i in range(n)]
    if not (hasattr(labels, "__len__") and hasattr(labels, "__iter__")) or isinstance(
            labels, dict):
        raise TypeError(f"{name} must be a sequence of {n} strings (got {labels!r})")
    if len(labels) != n:
        raise ValueError(f"{name} must hold one label per option, {n} (got {len(labels)})")
    return [str(s) for s in labels]


def fmt(x: float, spec: str = ".4f") -> str:
    """A number, or ``"-"`` for NaN."""
    return "-" if x is None or (isinstance(x, float) and math.isnan(x)) else format(x, spec)
