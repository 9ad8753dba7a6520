"""The one place that sets the numba options of the ``irl`` kernels.

``cache=True`` keeps compiled kernels on disk between sessions. ``fastmath`` is
not used: the kernels compare preferences with thresholds and must treat
``inf`` and ``nan`` exactly as IEEE arithmetic does.
"""

import numba

JIT_OPTIONS = {"cache": True, "nogil": True}

njit = numba.njit(**JIT_OPTIONS)
"""Decorator for serial kernels."""

njit_parallel = numba.njit(parallel=True, **JIT_OPTIONS)
"""Decorator for kernels whose outer loop is a ``prange`` over independent chunks."""

njit_inline = numba.njit(inline="always", **JIT_OPTIONS)
"""Decorator for small scalar helpers inlined into the kernels that call them (so loops over them vectorise)."""
