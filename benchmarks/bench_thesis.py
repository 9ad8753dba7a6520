"""Recover MDFT parameters on the thesis data sets and predict held-out SUSHI triples.

Usage::

    python benchmarks/bench_thesis.py --quick            # a few problems per set (minutes)
    python benchmarks/bench_thesis.py                    # all 50 problems of each fixed-time set
    python benchmarks/bench_thesis.py --with-M           # also fit M (multi-subset sets)
    python benchmarks/bench_thesis.py --threshold        # also the threshold (pref_based) sets
    python benchmarks/bench_thesis.py --data PATH        # another copy of the data sets
    python benchmarks/bench_thesis.py --workers 2 --checkpoint /tmp/thesis  # resumable

The 500 problems of the fixed-time sets (and the threshold sets) are fitted through
``mdft.fit_many``: ``--workers`` local processes, and with ``--checkpoint`` every finished fit
is saved as it completes, so an interrupted run resumes where it stopped.

For every problem of a set the attention weights ``w`` are estimated by maximum likelihood
with the other parameters at their true values (the thesis's set-up for learning ``w``);
with ``--with-M`` the evaluations ``M`` are estimated (with ``w`` known, and jointly with
``w``) on the multi-subset sets, from a start perturbed from the truth by N(0, 0.5) noise,
the first row of ``M`` anchoring its location (``docs/fitting.md``, section 4). Reported per set: the mean squared error between fitted and observed choice
shares (``mse``: mean over all subset x option cells; ``mse_thesis``: squared errors summed
over the options of a subset and averaged over subsets, the thesis's definition), the
same at the true parameters (the floor set by sampling noise), the mean and largest
``|w_hat - w|``, the share of problems with ``|w_hat - w| <= 0.05`` and the mean time per
problem. The thesis's network reached ``mse_thesis`` of about 2e-4 on the 3-option
fixed-time sets at about 0.8 s per problem.
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import mdft  # noqa: E402
from mdft.datasets import THESIS_DATA, load_sushi, load_thesis_set  # noqa: E402

THESIS_SETS = [  # the same ten file names under time_based/ and pref_based/
    "set_nopts3_ncomb1_nproblem50_no3.mat",
    "set_nopts5_ncomb1_nproblem50_no5.mat",
    "set_nopts7_ncomb1_nproblem50_no7.mat",
    "set_nopts10_ncomb1_nproblem50_no10.mat",
    "set_nopts7_ncomb3_nproblem50_no3.mat",
    "set_nopts7_ncomb5_nproblem50_no3.mat",
    "set_nopts7_ncomb10_nproblem50_no3.mat",
    "set_nopts10_ncomb5_nproblem50_no3.mat",
    "set_nopts10_ncomb10_nproblem50_no3.mat",
    "set_nopts10_ncomb20_nproblem50_no3.mat",
]
M_SETS = [
    "set_nopts7_ncomb10_nproblem50_no3.mat",
    "set_nopts10_ncomb20_nproblem50_no3.mat",
]


def share_errors(pred, observed):
    sq = [(np.asarray(a) - np.asarray(b)) ** 2 for a, b in zip(pred, observed)]
    return float(np.mean(np.concatenate(sq))), float(np.mean([s.sum() for s in sq]))


def true_predictions(problem):
    out = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", mdft.UnstableFeedbackWarning)
        for s in problem.data.subsets:
            m = mdft.MDFTModel(problem.M[s], problem.w, phi1=problem.phi1, phi2=problem.phi2,
                               beta=problem.beta, sigma2=problem.sigma2)
            if problem.time_based:
                # the fit's own likelihood model (the normal approximation)
                out.append(mdft.choice_probabilities(m, problem.n_steps, method="normal"))
            else:
                r = mdft.simulate(m, 100_000, stopping=mdft.Threshold(problem.theta), rng=0)
                out.append(r.probabilities / r.probabilities.sum())
    return out


def run_set(path, n_problems, params, *, rng_seed=0, n_starts=3, threshold=False,
            workers=1, checkpoint=None):
    """Fit every problem of a set with ``mdft.fit_many`` (resumable with ``checkpoint``);
    the time per problem is the wall time over the problems fitted in this run."""
    problems = load_thesis_set(path)[:n_problems]
    rng = np.random.default_rng(rng_seed)
    fits = []
    for p in problems:
        fixed = {k: v for k, v in p.true_params.items() if k not in params}
        M_start = np.array(p.M)
        if "M" in params:
            M_start[1:] += rng.normal(0.0, 0.5, size=M_start[1:].shape)
        kw = dict(method="simulation", n_samples=4000) if threshold else {}
        fits.append(dict(data=p.data, M=M_start, stopping=p.stopping, fixed=fixed, **kw))
    folder = None
    if checkpoint is not None:
        folder = Path(checkpoint) / f"{Path(path).parent.name}-{Path(path).stem}-{'+'.join(params)}"
    t0 = time.perf_counter()
    many = mdft.fit_many(fits, params=params, n_starts=n_starts, rng=rng_seed,
                         executor="serial" if workers == 1 else None, n_workers=workers,
                         checkpoint=folder)
    elapsed = (time.perf_counter() - t0) / max(len(problems) - many.n_resumed, 1)
    rows = []
    for p, fit_args, res in zip(problems, fits, many.results):
        mse, mse_thesis = share_errors(res.predicted, res.observed)
        true_mse, true_thesis = share_errors(true_predictions(p), p.data.shares)
        row = dict(mse=mse, mse_thesis=mse_thesis, true_mse=true_mse, true_thesis=true_thesis,
                   w_err=abs(res.params["w"][0] - p.w[0]), time=elapsed,
                   converged=res.converged)
        if "M" in params:
            row["M_rmse"] = float(np.sqrt(np.mean((res.params["M"] - p.M) ** 2)))
            row["M_rmse_start"] = float(np.sqrt(np.mean((fit_args["M"] - p.M) ** 2)))
        rows.append(row)
    return rows


def summarise(name, params, rows):
    a = {k: np.array([r[k] for r in rows]) for k in rows[0]}
    line = (f"{name:<42s} {'+'.join(params):<4s} {len(rows):>3d} "
            f"{a['mse'].mean():9.2e} {a['mse_thesis'].mean():10.2e} "
            f"{a['true_thesis'].mean():10.2e} {a['w_err'].mean():7.3f} {a['w_err'].max():6.3f} "
            f"{np.mean(a['w_err'] <= 0.05):6.2f} {a['time'].mean():7.3f} "
            f"{a['converged'].mean():5.2f}")
    if "M_rmse" in a:
        line += f"  M rmse {a['M_rmse'].mean():.3f} (start {a['M_rmse_start'].mean():.3f})"
    return line


def sushi(path, *, quick):
    s = load_sushi(path)
    out = []
    uniform = [np.full(t.size, 1.0 / t.size) for t in s.test.subsets]
    out.append(("uniform 1/3 prediction", None, None,
                share_errors(uniform, s.test.shares)[0]))
    fixed = {k: s.params[k] for k in ("w", "phi1", "phi2", "beta", "sigma2")}
    if hasattr(mdft, "simulate"):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", mdft.UnstableFeedbackWarning)
            stored = []
            for t in s.test.subsets:
                m = mdft.MDFTModel(s.M[t], fixed["w"], **{k: fixed[k] for k in fixed if k != "w"})
                r = mdft.simulate(m, 100_000, stopping=mdft.Threshold(s.params["theta"]), rng=0)
                stored.append(r.probabilities / r.probabilities.sum())
        out.append(("stored parameters, threshold 10", None, None,
                    share_errors(stored, s.test.shares)[0]))
    # Fixed time, closed form: fit w, phi1, phi2, sigma2 for several deliberation times and
    # keep the time with the best training likelihood (T is an integer, not a fitted value).
    best = None
    for T in ([10, 25] if quick else [5, 10, 25, 50, 100]):
        t0 = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", mdft.FitConvergenceWarning)
            res = mdft.fit(s.train, s.M, stopping=T, params=["w", "phi1", "phi2", "sigma2"],
                           fixed=dict(beta=s.params["beta"]), n_starts=3 if quick else 6, rng=0)
        el = time.perf_counter() - t0
        test_mse = share_errors(res.predict(s.test.subsets), s.test.shares)[0]
        out.append((f"fixed time T={T}: w, phi1, phi2, sigma2 (logL {res.log_likelihood:.0f})",
                    res.mse, el, test_mse))
        if best is None or res.log_likelihood > best[1].log_likelihood:
            best = (T, res)
    # Evaluations M as well (row 0 anchors the location; sigma2 = 1 fixes the scale, which
    # is otherwise exactly confounded with M and phi1): 21 parameters for 20 free shares,
    # so this is a saturated model whose held-out error is the real test.
    T, res4 = best
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", mdft.FitConvergenceWarning)
        res = mdft.fit(s.train, s.M, stopping=T, params=["w", "phi1", "phi2", "M"],
                       fixed=dict(beta=s.params["beta"], sigma2=1.0),
                       start=dict(phi1=min(res4.params["phi1"], 1.0),
                                  phi2=min(res4.params["phi2"], 0.5), w=res4.params["w"]),
                       n_starts=1 if quick else 3, rng=0)
    el = time.perf_counter() - t0
    test_mse = share_errors(res.predict(s.test.subsets), s.test.shares)[0]
    out.append((f"fixed time T={T}: w, phi1, phi2, M (sigma2 = 1)", res.mse, el, test_mse))
    if hasattr(mdft, "simulate"):
        t0 = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", mdft.FitConvergenceWarning)
            res = mdft.fit(s.train, s.M, stopping=mdft.Threshold(s.params["theta"]),
                           params=["w", "phi1", "phi2", "sigma2"], fixed=dict(beta=1.0),
                           method="simulation", n_samples=4000, n_starts=2, rng=0,
                           max_iter=60 if quick else 200)
        el = time.perf_counter() - t0
        test_mse = share_errors(res.predict(s.test.subsets), s.test.shares)[0]
        out.append(("threshold 10 (simulated): w, phi1, phi2, sigma2", res.mse, el, test_mse))
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="a few problems per set")
    ap.add_argument("--problems", type=int, default=None, help="problems per set")
    ap.add_argument("--with-M", action="store_true", help="also fit M on multi-subset sets")
    ap.add_argument("--threshold", action="store_true", help="also the pref_based sets")
    ap.add_argument("--only", nargs="+", default=None, metavar="PART",
                    help="only the sets whose file name contains one of these, e.g. nopts5_ncomb1")
    ap.add_argument("--no-sushi", action="store_true")
    ap.add_argument("--no-thesis", action="store_true", help="only the SUSHI part")
    ap.add_argument("--no-fixed-time", action="store_true", help="skip the time_based sets")
    ap.add_argument("--workers", type=int, default=1,
                    help="processes for mdft.fit_many (1: in this process)")
    ap.add_argument("--checkpoint", default=None,
                    help="folder for resumable results: a re-run skips finished fits")
    ap.add_argument("--data", default=None,
                    help="folder holding time_based/ and pref_based/ (default: the bundled sets)")
    args = ap.parse_args(argv)
    folder = THESIS_DATA if args.data is None else Path(args.data)
    n = args.problems or (3 if args.quick else 50)

    if not args.no_thesis:
        thesis(folder, n, args)
    if not args.no_sushi:
        print("\n# SUSHI: fit on the 10 training triples, predict the 5 held-out triples")
        print(f"{'model':<56s} {'train mse':>10s} {'fit s':>7s} {'test mse':>10s}")
        for label, train, el, test in sushi(folder / "pref_based" / "sushi.json",
                                             quick=args.quick):
            tr = f"{train:10.2e}" if train is not None else f"{'':>10s}"
            es = f"{el:7.2f}" if el is not None else f"{'':>7s}"
            print(f"{label:<56s} {tr} {es} {test:10.2e}", flush=True)


def thesis(folder, n, args):
    print(f"# thesis data sets, {n} problems per set; w fitted with the other parameters true")
    print(f"{'set':<42s} {'fit':<4s} {'n':>3s} {'mse':>9s} {'mse_thesis':>10s} "
          f"{'floor':>10s} {'|dw|':>7s} {'max':>6s} {'<=.05':>6s} {'s/prob':>7s} {'conv':>5s}")
    chosen = [name for name in THESIS_SETS if not args.only or any(o in name for o in args.only)]
    for name in [] if args.no_fixed_time else chosen:
        rows = run_set(folder / "time_based" / name, n, ["w"], workers=args.workers,
                       checkpoint=args.checkpoint)
        print(summarise("time_based/" + name, ["w"], rows), flush=True)
    if args.with_M:
        for params in (["M"], ["w", "M"]):
            for name in M_SETS:
                rows = run_set(folder / "time_based" / name, min(n, 3 if args.quick else n),
                               params, n_starts=1, workers=args.workers,
                               checkpoint=args.checkpoint)
                print(summarise("time_based/" + name, params, rows), flush=True)
    if args.threshold:
        for name in chosen:
            rows = run_set(folder / "pref_based" / name, min(n, 3 if args.quick else n), ["w"],
                           n_starts=2, threshold=True, workers=args.workers,
                           checkpoint=args.checkpoint)
            print(summarise("pref_based/" + name, ["w"], rows), flush=True)


if __name__ == "__main__":
    main()
