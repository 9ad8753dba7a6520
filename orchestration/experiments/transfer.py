"""``mdft reproduce transfer``: penalties learned on one world, used on another (paper Section 3.2).

The paper's Section 3.2 restricts the penalty-to-probability map to a subset
of features ``f`` (for example the colours) so that what was learned about
those features can be carried between worlds. Here, for each repeat:

- a source world A (:meth:`irl.GridWorld.random`, with slip) and
  ``n_source`` demonstrations of its true constrained MDP give MESC-IRL
  penalties ``omega_A``;
- a target world B is another random layout with the same constrained
  actions and colours (its constrained cells differ);
- the transferable part of ``omega_A`` (the ``transfer_features`` blocks:
  actions and colours, whose meaning does not depend on the layout; the
  state block is zeroed) is used on B:

  * ``transfer only``: B's nominal reward minus the transferred penalties, no
    demonstration of B;
  * ``from scratch``: MESC-IRL's default call (evidence selection) on ``n``
    demonstrations of B;
  * ``plain ML``: maximum likelihood (``selection="none"``) on the same
    demonstrations, started from zero;
  * ``warm start``: the same maximum likelihood started from the transferred
    penalties (``init=``; the evidence selection's path always starts from
    zero, so a warm start needs the plain fit);
  * ``nominal``: B's nominal reward (nothing learned).

Metrics on B: the soft false negatives and positives
(:func:`irl.soft_constraint_errors`, at ``chi``) over the transferable
features and over all features, and the Jensen-Shannon divergence between the
visits of ``n_model_trajectories`` trajectories of each model's soft policy and
as many held-out trajectories of B's true constrained world.
"""

from __future__ import annotations

import numpy as np

from . import _stats
from ._stats import soft_trajectories
from .base import Experiment, Report
from .runner import Unit, child_seed

METHODS = ("nominal", "transfer only", "from scratch", "plain ML", "warm start")


def settings(quick: bool) -> dict:
    """Ten source-target pairs, up to 50 demonstrations of the target."""
    if quick:
        return dict(n_repeats=2, n_source=100, n_demonstrations=[2, 20], p_slip=0.1, chi=0.2,
                    transfer_features=["action", "colour"], n_model_trajectories=200)
    return dict(n_repeats=10, n_source=200, n_demonstrations=[1, 2, 5, 10, 20, 50], p_slip=0.1,
                chi=0.2, transfer_features=["action", "colour"], n_model_trajectories=500)


def units(s: dict) -> list:
    """One unit per (pair, number of target demonstrations); a pair shares its worlds."""
    n_max = max(s["n_demonstrations"])
    common = {k: s[k] for k in ("n_source", "p_slip", "chi", "transfer_features",
                                "n_model_trajectories")}
    return [Unit(f"r{r:03d}-n{n:04d}", {**common, "n": n, "n_max": n_max}, (r,))
            for r in range(s["n_repeats"]) for n in s["n_demonstrations"]]


def target_world(source, seed, *, max_tries=100):
    """A random layout with the constrained actions and colours of ``source``."""
    import irl

    for k in range(max_tries):
        world = irl.GridWorld.random(rng=np.random.default_rng(child_seed(seed, k)),
                                     p_slip=source.p_slip,
                                     constrained_colours=source.constrained_colours)
        world = world.replace(constrained_actions=source.constrained_actions)
        if world.constraint_free_path_exists():
            return world
    raise ValueError(f"no target layout with a constraint-free path in {max_tries} tries")


