"""Accuracy of learned constraints on the paper's Figure 1 world, against the number of demonstrations.

For each setting (deterministic, and slip 0.1) and each number of demonstrations
n, over independent seeded draws of demonstrations from the true constrained
world (the soft policy of its MDP, as in the paper), this reports

* MESC-IRL (:func:`irl.mesc.mesc_irl`) in three variants (``--methods``): the
  default call ("MESC-IRL", evidence selection), plain maximum likelihood
  ("MESC ML", ``selection="none"``) and the paper's optimiser ("MESC EG",
  ``optimizer="eg"``); for each: precision, recall and false positive
  rate of the constraints with ``zeta >= threshold`` (default 0.6, the
  paper's; several thresholds give one row each), the paper's "false positive rate" (really the false discovery
  rate, 1 - precision), the soft false positives / negatives at ``chi``
  (paper Section 3.3), and the KL and Jensen-Shannon divergences from the
  state-action visitation of held-out demonstrations to that of trajectories
  of the learned model;
* the Scobee & Sastry baseline (:func:`irl.scobee.infer_hard_constraints`) on
  the same demonstrations, deterministic world only (it assumes determinism);
  its soft errors use zeta = 1 on inferred constraints and 0 elsewhere;
* "true model": the KL between held-out demonstrations and fresh ones of the
  true model, the floor that sampling noise alone puts under the KL column
  (with ``--paper-demos``, draw d learns from the paper's set d, holds out set
  d + 1 and takes set d + 2 as the fresh sample);
* the constraints that the original implementation of the baseline learned on
  the paper's own demonstrations (``scobee_results_scobee_example.json``).

Usage::

    python benchmarks/bench_accuracy.py            # 7 sizes x 10 draws x 2 settings
    python benchmarks/bench_accuracy.py --quick    # 3 sizes x 3 draws
    python benchmarks/bench_accuracy.py --paper-demos   # deterministic: the paper's 10 sets

The world and the paper's demonstrations are the package's copies
(:func:`irl.io.load_paper_worlds`); the original's results file is read from the
shared data folder, found as in the tests (``PYMDFT_DATA`` or ``../shared/data``).
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

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from irl.demonstrations import generate_demonstrations, sample_trajectories  # noqa: E402
from irl.io import load_paper_demonstrations, load_paper_worlds  # noqa: E402
from irl.mesc import MESCResult, mesc_irl  # noqa: E402
from irl.metrics import (  # noqa: E402
    hard_constraint_scores, soft_constraint_errors, visitation_js_divergence, visitation_kl_divergence,
)
from irl.scobee import infer_hard_constraints  # noqa: E402

DATA = Path(os.environ.get("PYMDFT_DATA", ROOT.parent / "shared" / "data")) / "paper"
COLUMNS = ("precision", "recall", "fpr", "fdr", "soft_fp", "soft_fn", "kl", "js", "seconds")
# MESC-IRL variants: label -> keyword arguments of mesc_irl
METHODS = {
    "MESC-IRL": {},  # the default call (evidence selection)
    "MESC ML": {"selection": "none"},  # plain maximum likelihood, the paper's zeta map
    "MESC EG": {"optimizer": "eg"},  # the paper's optimiser, the paper's zeta map
}


def load_world(p_slip):
    return load_paper_worlds("scobee_example", p_slip=p_slip)[0]


def scores(world, zeta_true, predicted_mask, zeta_pred, chi):
    hard = hard_constraint_scores(world.constraint_mask, predicted_mask)
    soft = soft_constraint_errors(world.true_penalties, zeta_true, zeta_pred, chi=chi)
    return {
        "precision": hard.precision, "recall": hard.recall, "fpr": hard.false_positive_rate,
        "fdr": hard.false_discovery_rate, "soft_fp": soft.false_positives, "soft_fn": soft.false_negatives,
    }


def kl_to(held, trajectories, world):
    return visitation_kl_divergence(held, trajectories, n_states=world.n_states, n_actions=world.n_actions,
                                    pseudocount=0.5)


def js_to(held, trajectories, world):
    return visitation_js_divergence(held, trajectories, n_states=world.n_states, n_actions=world.n_actions)


def run_setting(name, world, sizes, draws, args, pools=None):
    zeta_true = MESCResult.from_penalties(world.nominal_mdp, world.true_penalties).zeta
    rows = {}  # (method, n) -> list of dicts
    seeds = np.random.SeedSequence([args.seed, int(round(world.p_slip * 1000))]).spawn(draws)
    deterministic = world.p_slip == 0.0
    for d, seed in enumerate(seeds):
        g_pool, g_held, g_true, _, g_scobee = (np.random.default_rng(s) for s in seed.spawn(5))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            if pools is None:
                pool = generate_demonstrations(world.constrained_mdp, max(sizes), rng=g_pool)
                held = generate_demonstrations(world.constrained_mdp, args.n_heldout, rng=g_held)
                fresh = generate_demonstrations(world.constrained_mdp, args.n_model, rng=g_true)
            else:  # the paper's sets: hold out the next set, compare with the one after
                pool, held, fresh = (pools[(d + k) % len(pools)] for k in range(3))
        rows.setdefault(("true model", 0), []).append({"kl": kl_to(held, fresh, world)})
        for n in sizes:
            demos = pool.subset(np.arange(n))
            for m, method in enumerate(args.methods):
                t0 = time.perf_counter()
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore", RuntimeWarning)
                    kw = dict(METHODS[method])
                    if method == "MESC-IRL" and args.unselected_scale is not None:
                        kw["unselected_scale"] = args.unselected_scale
                    res = mesc_irl(world.nominal_mdp, demos, max_iter=args.max_iter, **kw)
                secs = time.perf_counter() - t0
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore", RuntimeWarning)
                    g_model = np.random.default_rng([args.seed, d, n, m])
                    model = generate_demonstrations(res.constrained, args.n_model, rng=g_model)
                kl, js = kl_to(held, model, world), js_to(held, model, world)
                for thr in args.thresholds:
                    row = scores(world, zeta_true, res.zeta >= thr, res.zeta, args.chi)
                    row.update(kl=kl, js=js, seconds=secs, converged=res.converged)
                    label = method if len(args.thresholds) == 1 else f"{method} z>={thr:g}"
                    rows.setdefault((label, n), []).append(row)
            if deterministic:
                t0 = time.perf_counter()
                base = infer_hard_constraints(world.nominal_mdp, demos, min_kl_decrease=args.min_kl_decrease,
                                              max_constraints=args.max_constraints)
                secs = time.perf_counter() - t0
                row = scores(world, zeta_true, base.mask, base.mask.astype(float), args.chi)
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore", RuntimeWarning)
                    model = sample_trajectories(world.nominal_mdp, base.policy(world.nominal_mdp), args.n_model,
                                                rng=g_scobee, max_steps=base.horizon)
                row.update(kl=kl_to(held, model, world), js=js_to(held, model, world), seconds=secs)
                rows.setdefault(("Scobee & Sastry", n), []).append(row)
        if args.progress:
            print(f"  {name}: draw {d + 1}/{draws} done", file=sys.stderr)
    return rows


def original_results(sizes, n_sets=None):
    """Precision, recall, FPR and FDR of the original baseline's constraints (paper demonstrations)."""
    path = DATA / "scobee_results_scobee_example.json"
    if not path.is_file():
        print(f"(no {path}: the original's rows are left out; set PYMDFT_DATA)", file=sys.stderr)
        return {}
    learned = json.loads(path.read_text())[0]["learned_constraints"]
    world = load_world(0.0)
    lens = list(range(1, 10)) + list(range(10, 101, 10))  # the file's column order
    # The file's "feature 2" is read as the blue cells (see docs/irl_baseline_and_metrics.md).
    offsets = {"state": 0, "action": world.n_states}
    rows = {}
    for n in sizes:
        if n not in lens:
            continue
        j = lens.index(n)
        for sets in learned[:n_sets]:
            mask = np.zeros(world.n_features, dtype=bool)
            for c in sets[j]:
                if c["type"] == "feature":
                    mask[world.n_states + world.n_actions + 1] = True
                else:
                    mask[offsets[c["type"]] + int(c["value"])] = True
            h = hard_constraint_scores(world.constraint_mask, mask)
            rows.setdefault(("original (file)", n), []).append(
                {"precision": h.precision, "recall": h.recall, "fpr": h.false_positive_rate, "fdr": h.false_discovery_rate}
            )
    return rows


