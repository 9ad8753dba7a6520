"""The one-page HTML report of :func:`orchestration.tour`, written with the standard library only.

Figures are embedded as base64 PNG, so the page is a single self-contained file
that can be mailed or opened offline. The tables hold the same cells as the
terminal output (:class:`orchestration.guided_tour.TourTable`).
"""

from __future__ import annotations

import base64
import html
from pathlib import Path

_STYLE = """
body { font-family: system-ui, -apple-system, "Segoe UI", Roboto, sans-serif; max-width: 1100px;
       margin: 2em auto; padding: 0 1.2em; color: #222; line-height: 1.45; }
h1 { font-size: 1.7em; margin-bottom: 0.2em; }
h2 { font-size: 1.25em; margin-top: 1.8em; border-bottom: 1px solid #ddd; padding-bottom: 0.2em; }
p.lead { color: #555; margin-top: 0; }
div.scroll { overflow-x: auto; }
table { border-collapse: collapse; margin: 0.8em 0; font-size: 0.92em; }
th, td { padding: 0.25em 0.8em; text-align: left; border-bottom: 1px solid #e4e4e4; }
th { background: #f4f4f4; }
td.num { text-align: right; font-variant-numeric: tabular-nums; white-space: nowrap; }
p.note { color: #555; font-size: 0.9em; margin: 0.2em 0; }
figure { margin: 1em 0; }
figure img { max-width: 100%; height: auto; border: 1px solid #eee; }
figcaption { color: #555; font-size: 0.9em; }
code, pre { background: #f6f6f6; border-radius: 3px; }
code { padding: 0 0.25em; }
pre { padding: 0.6em 0.8em; overflow-x: auto; }
ul.highlights { background: #f5f8fc; border-left: 4px solid #4a7bb7; padding: 0.6em 1em 0.6em 2em; }
footer { margin-top: 2.5em; color: #777; font-size: 0.85em; }
"""

_INTRO = {
    "Context effects": (
        "Multi-alternative Decision Field Theory (MDFT) accumulates preferences while attention "
        "shifts between attributes. Adding a third option to a choice between A and B changes "
        "the shares of A and B in the ways people do: a similar option takes share from its "
        "twin (similarity), a dominated decoy boosts its target (attraction) and a middle "
        "option wins over both extremes (compromise)."
    ),
    "Constraints learned from demonstrations": (
        "In the 9 x 9 world of the paper's Figure 1 the agent knows only its nominal reward "
        "(reach the goal in few steps). Demonstrators also avoid some cells, moves and colours. "
        "MESC-IRL learns a penalty per feature from their trajectories and maps it to zeta, "
        "the probability that the feature is a constraint."
    ),
    "Orchestrators": (
        "The agent now has two policies, one for its goal and one for the learned constraints. "
        "At every step an orchestrator combines them: Greedy takes the best action of either, "
        "the weighted average (WA) mixes their action probabilities with weights (w_n, w_c), "
        "and MDFT lets them compete in one deliberation, attending to each with those weights. "
        "More weight on the constraints gives longer paths and fewer violations."
    ),
}

_CAPTIONS = {
    "effects.png": "Choice shares with and without the third option (top) and a few "
                   "preference trajectories up to the threshold (bottom).",
    "constraints.png": "Learned zeta of every cell (left), move and colour (right); true "
                       "constraints are hatched.",
    "trajectories.png": "Trajectories of WA and MDFT at three weights, from S to G.",
    "tradeoff.png": "Path length and violations against the weight of the constraints; "
                    "Greedy as a dashed line.",
}

_FIGURE_OF = {
    "Context effects": ("effects.png",),
    "Constraints learned from demonstrations": ("constraints.png",),
    "Orchestrators": ("tradeoff.png", "trajectories.png"),
}

NEXT_COMMANDS = (
    ("mdft effects", "the context effects with your own sample size or stopping rule"),
    ("mdft simulate --options '1,3;3,1;2,2'", "choice probabilities of any set of options"),
    ("mdft reproduce orchestrators --quick", "the paper's orchestrator experiment, small"),
    ("mdft --help", "every command and its options"),
)
DOCS = ("docs/tour.md", "docs/tutorials/", "docs/concepts.md")


def _is_number(text: str) -> bool:
    head = text.split(" ")[0].lstrip("+-")
    return head.replace(".", "", 1).isdigit()


def _table_html(table) -> str:
    head = "".join(f"<th>{html.escape(str(h))}</th>" for h in table.header)
    body = []
    for row in table.rows:
        cells = "".join(
            f'<td class="num">{html.escape(str(c))}</td>' if _is_number(str(c))
            else f"<td>{html.escape(str(c))}</td>" for c in row)
        body.append(f"<tr>{cells}</tr>")
    notes = "".join(f'<p class="note">{html.escape(n)}</p>' for n in table.notes)
    return (f'<div class="scroll"><table data-title="{html.escape(table.title)}"><thead><tr>'
            f"{head}</tr></thead><tbody>{''.join(body)}</tbody></table></div>{notes}")


def _figure_html(name: str, path: Path) -> str:
    data = base64.b64encode(Path(path).read_bytes()).decode("ascii")
    caption = html.escape(_CAPTIONS.get(name, ""))
    return (f'<figure><img alt="{html.escape(name)}" src="data:image/png;base64,{data}">'
            f"<figcaption>{caption} ({html.escape(name)})</figcaption></figure>")


def render_html(result) -> str:
    """The report as one HTML page: highlights, then a section per step with its table and figures.

    Parameters
    ----------
    result : TourResult
        A finished tour, whose PNG figures are on disk.

    Returns
    -------
    str
    """
    seconds = result.seconds
    figures = result.files
    seed = "a Generator" if result.seed is None else f"seed {result.seed}"
    timing = ", ".join(f"{k} {v:.1f} s" for k, v in seconds.items())
    sections = []
    for number, table in enumerate(result.tables, start=1):
        figs = "".join(_figure_html(n, figures[n]) for n in _FIGURE_OF.get(table.title, ())
                       if n in figures)
        sections.append(
            f"<section><h2>{number}. {html.escape(table.title)}</h2>"
            f"<p>{html.escape(_INTRO.get(table.title, ''))}</p>{_table_html(table)}{figs}</section>"
        )
    commands = "".join(f"<li><code>{html.escape(c)}</code> &mdash; {html.escape(d)}</li>"
                       for c, d in NEXT_COMMANDS)
    docs = ", ".join(f"<code>{html.escape(d)}</code>" for d in DOCS)
    compiled = {True: "loaded from the cache", False: "compiled in this run",
                None: "compiled or loaded"}[result.compiled]
    size = "quick (test) sizes" if result.quick else "default sizes"
    highlights = "".join(f"<li>{html.escape(h)}</li>" for h in result.highlights)
    return f"""<!DOCTYPE html>
<html lang="en">
<head>
<meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1">
<title>pymdft tour</title>
<style>{_STYLE}</style>
</head>
<body>
<h1>pymdft tour</h1>
<p class="lead">Human-like trade-offs in constrained environments, in three steps: a cognitive
model of choice (MDFT), constraints learned from demonstrations (MESC-IRL), and orchestrators
that trade the goal off against the constraints (Glazier et al., 2022).</p>
<ul class="highlights">{highlights}</ul>
{''.join(sections)}
<section><h2>Next commands to try</h2>
<ul>{commands}</ul>
<p>Documentation: {docs}.</p>
</section>
<footer>Run with {html.escape(seed)}, {size}; kernels {compiled}. Wall time: {html.escape(timing)}.
Written by <code>mdft tour</code>.</footer>
</body>
</html>
"""
