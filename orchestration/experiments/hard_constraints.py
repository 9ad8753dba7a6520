"""``mdft reproduce hard-constraints``: MESC-IRL against Scobee & Sastry (the paper's Figure 3).

The paper's world of Figure 1 without slip (deterministic), its true
constraints read as hard constraints. For each repeat a set of demonstrations
is drawn from the soft policy of the true constrained world; the first ``n``
of them, for each ``n`` in ``n_demonstrations``, go to

- MESC-IRL (:func:`irl.mesc_irl`, defaults), whose per-feature probability
  ``zeta`` is thresholded at each level of ``zeta_levels`` to give a set of
  hard constraints, and
- the Scobee & Sastry baseline (:func:`irl.infer_hard_constraints`, defaults).

Scores against the true constraint set (:func:`irl.hard_constraint_scores`):
precision, recall and false discovery rate (what the paper calls the false
positive rate). KL: :func:`irl.visitation_kl_divergence` from the
demonstrations to ``n_model_trajectories`` trajectories of each learned model
(the maximum entropy policy of the nominal world with the inferred hard
constraints, or with MESC-IRL's soft penalties), and, as a floor, of the true
constrained world.
"""

from __future__ import annotations

import warnings

import numpy as np

from . import _stats
from .base import Experiment, Report
from ._stats import soft_trajectories
from .runner import Unit, child_seed

#: Penalty standing in for a hard constraint (exp(-1e4) is 0 in double precision).
HARD_PENALTY = 1.0e4


def settings(quick: bool) -> dict:
    """The paper's sizes: 10 sets of up to 100 demonstrations."""
    if quick:
        return dict(world="scobee_example", n_demonstrations=[2, 10, 50], n_repeats=2,
                    zeta_levels=[0.5, 0.6, 0.7, 0.8, 0.9], best_zeta=0.6, n_model_trajectories=200)
    return dict(world="scobee_example", n_demonstrations=[1, 2, 5, 10, 20, 50, 100], n_repeats=10,
                zeta_levels=[0.5, 0.6, 0.7, 0.8, 0.9], best_zeta=0.6, n_model_trajectories=500)


def units(s: dict) -> list:
    """One unit per (repeat, number of demonstrations); a repeat's sets are nested."""
    n_max = max(s["n_demonstrations"])
    return [
        Unit(f"r{r:03d}-n{n:04d}", {"repeat": r, "n": n, "n_max": n_max, "world": s["world"],
                                    "zeta_levels": s["zeta_levels"],
                                    "n_model_trajectories": s["n_model_trajectories"]}, (r,))
        for r in range(s["n_repeats"]) for n in s["n_demonstrations"]
    ]


def _world(name):
    import irl

    return irl.load_paper_worlds(name, p_slip=0.0)[0]


def _kl(demos, mdp, trajectories):
    import irl

    return irl.visitation_kl_divergence(demos, trajectories, n_states=mdp.n_states,
                                        n_actions=mdp.n_actions)


def _scores(true_mask, predicted):
    import irl

    s = irl.hard_constraint_scores(true_mask, predicted)
    return {"precision": s.precision, "recall": s.recall, "fdr": s.false_discovery_rate,
            "n_predicted": int(np.count_nonzero(predicted))}


def work(params: dict, seed) -> dict:
    """Learn from the first ``n`` of ``n_max`` demonstrations with both methods; score them."""
    import irl

    world = _world(params["world"])
    nominal, true_mask = world.nominal_mdp, world.constraint_mask
    all_demos = soft_trajectories(world.constrained_mdp, params["n_max"], child_seed(seed, 0))
    demos = all_demos.subset(np.arange(params["n"]))
    rng = np.random.default_rng(child_seed(seed, 1, params["n"]))
    m = params["n_model_trajectories"]

    mesc = irl.mesc_irl(nominal, demos)
    out = {"mesc": {}, "mesc_soft_kl": _kl(demos, nominal, soft_trajectories(mesc.constrained, m, rng))}
    for level in params["zeta_levels"]:
        mask = mesc.zeta >= level
        model = nominal.penalised(np.where(mask, HARD_PENALTY, 0.0))
        out["mesc"][f"{level:g}"] = {**_scores(true_mask, mask),
                                      "kl": _kl(demos, nominal, soft_trajectories(model, m, rng))}
    hard = irl.infer_hard_constraints(nominal, demos)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        traj = irl.sample_trajectories(nominal, hard.policy(nominal), m, rng=rng,
                                       max_steps=hard.horizon)
    out["scobee"] = {**_scores(true_mask, hard.mask), "kl": _kl(demos, nominal, traj)}
    out["true_kl"] = _kl(demos, nominal, soft_trajectories(world.constrained_mdp, m, rng))
    out["mesc_converged"] = bool(mesc.converged)
    return out


