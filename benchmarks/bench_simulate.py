"""Benchmark of the Monte Carlo engine (issue 2's speed targets).

Run from the repository root:

    python benchmarks/bench_simulate.py            # full size (100,000 trials x 100 steps)
    python benchmarks/bench_simulate.py --quick    # a smaller, faster check

It prints one table. Every figure is the best of ``--repeats`` runs measured in
this process, after a warm-up call that compiles the kernels, so the ratios
compare numbers taken on the same machine at the same time. Timings on a busy
machine are noisy: re-run on a quiet one for figures to quote.

Rows
----
numpy-vectorised      a straightforward NumPy implementation: vectorised over
                      trials, a Python loop over steps (the issue's yardstick).
compiled step-by-step mdft's plain kernel (the exact dynamics, step by step).
simulate (shortcut)   mdft.simulate with FixedTime: the exact decomposition of
                      P(T) (attention table + one Gaussian vector per trial).
draws: numpy          numpy.random.Generator drawing exactly the numbers the
                      shortcut consumes (n_steps uniforms + r normals a trial).
draws: kernel stream  the same numbers from the kernels' own xoshiro256++
                      streams, in the same 64 chunks and threads as simulate.
draws: step-by-step   numpy drawing what the plain dynamics consumes
                      (1 uniform + n_options normals a step), for reference.
decide                mdft.decide over a batch of (n_decisions, 8, 2) problems,
                      100 steps each; cost per decision.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
import warnings
from pathlib import Path

# The NumPy yardstick is a one-thread figure: keep OpenBLAS to one thread (its
# (n_trials, 3) x (3, 3) products otherwise wake a thread pool that, on a busy
# machine, spins and multiplies their cost by 40). Set before NumPy is imported.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numba  # noqa: E402
import numpy as np  # noqa: E402
from numba import prange  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import mdft  # noqa: E402
from mdft import _kernels  # noqa: E402
from mdft.simulate import (  # noqa: E402
    N_CHUNKS,
    _attention_cuts,
    _fixed_time_shortcut,
    _stream_states,
)

COMPROMISE = dict(M=[[1.0, 3.0], [3.0, 1.0], [2.0, 2.0]], w=[0.5, 0.5], phi1=0.022, phi2=0.05,
                  beta=12.0, sigma2=1.0)


class Timing(float):
    """Best wall-clock seconds of a measurement, carrying the CPU seconds of the same run."""

    cpu: float


def best_time(fn, repeats):
    """Best wall-clock time of ``repeats`` calls (after one warm-up call).

    The returned float is the wall-clock time; ``.cpu`` is the process CPU
    time of that same call (all threads together). On a machine shared with
    other jobs, the CPU time of a one-thread run is the steadier figure.
    """
    fn()
    best, best_cpu = math.inf, math.inf
    for _ in range(repeats):
        start, start_cpu = time.perf_counter(), time.process_time()
        fn()
        wall, cpu = time.perf_counter() - start, time.process_time() - start_cpu
        if wall < best:
            best, best_cpu = wall, cpu
    out = Timing(best)
    out.cpu = best_cpu
    return out


def numpy_fixed_time(model, n_trials, n_steps, rng):
    """Vectorised over trials, looping over steps: the plain NumPy implementation."""
    n = model.n_options
    S_T = model.S.T
    CM_T = (model.C @ model.M).T  # (J, n): row j is C M e_j
    C_T = model.C.T
    cumw = np.cumsum(model.w)[:-1]
    sd = math.sqrt(model.sigma2)
    P = np.zeros((n_trials, n))
    for _ in range(n_steps):
        attended = np.searchsorted(cumw, rng.random(n_trials), side="right")
        eps = sd * rng.standard_normal((n_trials, n))
        P = P @ S_T + CM_T[attended] + eps @ C_T
    return np.bincount(P.argmax(axis=1), minlength=n) / n_trials


@numba.njit(parallel=True, cache=False)
def kernel_stream_draws(states, bounds, n_steps, rank):
    """Draw exactly what the shortcut kernel draws (n_steps uniforms, rank normals a trial)."""
    n_chunks = bounds.shape[0] - 1
    sums = np.zeros(n_chunks)
    for c in prange(n_chunks):
        state = states[c]
        acc = 0.0
        for _k in range(bounds[c], bounds[c + 1]):
            for _t in range(n_steps):
                acc += _kernels.next_double(state)
            for _q in range(rank):
                acc += _kernels.standard_normal(state)
        sums[c] = acc
    return sums.sum()


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=100_000)
    parser.add_argument("--steps", type=int, default=100)
    parser.add_argument("--decisions", type=int, default=100_000)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--quick", action="store_true", help="10x fewer trials and decisions")
    args = parser.parse_args(argv)
    if args.quick:
        args.trials //= 10
        args.decisions //= 10
    n_trials, n_steps = args.trials, args.steps
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", mdft.UnstableFeedbackWarning)
        model = mdft.MDFTModel(**COMPROMISE)
    n = model.n_options
    stopping = mdft.FixedTime(n_steps)
    S, C = model.S, model.C
    CM = C @ model.M
    cuts = _attention_cuts(model.w)
    _, _, _, L = _fixed_time_shortcut(S, CM, C, model.P0, model.sigma2, n_steps)
    rank = L.shape[1]
    threads = numba.get_num_threads()
    trial_steps = n_trials * n_steps
    rows = []  # (label, seconds, unit cost text)

    def per_trial_step(seconds):
        return f"{seconds / trial_steps * 1e9:7.2f} ns/trial-step"

    # --- NumPy yardstick (fewer repeats: it is slow)
    rng = np.random.default_rng(0)
    t_numpy = best_time(lambda: numpy_fixed_time(model, n_trials, n_steps, rng),
                        max(1, args.repeats // 2))
    rows.append(("numpy-vectorised (1 thread)", t_numpy, per_trial_step(t_numpy)))

    # --- compiled step-by-step kernel
    states = _stream_states(np.random.default_rng(1), N_CHUNKS)
    bounds = (np.arange(N_CHUNKS + 1, dtype=np.int64) * n_trials) // N_CHUNKS
    choices = np.empty(n_trials, dtype=np.int64)
    steps = np.empty(n_trials, dtype=np.int64)

    def plain():
        _kernels.plain_chunks(states, bounds, S, CM, C, 1.0, cuts, model.P0, n_steps, math.inf,
                              False, choices, steps)

    for n_threads in sorted({1, threads}):
        numba.set_num_threads(n_threads)
        t = best_time(plain, args.repeats)
        rows.append((f"compiled step-by-step ({n_threads} thr)", t, per_trial_step(t)))

    # --- simulate (shortcut)
    t_sim = {}
    for n_threads in sorted({1, threads}):
        numba.set_num_threads(n_threads)
        t_sim[n_threads] = best_time(
            lambda: mdft.simulate(model, n_trials, stopping=stopping, rng=2), args.repeats)
        rows.append((f"simulate (shortcut, {n_threads} thr)", t_sim[n_threads],
                     per_trial_step(t_sim[n_threads])))

    # --- cost of the draws the shortcut consumes
    gen = np.random.default_rng(3)

    def numpy_draws():
        gen.random(trial_steps)
        gen.standard_normal(n_trials * rank)

    numba.set_num_threads(1)
    t_np_draws = best_time(numpy_draws, args.repeats)
    rows.append(("draws: numpy (1 thr)", t_np_draws, per_trial_step(t_np_draws)))
    t_k_draws = {}
    for n_threads in sorted({1, threads}):
        numba.set_num_threads(n_threads)
        t_k_draws[n_threads] = best_time(
            lambda: kernel_stream_draws(states, bounds, n_steps, rank), args.repeats)
        rows.append((f"draws: kernel stream ({n_threads} thr)", t_k_draws[n_threads],
                     per_trial_step(t_k_draws[n_threads])))
    numba.set_num_threads(threads)

    def step_draws():
        gen.random(trial_steps)
        gen.standard_normal(trial_steps * n)

    t_step_draws = best_time(step_draws, max(1, args.repeats // 2))
    rows.append(("draws: step-by-step, numpy", t_step_draws, per_trial_step(t_step_draws)))

    # --- decide: 8 options, 2 attributes, 100 steps
    M = np.random.default_rng(4).random((args.decisions, 8, 2))
    dkw = dict(phi1=0.01, phi2=0.01, beta=2.0, sigma2=1.0, n_steps=100)
    t_decide = {}
    for n_threads in sorted({1, threads}):
        numba.set_num_threads(n_threads)
        t_decide[n_threads] = best_time(lambda: mdft.decide(M, [0.5, 0.5], rng=5, **dkw),
                                        args.repeats)
        rows.append((f"decide, batch ({n_threads} thr)", t_decide[n_threads],
                     f"{t_decide[n_threads] / args.decisions * 1e6:7.2f} us/decision"))
    numba.set_num_threads(threads)
    one = M[0]
    n_single = 2000
    gen_single = np.random.default_rng(6)  # an agent passes its Generator along
    t_single = best_time(
        lambda: [mdft.decide(one, [0.5, 0.5], rng=gen_single, **dkw) for _ in range(n_single)],
        3)
    rows.append(("decide, one call each", t_single,
                 f"{t_single / n_single * 1e6:7.2f} us/decision"))

    # --- table
    print(f"pymdft simulation benchmark: compromise set, {n_trials:,} trials x {n_steps} steps;"
          f" decide: {args.decisions:,} x (8 options, 2 attributes, 100 steps)")
    print(f"numba {numba.__version__}, numpy {np.__version__}, {threads} thread(s) available; "
          f"shortcut draws per trial: {n_steps} uniforms + {rank} normals")
    print()
    width = max(len(r[0]) for r in rows)
    print(f"{'what':<{width}}  {'wall s':>8}  {'cpu s':>8}  cost (wall)")
    for label, seconds, cost in rows:
        print(f"{label:<{width}}  {seconds:8.4f}  {seconds.cpu:8.4f}  {cost}")
    print()
    best_sim = min(t_sim.values())
    print("targets (wall clock; in brackets the same ratio from one-thread CPU times)")
    print(f"  numpy-vectorised / simulate          = {t_numpy / best_sim:7.1f}x  "
          f"[{t_numpy.cpu / t_sim[1].cpu:7.1f}x]  need >= 10")
    print(f"  simulate / numpy draws               = {best_sim / t_np_draws:7.2f}x  "
          f"[{t_sim[1].cpu / t_np_draws.cpu:7.2f}x]  need <= 2")
    print(f"  simulate / kernel-stream draws       = {t_sim[threads] / t_k_draws[threads]:7.2f}x  "
          f"[{t_sim[1].cpu / t_k_draws[1].cpu:7.2f}x]  need <= 2 (same threads)")
    print(f"  decide, batch, us per decision       = "
          f"{min(t_decide.values()) / args.decisions * 1e6:7.2f}   "
          f"[{t_decide[1].cpu / args.decisions * 1e6:7.2f} ]  need <= 10")


if __name__ == "__main__":
    main()
