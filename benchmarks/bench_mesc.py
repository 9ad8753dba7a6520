"""MESC-IRL on the paper's 9 x 9 world from 100 demonstrations: speed of the default call, and the paper's optimiser.

Part 1 (timing). For the paper's demonstration set 0 and ``--sets``
generated sets per slip setting (0 and 0.1), it fits

* the default call :func:`irl.mesc_irl` (evidence selection),
* plain maximum likelihood (``selection="none"``, L-BFGS-B),
* the paper's optimiser (``optimizer="eg"``: clipped exponentiated gradient,
  500 steps, learning rate 0.3, clip 10, start 1e-6, the paper's stopping rule),

and prints the wall and CPU time (median of ``--repeats`` runs, after
compilation), the number of objective evaluations and the log-likelihood per
demonstration.

Part 2 (why the paper's code is more precise than plain maximum likelihood).
On the paper's deterministic demonstration sets, exponentiated gradient with
the paper's settings but a fixed number of steps (no early stop) is run for
50 to 5000 steps; the precision and recall of ``zeta >= 0.6`` and the number
of flagged features show what the paper's 500 steps from 1e-6 do: they stop
long before the likelihood is maximised, and the longer they run, the more
unvisited features reach zeta >= 0.6, until the converged maximum likelihood.

Run: ``python benchmarks/bench_mesc.py [--sets 5] [--repeats 3] [--study-sets 5]``

``mesc_irl`` limits BLAS to one thread itself (threadpoolctl); nothing is set here.
"""

import argparse
import os
import statistics
import sys
import time
import warnings
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

from irl import generate_demonstrations, load_paper_demonstrations, load_paper_worlds, mesc_irl  # noqa: E402
from irl.metrics import hard_constraint_scores  # noqa: E402

VARIANTS = {"default": {}, "plain ML": {"selection": "none"}, "paper EG": {"optimizer": "eg"}}


def timed(fn, repeats):
    """Result, median wall time and median CPU time of ``repeats`` calls."""
    times, cpu, out = [], [], None
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        out = fn()
        times.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    return out, statistics.median(times), statistics.median(cpu)


def timing(world, args):
    cases = [("paper set 0", 0.0, load_paper_demonstrations()[0])]
    for slip in (0.0, 0.1):
        w = world.replace(p_slip=slip)
        for k in range(args.sets):
            cases.append((f"generated {k}", slip, generate_demonstrations(w.constrained_mdp, args.n_demos, rng=k)))
    w0 = world.replace(p_slip=0.1)
    mesc_irl(w0.nominal_mdp, cases[-1][2])  # compile every kernel once
    print(f"{'demonstrations':<15}{'slip':>5} | " + " | ".join(f"{v:>10} LL  wall s   cpu s evals" for v in VARIANTS))
    summary = {v: [] for v in VARIANTS}
    for name, slip, demos in cases:
        w = world.replace(p_slip=slip)
        cells = []
        for v, kw in VARIANTS.items():
            res, t_wall, t_cpu = timed(lambda: mesc_irl(w.nominal_mdp, demos, **kw), args.repeats)
            summary[v].append((slip, t_wall, t_cpu))
            cells.append(f"{res.objective:>13.3f} {t_wall:>7.3f} {t_cpu:>7.3f} {res.n_evaluations:>5}")
        print(f"{name:<15}{slip:>5.1f} | " + " | ".join(cells))
    for v, rows in summary.items():
        for slip in (0.0, 0.1):
            wall = [r[1] for r in rows if r[0] == slip]
            cpu = [r[2] for r in rows if r[0] == slip]
            print(f"{v:>10}, slip {slip}: wall median {statistics.median(wall):.3f} s (max {max(wall):.3f}); "
                  f"CPU median {statistics.median(cpu):.3f} s (max {max(cpu):.3f})")


def steps_study(world, args):
    det = world.replace(p_slip=0.0)
    sets = load_paper_demonstrations()[: args.study_sets]
    print(f"\nExponentiated gradient (lr 0.3, clip 10, start 1e-6, fixed steps) on the paper's sets 0-{len(sets) - 1}"
          " (deterministic, 100 demonstrations): mean over sets")
    print(f"{'steps':>8} {'flagged':>8} {'precision':>10} {'recall':>8} {'LL/demo':>9}")
    fixed = {"burn_in": 0, "tol_step": 0.0, "tol_gradient": 0.0}
    runs = [(f"{s}", {"optimizer": "eg", "eg_options": dict(fixed, steps=s)}) for s in args.steps]
    runs += [("paper", {"optimizer": "eg"}), ("ML", {"selection": "none"}), ("default", {})]
    for label, kw in runs:
        out = []
        for demos in sets:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                res = mesc_irl(det.nominal_mdp, demos, **kw)
            h = hard_constraint_scores(det.constraint_mask, res.zeta >= 0.6)
            out.append((h.n_true_positive + h.n_false_positive, h.precision, h.recall, res.objective))
        m = np.mean(out, axis=0)
        print(f"{label:>8} {m[0]:>8.1f} {m[1]:>10.3f} {m[2]:>8.3f} {m[3]:>9.3f}")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sets", type=int, default=5, help="generated demonstration sets per slip setting")
    ap.add_argument("--repeats", type=int, default=3, help="timing repeats (median reported)")
    ap.add_argument("--n-demos", type=int, default=100)
    ap.add_argument("--study-sets", type=int, default=5, help="paper sets in the steps study (0: skip it)")
    ap.add_argument("--steps", default="50,100,200,500,1000,2000,5000")
    ap.add_argument("--no-timing", action="store_true")
    args = ap.parse_args(argv)
    args.steps = [int(s) for s in args.steps.split(",")]
    world = load_paper_worlds()[0]
    if not args.no_timing:
        timing(world, args)
    if args.study_sets:
        steps_study(world, args)
    print(f"load average at the end: {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")


if __name__ == "__main__":
    main()
