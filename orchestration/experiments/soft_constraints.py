"""``mdft reproduce soft-constraints``: soft false positives and negatives against demonstrations.

The paper's appendix figures (and its Figure 4): random 9 x 9 worlds
(:meth:`irl.GridWorld.random`: start and goal at least 8 cells apart, 6 blue,
6 green and 6 constrained cells, penalties of 50), deterministic and with slip.
For each repeat one world is drawn (the same layout with and without slip) and
one set of demonstrations from the soft policy of its true constrained MDP; the
first ``n`` of them, for each ``n`` in ``n_demonstrations``, go to
:func:`irl.mesc_irl` (defaults).

Metrics: the soft false positives and negatives of
:func:`irl.soft_constraint_errors` (divided, as in the paper, by the number of
candidate features) at each tolerance ``chi``, with the true zeta computed from
the true penalties by the same map as the learned one; and the Jensen-Shannon
divergence (:func:`irl.visitation_js_divergence`) between the state-action
visits of the demonstrations and of ``n_model_trajectories`` trajectories of
the learned model's soft policy.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from . import _stats
from .base import Experiment, Report
from ._stats import soft_trajectories
from .runner import Unit, child_seed


def settings(quick: bool) -> dict:
    """The paper's sizes: 10 random worlds, up to 100 demonstrations, with and without slip."""
    if quick:
        return dict(p_slips=[0.0, 0.1], n_demonstrations=[5, 50], n_repeats=2,
                    chi_levels=[0.1, 0.2, 0.3], best_chi=0.2, n_model_trajectories=200)
    return dict(p_slips=[0.0, 0.1], n_demonstrations=[1, 2, 5, 10, 20, 50, 100], n_repeats=10,
                chi_levels=[0.1, 0.2, 0.3, 0.4, 0.5], best_chi=0.2, n_model_trajectories=500)


def units(s: dict) -> list:
    """One unit per (slip, repeat, number of demonstrations); a repeat shares its world."""
    n_max = max(s["n_demonstrations"])
    return [
        Unit(f"slip{i}-r{r:03d}-n{n:04d}",
             {"p_slip": p, "slip_index": i, "n": n, "n_max": n_max, "chi_levels": s["chi_levels"],
              "n_model_trajectories": s["n_model_trajectories"]}, (r,))
        for i, p in enumerate(s["p_slips"]) for r in range(s["n_repeats"])
        for n in s["n_demonstrations"]
    ]


def work(params: dict, seed) -> dict:
    """Learn from the first ``n`` demonstrations of a random world; score zeta and behaviour."""
    import irl

    world = irl.GridWorld.random(rng=np.random.default_rng(child_seed(seed, 0)),
                                 p_slip=params["p_slip"])
    nominal = world.nominal_mdp
    demos = soft_trajectories(world.constrained_mdp, params["n_max"],
                              child_seed(seed, 1, params["slip_index"]))
    demos = demos.subset(np.arange(params["n"]))
    learned = irl.mesc_irl(nominal, demos)
    zeta_true = irl.MESCResult.from_penalties(nominal, world.true_penalties).zeta
    errors = {}
    for chi in params["chi_levels"]:
        e = irl.soft_constraint_errors(world.true_penalties, zeta_true, learned.zeta, chi=chi)
        errors[f"{chi:g}"] = {"fp": e.false_positives, "fn": e.false_negatives,
                              "fp_share": e.false_positive_share, "fn_share": e.false_negative_share}
    rng = np.random.default_rng(child_seed(seed, 2, params["slip_index"], params["n"]))
    model = soft_trajectories(learned.constrained, params["n_model_trajectories"], rng)
    truth = soft_trajectories(world.constrained_mdp, params["n_model_trajectories"], rng)
    js = {name: irl.visitation_js_divergence(demos, t, n_states=nominal.n_states,
                                             n_actions=nominal.n_actions)
          for name, t in (("learned", model), ("true", truth))}
    return {"errors": errors, "js": js["learned"], "js_true": js["true"],
            "converged": bool(learned.converged)}


