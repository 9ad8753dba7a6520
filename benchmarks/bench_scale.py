"""MESC-IRL at scale: a 100 x 100 gridworld (10,000 states, 8 actions, slip 0.1) from 200 demonstrations.

Prints the world, the time to build it and to generate the demonstrations, the
fit (wall and CPU time, iterations, evaluations, convergence, log-likelihood), the
recovery of the true constraints (zeta >= 0.6) and the peak resident memory
of the process (``resource.getrusage``, which includes the interpreter, NumPy,
SciPy and the compiled kernels) before and after the fit.

Run: ``python benchmarks/bench_scale.py [--size 100] [--n-demos 200] [--min-distance 50]``

The random world keeps the paper's proportions of special cells (6 of 81 cells
each blue, green and constrained; 2 constrained actions; both colours
constrained), with start and goal at least ``--min-distance`` cells apart.
mesc_irl keeps BLAS to one thread itself (threadpoolctl); nothing is set here.
"""

import argparse
import os

import resource  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402

from irl import GridWorld, generate_demonstrations, mesc_irl  # noqa: E402


def peak_rss_mb():
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # kB on Linux


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=100)
    ap.add_argument("--n-demos", type=int, default=200)
    ap.add_argument("--min-distance", type=float, default=50.0)
    ap.add_argument("--p-slip", type=float, default=0.1)
    ap.add_argument("--horizon", type=int, default=None, help="default: 1.5 times the longest demonstration")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--precondition", choices=("auto", "on", "off"), default="auto",
                    help="mesc_irl's precondition= (default 'auto', as a default call)")
    ap.add_argument("--selection", default="auto", help="mesc_irl's selection= (default 'auto', as a default call)")
    ap.add_argument("--tol", type=float, default=1e-3,
                    help="projected-gradient tolerance (mesc_irl's default 1e-3); 1 / n_demos is one visit over the data")
    ap.add_argument("--max-iter", type=int, default=1000)
    ap.add_argument("--maxcor", type=int, default=40, help="L-BFGS-B memory")
    args = ap.parse_args(argv)

    # compile the kernels on a small world first, so the timings below exclude compilation
    small = GridWorld.random(9, rng=0)
    mesc_irl(small.nominal_mdp, generate_demonstrations(small.constrained_mdp, 5, rng=0))

    n_cells = args.size**2
    n_special = round(n_cells * 6 / 81)
    t0 = time.perf_counter()
    world = GridWorld.random(
        args.size, rng=args.seed, n_blue=n_special, n_green=n_special, n_constrained_states=n_special,
        min_distance=args.min_distance, p_slip=args.p_slip,
    )
    nominal, true = world.nominal_mdp, world.constrained_mdp
    t_world = time.perf_counter() - t0
    t0 = time.perf_counter()
    demos = generate_demonstrations(true, args.n_demos, rng=args.seed)
    t_demos = time.perf_counter() - t0
    rss_before = peak_rss_mb()

    t0, c0 = time.perf_counter(), time.process_time()
    tol = args.tol
    precondition = {"auto": "auto", "on": True, "off": False}[args.precondition]
    res = mesc_irl(nominal, demos, horizon=args.horizon, precondition=precondition, tol=tol,
                   max_iter=args.max_iter, maxcor=args.maxcor, selection=args.selection)
    t_fit, c_fit = time.perf_counter() - t0, time.process_time() - c0
    rss_after = peak_rss_mb()

    truth = world.constraint_mask
    found = res.zeta >= 0.6
    # constraints the demonstrations can reveal: features within one move of a demonstrated cell
    near = np.zeros(world.n_states, dtype=bool)
    for s in np.unique(np.concatenate([demos.states, demos.next_states])):
        x, y = world.coords(s)
        for dx in (-1, 0, 1):
            for dy in (-1, 0, 1):
                if 0 <= x + dx < args.size and 0 <= y + dy < args.size:
                    near[world.state(x + dx, y + dy)] = True
    near_feature = np.ones(world.n_features, dtype=bool)
    near_feature[world.feature_slices["state"]] = near
    print(f"world: {args.size} x {args.size} = {world.n_states} states, {world.n_actions} actions, "
          f"{world.n_features} features, K = {nominal.n_successors} successors, slip {args.p_slip}")
    print(f"       {n_special} blue, {n_special} green, {n_special} constrained cells, actions "
          f"{world.constrained_actions}; start {world.coords(world.start)}, goal {world.coords(world.goal)}")
    print(f"build world and MDPs      {t_world:8.2f} s")
    print(f"generate {args.n_demos} demonstrations {t_demos:6.2f} s  (length mean {demos.lengths.mean():.1f}, "
          f"max {demos.lengths.max()})")
    print(f"MESC-IRL fit              {t_fit:8.2f} s  (horizon {res.horizon}, {res.n_iter} iterations, "
          f"{res.n_evaluations} evaluations, {t_fit / max(res.n_evaluations, 1) * 1e3:.0f} ms each, "
          f"converged {res.converged} at tol {tol:g}, precondition {args.precondition}, selection {res.selection})")
    print(f"MESC-IRL fit, CPU time    {c_fit:8.2f} s  (the wall time on an otherwise idle core)")
    print(f"log-likelihood per demonstration {res.objective:.3f}")
    print(f"true constraints with zeta >= 0.6: {int((found & truth).sum())} of {int(truth.sum())}; "
          f"other features with zeta >= 0.6: {int((found & ~truth).sum())}")
    print(f"  of which within one move of a demonstrated cell (or action/colour features): "
          f"{int((found & truth & near_feature).sum())} of {int((truth & near_feature).sum())} found, "
          f"{int((found & ~truth & near_feature).sum())} others")
    print(f"peak RSS before fit {rss_before:7.0f} MB, after fit {rss_after:7.0f} MB")
    print(f"load average at the end: {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")


if __name__ == "__main__":
    main()
