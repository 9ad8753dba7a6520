"""numba's threads fitted to the machine's load, for :func:`mdft.threshold_probabilities`.

The three-option chain runs each propagated step on numba's threads: thousands of short
parallel regions per call, each waiting for its slowest thread. Where other processes keep
the cores busy, a thread can wait a scheduler time slice for its core at every region: a call
that takes 0.2 s on an idle machine took 15 s on two threads against 0.2 s on one beside
three busy processes on two cores (``docs/threshold_exact_measurements.md``, "On a busy
machine, one thread"). So each call first times a few empty parallel regions
(:func:`region_latency`, the median of :data:`PROBES`): a few microseconds each where the
cores are free (the first wakes numba's threads, which can take milliseconds on a virtual
machine, hence the median), about a time slice where they are busy. Above
:data:`LATENCY_LIMIT` the call runs on one thread.

The signal is clear beside one busy process on two cores (60 of 60 tries), and where the
other processes' threads keep waking as numba's do (another numba program), but partial
beside two or three busy processes (a third of the tries), where the woken threads often get
their cores at once, and it does not see processes of lower priority (``nice``), which slow
two threads less. Counting other processes' runnable threads (``/proc/stat``) was tried as a
second signal and left out: the count saw transient and invisible tasks on an idle machine,
and would have put every other call of a loop on one thread.

The answer does not change: the chain's build is the same for any number of threads, and the
propagation keeps the parts it would have run on the threads configured (run on one), so it
is decided by the threads configured (:func:`configured_threads`), not by those the load
leaves.
"""

from __future__ import annotations

import functools
import threading
import time

import numba
import numpy as np
from numba import prange

from ._numba import njit_parallel

#: Median time of :data:`PROBES` empty parallel regions above which a call runs on one
#: thread (a few microseconds on an idle machine, never above 1 ms in 60 tries after pauses;
#: several milliseconds on a busy one).
LATENCY_LIMIT = 1e-3
#: Empty regions timed per call.
PROBES = 5

_state = threading.local()
_slots = np.zeros(64)


@njit_parallel
def _touch(slots):
    """An empty parallel region: one trivial update per slot."""
    for i in prange(slots.shape[0]):
        slots[i] += 1.0


def region_latency(probes=PROBES):
    """Median wall time of ``probes`` (odd) empty parallel regions on numba's threads
    (seconds)."""
    times = []
    for _ in range(probes):
        start = time.perf_counter()
        _touch(_slots)
        times.append(time.perf_counter() - start)
    return sorted(times)[len(times) // 2]


def threads_for_the_load(configured):
    """How many of the ``configured`` threads a call should run on now: 1 where an empty
    parallel region takes more than :data:`LATENCY_LIMIT` (the cores are busy), else all."""
    return 1 if region_latency() > LATENCY_LIMIT else configured


def configured_threads():
    """numba's threads as configured for this call, before any reduction for the load."""
    configured = getattr(_state, "configured", None)
    return numba.get_num_threads() if configured is None else configured


def fitted_to_the_load(runs_steps):
    """Decorator: run the function on :func:`threads_for_the_load` numba threads, for the
    calls where ``runs_steps(*args, **kwargs)`` is true (those that run parallel steps; the
    others do not look at the load); the threads are restored afterwards, and
    :func:`configured_threads` reports the configured count meanwhile."""

    def decorate(fn):
        @functools.wraps(fn)
        def wrapper(*args, **kwargs):
            threads = numba.get_num_threads()
            if (threads == 1 or getattr(_state, "configured", None) is not None
                    or not runs_steps(*args, **kwargs)):
                return fn(*args, **kwargs)
            _state.configured = threads
            try:
                numba.set_num_threads(threads_for_the_load(threads))
                return fn(*args, **kwargs)
            finally:
                numba.set_num_threads(threads)
                _state.configured = None

        return wrapper

    return decorate
