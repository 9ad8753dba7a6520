"""Time and error of mdft.threshold_probabilities as the lattice is refined.

For the binary canonical choice (A = (1, 3), B = (3, 1), w = (0.6, 0.4)) and the
three canonical context-effect sets (beta=12, phi1=.022, phi2=.05, w=(.5, .5),
sigma2=1, theta=17.5) the script prints, for each lattice resolution
``n_cells``: the number of transient states, the nonzeros of ``Q``, the wall
time, and the largest error in a choice probability and in a mean response
time, against the finest lattice (``--ref-cells``) and, for three options,
against a large Monte Carlo run of mdft.simulate (``--mc`` trials).

    python benchmarks/bench_threshold_exact.py            # full table
    python benchmarks/bench_threshold_exact.py --quick    # coarse resolutions only

Timings are wall-clock on whatever else the machine is doing: re-run on a
quiet machine for figures to quote.
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import mdft  # noqa: E402
from mdft.threshold_exact import _build_chain  # noqa: E402

A, B = (1.0, 3.0), (3.0, 1.0)
PARAMS = dict(phi1=0.022, phi2=0.05, beta=12.0, sigma2=1.0)
THETA = 17.5
SETS = {
    "binary (w=.6,.4)": ([A, B], (0.6, 0.4)),
    "similarity": ([A, B, (0.9, 3.1)], (0.5, 0.5)),
    "compromise": ([A, B, (2.0, 2.0)], (0.5, 0.5)),
    "attraction": ([A, B, (0.5, 2.5)], (0.5, 0.5)),
}


def model_of(options, w):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", mdft.UnstableFeedbackWarning)
        return mdft.MDFTModel(options, list(w), **PARAMS)


def timed(model, n_cells, **kw):
    start = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # coarse lattices warn; tabulated here
        res = mdft.threshold_probabilities(model, THETA, n_cells=n_cells, **kw)
    return res, time.perf_counter() - start


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="coarse resolutions only")
    parser.add_argument("--ref-cells", type=int, default=14,
                        help="n_cells of the reference lattice for three options")
    parser.add_argument("--mc", type=int, default=1_000_000,
                        help="Monte Carlo trials per three-option set (0 to skip)")
    parser.add_argument("--no-correction", action="store_true",
                        help="also tabulate variance_correction=False")
    args = parser.parse_args(argv)

    binary_cells = (5, 10, 20, 50, 100) if not args.quick else (5, 10, 20)
    three_cells = (5, 6, 8, 10, 12) if not args.quick else (5, 6)
    ref_cells3 = args.ref_cells if not args.quick else 8
    corrections = (True, False) if args.no_correction else (True,)

    # compile once, outside the timings
    timed(model_of([A, B], (0.5, 0.5)), 5)
    timed(model_of(SETS["compromise"][0], (0.5, 0.5)), 5)

    header = (f"{'set':<18} {'corr':>4} {'n_cells':>7} {'states':>8} {'nnz(Q)':>10} "
              f"{'time s':>7} {'steps':>5} {'max|dp|':>9} {'max|dRT|':>9} {'p (each option)':>26}")
    for name, (options, w) in SETS.items():
        model = model_of(options, w)
        n = model.n_options
        cells = binary_cells if n == 2 else three_cells
        ref, ref_time = timed(model, 400 if n == 2 else ref_cells3)
        print(f"\n{name}: reference lattice n_cells={ref.n_cells} ({ref.n_states} states, "
              f"{ref_time:.1f} s): p={np.round(ref.probabilities, 4)}, "
              f"mean RT={np.round(ref.mean_response_times, 2)}")
        if n == 3 and args.mc > 0:
            start = time.perf_counter()
            sim = mdft.simulate(model, args.mc, stopping=mdft.Threshold(THETA, max_steps=10_000),
                                rng=2026)
            gap = np.max(np.abs(ref.probabilities - sim.probabilities))
            print(f"  Monte Carlo, {args.mc} trials ({time.perf_counter() - start:.1f} s): "
                  f"p={np.round(sim.probabilities, 4)} +- {np.round(sim.standard_errors, 4)}, "
                  f"mean RT={np.round(sim.mean_response_times, 2)}; "
                  f"|reference - MC| max {gap:.4f}")
        print(header)
        for corr in corrections:
            for n_cells in cells:
                res, seconds = timed(model, n_cells, variance_correction=corr)
                dp = np.max(np.abs(res.probabilities - ref.probabilities))
                chosen = ref.probabilities > 1e-3
                drt = np.max(np.abs(res.mean_response_times - ref.mean_response_times)[chosen])
                nnz = _nnz(model, n_cells, corr)
                print(f"{name:<18} {'on' if corr else 'off':>4} {n_cells:>7} {res.n_states:>8} "
                      f"{nnz:>10} {seconds:>7.2f} {res.n_iter:>5} {dp:>9.5f} {drt:>9.4f} "
                      f"{str(np.round(res.probabilities, 4)):>26}")


def _nnz(model, n_cells, corr):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return _build_chain(model, THETA, n_cells, corr).Q.nnz


if __name__ == "__main__":
    main()
