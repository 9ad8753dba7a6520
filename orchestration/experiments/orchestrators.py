"""``mdft reproduce orchestrators``: Greedy, WA and MDFT in random worlds (the paper's Figure 6).

For each of ``n_worlds`` random worlds with slip (:meth:`irl.GridWorld.random`):

1. ``n_demonstrations`` demonstrations of the true constrained world (its soft
   policy) go to MESC-IRL (:func:`irl.mesc_irl`, defaults), which gives the
   learned constrained MDP;
2. :func:`orchestration.action_preferences` of the nominal and the learned
   constrained MDP feed every orchestrator: WA and MDFT at each weight
   ``(w_n, w_c)`` of the sweep, Greedy, and the two policies alone, Nominal
   (``sq_n``, i.e. WA at (1, 0)) and Constrained (``sq_c``, WA at (0, 1));
3. each runs ``n_trajectories`` trajectories (:func:`orchestration.rollout`).

Metrics per world and method: trajectory length over the shortest path from
start to goal (in moves; eight-connected grid, so the Chebyshev distance);
penalty of a trajectory under the *learned* penalties (``omega . phi`` summed
over its transitions), reported as a ratio to the Constrained policy's; true
constraint violations per trajectory, counting each violated feature of a
transition once (entering a constrained cell, taking a constrained action,
entering a cell of a constrained colour); and the Jensen-Shannon divergence
(:func:`irl.visitation_js_divergence`) between the state-action visits of the
method's trajectories and those of ``n_trajectories`` trajectories of the
optimal policy of the true constrained world (value iteration). At each
weight a two-sample Kolmogorov-Smirnov test (:func:`scipy.stats.ks_2samp`)
compares WA's and MDFT's trajectory lengths and penalties, per world and
pooled over worlds.
"""

from __future__ import annotations

import warnings

import numpy as np

from . import _stats
from ._stats import soft_trajectories
from .base import Experiment, Report
from .runner import Unit, child_seed

FIXED = ("nominal", "constrained", "greedy")
METRICS = (("length", "length / shortest path"), ("penalty", "penalty / Constrained's"),
           ("violations", "violations per trajectory"), ("js", "JS to the true optimum"))


def settings(quick: bool) -> dict:
    """The paper's sizes: 100 worlds, 200 demonstrations, 200 trajectories, 11 weights."""
    common = dict(p_slip=0.1, n_weights=11, temperature=1.0, max_length=500,
                  mdft=dict(phi1=0.01, phi2=0.01, beta=2.0, sigma2=1.0, n_steps=100))
    if quick:
        return dict(n_worlds=3, n_demonstrations=50, n_trajectories=50, **common)
    return dict(n_worlds=100, n_demonstrations=200, n_trajectories=200, **common)


def weights(s: dict) -> list:
    """The constraint weights w_c of the sweep, from 0 to 1 (w_n = 1 - w_c)."""
    return [round(k / (s["n_weights"] - 1), 10) for k in range(s["n_weights"])]


def units(s: dict) -> list:
    """One unit per world."""
    params = {k: s[k] for k in ("p_slip", "n_demonstrations", "n_trajectories", "temperature",
                                "max_length", "mdft")}
    return [Unit(f"world-{i:04d}", {**params, "weights": weights(s)}, (i,))
            for i in range(s["n_worlds"])]


def shortest_path_length(world) -> int:
    """Moves from start to goal on the eight-connected grid (the Chebyshev distance)."""
    (x0, y0), (x1, y1) = world.coords(world.start), world.coords(world.goal)
    return max(abs(x1 - x0), abs(y1 - y0))


def violations_per_trajectory(world, trajectories) -> np.ndarray:
    """True constraint violations of each trajectory, each violated feature of a transition once.

    A transition (s, a, s') violates the constrained state s', the constrained
    action a and the constrained colour of s': up to three per transition.
    """
    cell = np.zeros(world.n_states, dtype=np.int64)
    cell[list(world.constrained_states)] = 1
    colour = np.isin(world.colours, list(world.constrained_colours)).astype(np.int64)
    action = np.zeros(world.n_actions, dtype=np.int64)
    action[list(world.constrained_actions)] = 1
    per_step = cell[trajectories.next_states] + colour[trajectories.next_states] + \
        action[trajectories.actions]
    return np.add.reduceat(per_step, trajectories.offsets[:-1])


def penalty_per_trajectory(mdp, penalties, trajectories) -> np.ndarray:
    """Sum over each trajectory of ``penalties . phi(s, a, s')``."""
    u_src, u_act, u_dst = mdp.features.projections(penalties)
    per_step = u_src[trajectories.states] + u_act[trajectories.actions] + \
        u_dst[trajectories.next_states]
    return np.add.reduceat(per_step, trajectories.offsets[:-1])


