"""How much better are MDFT parameters recovered with response times than from choices alone?

Usage::

    python benchmarks/bench_fit_rt.py                         # 12 random models
    python benchmarks/bench_fit_rt.py --models 12 --workers 2 --checkpoint /tmp/rt-fits
    python benchmarks/bench_fit_rt.py --triple --models 6 --trials 600 --workers 2
    python benchmarks/bench_fit_rt.py --triple --models 8 --trials 300 --fit sigma2,theta \
        --first-seed 2000 --workers 2

For each random true model (3 options on 2 attributes uniform on [0, 3], w[0] in [0.3, 0.7],
sigma2 in [0.5, 3], threshold theta in [5, 15]; phi1 = 0.022, phi2 = 0.05, beta = 12 known),
``--trials`` trials of each of the three pairs of options are simulated with threshold
stopping, and ``w``, ``sigma2`` and ``theta`` are fitted twice from the same trials: with the
joint likelihood of choice and decision step (the exact engine's ``rt_pmf``) and from the
choices alone. Reported per model and parameter: the absolute error of ``w[0]`` and the
relative errors of ``sigma2`` and ``theta``, and their medians. The fits run through ``mdft.fit_many``; with ``--checkpoint`` a re-run resumes.

With ``--triple`` the trials are of the triple of the three options instead, and both fits use
the response times: one with the exact engine (``method="threshold_exact"``, the three-option
chain's ``rt_pmf``, every decision step), one with the simulated likelihood (``method=
"simulation"``, binned times); the table gives their errors side by side.

``--fit`` names the parameters fitted (default all three); the others are held at the truth.
``--first-seed`` sets the seed of the first model (the next ones follow it). After the table,
each fit that reports standard errors is checked against the truth: its log-likelihood less
the truth's (never below 0 at the maximum), and each fitted parameter's distance from the
truth in standard errors.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))  # the shared helpers, also when imported by path

import mdft  # noqa: E402
from _synthetic import threshold_trials  # noqa: E402

KNOWN = dict(phi1=0.022, phi2=0.05, beta=12.0)
PARAMS = ["w", "sigma2", "theta"]
MAX_STEPS = 500


PAIRS = [[0, 1], [0, 2], [1, 2]]


def random_model(seed, n_trials, subsets=PAIRS):
    """(ChoiceData with decision steps, M, truth): one random model, trials of each of
    ``subsets`` (its three pairs)."""
    rng = np.random.default_rng(seed)
    M = rng.uniform(0.0, 3.0, size=(3, 2))
    w0 = rng.uniform(0.3, 0.7)
    truth = dict(w=np.array([w0, 1 - w0]), sigma2=rng.uniform(0.5, 3.0),
                 theta=rng.uniform(5.0, 15.0))
    data = threshold_trials(M, truth["w"], dict(KNOWN, sigma2=truth["sigma2"]), subsets,
                            truth["theta"], MAX_STEPS, n_trials, rng)
    return data, M, truth


def errors(res, truth):
    return (abs(res.params["w"][0] - truth["w"][0]),
            abs(res.params["sigma2"] / truth["sigma2"] - 1.0),
            abs(res.params["theta"] / truth["theta"] - 1.0))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--models", type=int, default=12)
    ap.add_argument("--trials", type=int, default=200, help="trials per subset")
    ap.add_argument("--triple", action="store_true",
                    help="trials of the triple: exact against simulated likelihood, with times")
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--starts", type=int, default=2)
    ap.add_argument("--checkpoint", default=None)
    ap.add_argument("--fit", default=",".join(PARAMS),
                    help="parameters fitted, comma-separated (the others held at the truth)")
    ap.add_argument("--first-seed", type=int, default=1000)
    args = ap.parse_args(argv)
    fitted = [p for p in args.fit.split(",") if p]
    if not fitted or any(p not in PARAMS for p in fitted):
        ap.error(f"--fit must name some of {', '.join(PARAMS)} (got {args.fit!r})")
    subsets = [[0, 1, 2]] if args.triple else PAIRS
    models = [random_model(args.first_seed + i, args.trials, subsets)
              for i in range(args.models)]
    # the two fits of each model: (key, label, fit arguments)
    kinds = ([("exact", "exact engine", dict(response_times=True, method="threshold_exact")),
              ("sim", "simulated", dict(response_times=True, method="simulation"))]
             if args.triple else
             [("rt", "with response times", dict(response_times=True)),
              ("choice", "choices only", dict(response_times=False))])
    problems = {}
    for i, (data, M, truth) in enumerate(models):
        # the parameters not fitted are held at the truth (theta through the stopping rule)
        held = {p: truth[p] for p in ("w", "sigma2") if p not in fitted}
        theta = 10.0 if "theta" in fitted else truth["theta"]
        for key, _, extra in kinds:
            problems[f"{i}-{key}"] = dict(data=data, M=M, fixed=dict(KNOWN, **held),
                                          stopping=mdft.Threshold(theta, MAX_STEPS), **extra)
    t0 = time.perf_counter()
    many = mdft.fit_many(problems, rng=0, params=fitted, n_starts=args.starts,
                         n_screen_per_start=4,
                         tol=1e-6, bounds=dict(sigma2=(0.2, 8.0), theta=(2.0, 30.0)),
                         executor="serial" if args.workers == 1 else None,
                         n_workers=args.workers, checkpoint=args.checkpoint)
    elapsed = time.perf_counter() - t0
    what = "trials of the triple" if args.triple else "trials per pair"
    print(f"{args.models} random 3-option models, {args.trials} {what}; fitted {fitted}; "
          f"{elapsed / len(problems):.0f} s per fit")
    head = f"{'model':>5s} {'w0':>6s} {'sigma2':>7s} {'theta':>6s} |"
    for _, label, _ in kinds:
        head += f" {label}: {'|dw0|':>6s} {'sigma2':>7s} {'theta':>6s} conv |"
    print(head)
    table = {key: [] for key, _, _ in kinds}
    for i, (_, _, truth) in enumerate(models):
        row = f"{i:5d} {truth['w'][0]:6.3f} {truth['sigma2']:7.3f} {truth['theta']:6.2f} |"
        for key, label, _ in kinds:
            res = many[f"{i}-{key}"]
            e = errors(res, truth)
            table[key].append(e)
            row += (f" {'':>{len(label) + 1}s}{e[0]:6.3f} {e[1]:7.1%} {e[2]:6.1%} "
                    f"{'yes' if res.converged else 'no':>4s} |")
        print(row)
    for key, label, _ in kinds:
        med = np.median(np.array(table[key]), axis=0)
        mx = np.max(np.array(table[key]), axis=0)
        n_conv = sum(many[f"{i}-{key}"].converged for i in range(len(models)))
        print(f"{label:<22s} median |dw0| {med[0]:.3f}, sigma2 {med[1]:.1%}, theta "
              f"{med[2]:.1%}; largest {mx[0]:.3f}, {mx[1]:.1%}, {mx[2]:.1%}; "
              f"{n_conv} of {len(models)} converged")
    check_against_truth(many, models, kinds, fitted)


def check_against_truth(many, models, kinds, fitted):
    """Each fit with standard errors: its log-likelihood less the truth's, its evaluations,
    and how many standard errors each fitted parameter lies from the truth."""
    names = {"w": "w0", "sigma2": "sigma2", "theta": "theta"}
    zs = []
    for key, label, _ in kinds:
        for i, (_, _, truth) in enumerate(models):
            res = many[f"{i}-{key}"]
            ses = [res.standard_errors[p][0] if p == "w" else res.standard_errors[p]
                   for p in fitted]
            if not np.all(np.isfinite(ses)):
                continue
            gain = res.log_likelihood - res.log_likelihood_at({p: truth[p] for p in fitted})
            z = [((res.params[p][0] - truth[p][0]) if p == "w" else
                  (res.params[p] - truth[p])) / se for p, se in zip(fitted, ses)]
            zs += z
            print(f"{label} {i}: log-likelihood - truth's {gain:+.2f}, "
                  f"{res.n_evaluations} evaluations, from the truth in standard errors: "
                  + ", ".join(f"{names[p]} {v:+.2f}" for p, v in zip(fitted, z)))
    if zs:
        zs = np.abs(np.array(zs))
        print(f"{len(zs)} estimates: root mean square {np.sqrt(np.mean(zs**2)):.2f} standard "
              f"errors from the truth, largest {zs.max():.2f}")


if __name__ == "__main__":
    main()
