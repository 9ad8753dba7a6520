"""Benchmark of MDFT orchestrator rollouts: one deliberation per decision.

Run from the repository root:

    python benchmarks/bench_rollout.py            # 2,000 trajectories on the paper's world
    python benchmarks/bench_rollout.py --quick    # 200 trajectories

The world is the paper's Figure-1 gridworld (9 x 9, 8 actions, slip 0.1) with its true
constraints; the MDFT orchestrator uses the paper's settings (phi1 = phi2 = 0.01,
beta = 2, sigma2 = 1, T = 100 fixed steps) at weights (0.5, 0.5), so every decision is
one 100-step deliberation over 8 options. The figure is the wall time of
``orchestration.rollout`` divided by the number of decisions it made (transitions),
best of ``--repeats`` runs after a warm-up that compiles the kernels. The target is
at most 10 us per decision; the paper's code takes about 1,350 us. The CPU column
(process time of all threads, per decision) is less sensitive to other load on the
machine than the wall-clock one; on a busy machine quote both.

Rows
----
rollout MDFT        orchestration.rollout: lockstep trajectories, one batched
                    mdft.decide per time step, transitions drawn in NumPy.
decide only         mdft.decide on the same number of (8, 2) problems in one call:
                    the compiled deliberations alone.
rollout WA          the weighted-average orchestrator, for the cost of the loop
                    without deliberation.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

import irl  # noqa: E402
import mdft  # noqa: E402
import orchestration  # noqa: E402


def best_of(fn, repeats):
    """Best wall time and best CPU time (all threads of the process) over ``repeats`` runs."""
    walls, cpus = [], []
    out = None
    for _ in range(repeats):
        t, c = time.perf_counter(), time.process_time()
        out = fn()
        walls.append(time.perf_counter() - t)
        cpus.append(time.process_time() - c)
    return min(walls), min(cpus), out


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="200 trajectories")
    parser.add_argument("--trajectories", type=int, default=None)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args(argv)
    n = args.trajectories or (200 if args.quick else 2000)

    world = irl.load_paper_worlds()[0]
    prefs = orchestration.action_preferences(world.nominal_mdp, world.constrained_mdp)
    mdft_orch = orchestration.MDFTOrchestrator.from_preferences(prefs, (0.5, 0.5))
    wa_orch = orchestration.WeightedAverageOrchestrator.from_preferences(prefs, (0.5, 0.5))
    orchestration.rollout(mdft_orch, 20, rng=0)  # warm-up: compile

    t_mdft, c_mdft, demos = best_of(lambda: orchestration.rollout(mdft_orch, n, rng=1), args.repeats)
    n_dec = demos.n_transitions
    M = np.ascontiguousarray(np.stack([prefs.sq_nominal, prefs.sq_constrained], -1)[demos.states])
    t_decide, c_decide, _ = best_of(lambda: mdft.decide(M, [0.5, 0.5], phi1=0.01, phi2=0.01, beta=2.0,
                                              sigma2=1.0, n_steps=100, rng=2), args.repeats)
    t_wa, c_wa, wa_demos = best_of(lambda: orchestration.rollout(wa_orch, n, rng=1), args.repeats)

    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"MDFT orchestrator rollouts: {n} trajectories on the paper's world, "
          f"8 actions, T = 100 (load average {load:.2f})")
    print(f"{'row':<16}{'decisions':>12}{'wall s':>9}{'wall us/dec':>13}{'CPU us/dec':>12}")
    for name, t, c, k in (("rollout MDFT", t_mdft, c_mdft, n_dec),
                          ("decide only", t_decide, c_decide, n_dec),
                          ("rollout WA", t_wa, c_wa, wa_demos.n_transitions)):
        print(f"{name:<16}{k:>12,}{t:>9.3f}{t / k * 1e6:>13.2f}{c / k * 1e6:>12.2f}")
    per = t_mdft / n_dec * 1e6
    print(f"target <= 10 us per decision: {'met' if per <= 10 else 'NOT met'} ({per:.2f} us; "
          "the paper's code takes about 1,350 us)")


if __name__ == "__main__":
    main()
