"""The bound on deciding at all (threshold stopping) against simulation, and its cost.

``mdft.threshold_probabilities`` answers "undecided" without a chain where a bound on the
probability that any option reaches ``theta`` within ``max_steps`` steps meets the
tolerances (``docs/threshold_exact.md``, section 10). This script checks that the bound
lies above the truth and measures how far: on random models (2-4 options, the draws of
``bench_threshold_exact.py``; step limits of 5 to 1,000), at the threshold where the bound
equals ``--level`` (default 0.05), it simulates ``--trials`` trials and prints the share
that decided, which must stay below the bound. Then it times one bound at 10,000 steps per
model and counts, on ``--draws`` of the threshold benchmark's three-option draws (its
``--seed``), the models that the bound answers with the default tolerances.

``--chernoff`` checks and times the bound as ``threshold_probabilities`` uses it, the
Chernoff bound tried where Hoeffding's and Bernstein's misses the level (without it,
Hoeffding's and Bernstein's bound alone); the counts of answered draws give both.

    python benchmarks/bench_threshold_bound.py
    python benchmarks/bench_threshold_bound.py --models 30 --trials 200000 --seed 1000
    python benchmarks/bench_threshold_bound.py --chernoff --draw-seeds 1313 8383 5150 6061
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import mdft  # noqa: E402
from bench_threshold_exact import draw_model  # noqa: E402
from mdft._threshold_bound import (decision_bound, theta_for_bound, tolerance_level,  # noqa: E402
                                   within_tolerances)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--models", type=int, default=30, help="random models checked")
    parser.add_argument("--trials", type=int, default=200_000, help="simulated trials each")
    parser.add_argument("--level", type=float, default=0.05, help="the bound at the threshold")
    parser.add_argument("--seed", type=int, default=1000)
    parser.add_argument("--draws", type=int, default=40,
                        help="three-option draws of bench_threshold_exact.py counted")
    parser.add_argument("--draw-seeds", type=int, nargs="*", default=[1313, 8383])
    parser.add_argument("--chernoff", action="store_true",
                        help="the bound with the Chernoff bound tried (as the library uses it)")
    args = parser.parse_args(argv)
    level = args.level if args.chernoff else None

    rng = np.random.default_rng(args.seed)
    shares, times = [], []
    print(f"{'#':>3} {'options':>7} {'attrs':>5} {'steps':>5} {'theta':>8} {'decided':>9} "
          f"{'bound':>7}")
    decision_bound(draw_model(rng, 2)[0], 10.0, 10)  # compile outside the timings
    mdft._threshold_bound.compile_kernels()
    for k in range(args.models):
        model, _ = draw_model(rng, int(rng.integers(2, 5)))
        steps = int(rng.choice([5, 30, 100, 300, 1000]))
        theta = theta_for_bound(model, steps, args.level, chernoff=args.chernoff)
        sim = mdft.simulate(model, args.trials, stopping=mdft.Threshold(theta, max_steps=steps),
                            rng=k)
        decided = float(np.mean(sim.choices >= 0))
        shares.append(decided)
        t0 = time.perf_counter()
        decision_bound(model, theta, 10_000, target=level)
        times.append(time.perf_counter() - t0)
        flag = "" if decided <= args.level else "  ABOVE THE BOUND"
        print(f"{k:>3} {model.n_options:>7} {model.M.shape[1]:>5} {steps:>5} {theta:>8.2f} "
              f"{decided:>9.5f} {args.level:>7.3g}{flag}")
    shares = np.array(shares)
    print(f"decided share at a bound of {args.level:g}: max {shares.max():.5f}, median "
          f"{np.median(shares):.5f}; {int(np.sum(shares > args.level))} of {args.models} "
          f"above the bound")
    print(f"one bound at 10,000 steps: median {1e3 * np.median(times):.2f} ms, max "
          f"{1e3 * np.max(times):.2f} ms")
    for seed in args.draw_seeds:
        draws = np.random.default_rng(seed)
        models = [draw_model(draws, 3) for _ in range(args.draws)]
        target = tolerance_level(1e-3, 3e-3)
        for label, tried in (("Hoeffding and Bernstein", None), ("with Chernoff", target)):
            answered = [i for i, (m, th) in enumerate(models) if within_tolerances(
                decision_bound(m, th, 10_000, target=tried), 1e-3, 3e-3)]
            print(f"seed {seed}, {label}: the bound answers {len(answered)} of {args.draws} "
                  f"three-option draws at max_steps=10,000 and the default tolerances: "
                  f"{answered}")


if __name__ == "__main__":
    main()
