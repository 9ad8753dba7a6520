"""The tour (``orchestration.tour`` and ``mdft tour``): files, report, numbers, determinism, errors."""

import base64
import sys
import json
import re
from html.parser import HTMLParser

import numpy as np
import pytest

import irl
import mdft
import orchestration
from orchestration.cli import main
from orchestration.guided_tour import FIGURES, WEIGHTS_W_C, kernels_compiled, settings

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


class _Page(HTMLParser):
    """Tables (cell text by table title), images and headings of an HTML page."""

    def __init__(self):
        super().__init__()
        self.tables, self.images, self.headings, self.links = {}, [], [], []
        self._table = self._row = self._cell = self._heading = None

    def handle_starttag(self, tag, attrs):
        attrs = dict(attrs)
        if tag == "table":
            self._table = self.tables.setdefault(attrs.get("data-title"), [])
        elif tag == "tr" and self._table is not None:
            self._row = []
        elif tag in ("td", "th") and self._row is not None:
            self._cell = ""
        elif tag == "img":
            self.images.append(attrs.get("src", ""))
        elif tag in ("h1", "h2"):
            self._heading = ""
        elif tag in ("link", "script", "iframe") or (tag == "a" and "href" in attrs):
            self.links.append((tag, attrs))

    def handle_endtag(self, tag):
        if tag in ("td", "th") and self._cell is not None:
            self._row.append(self._cell)
            self._cell = None
        elif tag == "tr" and self._row is not None:
            self._table.append(tuple(self._row))
            self._row = None
        elif tag == "table":
            self._table = None
        elif tag in ("h1", "h2") and self._heading is not None:
            self.headings.append(self._heading)
            self._heading = None

    def handle_data(self, data):
        if self._cell is not None:
            self._cell += data
        if self._heading is not None:
            self._heading += data


def _page(path):
    parser = _Page()
    parser.feed(path.read_text(encoding="utf-8"))
    return parser


@pytest.fixture(scope="module")
def quick_tour(tmp_path_factory):
    steps = []
    out = tmp_path_factory.mktemp("tour")
    result = orchestration.tour(out, rng=3, quick=True,
                                progress=lambda done, total, step: steps.append((done, total, step)))
    return result, steps


# ----------------------------------------------------------------------------- library
def test_tour_writes_every_file(quick_tour):
    result, _ = quick_tour
    names = set(FIGURES) | {"results.json", "report.html"}
    assert set(result.files) == names
    for name in names:
        path = result.files[name]
        assert path.parent == result.out_dir and path.name == name
        assert path.is_file() and path.stat().st_size > 0
    for name in FIGURES:
        assert result.files[name].read_bytes()[:8] == PNG_MAGIC


def test_progress_announces_every_step_and_the_kernels_first(quick_tour):
    _, steps = quick_tour
    assert [d for d, _, _ in steps] == [0, 1, 2, 3, 4, 5]
    assert {t for _, t, _ in steps} == {5}
    assert "kernels" in steps[0][2] and re.search(r"compil|cache", steps[0][2])
    assert steps[-1][2] == "done"


def test_report_is_one_self_contained_page_with_the_tables_and_figures(quick_tour):
    result, _ = quick_tour
    page = _page(result.files["report.html"])
    assert page.links == []  # no stylesheet, script, frame or link to fetch: one file
    assert page.headings[0] == "pymdft tour"
    assert [h.split(". ", 1)[1] for h in page.headings[1:4]] == [t.title for t in result.tables]
    # every figure embedded once, and the embedded bytes are the files written
    embedded = [base64.b64decode(src.split(",", 1)[1]) for src in page.images]
    assert len(embedded) == len(FIGURES)
    assert sorted(embedded) == sorted(result.files[n].read_bytes() for n in FIGURES)
    for src in page.images:
        assert src.startswith("data:image/png;base64,")
    # the tables of the page are those of the result, cell for cell
    for table in result.tables:
        html_rows = page.tables[table.title]
        assert html_rows[0] == tuple(table.header)
        assert html_rows[1:] == [tuple(r) for r in table.rows]
    text = result.files["report.html"].read_text()
    assert "mdft reproduce orchestrators --quick" in text and "mdft effects" in text


