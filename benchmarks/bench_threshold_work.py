"""The work units behind the simulation fallback's choice in mdft.threshold_probabilities.

With ``fallback="simulation"``, a three-option call hands over to simulation when simulating
to the tolerances would cost less than the chain's next, finer grid. Both costs are counted,
not timed, in units of propagating one nonzero of the chain by one step: building a nonzero
costs ``_BUILD_WORK`` units and simulating one step of one trial ``_SIM_STEP_WORK`` units
(``mdft/threshold_exact.py``). This script measures the three on random models of the
benchmark's ranges (``bench_threshold_exact.draw_model``):

* propagation: wall time per step of the chain with every state occupied (a uniform start,
  so that no row is skipped as empty), divided by the nonzeros;
* build: wall time of ``build_moment_chain`` divided by the nonzeros;
* simulation: wall time of the fallback's trials (``mdft.simulate._fallback_trials``)
  divided by the trial-steps they ran;
* controlled simulation: the same trials with control variates
  (``mdft.simulate._controlled_trials``), with the monomials' controls alone and with
  every control, their time over the plain trials' time, against what
  ``mdft._threshold_fallback.controlled_cost`` assumes for their mean steps a trial.

    python benchmarks/bench_threshold_work.py               # 12 models, resolutions 0.71 and 0.5
    python benchmarks/bench_threshold_work.py --models 20 --seed 7 --resolutions 1 0.71

Prints a line per chain and per simulation, then the medians in units of a propagated
nonzero-step. Timings are wall-clock after compilation; run on an otherwise idle machine.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numba
import numpy as np

from mdft import _plane_step
from mdft._plane_chain import (_PARTS_MIN_NONZEROS, build_moment_chain, propagate_moments,
                               tail_track)
from mdft._threshold_fallback import controlled_cost
from mdft.simulate import _controlled_trials, _fallback_trials

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from bench_threshold_exact import draw_model  # noqa: E402


def occupied_step_seconds(chain, steps=60, repeats=2):
    """Best wall time of one propagated step with every state holding probability."""
    n = chain.n_states
    in_parts = numba.get_num_threads() > 1 and chain.cols.shape[0] >= _PARTS_MIN_NONZEROS
    best = np.inf
    for _ in range(repeats):
        x = np.full(n, 1.0 / n)
        m = x * chain.sref
        q = np.zeros(n)
        rt_pmf = np.zeros((steps, 3))
        occ = np.zeros((n, 3))
        errors = np.zeros(3)
        start = time.perf_counter()
        _plane_step.propagate(chain.row_ptr, chain.cols, chain.t0, chain.t1, chain.r0,
                                chain.r1, chain.sref, chain.snext, chain.b_sum,
                                chain.delta**2, x, m, q, rt_pmf, occ, 0.0, False, 0.0, 0.0,
                                0.01, errors, in_parts, chain.frontier, steps, 1,
                                *tail_track(steps, n), np.inf)
        best = min(best, (time.perf_counter() - start) / (steps - 1))
    return best


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--models", type=int, default=12)
    parser.add_argument("--seed", type=int, default=5150)
    parser.add_argument("--trials", type=int, default=20_000, help="simulated trials per model")
    parser.add_argument("--max-steps", type=int, default=3_000)
    parser.add_argument("--resolutions", type=float, nargs="+", default=[0.71, 0.5],
                        help="grid resolutions of the chains timed per model")
    args = parser.parse_args(argv)
    for name in ("models", "trials", "max_steps"):
        if getattr(args, name) < 1:
            parser.error(f"--{name.replace('_', '-')} must be at least 1, got "
                         f"{getattr(args, name)}")
    if not all(0.3 <= r <= 2.0 for r in args.resolutions):
        parser.error(f"--resolutions must lie in [0.3, 2], got {args.resolutions}")

    # compile everything first
    warm, theta = draw_model(np.random.default_rng(0), 3)
    ref = np.array([float(np.sum(warm.P0)), 0.0, 0.0])
    chain = build_moment_chain(warm, theta, 1.4, ref, 0.5, 100_000)
    propagate_moments(chain, 50, 1e-10)
    occupied_step_seconds(chain, steps=5, repeats=1)
    _fallback_trials(warm, 1_000, theta, args.max_steps, np.random.default_rng(1))
    _controlled_trials(warm, 1_000, theta, args.max_steps, np.random.default_rng(1), 10.0)

    rng = np.random.default_rng(args.seed)
    prop, build, sim = [], [], []
    ratios = {False: [], True: []}
    print(f"{'model':>5} {'kind':>10} {'size':>10} {'ns per unit':>12} {'units':>8}")
    for k in range(args.models):
        model, theta = draw_model(rng, 3)
        ref = np.array([float(np.sum(model.P0)), 0.0, 0.0])
        for kappa in args.resolutions:
            start = time.perf_counter()
            try:
                chain = build_moment_chain(model, theta, kappa, ref, 0.5, 100_000)
            except ValueError:
                continue
            seconds = time.perf_counter() - start
            nnz = chain.cols.shape[0]
            step_ns = occupied_step_seconds(chain) / nnz * 1e9
            build_units = seconds / nnz * 1e9 / step_ns
            prop.append(step_ns)
            build.append(build_units)
            print(f"{k:>5} {'chain ' + str(kappa):>10} {nnz:>10} {step_ns:12.2f} "
                  f"{build_units:8.0f}", flush=True)
        start = time.perf_counter()
        choices, decision_steps = _fallback_trials(model, args.trials, theta, args.max_steps,
                                                   np.random.default_rng(1))
        seconds = time.perf_counter() - start
        steps = float(np.where(choices >= 0, decision_steps, args.max_steps).sum())
        sim.append(seconds / steps * 1e9)
        print(f"{k:>5} {'simulate':>10} {int(steps):>10} {sim[-1]:12.2f}", flush=True)
        for rich in (False, True):
            start = time.perf_counter()
            _controlled_trials(model, args.trials, theta, args.max_steps,
                               np.random.default_rng(1), steps / args.trials, rich)
            ratio = (time.perf_counter() - start) / seconds
            assumed = controlled_cost(steps / args.trials, rich)
            ratios[rich].append((ratio, assumed))
            label = "every ctrl" if rich else "monomials"
            print(f"{k:>5} {label:>10} {int(steps):>10} {seconds * ratio / steps * 1e9:12.2f}"
                  f"  {ratio:.2f} times the plain trials' time (assumed {assumed:.2f})",
                  flush=True)
    if not prop:
        print("\nno chain could be built within 100,000 states: no units to report")
        return
    unit = float(np.median(prop))
    print(f"\npropagated nonzero-step: median {unit:.2f} ns (range {min(prop):.2f}-{max(prop):.2f})")
    print(f"built nonzero: median {np.median(build):.0f} units (range {min(build):.0f}-{max(build):.0f})")
    print(f"simulated trial-step: median {np.median(sim):.1f} ns = "
          f"{np.median(sim) / unit:.2f} units")
    for rich, label in ((False, "the monomials' controls"), (True, "every control")):
        seen, assumed = np.array(ratios[rich]).T
        print(f"trials with {label}: {np.median(seen):.2f} times the plain trials' time in "
              f"the median (range {seen.min():.2f}-{seen.max():.2f}); controlled_cost "
              f"assumed {np.median(assumed):.2f} (range {assumed.min():.2f}-"
              f"{assumed.max():.2f})")


if __name__ == "__main__":
    main()
