"""Work functions for the runner tests (importable by worker processes and subprocesses)."""

import time

import numpy as np


def noisy_sum(params, seed):
    """A pure function of (params, seed): a few draws and their sum."""
    rng = np.random.default_rng(seed)
    x = rng.normal(size=int(params["n"]))
    return {"draws": x.tolist(), "sum": float(x.sum()), "k": params["k"]}


def slow_noisy_sum(params, seed):
    time.sleep(float(params.get("sleep", 0.2)))
    return noisy_sum(params, seed)


def fails_on_three(params, seed):
    if params["k"] == 3:
        raise ArithmeticError("unit three always fails")
    return noisy_sum(params, seed)