def test_tables_carry_the_returned_numbers(quick_tour):
    result, _ = quick_tour
    effects, constraints, orchestrators = result.tables
    for row, e in zip(effects.rows, result.effects):
        assert row[0] == e["name"]
        assert [float(x) for x in row[2].split()] == pytest.approx(e["ternary"], abs=5e-4)
        assert float(row[4]) == pytest.approx(e["effect_size"], abs=5e-4)
        assert float(row[5]) == pytest.approx(e["standard_error"], abs=5e-4)
        assert row[7] == ("yes" if e["shown"] else "no")
    for row, f in zip(constraints.rows, result.constraints["features"]):
        assert row[0] == f["name"]
        assert float(row[2]) == pytest.approx(f["penalty"], abs=0.05)
        assert float(row[3]) == pytest.approx(f["zeta"], abs=0.005)
    assert f"precision {result.constraints['precision']:.2f}" in " ".join(constraints.notes)
    for row, r in zip(orchestrators.rows, result.orchestrators):
        assert row[0] == r["method"]
        mean, se = (float(x) for x in row[4].split(" ± "))
        assert mean == pytest.approx(r["violations"], abs=0.005)
        assert se == pytest.approx(r["violations_se"], abs=0.005)
        assert float(row[2].split(" ± ")[0]) == pytest.approx(r["length"], abs=0.05)


def test_results_json_equals_the_returned_result(quick_tour):
    result, _ = quick_tour
    data = json.loads(result.files["results.json"].read_text())
    assert data == json.loads(json.dumps(result.to_dict()))
    assert data["seed"] == 3 and data["quick"] is True
    assert data["seconds"]["total"] >= max(v for k, v in data["seconds"].items() if k != "total")


def test_learned_constraints_are_scored_against_the_truth(quick_tour):
    """Precision and recall recomputed from the listed features and the world's true constraints."""
    result, _ = quick_tour
    c = result.constraints
    world = irl.load_paper_worlds("scobee_example")[0]
    truth = set(np.flatnonzero(world.constraint_mask))
    assert {f["feature"] for f in c["features"] if f["true"]} == truth
    learned = {f["feature"] for f in c["features"] if f["zeta"] >= 0.6}
    assert {f["feature"] for f in c["features"] if f["learned"]} == learned
    tp = len(learned & truth)
    assert c["precision"] == pytest.approx(tp / len(learned) if learned else 1.0)
    assert c["recall"] == pytest.approx(tp / len(truth))
    for f in c["features"]:
        assert f["true_penalty"] == (world.penalty if f["true"] else 0.0)


def test_orchestrator_rows_cover_every_method_and_weight(quick_tour):
    result, _ = quick_tour
    keys = [(r["method"], r["w_c"]) for r in result.orchestrators]
    assert keys == [("Greedy", None)] + [(m, w) for w in WEIGHTS_W_C for m in ("WA", "MDFT")]
    for r in result.orchestrators:
        assert r["n_trajectories"] == settings(quick=True)["n_rollouts"]
        assert r["length"] >= r["shortest_path"] and 0.0 <= r["reached"] <= 1.0
        assert r["violations"] >= 0 and r["penalty"] >= 0


def test_effects_match_a_direct_library_call(quick_tour):
    """The effect sizes are those of mdft.context_effects with the tour's child generator."""
    result, _ = quick_tour
    s = settings(quick=True)
    (g_effects, *_) = np.random.default_rng(3).spawn(4)
    direct = mdft.context_effects(n_samples=s["n_samples"],
                                  n_trajectories=s["n_trajectories_effects"], rng=g_effects)
    assert [e["effect_size"] for e in result.effects] == [r.effect_size for r in direct]


def test_same_seed_same_numbers_other_seed_other_numbers(quick_tour, tmp_path):
    result, _ = quick_tour
    again = orchestration.tour(tmp_path / "again", rng=3, quick=True)
    for field in ("effects", "constraints", "orchestrators", "tables", "highlights"):
        assert getattr(again, field) == getattr(result, field)
    other = orchestration.tour(tmp_path / "other", rng=4, quick=True)
    assert other.effects != result.effects and other.orchestrators != result.orchestrators


def test_kernels_are_reported_as_compiled_after_a_tour(quick_tour):
    assert kernels_compiled() is True
    assert quick_tour[0].compiled in (True, False, None)


def test_bad_arguments_are_refused_by_name(tmp_path):
    a_file = tmp_path / "a_file"
    a_file.write_text("x")
    with pytest.raises(ValueError, match=r"out_dir .*a_file.* exists and is not a folder"):
        orchestration.tour(a_file, quick=True)
    with pytest.raises(ValueError, match=r"out_dir .* cannot be created"):
        orchestration.tour(a_file / "sub", quick=True)
    with pytest.raises(TypeError, match=r"out_dir must be a folder path .*got 5"):
        orchestration.tour(5, quick=True)
    with pytest.raises(TypeError, match=r"progress must be None or a callable .*got 3"):
        orchestration.tour(tmp_path, quick=True, progress=3)
    with pytest.raises(TypeError, match=r"quick must be True or False \(got 'yes'\)"):
        orchestration.tour(tmp_path, quick="yes")
    with pytest.raises(ValueError, match=r"rng must be None, an integer >= 0 .*got -1"):
        orchestration.tour(tmp_path, quick=True, rng=-1)
    with pytest.raises(TypeError, match=r"rng must be None, an integer >= 0 .*got 'abc'"):
        orchestration.tour(tmp_path, quick=True, rng="abc")
    with pytest.raises(ValueError, match=r"rng must be .*got True"):
        orchestration.tour(tmp_path, quick=True, rng=True)
    assert not any(tmp_path.glob("*.png"))  # nothing written before the arguments are checked