def _orchestrators(prefs, params):
    import orchestration as orch

    out = {
        "nominal": orch.WeightedAverageOrchestrator.from_preferences(prefs, (1.0, 0.0)),
        "constrained": orch.WeightedAverageOrchestrator.from_preferences(prefs, (0.0, 1.0)),
        "greedy": orch.GreedyOrchestrator.from_preferences(prefs),
    }
    for k, w_c in enumerate(params["weights"]):
        w = (1.0 - w_c, w_c)
        out[f"wa-{k}"] = orch.WeightedAverageOrchestrator.from_preferences(prefs, w)
        out[f"mdft-{k}"] = orch.MDFTOrchestrator.from_preferences(prefs, w, **params["mdft"])
    return out


def work(params: dict, seed) -> dict:
    """One world: learn its constraints, run every orchestrator, measure the trajectories."""
    import irl
    from scipy import stats

    import orchestration as orch

    world = irl.GridWorld.random(rng=np.random.default_rng(child_seed(seed, 0)),
                                 p_slip=params["p_slip"])
    nominal = world.nominal_mdp
    demos = soft_trajectories(world.constrained_mdp, params["n_demonstrations"], child_seed(seed, 1))
    learned = irl.mesc_irl(nominal, demos)
    prefs = orch.action_preferences(nominal, learned.constrained, temperature=params["temperature"])
    n, n_s, n_a = params["n_trajectories"], nominal.n_states, nominal.n_actions
    optimum = irl.value_iteration(world.constrained_mdp).policy
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        reference = irl.sample_trajectories(world.constrained_mdp, optimum, n,
                                            rng=np.random.default_rng(child_seed(seed, 2)),
                                            max_steps=params["max_length"])
    shortest = shortest_path_length(world)
    methods, raw = {}, {}
    for i, (name, orchestrator) in enumerate(_orchestrators(prefs, params).items()):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # cut trajectories are counted below
            traj = orch.rollout(orchestrator, n, rng=np.random.default_rng(child_seed(seed, 3, i)),
                                max_length=params["max_length"])
        lengths = np.asarray(traj.lengths)
        reached = traj.reached_terminal
        assert reached is not None  # rollout always records it
        penalty = penalty_per_trajectory(nominal, learned.penalties, traj)
        violations = violations_per_trajectory(world, traj)
        methods[name] = {
            "length": float(lengths.mean() / shortest),
            "penalty": float(penalty.mean()),
            "violations": float(violations.mean()),
            "js": irl.visitation_js_divergence(traj, reference, n_states=n_s, n_actions=n_a),
            "reached": float(np.mean(reached)),
        }
        raw[name] = (lengths, penalty)
    ks = []
    for k in range(len(params["weights"])):
        (l_wa, p_wa), (l_md, p_md) = raw[f"wa-{k}"], raw[f"mdft-{k}"]
        ks.append({"length_p": float(stats.ks_2samp(l_wa, l_md, method="asymp").pvalue),
                   "penalty_p": float(stats.ks_2samp(p_wa, p_md, method="asymp").pvalue)})
    kept = {name: raw[name][0].tolist() for name in raw if name.startswith(("wa-", "mdft-"))}
    return {"shortest": shortest, "methods": methods, "ks": ks, "lengths": kept,
            "mesc_converged": bool(learned.converged),
            "true_violations": float(violations_per_trajectory(world, reference).mean())}