def summarise(s: dict, results: dict) -> Report:
    """Means and standard errors over the random worlds, per slip and number of demonstrations."""
    ns, chis = s["n_demonstrations"], [f"{c:g}" for c in s["chi_levels"]]
    best = f"{s['best_chi']:g}"
    curves = {}
    rows = []
    for i, p in enumerate(s["p_slips"]):
        group = {n: [r for k, r in results.items() if k.startswith(f"slip{i}-") and
                     k.endswith(f"-n{n:04d}")] for n in ns}
        c: dict[str, Any] = {
            "fn": {chi: [_stats.mean_se([r["errors"][chi]["fn"] for r in group[n]]) for n in ns]
                   for chi in chis},
            "fp": {chi: [_stats.mean_se([r["errors"][chi]["fp"] for r in group[n]]) for n in ns]
                   for chi in chis},
            "js": [_stats.mean_se([r["js"] for r in group[n]]) for n in ns],
            "js_true": [_stats.mean_se([r["js_true"] for r in group[n]]) for n in ns],
        }
        curves[f"{p:g}"] = c
        for j, n in enumerate(ns):
            rows.append(("deterministic" if p == 0 else f"slip {p:g}", str(n),
                         _stats.cell(*c["fn"][best][j], digits=4) if best in c["fn"] else "-",
                         _stats.cell(*c["fp"][best][j], digits=4) if best in c["fp"] else "-",
                         _stats.cell(*c["js"][j]), _stats.cell(*c["js_true"][j])))
    n_unconv = sum(not r["converged"] for r in results.values())
    notes = [f"Means ± standard errors over {s['n_repeats']} random worlds; fn and fp at "
             f"chi = {best}, divided by the number of candidate features (the paper's "
             "definition); 'JS true': fresh trajectories of the true constrained world, the "
             "divergence of an exactly right model; below it a model reproduces the "
             "demonstrations themselves rather than the world."]
    if n_unconv:
        notes.append(f"MESC-IRL did not converge in {n_unconv} of {len(results)} fits.")
    data = {"n_demonstrations": ns, "curves": curves, "mesc_unconverged": n_unconv}
    return Report(
        "soft-constraints", "Soft constraints: MESC-IRL on random worlds",
        ("world", "demos", f"fn (chi={best})", f"fp (chi={best})", "JS learned", "JS true"),
        tuple(rows), tuple(notes), data,
        {"soft_constraints.png": _figure(s, curves)},
    )


def _figure(s, curves):
    from .plot import new_figure, plot_curves

    ns = s["n_demonstrations"]
    fig, axes = new_figure(3 * len(s["p_slips"]), ncols=3)
    for row, p in enumerate(s["p_slips"]):
        c = curves[f"{p:g}"]
        kind = "deterministic" if p == 0 else f"slip {p:g}"
        a_fn, a_fp, a_js = axes[3 * row: 3 * row + 3]
        for ax, key, label in ((a_fn, "fn", "false negatives"), (a_fp, "fp", "false positives")):
            plot_curves(ax, ns, {f"chi = {chi}": tuple(np.array(v).T) for chi, v in c[key].items()},
                        xlabel="number of demonstrations", ylabel=label, logx=True,
                        title=kind, legend=key == "fn")
        plot_curves(a_js, ns, {"learned model": tuple(np.array(c["js"]).T),
                               "true world, fresh": tuple(np.array(c["js_true"]).T)},
                    xlabel="number of demonstrations", ylabel="JS(demonstrations, model)",
                    logx=True, title=kind)
    return fig


EXPERIMENT = Experiment(
    "soft-constraints",
    "Soft false positives, false negatives and JS divergence of MESC-IRL (paper's appendix)",
    settings, units, work, summarise,
)
