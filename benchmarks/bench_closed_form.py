"""Speed and accuracy of the fixed-time closed form.

Usage::

    python benchmarks/bench_closed_form.py                 # timing + accuracy tables
    python benchmarks/bench_closed_form.py --sequences 200000 --mc 4000000

Timing: ``mdft.choice_probabilities(model, 100)`` on the canonical sets (2 and 3 options)
and on larger option sets, median over repeats (target: at most 2 ms for 3 options), with
``method="normal"`` (the approximation alone) and ``method="auto"`` (the default: the
approximation and its error estimate), against scipy's ``multivariate_normal.cdf`` applied
to the same moments.

Accuracy: the normal approximation of ``P(T)`` against the exact mixture of normals
(``mixture_choice_probabilities``, conditional Monte Carlo over attention sequences) and,
with ``--mc N``, against ``mdft.simulate`` with ``N`` trials. Differences are printed with
their standard errors.
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import scipy.stats as st

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import mdft  # noqa: E402
from mdft.closed_form import mixture_choice_probabilities  # noqa: E402

CANON = dict(phi1=0.022, phi2=0.05, beta=12.0, sigma2=1.0)
A, B = [1.0, 3.0], [3.0, 1.0]
SETS = {
    "binary": [A, B],
    "similarity": [A, B, [0.9, 3.1]],
    "compromise": [A, B, [2.0, 2.0]],
    "attraction": [A, B, [0.5, 2.5]],
}


def model(M):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", mdft.UnstableFeedbackWarning)
        return mdft.MDFTModel(M, [0.5, 0.5], **CANON)


def median_time(fn, repeats):
    fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def scipy_probabilities(mean, cov):
    n = mean.size
    out = []
    for i in range(n):
        L = -np.eye(n)[np.arange(n) != i]
        L[:, i] = 1.0
        out.append(st.multivariate_normal.cdf(np.zeros(n - 1), mean=-(L @ mean),
                                              cov=L @ cov @ L.T, rng=0))
    return np.array(out)


def timing(repeats):
    print("# timing, T = 100 (median of repeats)")
    print(f"{'set':<14s} {'n':>3s} {'normal ms':>10s} {'auto ms':>9s} {'scipy mvn ms':>13s}")
    rng = np.random.default_rng(0)
    cases = dict(SETS)
    for n in (5, 10):
        M = rng.uniform(1, 5, size=(n, 2))
        cases[f"random {n}"] = M
    for name, M in cases.items():
        m = model(M)
        t_cf = median_time(lambda: mdft.choice_probabilities(m, 100, method="normal"), repeats)
        t_auto = median_time(lambda: mdft.choice_probabilities(m, 100), repeats)
        mean, cov = mdft.preference_moments(m, 100)
        t_sp = median_time(lambda: scipy_probabilities(mean, cov), max(3, repeats // 20))
        print(f"{name:<14s} {len(M):>3d} {1e3 * t_cf:10.3f} {1e3 * t_auto:9.3f} "
              f"{1e3 * t_sp:13.3f}", flush=True)


def accuracy(steps, n_sequences, n_mc):
    print(f"\n# normal approximation vs exact mixture ({n_sequences} attention sequences)"
          + (f" and Monte Carlo ({n_mc} trials)" if n_mc else ""))
    print(f"{'T':>4s} {'set':<11s} {'gauss':>24s} {'mixture':>24s} {'gauss-mix':>25s} "
          f"{'max|z|':>7s}" + (f" {'mix-mc max|z|':>14s}" if n_mc else ""))
    worst = (0.0, None)
    for T in steps:
        for name, M in SETS.items():
            m = model(M)
            g = mdft.choice_probabilities(m, T, method="normal")
            mix = mixture_choice_probabilities(m, T, n_sequences=n_sequences, rng=T)
            d = g - mix.probabilities
            z = np.abs(d) / np.maximum(mix.standard_errors, 1e-12)
            if np.abs(d).max() > worst[0]:
                worst = (float(np.abs(d).max()), (T, name))
            line = (f"{T:>4d} {name:<11s} {np.array2string(g, precision=4):>24s} "
                    f"{np.array2string(mix.probabilities, precision=4):>24s} "
                    f"{np.array2string(d, precision=4):>25s} {z.max():7.1f}")
            if n_mc:
                sim = mdft.simulate(m, n_mc, stopping=mdft.FixedTime(T), rng=T)
                q = np.asarray(sim.probabilities)
                se = np.sqrt(q * (1 - q) / n_mc + mix.standard_errors**2)
                line += f" {np.max(np.abs(q - mix.probabilities) / np.maximum(se, 1e-12)):14.1f}"
            print(line, flush=True)
    print(f"largest |gauss - mixture|: {worst[0]:.4f} at T, set = {worst[1]}")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=200)
    ap.add_argument("--steps", default="5,10,25,50,100,200")
    ap.add_argument("--sequences", type=int, default=100_000)
    ap.add_argument("--mc", type=int, default=0, help="Monte Carlo trials (0: skip)")
    args = ap.parse_args(argv)
    timing(args.repeats)
    accuracy([int(s) for s in args.steps.split(",")], args.sequences, args.mc)


if __name__ == "__main__":
    main()