def format_table(title, rows, draws_note):
    lines = [f"\n## {title}  ({draws_note})", ""]
    head = f"{'method':<17} {'n':>4} " + " ".join(f"{c:>15}" for c in COLUMNS)
    lines += [head, "-" * len(head)]
    order = {"Scobee & Sastry": 1, "original (file)": 2, "true model": 3}
    for (method, n) in sorted(rows, key=lambda k: (k[1], order.get(k[0], 0), k[0])):
        vals = rows[(method, n)]
        cells = []
        for c in COLUMNS:
            xs = np.array([v[c] for v in vals if c in v], dtype=float)
            cells.append(f"{xs.mean():>8.3f} ±{xs.std():>5.3f}" if xs.size else f"{'':>15}")
        label = "-" if method == "true model" else str(n)
        lines.append(f"{method:<17} {label:>4} " + " ".join(cells))
        conv = [v.get("converged") for v in vals if "converged" in v]
        if conv and not all(conv):
            lines[-1] += f"   ({conv.count(False)}/{len(conv)} fits not converged)"
    return "\n".join(lines)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="3 sizes (1, 5, 20) and 3 draws")
    ap.add_argument("--sizes", default="1,2,5,10,20,50,100", help="numbers of demonstrations")
    ap.add_argument("--draws", type=int, default=10, help="independent draws per size")
    ap.add_argument("--settings", default="det,slip", help="det (p_slip 0), slip (p_slip 0.1), or both")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--threshold", default="0.6",
                    help="zeta threshold(s) for a hard constraint, e.g. 0.4,0.5,0.6,0.7 as in the paper's appendix")
    ap.add_argument("--chi", type=float, default=0.2, help="tolerance of the soft false positives/negatives")
    ap.add_argument("--n-heldout", type=int, default=100, help="held-out demonstrations per draw")
    ap.add_argument("--n-model", type=int, default=100, help="model trajectories sampled for the KL")
    ap.add_argument("--max-iter", type=int, default=1000, help="L-BFGS-B iterations of MESC-IRL")
    ap.add_argument("--methods", default="MESC-IRL,MESC ML,MESC EG",
                    help="MESC-IRL variants: " + ", ".join(f"{k!r} {v}" for k, v in METHODS.items()))
    ap.add_argument("--min-kl-decrease", type=float, default=0.1, help="stopping rule of the baseline")
    ap.add_argument("--max-constraints", type=int, default=None,
                    help="cap on the baseline's constraints (the original never exceeds 9)")
    ap.add_argument("--unselected-scale", type=float, default=None,
                    help="unselected_scale of the default call (MESC-IRL rows); 0: the selected model alone")
    ap.add_argument("--paper-demos", action="store_true",
                    help="deterministic setting: use the paper's 10 sets of 100 demonstrations")
    ap.add_argument("--json", help="also write the raw rows to this file")
    ap.add_argument("--progress", action="store_true", help="report progress on stderr")
    args = ap.parse_args(argv)
    args.thresholds = [float(x) for x in args.threshold.split(",")]
    args.methods = [m.strip() for m in args.methods.split(",")]
    unknown = [m for m in args.methods if m not in METHODS]
    if unknown:
        ap.error(f"unknown methods {unknown}; choose from {list(METHODS)}")
    sizes = [1, 5, 20] if args.quick else [int(x) for x in args.sizes.split(",")]
    draws = 3 if args.quick else args.draws
    settings = ["det", "slip"] if args.settings.strip() == "both" else [s.strip() for s in args.settings.split(",")]
    unknown = [s for s in settings if s not in ("det", "slip")]
    if unknown:
        ap.error(f"--settings must be det, slip, det,slip or both (got {args.settings!r})")
    print("# Accuracy of learned constraints: the paper's Figure 1 world")
    print(f"zeta threshold {args.threshold}, chi {args.chi}; KL(held-out || model) of state-action visitation,"
          f" pseudocount 0.5, and JS (no smoothing); {args.n_heldout} held-out and {args.n_model} model trajectories; mean ± sd over draws")
    print("precision/recall/fpr: hard constraints; fdr = 1 - precision (the paper's 'false positive rate');"
          " seconds: one fit")
    out = {}
    t_start = time.perf_counter()
    for setting in settings:
        p_slip = {"det": 0.0, "slip": 0.1}[setting]
        world = load_world(p_slip)
        pools = None
        if setting == "det" and args.paper_demos:
            pools = load_paper_demonstrations()
            draws_here = min(draws, len(pools))
        else:
            draws_here = draws
        rows = run_setting(setting, world, sizes, draws_here, args, pools)
        if setting == "det":
            rows.update(original_results(sizes, draws_here if pools is not None else None))
        source = "the paper's demonstrations" if pools is not None else f"seed {args.seed}"
        print(format_table(f"{'deterministic' if p_slip == 0 else 'slip 0.1'}", rows,
                           f"{draws_here} draws, {source}"))
        out[setting] = {f"{m}|{n}": v for (m, n), v in rows.items()}
    print(f"\ntotal {time.perf_counter() - t_start:.0f} s")
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1, default=float))


if __name__ == "__main__":
    main()
