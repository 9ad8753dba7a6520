"""``mdft reproduce mdft-vs-wa``: can two-attribute MDFT learn any WA distribution? (paper Section 4.1).

Each unit is one instance of :func:`orchestration.mdft_vs_wa_instance`: random
``sq_n`` and ``sq_c`` over ``n_actions`` actions and random WA weights;
``n_choices`` choices sampled from the WA distribution; MDFT attention fitted to
them (``M = [sq_n, sq_c]`` fixed, ``n_steps`` deliberation steps); the
Jensen-Shannon divergence between the WA and the fitted MDFT distributions.
Each instance also reports the divergence of the attention that best fits the
exact WA distribution, which separates the limits of two-attribute MDFT (what
remains with unlimited data) from the sampling noise of ``n_choices`` choices.
"""

from __future__ import annotations

import numpy as np

from . import _stats
from .base import Experiment, Report
from .runner import Unit

#: The paper's figure: mean JS divergence 0.024, standard error 0.0013.
PAPER_JS = (0.024, 0.0013)


def settings(quick: bool) -> dict:
    """The paper's sizes: 100 instances, 8 actions, 100 choices, 25 deliberation steps."""
    return dict(n_instances=4 if quick else 100, n_actions=8, n_choices=100, n_steps=25)


def units(s: dict) -> list:
    """One unit per instance."""
    params = {k: s[k] for k in ("n_actions", "n_choices", "n_steps")}
    return [Unit(f"instance-{i:04d}", params, (i,)) for i in range(s["n_instances"])]


def work(params: dict, seed) -> dict:
    """One instance, seeded by an integer drawn from the unit's seed."""
    import orchestration

    instance_seed = int(seed.generate_state(1, dtype=np.uint64)[0] >> np.uint64(1))
    inst = orchestration.mdft_vs_wa_instance(instance_seed, n_actions=params["n_actions"],
                                             n_choices=params["n_choices"],
                                             n_steps=params["n_steps"])
    return {
        "seed": inst.seed,
        "wa_w_n": float(inst.wa_weights[0]),
        "fitted_w_n": float(inst.fitted_weights[0]),
        "exact_fit_w_n": float(inst.exact_fit_weights[0]),
        "js": float(inst.js_divergence),
        "exact_fit_js": float(inst.exact_fit_js_divergence),
    }


def summarise(s: dict, results: dict) -> Report:
    """Mean JS divergences with standard errors, against the paper's 0.024 (SE 0.0013)."""
    values = list(results.values())
    js = _stats.mean_se([v["js"] for v in values])
    exact = _stats.mean_se([v["exact_fit_js"] for v in values])
    rows = (
        ("MDFT fitted to sampled choices", _stats.cell(*js, digits=4),
         _stats.cell(*PAPER_JS, digits=4)),
        ("MDFT best fit to the exact WA distribution", _stats.cell(*exact, digits=4), ""),
    )
    notes = [f"{len(values)} instances, {s['n_actions']} actions, {s['n_choices']} sampled choices, "
             f"{s['n_steps']} deliberation steps; JS divergence in nats; means ± standard errors.",
             "The exact fit is what two-attribute MDFT cannot reproduce even with unlimited "
             "data; the rest of the first line is sampling noise of the choices."]
    data = {"js": list(js), "exact_fit_js": list(exact), "paper_js": list(PAPER_JS),
            "instances": values}
    return Report("mdft-vs-wa", "MDFT vs WA: learning WA distributions with two-attribute MDFT",
                  ("MDFT", "mean JS", "paper"), rows, tuple(notes), data,
                  {"mdft_vs_wa.png": _figure(values)})


def _figure(values):
    from .plot import new_figure, plot_histograms, plot_scatter

    fig, (a, b) = new_figure(2)
    plot_histograms(a, {"fitted to choices": [v["js"] for v in values],
                        "best fit to the exact WA": [v["exact_fit_js"] for v in values]},
                    xlabel="JS(WA, MDFT) (nats)")
    plot_scatter(b, [v["wa_w_n"] for v in values], [v["fitted_w_n"] for v in values],
                 xlabel="WA weight $w_n$", ylabel="fitted MDFT attention $w_n$", diagonal=True)
    return fig


EXPERIMENT = Experiment(
    "mdft-vs-wa",
    "Fit two-attribute MDFT to WA choice distributions (paper Section 4.1)",
    settings, units, work, summarise,
)
