"""Identification of constraints on random gridworlds: MESC-IRL's default against the paper's optimiser and the baseline.

For each grid size (default 9 and 15), each slip (0 and 0.1) and each of
``--worlds`` random worlds (:meth:`irl.GridWorld.random` with the paper's
proportions of special cells: 6 of 81 cells each blue, green and constrained,
2 constrained actions, both colours constrained; start and goal at least
``size - 1`` apart), ``--n-demos`` demonstrations are drawn from the true
world's soft policy and given to

* "MESC-IRL": the default call :func:`irl.mesc_irl` (evidence selection);
* "MESC EG": the paper's optimiser (``optimizer="eg"``: 500 clipped
  exponentiated-gradient steps, the paper's zeta map);
* "MESC ML": plain maximum likelihood (``selection="none"``);
* "Scobee & Sastry": :func:`irl.infer_hard_constraints` (deterministic worlds
  only; the method assumes determinism).

Each row gives precision and recall of ``zeta >= 0.6`` (mean, standard
deviation, 10th percentile and median over worlds), the soft false
positives and negatives of the paper's appendix at ``chi = 0.2``
(:func:`irl.soft_constraint_errors`) and, for the MESC-IRL variants, the
visitation KL and JS divergences from ``--n-heldout`` held-out demonstrations
to ``--n-model`` trajectories of the learned model (as in
``bench_accuracy.py``; mean ± standard error over worlds). Where both
"MESC-IRL" and "MESC ML" run, the table ends with their paired differences.

Run: ``python benchmarks/bench_random_worlds.py [--worlds 20] [--n-demos 50] [--json out.json]``
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from irl import GridWorld, MESCResult, generate_demonstrations, infer_hard_constraints, mesc_irl  # noqa: E402
from irl.metrics import (  # noqa: E402
    hard_constraint_scores, soft_constraint_errors, visitation_js_divergence, visitation_kl_divergence,
)

METHODS = {"MESC-IRL": {}, "MESC EG": {"optimizer": "eg"}, "MESC ML": {"selection": "none"}}


def make_world(size, p_slip, seed):
    n_special = round(size * size * 6 / 81)
    return GridWorld.random(size, rng=seed, n_blue=n_special, n_green=n_special, n_constrained_states=n_special,
                            min_distance=size - 1, p_slip=p_slip)


def score(world, zeta_true, mask, zeta, chi):
    hard = hard_constraint_scores(world.constraint_mask, mask)
    soft = soft_constraint_errors(world.true_penalties, zeta_true, zeta, chi=chi)
    return {"precision": hard.precision, "recall": hard.recall, "soft_fp": soft.false_positives,
            "soft_fn": soft.false_negatives}


def mean_se(values, digits, signed=False):
    """``mean ± standard error`` of ``values`` as text."""
    x = np.asarray(values, dtype=float)
    se = x.std(ddof=1) / np.sqrt(x.size) if x.size > 1 else float("nan")
    return f"{x.mean():{'+' if signed else ''}.{digits}f} ±{se:.{digits}f}"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--worlds", type=int, default=20)
    ap.add_argument("--sizes", default="9,15")
    ap.add_argument("--slips", default="0,0.1")
    ap.add_argument("--n-demos", type=int, default=50)
    ap.add_argument("--methods", default=",".join(METHODS))
    ap.add_argument("--threshold", type=float, default=0.6)
    ap.add_argument("--chi", type=float, default=0.2)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--n-heldout", type=int, default=100, help="held-out demonstrations per world")
    ap.add_argument("--n-model", type=int, default=400, help="trajectories of each learned model for the divergences")
    ap.add_argument("--json", help="write the per-world rows to this file")
    args = ap.parse_args(argv)
    methods = [m.strip() for m in args.methods.split(",")]
    rows = {}
    t_start = time.perf_counter()
    for size in (int(x) for x in args.sizes.split(",")):
        for p_slip in (float(x) for x in args.slips.split(",")):
            for k in range(args.worlds):
                world = make_world(size, p_slip, [args.seed, size, k])
                zeta_true = MESCResult.from_penalties(world.nominal_mdp, world.true_penalties).zeta
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore", RuntimeWarning)
                    demos = generate_demonstrations(world.constrained_mdp, args.n_demos, rng=[args.seed, size, k, 1])
                    held = generate_demonstrations(world.constrained_mdp, args.n_heldout, rng=[args.seed, size, k, 2])
                dims = dict(n_states=world.n_states, n_actions=world.n_actions)
                for j, m in enumerate(methods):
                    t0 = time.perf_counter()
                    with warnings.catch_warnings():
                        warnings.simplefilter("ignore", RuntimeWarning)
                        res = mesc_irl(world.nominal_mdp, demos, **METHODS[m])
                    row = score(world, zeta_true, res.zeta >= args.threshold, res.zeta, args.chi)
                    row["seconds"] = time.perf_counter() - t0
                    with warnings.catch_warnings():
                        warnings.simplefilter("ignore", RuntimeWarning)
                        model = generate_demonstrations(res.constrained, args.n_model, rng=[args.seed, size, k, 3, j])
                    row["kl"] = visitation_kl_divergence(held, model, pseudocount=0.5, **dims)
                    row["js"] = visitation_js_divergence(held, model, **dims)
                    rows.setdefault((size, p_slip, m), []).append(row)
                if p_slip == 0.0:
                    t0 = time.perf_counter()
                    base = infer_hard_constraints(world.nominal_mdp, demos)
                    row = score(world, zeta_true, base.mask, base.mask.astype(float), args.chi)
                    row["seconds"] = time.perf_counter() - t0
                    rows.setdefault((size, p_slip, "Scobee & Sastry"), []).append(row)
            print(f"  {size} x {size}, slip {p_slip}: done ({time.perf_counter() - t_start:.0f} s)", file=sys.stderr)
    print(f"# Random worlds: {args.worlds} per setting, {args.n_demos} demonstrations, zeta >= {args.threshold},"
          f" chi {args.chi}; precision / recall as mean ± sd [10th percentile, median] over worlds")
    head = (f"{'size':>4} {'slip':>4} {'method':<16} {'precision':>26} {'recall':>26} {'soft fp':>8} {'soft fn':>8}"
            f" {'KL':>14} {'JS':>16} {'s/fit':>6}")
    print(head)
    print("-" * len(head))
    for (size, p_slip, m), vals in rows.items():
        cells = []
        for c in ("precision", "recall"):
            x = np.array([v[c] for v in vals])
            cells.append(f"{x.mean():.3f} ±{x.std():.3f} [{np.percentile(x, 10):.2f}, {np.median(x):.2f}]")
        fp = np.mean([v["soft_fp"] for v in vals])
        fn = np.mean([v["soft_fn"] for v in vals])
        secs = np.mean([v["seconds"] for v in vals])
        div = [f"{mean_se([v[c] for v in vals], 3 + (c == 'js'))}" if "kl" in vals[0] else "" for c in ("kl", "js")]
        print(f"{size:>4} {p_slip:>4.1f} {m:<16} {cells[0]:>26} {cells[1]:>26} {fp:>8.3f} {fn:>8.3f}"
              f" {div[0]:>14} {div[1]:>16} {secs:>6.2f}")
    for (size, p_slip, m), vals in rows.items():
        plain = rows.get((size, p_slip, "MESC ML"))
        if m != "MESC-IRL" or plain is None:
            continue
        diffs = [mean_se(np.subtract([v[c] for v in vals], [v[c] for v in plain]), 4, signed=True) for c in ("kl", "js")]
        print(f"{size:>4} {p_slip:>4.1f} default - plain ML, paired over worlds: KL {diffs[0]}, JS {diffs[1]}")
    print(f"total {time.perf_counter() - t_start:.0f} s; load average at the end {os.getloadavg()[0]:.1f}"
          f" on {os.cpu_count()} cores")
    if args.json:
        Path(args.json).write_text(json.dumps({f"{s}|{p}|{m}": v for (s, p, m), v in rows.items()}, indent=1))


if __name__ == "__main__":
    main()
