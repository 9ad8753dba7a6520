"""Error of the normal fixed-time closed form on random models, and how well it is estimated.

Usage::

    python benchmarks/bench_closed_form_random.py --options 2,3 --models 200
    python benchmarks/bench_closed_form_random.py --options 4-8 --models 60 --mc 400000

Each random model: ``n`` options drawn from ``--options`` on 1 to 4 attributes (evaluations
uniform on [0, 5]), random attention on the simplex, ``phi1`` in [0.005, 0.1], ``phi2`` in
[0, 0.5] (the fit's upper bound), ``beta`` in [0, 15], ``sigma2`` log-uniform in
[0.01, 4], ``T`` log-uniform in [1, 1000]. For each model the normal approximation
(``choice_probabilities(..., method="normal")``) and its error estimate (what
``method="auto"`` compares with ``tol / 2``) are compared with the exact law:

* 2 or 3 options: enumeration of all attention sequences when there are at most 4,096,
  else the exact mixture (``mixture_choice_probabilities``, ``--sequences``);
* 4 or more options: simulation (``mdft.simulate``, ``--mc`` trials); the error is then
  known only up to the simulation's standard error, reported as ``|err| - 2 SE``.

It also checks ``method="auto"`` itself: the error of its answer, whichever way it was
obtained (enumeration, normal approximation, exact mixture), against the same reference.

Reported: the error of the normal approximation, the estimate against it, the largest
error among the models the estimate accepts at a given tolerance (the guarantee of
``method="auto"``), and the time per call of both methods.
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
from mdft._edgeworth import lumpiness  # noqa: E402
from mdft.closed_form import (_ENUMERATE_MAX, _LUMPY_MAX, _SAFETY,  # noqa: E402
                              _enumerated_probabilities, _n_sequences, _normal_error)


def parse_options(text):
    if "-" in text:
        lo, hi = (int(v) for v in text.split("-"))
        return list(range(lo, hi + 1))
    return [int(v) for v in text.split(",")]


def random_model(rng, choices):
    n = int(rng.choice(choices))
    J = int(rng.integers(1, 5))
    M = rng.uniform(0.0, 5.0, size=(n, J))
    w = rng.dirichlet(np.ones(J))
    params = dict(phi1=rng.uniform(0.005, 0.1), phi2=rng.uniform(0.0, 0.5),
                  beta=rng.uniform(0.0, 15.0),
                  sigma2=float(np.exp(rng.uniform(np.log(0.01), np.log(4.0)))))
    T = int(np.exp(rng.uniform(0.0, np.log(1000.0))))
    return mdft.MDFTModel(M, w, **params), T, params


def auto(model, T, tol):
    try:
        return mdft.choice_probabilities(model, T, tol=tol)
    except ValueError:
        return None  # no exact method applies: it says so


def median_ms(fn, repeats=5):
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return 1e3 * float(np.median(times))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--options", default="2,3", help="e.g. 2,3 or 4-8")
    ap.add_argument("--models", type=int, default=200)
    ap.add_argument("--mc", type=int, default=400_000)
    ap.add_argument("--sequences", type=int, default=50_000)
    ap.add_argument("--tol", type=float, default=mdft.closed_form.DEFAULT_TOL)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--no-timing", action="store_true")
    args = ap.parse_args(argv)
    choices = parse_options(args.options)
    rng = np.random.default_rng(args.seed)
    rows = []
    t0 = time.perf_counter()
    warnings.simplefilter("ignore", mdft.UnstableFeedbackWarning)
    for i in range(args.models):
        model, T, params = random_model(rng, choices)
        try:
            mean, cov = mdft.preference_moments(model, T)
        except ValueError:
            continue  # preferences overflow: no closed form at all
        normal = mdft.choice_probabilities(model, T, method="normal")
        est = _normal_error(model, T, mean, cov, normal).max()
        n = model.n_options
        if n <= 3 and _n_sequences(model, T) <= _ENUMERATE_MAX:
            exact, se, ref = _enumerated_probabilities(model, T), 0.0, "enum"
        elif n <= 3:
            mix = mdft.mixture_choice_probabilities(model, T, n_sequences=args.sequences, rng=i)
            exact, se, ref = mix.probabilities, mix.standard_errors, "mix"
        else:
            sim = mdft.simulate(model, args.mc, stopping=mdft.FixedTime(T), rng=i)
            exact, ref = sim.probabilities, "sim"
            se = np.sqrt(np.maximum(exact * (1 - exact), 1e-12) / args.mc)
        diff = np.abs(normal - exact)
        err = float(diff.max())
        err_low = float(np.max(diff - 2 * se))  # the error is at least this (2 SE)
        enumerable = _n_sequences(model, T) <= _ENUMERATE_MAX and (n <= 3 or params["sigma2"] == 0)
        lumpy = lumpiness(cov, np.asarray(model.C) @ np.asarray(model.M), np.asarray(model.w))
        trusted = lumpy <= _LUMPY_MAX
        path = ("enumerate" if enumerable else "normal" if trusted and est <= args.tol / _SAFETY
                else "mixture" if params["sigma2"] > 0 else "raise")
        answer = auto(model, T, args.tol)
        if answer is None:
            path = "raise"
            auto_err = auto_low = 0.0
        else:
            auto_err = float(np.abs(answer - exact).max())
            auto_low = float(np.max(np.abs(answer - exact) - 2 * se))
        row = dict(n=n, T=T, J=model.n_attributes, est=est, err=err, err_low=err_low,
                   se=float(np.max(se)), ref=ref, path=path, trusted=trusted,
                   auto_err=auto_err, auto_low=auto_low, **params)
        if not args.no_timing:
            row["t_normal"] = median_ms(lambda: mdft.choice_probabilities(model, T,
                                                                          method="normal"))
            row["t_auto"] = median_ms(lambda: auto(model, T, args.tol),
                                      repeats=1 if path in ("mixture", "raise") else 5)
        rows.append(row)
    elapsed = time.perf_counter() - t0
    err = np.array([r["err"] for r in rows])
    low = np.array([r["err_low"] for r in rows])
    est = np.array([r["est"] for r in rows])
    print(f"{len(rows)} random models with {args.options} options ({elapsed:.0f} s); references: "
          + ", ".join(f"{k} {sum(r['ref'] == k for r in rows)}" for k in ("enum", "mix", "sim")))
    q = lambda a: f"median {np.median(a):.4f}, 90% {np.quantile(a, 0.9):.4f}, max {a.max():.4f}"  # noqa: E731
    print(f"largest |normal - exact| per model:      {q(err)}")
    print(f"  (reference standard error up to {max(r['se'] for r in rows):.4f})")
    print(f"error estimate (largest per model):      {q(est)}")
    big = err > 5e-4
    if big.any():
        ratio = est[big] / err[big]
        print(f"estimate / error where error > 5e-4 ({big.sum()} models): min {ratio.min():.2f}, "
              f"5% {np.quantile(ratio, 0.05):.2f}, median {np.median(ratio):.2f}, "
              f"95% {np.quantile(ratio, 0.95):.2f}")
    print("accepted by the estimate (est <= c) -> largest error among them "
          "(and its lower bound |err| - 2 SE):")
    for c in (0.0005, 0.001, 0.0025, 0.005):
        sel = est <= c
        if sel.any():
            print(f"  c = {c:<6g}: {sel.sum():3d} models ({sel.mean():.0%}), largest error "
                  f"{err[sel].max():.4f} (>= {max(low[sel].max(), 0):.4f})")
    trusted = np.array([r["trusted"] for r in rows])
    print(f"models where the last attention draw splits P(T) into modes (estimate not "
          f"trusted): {np.mean(~trusted):.0%}")
    if trusted.any():
        ratio = est[big & trusted] / err[big & trusted]
        if ratio.size:
            print(f"  among the others, estimate / error where error > 5e-4: min "
                  f"{ratio.min():.2f}, median {np.median(ratio):.2f}")
    used = np.array([r["path"] != "enumerate" for r in rows])
    acc = used & trusted & (est <= args.tol / _SAFETY)
    print(f"returned as the normal answer by method='auto' ({acc.sum()} models): largest error "
          f"{err[acc].max(initial=0):.4f} (>= {max(low[acc].max(initial=0), 0):.4f})")
    paths = [r["path"] for r in rows]
    for k in ("enumerate", "normal", "mixture"):
        sel = [r for r in rows if r["path"] == k]
        if sel:
            print(f"method='auto' answers by {k:9s} ({len(sel)} models): largest error "
                  f"{max(r['auto_err'] for r in sel):.4f} (>= "
                  f"{max(max(r['auto_low'] for r in sel), 0.0):.4f} at 2 reference SE)")
    print(f"method='auto' with tol={args.tol:g}: "
          + ", ".join(f"{k} {paths.count(k) / len(paths):.0%}"
                      for k in ("enumerate", "normal", "mixture", "raise")))
    if not args.no_timing:
        tn = np.array([r["t_normal"] for r in rows])
        ta = np.array([r["t_auto"] for r in rows])
        print(f"time per call, method='normal': median {np.median(tn):.2f} ms, max "
              f"{tn.max():.1f} ms")
        for k in ("enumerate", "normal", "mixture", "raise"):
            sel = np.array([p == k for p in paths])
            if sel.any():
                print(f"time per call, method='auto' -> {k:9s}: median {np.median(ta[sel]):.2f} "
                      f"ms, max {ta[sel].max():.1f} ms ({sel.sum()} models)")
    print("models with the largest error-to-estimate ratio:")
    print(f"{'err':>7s} {'est':>7s} {'ref':>4s} {'n':>2s} {'T':>4s} {'J':>2s} {'phi2':>6s} "
          f"{'sigma2':>6s}")
    for r in sorted(rows, key=lambda r: -(r["err_low"] / max(r["est"], 1e-6)))[:6]:
        print(f"{r['err']:7.4f} {r['est']:7.4f} {r['ref']:>4s} {r['n']:2d} {r['T']:4d} "
              f"{r['J']:2d} {r['phi2']:6.3f} {r['sigma2']:6.3f}")


if __name__ == "__main__":
    main()
