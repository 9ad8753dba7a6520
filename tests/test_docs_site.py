"""The documentation site builds with warnings as errors and documents every public name.

The build needs the ``docs`` extra (Sphinx, numpydoc, MyST, furo); without it the build
tests are skipped with that reason. The Python blocks of the landing page and of the
getting-started page run in any case, like the tutorials (tests/test_tutorials.py).
"""

import importlib
import os
import re
import subprocess
import sys
import zlib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
PACKAGES = ("mdft", "irl", "orchestration")
BLOCK = re.compile(r"^```python\n(.*?)^```", re.DOTALL | re.MULTILINE)


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    """Build the HTML site once (``-W --keep-going``: any warning fails the build)."""
    for module in ("sphinx", "myst_parser", "numpydoc", "furo"):
        pytest.importorskip(module, reason="the docs extra is not installed")
    out = tmp_path_factory.mktemp("site")
    command = [sys.executable, "-m", "sphinx", "-W", "--keep-going", "-q", "-b", "html",
               "-d", str(out / "doctrees"), str(DOCS), str(out / "html")]
    run = subprocess.run(command, cwd=ROOT, capture_output=True, text=True,
                         env={**os.environ, "MPLBACKEND": "Agg"})
    assert run.returncode == 0, f"the site does not build cleanly:\n{run.stderr}{run.stdout}"
    return out / "html"


def inventory(html: Path) -> dict[str, str]:
    """``{object name: role}`` from the site's ``objects.inv`` (Sphinx inventory v2)."""
    raw = (html / "objects.inv").read_bytes()
    header_end = 0
    for _ in range(4):  # four text lines, then the zlib-compressed entries
        header_end = raw.index(b"\n", header_end) + 1
    entries = {}
    for line in zlib.decompress(raw[header_end:]).decode().splitlines():
        match = re.match(r"(\S+)\s+(\S+):(\S+)\s+-?\d+\s+", line)
        if match and match.group(2) == "py":
            entries[match.group(1)] = match.group(3)
    return entries


def public_names() -> list[str]:
    names = []
    for package in PACKAGES:
        module = importlib.import_module(package)
        names += [f"{package}.{name}" for name in getattr(module, "__all__", [])]
    return names


def test_every_public_name_is_in_the_api_reference(site):
    documented = inventory(site)
    missing = [name for name in public_names() if name not in documented]
    assert not missing, f"public names without an API page: {missing}"
    for name in public_names():
        page = site / "api" / "generated" / f"{name}.html"
        assert page.exists(), f"no page {page.name} for {name}"


def test_api_reference_kinds(site):
    """Functions are documented as functions, classes as classes, constants as data."""
    documented = inventory(site)
    assert documented["mdft.simulate"] == "function"
    assert documented["mdft.MDFTModel"] == "class"
    assert documented["mdft.UnstableFeedbackWarning"] == "exception"
    assert documented["mdft.SIMILARITY"] == "data"
    assert documented["irl.mesc_irl"] == "function"
    # Methods and properties of a class come from its docstrings too.
    assert documented["mdft.MDFTModel.spectral_radius"] == "property"


def test_every_markdown_page_is_on_the_site(site):
    pages = [p for p in DOCS.rglob("*.md") if "_build" not in p.parts]
    assert len(pages) >= 10
    for page in pages:
        built = site / page.relative_to(DOCS).with_suffix(".html")
        assert built.exists(), f"{page.relative_to(ROOT)} is not on the site"


def test_command_line_reference_lists_every_command(site):
    import argparse

    from orchestration.cli import build_parser

    text = (site / "cli.html").read_text()
    (commands,) = [a for a in build_parser()._actions
                   if isinstance(a, argparse._SubParsersAction)]
    assert commands.choices, "the program has no subcommands"
    for name in commands.choices:
        assert f"usage: mdft {name}" in text, f"mdft {name} is missing from cli.html"


def test_concept_equations_link_to_their_functions(site):
    text = (site / "concepts.html").read_text()
    assert text.count('id="equation-') >= 8, "concepts.md lost its numbered equations"
    for name in ("contrast_matrix", "distance_matrix", "feedback_matrix", "simulate",
                 "preference_moments", "choice_probabilities", "threshold_probabilities"):
        assert f'href="api/generated/mdft.{name}.html#mdft.{name}"' in text, name


@pytest.mark.parametrize("page", ["index.md", "getting_started.md"])
def test_page_examples_run(page, tmp_path, monkeypatch):
    """The Python blocks of the landing and getting-started pages run, in order."""
    import matplotlib

    matplotlib.use("Agg")
    blocks = BLOCK.findall((DOCS / page).read_text())
    assert blocks, f"{page} shows no Python example"
    monkeypatch.chdir(tmp_path)
    namespace = {"__name__": f"docs_{Path(page).stem}"}
    for i, block in enumerate(blocks):
        exec(compile(block, f"{page}[block {i}]", "exec"), namespace)


def test_signatures_show_type_aliases_by_name(site):
    page = (site / "api" / "generated" / "mdft.MDFTModel.html").read_text()
    assert "ArrayLike" in page and "_NestedSequence" not in page
    for path in (site / "api" / "generated").glob("*.html"):
        assert "TypeAliasForwardRef" not in path.read_text(), path.name