def work(params: dict, seed) -> dict:
    """Learn on a source world, carry the action and colour penalties to a target, compare."""
    import irl

    source = irl.GridWorld.random(rng=np.random.default_rng(child_seed(seed, 0)),
                                  p_slip=params["p_slip"])
    source_demos = soft_trajectories(source.constrained_mdp, params["n_source"], child_seed(seed, 1))
    learned_source = irl.mesc_irl(source.nominal_mdp, source_demos)
    target = target_world(source, child_seed(seed, 2))
    nominal = target.nominal_mdp
    mask = np.zeros(target.n_features, dtype=bool)
    for block in params["transfer_features"]:
        mask[target.feature_slices[block]] = True
    transferred = np.where(mask, learned_source.penalties, 0.0)

    demos = soft_trajectories(target.constrained_mdp, params["n_max"], child_seed(seed, 3))
    demos = demos.subset(np.arange(params["n"]))
    models = {
        "nominal": irl.MESCResult.from_penalties(nominal, np.zeros(target.n_features)),
        "transfer only": irl.MESCResult.from_penalties(nominal, transferred),
        "from scratch": irl.mesc_irl(nominal, demos),
        "plain ML": irl.mesc_irl(nominal, demos, selection="none"),
        "warm start": irl.mesc_irl(nominal, demos, selection="none", init=transferred),
    }
    zeta_true = irl.MESCResult.from_penalties(nominal, target.true_penalties).zeta
    rng = np.random.default_rng(child_seed(seed, 4, params["n"]))
    m = params["n_model_trajectories"]
    held_out = soft_trajectories(target.constrained_mdp, m, rng)
    out = {}
    for name, model in models.items():
        errors = {}
        for scope, sel in (("transferable", mask), ("all", slice(None))):
            e = irl.soft_constraint_errors(target.true_penalties[sel], zeta_true[sel],
                                           model.zeta[sel], chi=params["chi"])
            errors[scope] = {"fn": e.false_negatives, "fp": e.false_positives}
        traj = soft_trajectories(model.constrained, m, rng)
        js = irl.visitation_js_divergence(held_out, traj, n_states=nominal.n_states,
                                          n_actions=nominal.n_actions)
        out[name] = {"errors": errors, "js": js}
    return out


def summarise(s: dict, results: dict) -> Report:
    """Means and standard errors over the pairs, per method and number of target demonstrations."""
    ns = s["n_demonstrations"]
    by_n = {n: [r for k, r in results.items() if k.endswith(f"-n{n:04d}")] for n in ns}
    curves = {}
    for method in METHODS:
        curves[method] = {
            "js": [_stats.mean_se([r[method]["js"] for r in by_n[n]]) for n in ns],
            **{f"{key}_{scope}": [_stats.mean_se([r[method]["errors"][scope][key] for r in by_n[n]])
                                  for n in ns]
               for key in ("fn", "fp") for scope in ("transferable", "all")},
        }
    rows = []
    for method in METHODS:
        for i, n in enumerate(ns):
            if method in ("nominal", "transfer only") and i > 0:
                continue  # they use no demonstration of the target
            c = curves[method]
            rows.append((method, "0" if method in ("nominal", "transfer only") else str(n),
                         _stats.cell(*c["fn_transferable"][i], digits=4),
                         _stats.cell(*c["fp_transferable"][i], digits=4),
                         _stats.cell(*c["fn_all"][i], digits=4), _stats.cell(*c["js"][i])))
    notes = [f"Means ± standard errors over {s['n_repeats']} source-target pairs (slip "
             f"{s['p_slip']:g}); fn, fp at chi = {s['chi']:g} over the transferable features "
             f"({' and '.join(s['transfer_features'])}) and fn over all features; JS to held-out "
             "trajectories of the target's true constrained world."]
    return Report(
        "transfer", "Transfer: penalties learned on one world used on another",
        ("method", "target demos", "fn transferable", "fp transferable", "fn all", "JS"),
        tuple(rows), tuple(notes), {"n_demonstrations": ns, "curves": curves},
        {"transfer.png": _figure(ns, curves)},
    )


def _figure(ns, curves):
    from .plot import new_figure, plot_curves

    fig, axes = new_figure(3)
    panels = (("fn_transferable", "false negatives (actions, colours)"),
              ("fn_all", "false negatives (all features)"), ("js", "JS to the true world"))
    for ax, (key, label) in zip(axes, panels):
        lines = {}
        for method in METHODS:
            mean, se = np.array(curves[method][key]).T
            if method in ("nominal", "transfer only"):
                mean, se = np.full(len(ns), mean[0]), np.full(len(ns), se[0])
            lines[method] = (mean, se)
        plot_curves(ax, ns, lines, xlabel="demonstrations of the target world", ylabel=label,
                    logx=True, legend=key == "js")
    return fig


EXPERIMENT = Experiment(
    "transfer",
    "Penalties learned on one world used on another (paper Section 3.2)",
    settings, units, work, summarise,
)
