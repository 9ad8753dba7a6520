"""Tests of numba's threads fitted to the machine's load (mdft._threads).

A three-option call of mdft.threshold_probabilities times a few empty parallel regions and
runs on one thread where they are slow (the cores busy). The answer must be the same to the last bit whichever way the call goes, the
configured threads must come back afterwards, and calls that run no parallel steps must not
look at the load.
"""

import subprocess
import sys
import time

import numba
import numpy as np
import pytest

import mdft
from mdft import _plane_chain, _threads

two_threads = pytest.mark.skipif(numba.config.NUMBA_NUM_THREADS < 2,
                                 reason="needs two numba threads")


def compromise(theta=17.5):
    model = mdft.MDFTModel([[1, 3], [3, 1], [2, 2]], [0.5, 0.5], phi1=0.022, phi2=0.05,
                           beta=12.0)
    return model, theta


def test_an_empty_parallel_region_is_timed():
    latency = _threads.region_latency()
    assert 0.0 < latency < 10.0


@two_threads
def test_a_busy_machine_runs_the_call_on_one_thread_with_the_same_answer(monkeypatch):
    model, theta = compromise()
    threads = numba.get_num_threads()
    if threads < 2:
        numba.set_num_threads(2)
    seen = []
    propagate = _plane_chain._plane_step.propagate

    def spy(*args):
        seen.append((numba.get_num_threads(), _threads.configured_threads(), args[21]))
        return propagate(*args)

    monkeypatch.setattr(_plane_chain._plane_step, "propagate", spy)
    try:
        configured = numba.get_num_threads()
        answers = {}
        for label, limit in (("free", np.inf), ("busy", -1.0)):
            monkeypatch.setattr(_threads, "LATENCY_LIMIT", limit)
            seen.clear()
            answers[label] = mdft.threshold_probabilities(model, theta, fallback="raise")
            assert numba.get_num_threads() == configured  # restored
            running = {s[0] for s in seen}
            assert running == ({configured} if label == "free" else {1})
            # the configured threads decide the parts, so both runs propagate in parts
            assert {s[1] for s in seen} == {configured}
            assert any(s[2] for s in seen)
    finally:
        numba.set_num_threads(threads)
    free, busy = answers["free"], answers["busy"]
    np.testing.assert_array_equal(free.probabilities, busy.probabilities)
    np.testing.assert_array_equal(free.mean_response_times, busy.mean_response_times)
    np.testing.assert_array_equal(free.rt_pmf, busy.rt_pmf)
    assert (free.error_probabilities, free.error_mean_rt, free.n_states) == (
        busy.error_probabilities, busy.error_mean_rt, busy.n_states)


@two_threads
def test_the_threads_come_back_after_an_error(monkeypatch):
    threads = numba.get_num_threads()
    monkeypatch.setattr(_threads, "LATENCY_LIMIT", -1.0)
    model, _ = compromise()
    with pytest.raises(ValueError, match="theta"):
        mdft.threshold_probabilities(model, -1.0)
    assert numba.get_num_threads() == threads
    assert _threads.configured_threads() == threads


def test_a_slow_empty_region_means_one_thread(monkeypatch):
    monkeypatch.setattr(_threads, "region_latency", lambda: 5e-3)
    assert _threads.threads_for_the_load(4) == 1
    monkeypatch.setattr(_threads, "region_latency", lambda: 5e-6)
    assert _threads.threads_for_the_load(4) == 4


@pytest.mark.skipif(numba.config.NUMBA_NUM_THREADS != 2, reason="measured on two cores")
def test_a_busy_core_puts_the_call_on_one_thread():
    # one busy process beside numba's two threads on two cores: the thread that shares its
    # core waits for a time slice at the regions (measured: detected in 60 of 60 tries, each
    # after a pause)
    threads = numba.get_num_threads()
    numba.set_num_threads(2)
    hog = subprocess.Popen([sys.executable, "-c", "while True: pass"])
    try:
        time.sleep(0.3)
        seen = []
        for _ in range(5):
            time.sleep(0.05)  # as between calls: numba's threads fall asleep
            seen.append(_threads.threads_for_the_load(2))
    finally:
        hog.kill()
        hog.wait()
        numba.set_num_threads(threads)
    assert seen.count(1) >= 3


def test_calls_without_parallel_steps_do_not_look_at_the_load(monkeypatch):
    def no_probe(*args, **kwargs):
        raise AssertionError("looked at the load")

    monkeypatch.setattr(_threads, "threads_for_the_load", no_probe)
    two = mdft.MDFTModel([[1, 3], [3, 1]], [0.5, 0.5], phi1=0.022, phi2=0.05, beta=12.0)
    assert mdft.threshold_probabilities(two, 5.0).engine == "lattice"
    # one thread configured: nothing to fit
    threads = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        model, _ = compromise()
        assert mdft.threshold_probabilities(model, 5.0).engine == "plane"
    finally:
        numba.set_num_threads(threads)
