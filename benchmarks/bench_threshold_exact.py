"""Accuracy and speed of mdft.threshold_probabilities on random models, against simulation.

Draws random ternary (and binary) models across the documented range
(2-3 attributes, M uniform on [0.5, 4], attention from a Dirichlet(4, ..., 4),
phi1 log-uniform on [0.005, 0.1], phi2 uniform on [0.01, 0.1], beta uniform on
[1, 15], sigma2 log-uniform on [0.1, 4], theta uniform on [5, 60]), computes the
threshold-stopping probabilities and mean response times with
mdft.threshold_probabilities, and compares them with mdft.simulate
(``--trials`` trials, default 10**6) under the same step limit. Prints one line
per model and then the median and maximum errors and times.

    python benchmarks/bench_threshold_exact.py                        # 20 ternary + 10 binary
    python benchmarks/bench_threshold_exact.py --ternary 5 --binary 0 --trials 100000

Errors are the largest difference in a choice probability (or in the
undecided share) and the largest relative difference in a mean response time
among options chosen in at least 1000 simulated trials; both include the
simulation's own error (``se``: its largest standard error). A model the method
cannot vouch for (ValueError) is counted and listed. Timings are wall-clock
after compilation, on whatever else the machine is doing: quote them with the
load average.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import mdft  # noqa: E402


def draw_model(rng, n_options):
    n_attributes = int(rng.integers(2, 4))
    M = rng.uniform(0.5, 4.0, (n_options, n_attributes))
    w = rng.dirichlet(np.full(n_attributes, 4.0))
    params = dict(phi1=float(np.exp(rng.uniform(np.log(0.005), np.log(0.1)))),
                  phi2=float(rng.uniform(0.01, 0.1)), beta=float(rng.uniform(1.0, 15.0)),
                  sigma2=float(np.exp(rng.uniform(np.log(0.1), np.log(4.0)))))
    theta = float(rng.uniform(5.0, 60.0))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", mdft.UnstableFeedbackWarning)
        model = mdft.MDFTModel(M, w, **params)
    return model, theta


def compare(model, theta, trials, max_steps, seed):
    start = time.perf_counter()
    try:
        res = mdft.threshold_probabilities(model, theta, max_steps=max_steps)
    except ValueError as exc:
        return None, time.perf_counter() - start, str(exc)
    seconds = time.perf_counter() - start
    sim = mdft.simulate(model, trials, stopping=mdft.Threshold(theta, max_steps=max_steps),
                        rng=seed)
    dp = float(max(np.max(np.abs(res.probabilities - sim.probabilities)),
                   abs(res.p_undecided - sim.p_undecided)))
    se = float(np.max(sim.standard_errors))
    drt = 0.0
    for i in np.flatnonzero(sim.counts >= 1000):
        drt = max(drt, abs(res.mean_response_times[i] / sim.mean_response_times[i] - 1.0))
    return dict(dp=dp, se=se, drt=drt, res=res, sim=sim), seconds, ""


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ternary", type=int, default=20, help="random three-option models")
    parser.add_argument("--binary", type=int, default=10, help="random two-option models")
    parser.add_argument("--trials", type=int, default=1_000_000, help="simulated trials")
    parser.add_argument("--max-steps", type=int, default=3_000, help="step limit (both)")
    parser.add_argument("--seed", type=int, default=2026)
    args = parser.parse_args(argv)
    rng = np.random.default_rng(args.seed)
    print(f"load average {os.getloadavg()[0]:.2f}; {args.trials} simulated trials per model; "
          f"max_steps={args.max_steps}")
    # compile outside the timings
    warm, th = draw_model(np.random.default_rng(0), 3)
    for m in (warm, draw_model(np.random.default_rng(0), 2)[0]):
        try:
            mdft.threshold_probabilities(m, 5.0, max_steps=50)
        except ValueError:
            pass
    for n_options, count in ((3, args.ternary), (2, args.binary)):
        rows, refused = [], []
        print(f"\n{n_options} options")
        print(f"{'#':>3} {'theta':>6} {'sigma2':>6} {'states':>7} {'time s':>7} {'max|dp|':>8} "
              f"{'se':>7} {'est dp':>8} {'max dRT':>8} {'est dRT':>8}  p (chain) / p (simulation)")
        for k in range(count):
            model, theta = draw_model(rng, n_options)
            out, seconds, why = compare(model, theta, args.trials, args.max_steps,
                                        args.seed + k)
            if out is None:
                refused.append((k, theta, model.sigma2, seconds, why))
                print(f"{k:>3} {theta:6.1f} {model.sigma2:6.2f}   refused after {seconds:.1f} s: "
                      f"{why[:110]}")
                continue
            res, sim = out["res"], out["sim"]
            rows.append((out["dp"], out["drt"], seconds, out["se"]))
            print(f"{k:>3} {theta:6.1f} {model.sigma2:6.2f} {res.n_states:>7} {seconds:7.2f} "
                  f"{out['dp']:8.4f} {out['se']:7.4f} {res.error_probabilities:8.1e} "
                  f"{out['drt']:8.4f} {res.error_mean_rt:8.1e}  "
                  f"{np.round(res.probabilities, 4)} / {np.round(sim.probabilities, 4)}")
        if rows:
            a = np.array(rows)
            print(f"{n_options} options, {len(rows)} models answered, {len(refused)} refused: "
                  f"|dp| median {np.median(a[:, 0]):.4f} max {a[:, 0].max():.4f} "
                  f"(simulation se up to {a[:, 3].max():.4f}); "
                  f"|dRT| median {np.median(a[:, 1]):.4f} max {a[:, 1].max():.4f}; "
                  f"time median {np.median(a[:, 2]):.2f} s max {a[:, 2].max():.2f} s")
        if refused:
            times = [r[3] for r in refused]
            print(f"refused models took median {np.median(times):.1f} s to refuse")
    print(f"load average {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