# ----------------------------------------------------------------------------- command line
def test_command_prints_tables_highlights_and_next_commands(tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["tour", "--quick", "--seed", "3", "--out", str(out)]) == 0
    captured = capsys.readouterr()
    for title in ("1. Context effects", "2. Constraints learned from demonstrations",
                  "3. Orchestrators"):
        assert title in captured.out
    assert "Next commands to try" in captured.out
    assert "mdft reproduce orchestrators --quick" in captured.out
    assert "report.html" in captured.out
    # step lines on stderr, the kernels first
    assert re.search(r"^\[1/5\] .*kernels", captured.err, re.M)
    assert "[5/5]" in captured.err and "done in" in captured.err
    # the printed tables are those of the results file
    data = json.loads((out / "results.json").read_text())
    for table in data["tables"]:
        for row in table["rows"]:
            assert re.search(r"\s+".join(re.escape(c) for c in row), captured.out)


def test_command_json_and_quiet(tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["tour", "--quick", "--seed", "3", "--out", str(out), "--json", "--quiet"]) == 0
    captured = capsys.readouterr()
    data = json.loads(captured.out)
    assert captured.err == ""
    assert data["out_dir"] == str(out)
    assert data["effects"] == json.loads((out / "results.json").read_text())["effects"]


@pytest.mark.parametrize("argv, message", [
    (["--out", "{file}"], r"--out: '.*a_file' exists and is not a folder"),
    (["--out", "{file}/sub"], r"--out: cannot create the folder"),
    (["--seed", "-1"], r"argument --seed: expected an integer >= 0, got -1"),
    (["--seed", "x"], r"argument --seed: expected an integer >= 0, got 'x'"),
    (["--samples", "5"], r"unrecognized arguments: --samples 5"),
])
def test_command_errors_are_one_line_exit_2(tmp_path, capsys, argv, message):
    a_file = tmp_path / "a_file"
    a_file.write_text("x")
    argv = [a.format(file=a_file) for a in argv]
    with pytest.raises(SystemExit) as exc:
        main(["tour", "--quick", *argv])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert re.search(message, err)


def test_step_display_ticks_on_a_terminal_and_prints_lines_elsewhere():
    import io
    import time

    from orchestration.cli.tour import _Steps

    class Terminal(io.StringIO):
        def isatty(self):
            return True

    for stream, live in ((Terminal(), True), (io.StringIO(), False)):
        steps = _Steps(False, stream=stream)
        steps(0, 2, "compiling the kernels")
        time.sleep(1.3 if live else 0.0)
        steps(1, 2, "the effects")
        steps(2, 2, "done")
        text = stream.getvalue()
        assert text.startswith("[1/2] compiling the kernels ...\n")
        assert "[2/2] the effects ...\n" in text
        assert len(re.findall(r"done in \d+\.\d s", text)) == 2
        assert bool(re.search(r"\r      1 s\x1b\[K", text)) == live  # the clock ticked
    quiet = io.StringIO()
    steps = _Steps(True, stream=quiet)
    steps(0, 1, "x")
    steps(1, 1, "done")
    steps.close()
    assert quiet.getvalue() == ""


def test_kernels_reported_uncompiled_with_an_empty_cache(tmp_path):
    """A fresh numba cache folder (as on a new installation) means compilation is announced."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    code = ("from orchestration.guided_tour import kernels_compiled; "
            "print(kernels_compiled())")
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path))
    proc = subprocess.run([sys.executable, "-c", code], cwd=root, env=env, capture_output=True,
                          text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "False"


def test_kernels_compiled_cannot_tell_without_an_inspectable_cache(monkeypatch):
    import types

    import numba

    fake = types.ModuleType("mdft._uncached_for_test")
    fake.kernel = numba.njit(cache=False)(lambda x: x)  # a dispatcher without a disk cache
    monkeypatch.setitem(sys.modules, fake.__name__, fake)
    assert kernels_compiled() is None
