"""Accuracy and speed of mdft.threshold_probabilities on random models, against simulation.

Draws random ternary (and binary) models across the documented range
(2-3 attributes, M uniform on [0.5, 4], attention from a Dirichlet(4, ..., 4),
phi1 log-uniform on [0.005, 0.1], phi2 uniform on [0.01, 0.1], beta uniform on
[1, 15], sigma2 log-uniform on [0.1, 4], theta uniform on [5, 60]), computes the
threshold-stopping probabilities and mean response times with
mdft.threshold_probabilities, and compares them with mdft.simulate
(``--trials`` trials, default 10**6) under the same step limit. Prints one line
per model and then the median and maximum errors, and the times against the speed
targets (the median, the calls of at most 0.2 s and of more than 2 s, the largest).

    python benchmarks/bench_threshold_exact.py                        # 20 ternary + 10 binary
    python benchmarks/bench_threshold_exact.py --ternary 5 --binary 0 --trials 100000
    python benchmarks/bench_threshold_exact.py --ternary 20 --binary 0 --live --cache /tmp/refs
    python benchmarks/bench_threshold_exact.py --ranges wide --fallback simulation --binary 0
    python benchmarks/bench_threshold_exact.py --ranges flat --fallback simulation --binary 0
    python benchmarks/bench_threshold_exact.py --ternary 40 --binary 0 --trials 0 --seed 8383
    python benchmarks/bench_threshold_exact.py --canonical --ternary 0 --binary 0 --max-steps 10000
    python benchmarks/bench_threshold_exact.py --edge-correction --fallback simulation --binary 0
    python benchmarks/bench_threshold_exact.py --ternary 0 --binary 30 --start 0.4 --max-steps 10000

``--canonical`` adds the three context-effect option sets of ``mdft.effects``
(similarity, attraction, compromise) at the canonical parameters (``w = (.5, .5)``,
``phi1 = .022``, ``phi2 = .05``, ``beta = 12``, ``sigma2 = 1``, ``theta = 17.5``), and the
compromise set at ``theta`` 12 and 60 and at ``sigma2`` 0.1 and 0.05.

``--start S`` starts the two-option draws away from 0: each entry of ``P0`` uniform within
``+-S theta`` (drawn from a stream of its own, so the models are those of ``--start 0``). A
start that does not sum to zero moves the summed preference, and with it the thresholds.

``--live`` adds a second, screened set of three-option models: draws (from
another seed) whose simulation leaves more than half the trials undecided
are redrawn, so every screened model decides. The unscreened draws include
many models whose leakage keeps the preferences below theta, which must be
answered with ``p_undecided`` near 1 or refused. ``--cache DIR`` stores the
simulated references (keyed by model, threshold, trials, step limit and
seed), so that re-running the benchmark times only the method.

Errors are the largest difference in a choice probability (or in the
undecided share) and the largest relative difference in a mean response time
among options chosen in at least 1000 simulated trials (``max dRT``) and among
those chosen in at least 10 % of them (``dRT p>.1``, where the simulation's own
relative error is below about 0.2 %); all include the simulation's own error
(``se``: its largest standard error in a probability). A model the method
cannot vouch for (ValueError) is counted and listed; with ``--fallback simulation``
it is answered by the simulation fallback instead ("sim" in the states column). Timings are wall-clock
after compilation, on whatever else the machine is doing: quote them with the
load average. ``--threads N`` sets numba's threads (the chain's build and
propagation run in parallel parts; default one thread per core).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import sys
import time
import warnings
from pathlib import Path

import numba
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import mdft  # noqa: E402


RANGES = ("standard", "wide", "flat")


def draw_model(rng, n_options, ranges="standard"):
    """A random model and threshold. ``"standard"``: the ranges of the module docstring;
    ``"wide"``: M uniform on [0, 10], attention Dirichlet(1, ...), phi1 and phi2 uniform on
    [0, 0.15], beta uniform on [0.5, 25] (sigma2 and theta as in "standard"); ``"flat"``: M
    uniform on [1, 5], attention Dirichlet(1, ...), phi1 and phi2 uniform on [0.01, 0.1], beta
    uniform on [1, 15] and sigma2 uniform (not log-uniform) on [0.1, 4] (theta as in
    "standard"): sigma2 above 1 in 77 % of the draws instead of 38 %."""
    n_attributes = int(rng.integers(2, 4))
    if ranges == "flat":
        M = rng.uniform(1.0, 5.0, (n_options, n_attributes))
        w = rng.dirichlet(np.ones(n_attributes))
        params = dict(phi1=float(rng.uniform(0.01, 0.1)), phi2=float(rng.uniform(0.01, 0.1)),
                      beta=float(rng.uniform(1.0, 15.0)), sigma2=float(rng.uniform(0.1, 4.0)))
    else:
        if ranges == "wide":
            M = rng.uniform(0.0, 10.0, (n_options, n_attributes))
            w = rng.dirichlet(np.ones(n_attributes))
            params = dict(phi1=float(rng.uniform(0.0, 0.15)), phi2=float(rng.uniform(0.0, 0.15)),
                          beta=float(rng.uniform(0.5, 25.0)))
        else:
            M = rng.uniform(0.5, 4.0, (n_options, n_attributes))
            w = rng.dirichlet(np.full(n_attributes, 4.0))
            params = dict(phi1=float(np.exp(rng.uniform(np.log(0.005), np.log(0.1)))),
                          phi2=float(rng.uniform(0.01, 0.1)), beta=float(rng.uniform(1.0, 15.0)))
        params["sigma2"] = float(np.exp(rng.uniform(np.log(0.1), np.log(4.0))))
    theta = float(rng.uniform(5.0, 60.0))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", mdft.UnstableFeedbackWarning)
        model = mdft.MDFTModel(M, w, **params)
    return model, theta


# (effect, theta, changed parameters) of --canonical
CANONICAL_CASES = (("compromise", None, {}), ("compromise", 12.0, {}), ("compromise", 60.0, {}),
                   ("compromise", None, {"sigma2": 0.1}), ("compromise", None, {"sigma2": 0.05}),
                   ("similarity", None, {}), ("attraction", None, {}))


def canonical_models(seed):
    """The ``--canonical`` cases as ``(model, theta, seed)``, and a label for each: the
    scenarios of ``mdft.effects`` with their own parameters, some of them changed, at
    ``mdft.effects.CANONICAL_THETA`` unless a case gives another threshold."""
    models, labels = [], []
    for k, (name, theta, changes) in enumerate(CANONICAL_CASES):
        theta = mdft.effects.CANONICAL_THETA if theta is None else theta
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", mdft.UnstableFeedbackWarning)
            model = mdft.effects.SCENARIOS[name].with_parameters(**changes).model()
        models.append((model, theta, seed + k))
        labels.append(f"{k}: {name}, theta={theta:g}"
                      + "".join(f", {key}={value:g}" for key, value in changes.items()))
    return models, labels


class Reference:
    """What the benchmark needs from a simulation (also what the cache stores)."""

    def __init__(self, probabilities, p_undecided, mean_response_times, counts,
                 standard_errors):
        self.probabilities = np.asarray(probabilities, dtype=float)
        self.p_undecided = float(p_undecided)
        self.mean_response_times = np.asarray(mean_response_times, dtype=float)
        self.counts = np.asarray(counts, dtype=np.int64)
        self.standard_errors = np.asarray(standard_errors, dtype=float)


def reference(model, theta, trials, max_steps, seed, cache):
    """Simulated reference of one model, from ``cache`` (a directory) when stored there."""
    key = json.dumps(dict(M=np.asarray(model.M).tolist(), w=np.asarray(model.w).tolist(),
                          phi1=model.phi1, phi2=model.phi2, beta=model.beta,
                          sigma2=model.sigma2, theta=theta, trials=trials,
                          max_steps=max_steps, seed=seed), sort_keys=True)
    path = None
    if cache is not None:
        path = Path(cache) / (hashlib.sha1(key.encode()).hexdigest()[:16] + ".json")
        if path.exists():
            return Reference(**json.loads(path.read_text())["result"])
    sim = mdft.simulate(model, trials, stopping=mdft.Threshold(theta, max_steps=max_steps),
                        rng=seed)
    ref = Reference(sim.probabilities, sim.p_undecided, sim.mean_response_times, sim.counts,
                    sim.standard_errors)
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        data = {k: (v.tolist() if isinstance(v, np.ndarray) else v)
                for k, v in vars(ref).items()}
        path.write_text(json.dumps(dict(key=json.loads(key), result=data)))
    return ref


def compare(model, theta, trials, max_steps, seed, cache=None, fallback="raise", edge=False):
    """The call's answer against the simulated reference; with ``trials=0``, the answer
    alone, timed as the shorter of two calls (calls over a second once). ``edge``: the
    three-option calls with ``edge_correction=True``."""
    def call():
        start = time.perf_counter()
        res = mdft.threshold_probabilities(model, theta, max_steps=max_steps, fallback=fallback,
                                           edge_correction=edge and model.n_options == 3)
        return res, time.perf_counter() - start

    start = time.perf_counter()
    try:
        res, seconds = call()
    except ValueError as exc:
        return None, time.perf_counter() - start, str(exc)
    if trials == 0:
        if seconds <= 1.0:
            seconds = min(seconds, call()[1])
        return dict(res=res), seconds, ""
    sim = reference(model, theta, trials, max_steps, seed, cache)
    dp = float(max(np.max(np.abs(res.probabilities - sim.probabilities)),
                   abs(res.p_undecided - sim.p_undecided)))
    se = float(np.max(sim.standard_errors))
    drt = drt_major = 0.0
    for i in np.flatnonzero(sim.counts >= 1000):
        gap = abs(res.mean_response_times[i] / sim.mean_response_times[i] - 1.0)
        drt = max(drt, gap)
        if sim.counts[i] >= 0.1 * trials:
            drt_major = max(drt_major, gap)
    return dict(dp=dp, se=se, drt=drt, drt_major=drt_major, res=res, sim=sim), seconds, ""


def screened_models(rng, count, trials, max_steps, seed, cache, ranges="standard"):
    """``count`` three-option draws whose simulation decides in at least half the trials."""
    out = []
    while len(out) < count:
        model, theta = draw_model(rng, 3, ranges)
        probe = mdft.simulate(model, 2_000, stopping=mdft.Threshold(theta, max_steps=max_steps),
                              rng=seed)
        if probe.p_undecided > 0.6:
            continue
        sim = reference(model, theta, trials, max_steps, seed + 1000 + len(out), cache)
        if sim.p_undecided <= 0.5:
            out.append((model, theta, seed + 1000 + len(out)))
    return out


def run_set(label, models, n_options, args):
    """Benchmark one set of models; print a line per model and a summary line."""
    rows, refused = [], []
    print(f"\n{label}")
    print(f"{'#':>3} {'theta':>6} {'sigma2':>6} {'states':>7} {'time s':>7} {'max|dp|':>8} "
          f"{'se':>7} {'est dp':>8} {'max dRT':>8} {'dRT p>.1':>8} {'est dRT':>8}  "
          "p (chain) / p (simulation)")
    for k, (model, theta, seed) in enumerate(models):
        out, seconds, why = compare(model, theta, args.trials, args.max_steps, seed,
                                    args.cache, args.fallback, args.edge_correction)
        if out is None:
            refused.append((k, theta, model.sigma2, seconds, why))
            print(f"{k:>3} {theta:6.1f} {model.sigma2:6.2f}   refused after {seconds:.2f} s: "
                  f"{why[:110]}")
            continue
        res = out["res"]
        size = "sim" if res.engine == "simulation" else res.n_states
        if "sim" not in out:
            rows.append((0.0, 0.0, seconds, 0.0, 0.0, res.engine == "simulation"))
            print(f"{k:>3} {theta:6.1f} {model.sigma2:6.2f} {size:>7} {seconds:7.2f} "
                  f"{'':>8} {'':>7} {res.error_probabilities:8.1e} {'':>8} {'':>8} "
                  f"{res.error_mean_rt:8.1e}  {np.round(res.probabilities, 4)} "
                  f"u={res.p_undecided:.3f}", flush=True)
            continue
        sim = out["sim"]
        rows.append((out["dp"], out["drt"], seconds, out["se"], out["drt_major"],
                     res.engine == "simulation"))
        print(f"{k:>3} {theta:6.1f} {model.sigma2:6.2f} {size:>7} {seconds:7.2f} "
              f"{out['dp']:8.4f} {out['se']:7.4f} {res.error_probabilities:8.1e} "
              f"{out['drt']:8.4f} {out['drt_major']:8.4f} {res.error_mean_rt:8.1e}  "
              f"{np.round(res.probabilities, 4)} u={res.p_undecided:.3f} / "
              f"{np.round(sim.probabilities, 4)} u={sim.p_undecided:.3f}", flush=True)
    times = [r[2] for r in rows] + [r[3] for r in refused]
    if args.trials == 0:
        if times:
            print(f"{label}: {len(rows)} models answered ({sum(r[5] for r in rows)} of them by "
                  f"the simulation fallback), {len(refused)} refused; time (answered and "
                  f"refused) {speed_summary(times)}")
        else:
            print(f"{label}: no models")
        return
    if rows:
        a = np.array(rows)
        print(f"{label}: {len(rows)} models answered ({int(a[:, 5].sum())} of them by the "
              f"simulation fallback), {len(refused)} refused: "
              f"|dp| median {np.median(a[:, 0]):.4f} max {a[:, 0].max():.4f} "
              f"(simulation se up to {a[:, 3].max():.4f}); "
              f"|dRT| median {np.median(a[:, 1]):.4f} max {a[:, 1].max():.4f} "
              f"(options with p > 0.1: max {a[:, 4].max():.4f}); "
              f"time (answered and refused) {speed_summary(times)}")
    elif refused:
        print(f"{label}: all {len(refused)} refused")


#: The speed targets of a three-option call: a median of 0.2 s and at most 2 s.
TARGET_MEDIAN_S = 0.2
TARGET_MAX_S = 2.0


def speed_summary(times):
    """The times of a set of calls against the speed targets, as one phrase: the median, how
    many calls took at most ``TARGET_MEDIAN_S`` and how many more than ``TARGET_MAX_S``, and
    the largest."""
    times = np.asarray(times, dtype=np.float64)
    fast = int(np.count_nonzero(times <= TARGET_MEDIAN_S))
    slow = int(np.count_nonzero(times > TARGET_MAX_S))
    return (f"median {np.median(times):.2f} s, {fast} of {times.size} calls at most "
            f"{TARGET_MEDIAN_S:g} s, {slow} over {TARGET_MAX_S:g} s, max {times.max():.2f} s")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ternary", type=int, default=20, help="random three-option models")
    parser.add_argument("--binary", type=int, default=10, help="random two-option models")
    parser.add_argument("--trials", type=int, default=1_000_000,
                        help="simulated trials (0: no reference; times the calls alone, the "
                             "shorter of two calls)")
    parser.add_argument("--max-steps", type=int, default=3_000, help="step limit (both)")
    parser.add_argument("--seed", type=int, default=2026)
    parser.add_argument("--live", action="store_true",
                        help="add a screened set of three-option models that decide")
    parser.add_argument("--fallback", choices=("raise", "simulation"), default="raise",
                        help="threshold_probabilities' fallback= (default 'raise': the chain "
                             "alone; 'simulation': the library's default)")
    parser.add_argument("--edge-correction", action="store_true",
                        help="three options: threshold_probabilities(..., "
                             "edge_correction=True)")
    parser.add_argument("--cache", default=None,
                        help="directory that stores the simulated references")
    parser.add_argument("--ranges", choices=RANGES, default="standard",
                        help="parameter ranges of the draws (see draw_model)")
    parser.add_argument("--canonical", action="store_true",
                        help="also the context-effect sets at the canonical parameters (see "
                             "the module docstring)")
    parser.add_argument("--start", type=float, default=0.0,
                        help="two options: each entry of P0 uniform within +-START theta "
                             "(default 0: P0 = 0)")
    parser.add_argument("--threads", type=int, default=None,
                        help="numba threads of the chain (default: numba's, one per core)")
    args = parser.parse_args(argv)
    if args.trials < 0:
        parser.error(f"--trials must be at least 0, got {args.trials}")
    if args.trials == 0 and args.live:
        parser.error("--live screens the draws by simulation: it needs --trials > 0")
    if not 0.0 <= args.start < 1.0:
        parser.error(f"--start must be in [0, 1), got {args.start}")
    if args.threads is not None:
        if args.threads < 1:
            parser.error(f"--threads must be at least 1, got {args.threads}")
        numba.set_num_threads(min(args.threads, numba.config.NUMBA_NUM_THREADS))
    rng = np.random.default_rng(args.seed)
    print(f"load average {os.getloadavg()[0]:.2f}; {args.trials} simulated trials per model; "
          f"max_steps={args.max_steps}; {numba.get_num_threads()} numba threads")
    # compile outside the timings: the chain's kernels and the simulation's (which the
    # fallback uses; otherwise the first model it answers would carry their compilation)
    mdft.warmup()
    ternary = [(*draw_model(rng, 3, args.ranges), args.seed + k) for k in range(args.ternary)]
    binary = [(*draw_model(rng, 2, args.ranges), args.seed + args.ternary + k)
              for k in range(args.binary)]
    if args.start > 0.0:
        starts = np.random.default_rng([args.seed, 2])
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", mdft.UnstableFeedbackWarning)
            binary = [(model.replace(P0=starts.uniform(-args.start, args.start, 2) * theta),
                       theta, seed) for model, theta, seed in binary]
    if args.canonical:
        models, labels = canonical_models(args.seed)
        print("\ncanonical sets: " + "; ".join(labels))
        run_set("3 options, canonical sets", models, 3, args)
    if ternary:
        run_set("3 options, unscreened", ternary, 3, args)
    if args.live:
        live = screened_models(np.random.default_rng(args.seed + 1), args.ternary, args.trials,
                               args.max_steps, args.seed, args.cache, args.ranges)
        run_set("3 options, screened (simulation decides in at least half the trials)", live,
                3, args)
    if binary:
        run_set("2 options", binary, 2, args)
    print(f"load average {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
