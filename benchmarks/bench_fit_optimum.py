"""Does mdft.fit find the maximum of the likelihood? Random synthetic problems.

Usage::

    python benchmarks/bench_fit_optimum.py                 # 40 fixed-time problems
    python benchmarks/bench_fit_optimum.py --problems 100 --workers 2 --checkpoint /tmp/opt
    python benchmarks/bench_fit_optimum.py --stopping threshold --problems 12 --workers 2

Fixed time (the default): each problem draws 4 options on 2 attributes (uniform on
[0, 2.5]), a true model (w[0] in [0.2, 0.8], phi1 in [0.005, 0.1], phi2 in [0.01, 0.2], beta
in [1, 15], sigma2 in [0.5, 4]), a deliberation time T in [10, 60) and 15-40 simulated choices
on each of four subsets. The fit estimates w, phi1, phi2 and sigma2 (beta known) with the
default settings.

Threshold stopping (``--stopping threshold``): 3 options on 2 attributes (uniform on
[0, 3]), w[0] in [0.2, 0.8], sigma2 in [0.3, 3], theta in [5, 20] (phi1, phi2 and beta drawn as
above and known), and 40-100 simulated trials with their decision steps (at most 1,000) on
each of the three pairs and the triple. The fit estimates w, sigma2 and theta from choices and
decision steps with the default settings: with a subset of three options the likelihood is
simulated (common random numbers, binned decision steps).

The maximum of the likelihood can never be below its value at the true parameters (for a
simulated likelihood: the same simulation, seed and bins): a fit whose log-likelihood is
more than 0.01 below it has missed the optimum. Reported: the share of problems where the fit
reaches the truth's log-likelihood, the share that report converged=True, and how many missed
the optimum while claiming convergence (the defect to avoid: it should be 0).
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))  # the shared helpers, also when imported by path

import mdft  # noqa: E402
from _synthetic import threshold_trials  # noqa: E402

PARAMS = ["w", "phi1", "phi2", "sigma2"]
SUBSETS = [[0, 1], [0, 1, 2], [0, 1, 3], [1, 2, 3]]
#: Threshold problems: what is fitted, the subsets offered, and the step limit.
THRESHOLD_PARAMS = ["w", "sigma2", "theta"]
THRESHOLD_SUBSETS = [[0, 1], [0, 2], [1, 2], [0, 1, 2]]
THRESHOLD_MAX_STEPS = 1000


def random_truth(rng, sigma2_range):
    """True parameters of a random problem, drawn from ``rng`` in this order: w (w[0] in
    [0.2, 0.8]), phi1 in [0.005, 0.1], phi2 in [0.01, 0.2], beta in [1, 15], sigma2 in
    ``sigma2_range``."""
    w0 = rng.uniform(0.2, 0.8)
    return dict(w=np.array([w0, 1.0 - w0]), phi1=rng.uniform(0.005, 0.1),
                phi2=rng.uniform(0.01, 0.2), beta=rng.uniform(1.0, 15.0),
                sigma2=rng.uniform(*sigma2_range))


def random_problem(seed):
    """A random synthetic fixed-time problem: (fit arguments, true parameters)."""
    rng = np.random.default_rng(seed)
    M = rng.uniform(0.0, 2.5, size=(4, 2))
    truth = random_truth(rng, (0.5, 4.0))
    T = int(rng.integers(10, 60))
    counts = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", mdft.UnstableFeedbackWarning)
        for s in SUBSETS:
            model = mdft.MDFTModel(M[s], truth["w"], phi1=truth["phi1"], phi2=truth["phi2"],
                                   beta=truth["beta"], sigma2=truth["sigma2"])
            # the fit's own likelihood model (the normal approximation)
            counts.append(rng.multinomial(int(rng.integers(15, 40)),
                                          mdft.choice_probabilities(model, T, method="normal")))
    problem = dict(data=mdft.ChoiceData(SUBSETS, counts), M=M, stopping=T, params=PARAMS,
                   fixed=dict(beta=truth["beta"]))
    return problem, truth


def random_threshold_problem(seed):
    """A random synthetic threshold problem with decision steps: (fit arguments, truth)."""
    rng = np.random.default_rng(seed)
    M = rng.uniform(0.0, 3.0, size=(3, 2))
    truth = random_truth(rng, (0.3, 3.0))
    truth["theta"] = rng.uniform(5.0, 20.0)
    known = {k: truth[k] for k in ("phi1", "phi2", "beta")}
    data = threshold_trials(M, truth["w"], dict(known, sigma2=truth["sigma2"]),
                            THRESHOLD_SUBSETS, truth["theta"], THRESHOLD_MAX_STEPS,
                            lambda: int(rng.integers(40, 101)), rng)
    problem = dict(data=data, M=M, stopping=mdft.Threshold(10.0, THRESHOLD_MAX_STEPS),
                   params=THRESHOLD_PARAMS, fixed=known,
                   bounds=dict(sigma2=(0.05, 10.0), theta=(2.0, 60.0)))
    return problem, truth


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--problems", type=int, default=40)
    ap.add_argument("--checkpoint", default=None, help="folder: a re-run resumes")
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--stopping", choices=("fixed", "threshold"), default="fixed")
    args = ap.parse_args(argv)
    draw, params = ((random_problem, PARAMS) if args.stopping == "fixed"
                    else (random_threshold_problem, THRESHOLD_PARAMS))
    pairs = [draw(args.seed * 100_000 + i) for i in range(args.problems)]
    t0 = time.perf_counter()
    many = mdft.fit_many([p for p, _ in pairs], rng=args.seed,
                         executor="serial" if args.workers == 1 else None,
                         n_workers=args.workers, checkpoint=args.checkpoint,
                         progress=lambda i, n, key, res: print(f"{i}/{n}", end="\r",
                                                               file=sys.stderr, flush=True))
    elapsed = time.perf_counter() - t0
    gaps, conv = [], []
    for (_, truth), res in zip(pairs, many.results):
        at_truth = res.log_likelihood_at({k: truth[k] for k in params})
        gaps.append(res.log_likelihood - at_truth)
        conv.append(res.converged)
    gaps, conv = np.array(gaps), np.array(conv)
    reached = gaps >= -0.01
    print(f"{args.problems} random {args.stopping} problems, params {params}, "
          f"{elapsed / args.problems:.2f} s per fit")
    print(f"fit log-likelihood >= truth's - 0.01: {reached.mean():.1%}")
    print(f"converged=True: {conv.mean():.1%}")
    print(f"missed the optimum but claimed convergence: {int(np.sum(~reached & conv))}")
    print(f"smallest gain of the fit over the truth's log-likelihood: {gaps.min():.3f}; "
          f"on a bound: "
          f"{sum(bool(r.on_bound) for r in many.results)}")


if __name__ == "__main__":
    main()
