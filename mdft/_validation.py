"""Input checks shared by the public layer of :mod:`mdft`.

Every check raises ``ValueError`` or ``TypeError`` with a message that names the
parameter, says what was received and what is required. Nothing invalid
reaches a compiled kernel.
"""

from __future__ import annotations

import numbers

import numpy as np

#: Size limits of the public API (``docs/decisions.md``): they keep a typo from asking for
#: terabytes of memory or years of computation, far above any use in the literature.
MAX_OPTIONS = 1_000
MAX_STEPS = 10_000_000
#: Largest threshold: the preference that first passes it is still a finite float unless one
#: step multiplies it by more than about 1e8.
MAX_THETA = 1e300
MAX_SAMPLES = 100_000_000


def _describe(x) -> str:
    arr = np.asarray(x)
    if arr.ndim == 0:
        return repr(arr.item()) if arr.dtype != object else repr(x)
    return f"an array of shape {arr.shape}"


def as_float_array(name: str, value, *, ndim: int | None = None, shape=None) -> np.ndarray:
    """Return ``value`` as a new C-contiguous float64 array, checked for shape and finiteness.

    ``shape`` may hold ``None`` for a free dimension.
    """
    try:
        complex_values = np.iscomplexobj(value)
    except (TypeError, ValueError):  # ragged or not numbers: the conversion below says so
        complex_values = False
    if complex_values:
        raise TypeError(f"{name} must be an array of real numbers (got complex values)")
    try:
        arr = np.array(value, dtype=np.float64, order="C", copy=True)
    except OverflowError:
        raise ValueError(f"{name} must contain only finite values (got a number too large "
                         "for a float)") from None
    except (TypeError, ValueError) as exc:
        text = repr(value)
        text = text if len(text) <= 80 else text[:77] + "..."
        raise TypeError(f"{name} must be an array of real numbers (got {text})") from exc
    if ndim is not None and arr.ndim != ndim:
        raise ValueError(
            f"{name} must be a {ndim}-d array (got {arr.ndim}-d with shape {arr.shape})"
        )
    if shape is not None:
        if arr.ndim != len(shape) or any(
            want is not None and got != want for got, want in zip(arr.shape, shape)
        ):
            wanted = "(" + ", ".join("any" if s is None else str(s) for s in shape) + ")"
            raise ValueError(f"{name} must have shape {wanted} (got {arr.shape})")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must contain only finite values (got NaN or infinity in {name})")
    return arr


def as_scalar(
    name: str,
    value,
    *,
    low: float | None = None,
    high: float | None = None,
    low_inclusive: bool = True,
) -> float:
    """Return ``value`` as a finite float within the given bounds."""
    if isinstance(value, bool) or not isinstance(value, (numbers.Real, np.ndarray, np.generic)):
        raise TypeError(f"{name} must be a real number (got {value!r})")
    arr = np.asarray(value)
    if np.iscomplexobj(arr):
        raise TypeError(f"{name} must be a real number (got {value!r})")
    if arr.ndim != 0:
        raise TypeError(f"{name} must be a scalar (got {_describe(value)})")
    try:
        x = float(arr)
    except OverflowError:
        raise ValueError(f"{name} must be finite (got an integer too large for a float)"
                         ) from None
    if not np.isfinite(x):
        raise ValueError(f"{name} must be finite (got {x})")
    if low is not None:
        if low_inclusive and x < low:
            raise ValueError(f"{name} must be >= {low} (got {x})")
        if not low_inclusive and x <= low:
            raise ValueError(f"{name} must be > {low} (got {x})")
    if high is not None and x > high:
        raise ValueError(f"{name} must be <= {high} (got {x})")
    return x


def as_count(name: str, value, *, low: int = 1, high: int | None = None) -> int:
    """Return ``value`` as a Python int >= ``low`` (and <= ``high``)."""
    if isinstance(value, bool) or not isinstance(value, (numbers.Integral, np.integer)):
        raise TypeError(f"{name} must be an integer (got {value!r})")
    n = int(value)
    if n < low:
        raise ValueError(f"{name} must be an integer >= {low} (got {n})")
    if high is not None and n > high:
        shown = f"{n:,}" if n < 10**30 else f"an integer of {n.bit_length()} bits"
        raise ValueError(f"{name} must be an integer <= {high:,} (got {shown})")
    return n


def as_attention(w, n_attributes: int, *, name: str = "w", atol: float = 1e-6) -> np.ndarray:
    """Check attention weights: shape (n_attributes,), non-negative, summing to one.

    Returns a copy renormalised to sum to one; weights that already sum to one within
    1e-12 are kept as they are, so that normalised weights pass through unchanged (a model
    rebuilt from its own ``w`` has the same ``w``, bit for bit).
    """
    arr = as_float_array(name, w, ndim=1)
    if arr.shape[0] != n_attributes:
        raise ValueError(
            f"{name} must have one weight per attribute, length {n_attributes} "
            f"(got length {arr.shape[0]})"
        )
    if np.any(arr < 0):
        raise ValueError(f"{name} must be non-negative (got {arr.tolist()})")
    total = arr.sum()
    if abs(total - 1.0) > atol:
        raise ValueError(
            f"{name} must sum to 1 (got {total:.6g}); pass normalised attention weights"
        )
    return arr if abs(total - 1.0) <= 1e-12 else arr / total


def as_generator(name: str, value) -> np.random.Generator:
    """``value`` resolved with :func:`numpy.random.default_rng`, with an error that names
    the parameter when numpy cannot resolve it (or would take a float or a bool as a seed)."""
    wanted = (f"{name} must be None, a non-negative int seed, a sequence of them, a numpy "
              f"SeedSequence or Generator (got {value!r}")
    if isinstance(value, (bool, float, complex, str, bytes)):
        raise TypeError(wanted + ")")
    try:
        return np.random.default_rng(value)
    except (TypeError, ValueError) as exc:
        raise type(exc)(f"{wanted}: {exc})") from None