_METRICS = (("precision", "precision"), ("recall", "recall"),
            ("fdr", "false discovery rate"), ("kl", "KL(demonstrations || model)"))


def summarise(s: dict, results: dict) -> Report:
    """Mean and standard error over repeats, per method and number of demonstrations."""
    ns = s["n_demonstrations"]
    methods = {"Scobee & Sastry": lambda r: r["scobee"]}
    for level in s["zeta_levels"]:
        methods[f"MESC-IRL zeta >= {level:g}"] = (lambda lv: lambda r: r["mesc"][f"{lv:g}"])(level)
    by_n = {n: [r for k, r in results.items() if k.endswith(f"-n{n:04d}")] for n in ns}
    curves = {}
    for label, get in methods.items():
        curves[label] = {m: [_stats.mean_se([get(r)[m] for r in by_n[n]]) for n in ns]
                         for m, _ in _METRICS}
    extra = {
        "MESC-IRL soft penalties": [_stats.mean_se([r["mesc_soft_kl"] for r in by_n[n]]) for n in ns],
        "true constrained world": [_stats.mean_se([r["true_kl"] for r in by_n[n]]) for n in ns],
    }
    best = f"MESC-IRL zeta >= {s['best_zeta']:g}"
    shown = ["Scobee & Sastry"] + ([best] if best in curves else [])
    rows = []
    for label in shown:
        for i, n in enumerate(ns):
            rows.append((label, str(n), *(_stats.cell(*curves[label][m][i]) for m, _ in _METRICS)))
    for label, vals in extra.items():
        for i, n in enumerate(ns):
            rows.append((label, str(n), "", "", "", _stats.cell(*vals[i])))
    n_unconv = sum(not r["mesc_converged"] for r in results.values())
    notes = [f"Means ± standard errors over {s['n_repeats']} sets of demonstrations "
             f"(world {s['world']!r}, no slip); false discovery rate = the paper's "
             "'false positive rate'. All zeta levels are in results.json and the figure."]
    if n_unconv:
        notes.append(f"MESC-IRL did not converge in {n_unconv} of {len(results)} fits.")
    data = {
        "n_demonstrations": ns,
        "curves": {label: {m: [list(v) for v in vals] for m, vals in c.items()}
                   for label, c in curves.items()},
        "kl_reference": {label: [list(v) for v in vals] for label, vals in extra.items()},
        "mesc_unconverged": n_unconv,
    }
    return Report(
        "hard-constraints",
        "Hard constraints: MESC-IRL against Scobee & Sastry (deterministic world)",
        ("method", "demos", "precision", "recall", "FDR", "KL"), tuple(rows), tuple(notes), data,
        {"hard_constraints.png": _figure(ns, curves, extra)},
    )


def _figure(ns, curves, extra):
    from .plot import new_figure, plot_curves

    fig, axes = new_figure(4, ncols=2)
    for ax, (m, label) in zip(axes, _METRICS):
        lines = {k: tuple(np.array(v[m]).T) for k, v in curves.items()}
        if m == "kl":
            lines.update({k: tuple(np.array(v).T) for k, v in extra.items()})
        plot_curves(ax, ns, lines, xlabel="number of demonstrations", ylabel=label, logx=True,
                    legend=m in ("precision", "kl"))
    fig.suptitle("Hard constraints in the deterministic world of Figure 1")
    return fig


EXPERIMENT = Experiment(
    "hard-constraints",
    "MESC-IRL against the Scobee & Sastry baseline on hard constraints (paper's Figure 3)",
    settings, units, work, summarise,
)