def summarise(s: dict, results: dict) -> Report:
    """Means over worlds (standard errors across worlds), KS tests, table and four-panel figure."""
    from scipy import stats

    ws = weights(s)
    worlds = list(results.values())

    def per_world(name, metric):
        return [w["methods"][name][metric] for w in worlds]

    def summary(name):
        out = {m: _stats.mean_se(per_world(name, m)) for m, _ in METRICS if m != "penalty"}
        out["penalty"] = _stats.ratio_se(per_world(name, "penalty"), per_world("constrained", "penalty"))
        out["reached"] = _stats.mean_se(per_world(name, "reached"))
        return out

    table = {name: summary(name) for name in FIXED}
    for k in range(len(ws)):
        table[f"wa-{k}"] = summary(f"wa-{k}")
        table[f"mdft-{k}"] = summary(f"mdft-{k}")
    ks = []
    for k in range(len(ws)):
        pooled_wa = np.concatenate([w["lengths"][f"wa-{k}"] for w in worlds])
        pooled_md = np.concatenate([w["lengths"][f"mdft-{k}"] for w in worlds])
        test = stats.ks_2samp(pooled_wa, pooled_md, method="asymp")
        ks.append({
            "w_c": ws[k], "pooled_length_statistic": float(test.statistic),
            "pooled_length_p": float(test.pvalue),
            "share_worlds_length_p_le_0.01": float(np.mean([w["ks"][k]["length_p"] <= 0.01 for w in worlds])),
            "share_worlds_penalty_p_le_0.01": float(np.mean([w["ks"][k]["penalty_p"] <= 0.01 for w in worlds])),
        })
    # paired over worlds: MDFT minus WA at each weight (penalty in learned-penalty units)
    paired = {m: [_stats.mean_se(np.subtract(per_world(f"mdft-{k}", m), per_world(f"wa-{k}", m)))
                  for k in range(len(ws))] for m, _ in METRICS}
    better = {m: sum(d[0] < 0 for d in paired[m]) for m in paired}
    clearly = {m: sum(d[0] + 2 * d[1] < 0 for d in paired[m]) for m in paired}
    clearly_worse = {m: sum(d[0] - 2 * d[1] > 0 for d in paired[m]) for m in paired}

    def row(label, w_c, entry, ks_entry=None):
        cells = [_stats.cell(*entry[m], digits=3) for m, _ in METRICS]
        p = None if ks_entry is None else ks_entry["pooled_length_p"]
        ks_cell = "" if p is None else (f"{p:.2g}" if p >= 1e-300 else "< 1e-300")
        return (label, w_c, *cells, _stats.cell(*entry["reached"], digits=3), ks_cell)

    rows = [row(name.capitalize(), "", table[name]) for name in FIXED]
    for k, w_c in enumerate(ws):
        rows.append(row("WA", f"{w_c:.1f}", table[f"wa-{k}"]))
        rows.append(row("MDFT", f"{w_c:.1f}", table[f"mdft-{k}"], ks[k]))
    n_unconv = sum(not w["mesc_converged"] for w in worlds)
    notes = [
        f"{len(worlds)} random worlds (slip {s['p_slip']:g}), MESC-IRL on {s['n_demonstrations']} "
        f"demonstrations each, {s['n_trajectories']} trajectories per method and world; means ± "
        "standard errors across worlds. Penalty: learned penalties, ratio of means to the "
        "Constrained policy's. KS p: two-sample test of WA vs MDFT trajectory lengths pooled over "
        "worlds.",
        "MDFT below WA (paired over worlds; in brackets: by more than two standard errors / "
        "above WA by more than two) at " + ", ".join(
            f"{better[m]} of {len(ws)} weights on {label} ({clearly[m]} / {clearly_worse[m]})"
            for m, label in METRICS) + ".",
        f"True constrained optimum: {np.mean([w['true_violations'] for w in worlds]):.3f} "
        "violations per trajectory.",
    ]
    if n_unconv:
        notes.append(f"MESC-IRL did not converge in {n_unconv} of {len(worlds)} worlds.")
    data = {"weights_w_c": ws, "methods": table, "ks": ks, "mdft_minus_wa": paired,
            "mdft_below_wa_at": better, "mdft_below_wa_by_2se_at": clearly,
            "mdft_above_wa_by_2se_at": clearly_worse, "mesc_unconverged": n_unconv}
    return Report(
        "orchestrators", "Orchestrators: Greedy, WA and MDFT on learned constraints",
        ("method", "w_c", "length/shortest", "penalty/constr.", "violations", "JS to optimum",
         "reached goal", "KS p (length)"),
        tuple(rows), tuple(notes), data, {"orchestrators.png": _figure(ws, table)},
    )


def _figure(ws, table):
    from .plot import new_figure, plot_weight_sweep

    fig, axes = new_figure(4, ncols=2)
    for ax, (m, label) in zip(axes, METRICS):
        curves = {method: tuple(np.array([table[f"{key}-{k}"][m] for k in range(len(ws))]).T)
                  for method, key in (("WA", "wa"), ("MDFT", "mdft"))}
        baselines = {name.capitalize(): table[name][m][0] for name in FIXED}
        plot_weight_sweep(ax, ws, curves, baselines=baselines, ylabel=label)
    fig.suptitle("Orchestrators in random worlds with slip (means and standard errors over worlds)")
    return fig


EXPERIMENT = Experiment(
    "orchestrators",
    "Greedy, WA and MDFT orchestrators on learned constraints (paper's Figure 6 and JS figure)",
    settings, units, work, summarise,
)
