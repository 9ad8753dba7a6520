"""MESC-IRL on the paper's 9 x 9 world from 100 demonstrations: L-BFGS-B against the paper's optimiser.

The paper's code maximises the same likelihood by 500 steps of exponentiated
gradient ascent (omega <- omega * exp(0.3 * g), g the likelihood gradient
clipped at norm 10, omega started at 1e-6). This script runs that optimiser
on the exact objective and gradient of :class:`irl.MESCObjective` and
compares it with :func:`irl.mesc_irl` (L-BFGS-B) on the same demonstrations:
log-likelihood per demonstration (higher is better) and wall time after
compilation (median of ``--repeats`` runs).

Run: ``python benchmarks/bench_mesc.py [--sets 5] [--repeats 3]``

OpenBLAS threads are limited to one (set before NumPy loads) unless
``OPENBLAS_NUM_THREADS`` is already set: on a busy machine, L-BFGS-B's tiny
BLAS calls otherwise wait on spinning threads (about 10 ms per iteration
instead of 0.1 ms on the 2-core machine this was written on).
"""

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

from irl import MESCObjective, generate_demonstrations, load_paper_demonstrations, load_paper_worlds, mesc_irl  # noqa: E402


def exponentiated_gradient(objective, n_features, *, steps=500, lr=0.3, clip=10.0, init=1e-6):
    """The paper's optimiser on our objective: multiplicative ascent with a clipped gradient."""
    w = np.full(n_features, init)
    for _ in range(steps):
        _, g = objective(w)
        norm = np.linalg.norm(g)
        if norm > clip:
            g = g * (clip / norm)
        w = w * np.exp(lr * g)
    return w


def timed(fn, repeats):
    """Result, median wall time and median CPU time of ``repeats`` calls."""
    times, cpu, out = [], [], None
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        out = fn()
        times.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    return out, statistics.median(times), statistics.median(cpu)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sets", type=int, default=5, help="generated demonstration sets per slip setting")
    ap.add_argument("--repeats", type=int, default=3, help="timing repeats (median reported)")
    ap.add_argument("--n-demos", type=int, default=100)
    args = ap.parse_args(argv)

    world = load_paper_worlds()[0]
    cases = [("paper set 0", 0.0, load_paper_demonstrations()[0])]
    for slip in (0.0, 0.1):
        w = world.replace(p_slip=slip)
        for k in range(args.sets):
            cases.append((f"generated {k}", slip, generate_demonstrations(w.constrained_mdp, args.n_demos, rng=k)))

    # compile every kernel once
    w0 = world.replace(p_slip=0.1)
    mesc_irl(w0.nominal_mdp, cases[-1][2])

    header = f"{'demonstrations':<15}{'slip':>5}{'H':>5} | {'L-BFGS-B LL':>12}{'wall s':>8}{'cpu s':>8}{'evals':>6} | {'EG-500 LL':>11}{'time s':>8} | {'LL gain':>8}"
    print(header)
    print("-" * len(header))
    rows = []
    for name, slip, demos in cases:
        w = world.replace(p_slip=slip)
        res, t_fit, c_fit = timed(lambda: mesc_irl(w.nominal_mdp, demos), args.repeats)
        obj = MESCObjective(w.nominal_mdp, demos)
        w_eg, t_eg, _ = timed(lambda: exponentiated_gradient(obj, w.n_features), 1)
        ll_eg = obj(w_eg)[0]
        rows.append((t_fit, res.objective - ll_eg, c_fit))
        print(
            f"{name:<15}{slip:>5.1f}{res.horizon:>5} | {res.objective:>12.4f}{t_fit:>8.3f}{c_fit:>8.3f}{res.n_evaluations:>6} | "
            f"{ll_eg:>11.4f}{t_eg:>8.2f} | {res.objective - ll_eg:>8.4f}"
        )
    print("-" * len(header))
    print(
        f"L-BFGS-B: wall median {statistics.median(r[0] for r in rows):.3f} s, max {max(r[0] for r in rows):.3f} s; "
        f"CPU median {statistics.median(r[2] for r in rows):.3f} s, max {max(r[2] for r in rows):.3f} s; "
        f"log-likelihood >= EG-500 in {sum(r[1] >= -1e-9 for r in rows)}/{len(rows)} cases"
    )
    print(f"load average at the end: {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")


if __name__ == "__main__":
    main()
