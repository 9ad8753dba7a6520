"""Error of the Gaussian fixed-time closed form on random models (not only the canonical sets).

Usage::

    python benchmarks/bench_closed_form_random.py                  # 60 random models
    python benchmarks/bench_closed_form_random.py --models 20 --mc 200000 --sequences 50000

Each random model has 3 options on 2 or 3 attributes (evaluations uniform on [0, 5]), random
attention on the simplex, phi1 in [0.005, 0.1], phi2 in [0.01, 0.2], beta in [1, 15], sigma2
in [0.1, 4], and a deliberation time T in [5, 200]. For each model the normal approximation
(``mdft.choice_probabilities``) is compared with the exact mixture
(``mdft.mixture_choice_probabilities``, its own standard error) and with plain simulation
(``mdft.simulate``, ``--mc`` trials). Reported: the distribution over models of the largest
absolute error per model against the exact mixture and the largest |z| against simulation,
and the worst models with what distinguishes them (T, phi2, sigma2, the smallest probability).
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


def random_model(rng):
    J = int(rng.integers(2, 4))
    M = rng.uniform(0.0, 5.0, size=(3, J))
    w = rng.dirichlet(np.ones(J))
    params = dict(phi1=rng.uniform(0.005, 0.1), phi2=rng.uniform(0.01, 0.2),
                  beta=rng.uniform(1.0, 15.0), sigma2=rng.uniform(0.1, 4.0))
    T = int(rng.integers(5, 201))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", mdft.UnstableFeedbackWarning)
        return mdft.MDFTModel(M, w, **params), T, params


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--models", type=int, default=60)
    ap.add_argument("--mc", type=int, default=200_000)
    ap.add_argument("--sequences", type=int, default=50_000)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    rng = np.random.default_rng(args.seed)
    rows = []
    t0 = time.perf_counter()
    for i in range(args.models):
        model, T, params = random_model(rng)
        normal = mdft.choice_probabilities(model, T)
        mix = mdft.mixture_choice_probabilities(model, T, n_sequences=args.sequences, rng=i)
        sim = mdft.simulate(model, args.mc, stopping=mdft.FixedTime(T), rng=i)
        err_mix = np.abs(normal - mix.probabilities)
        se = np.sqrt(np.maximum(normal * (1 - normal), 1e-12) / args.mc)
        z = np.abs(normal - sim.probabilities) / se
        rows.append(dict(err=err_mix.max(), se_mix=mix.standard_errors.max(), z=z.max(),
                         err_sim=np.abs(normal - sim.probabilities).max(), T=T,
                         J=model.n_attributes, p_min=normal.min(), **params))
    el = time.perf_counter() - t0
    err = np.array([r["err"] for r in rows])
    z = np.array([r["z"] for r in rows])
    err_sim = np.array([r["err_sim"] for r in rows])
    print(f"{args.models} random 3-option models, {args.mc} simulated trials and "
          f"{args.sequences} attention sequences each ({el:.0f} s)")
    q = lambda a, f: f"median {np.median(a):{f}}, 90% {np.quantile(a, 0.9):{f}}, max {a.max():{f}}"  # noqa: E731
    print(f"largest |normal - exact mixture| per model: {q(err, '.4f')}")
    print(f"  (mixture standard error: up to {max(r['se_mix'] for r in rows):.4f})")
    print(f"largest |normal - simulation| per model:    {q(err_sim, '.4f')}")
    print(f"largest |z| against simulation per model:    {q(z, '.1f')}")
    print(f"models beyond 3 SE of simulation: {np.mean(z > 3):.0%}; error > 0.002 against the "
          f"mixture: {np.mean(err > 0.002):.0%}")
    print("worst models:")
    print(f"{'err':>7s} {'|z|':>5s} {'T':>4s} {'J':>2s} {'phi1':>6s} {'phi2':>6s} {'beta':>5s} "
          f"{'sigma2':>6s} {'p_min':>7s}")
    for r in sorted(rows, key=lambda r: -r["err"])[:8]:
        print(f"{r['err']:7.4f} {r['z']:5.1f} {r['T']:4d} {r['J']:2d} {r['phi1']:6.3f} "
              f"{r['phi2']:6.3f} {r['beta']:5.1f} {r['sigma2']:6.2f} {r['p_min']:7.4f}")


if __name__ == "__main__":
    main()
