"""Every tutorial in docs/tutorials runs: its ```python blocks are executed in order.

A tutorial that no longer runs is a failing test. Each tutorial runs in a fresh namespace
inside a temporary working directory, so the figures it writes do not litter the tree.
"""

import re
import warnings
from pathlib import Path

import pytest

TUTORIALS = sorted((Path(__file__).resolve().parents[1] / "docs" / "tutorials").glob("*.md"))
BLOCK = re.compile(r"^```python\n(.*?)^```", re.DOTALL | re.MULTILINE)
# The warnings of mdft (and numpy's RuntimeWarnings) that a tutorial's text says its code
# raises: tutorial -> [(category name, part of the message)]. Each must be raised, and any
# other such warning fails the test: a tutorial should not leave the reader with a warning it
# does not explain. Other libraries' warnings are passed on to pytest.
EXPECTED_WARNINGS = {
    "fitting": [("FitConvergenceWarning", "phi2 on a bound")],
}


def python_blocks(path: Path) -> list[str]:
    return BLOCK.findall(path.read_text())


def _is(w, name, part):
    """Whether the recorded warning ``w`` is of the category named ``name`` and says ``part``."""
    return w.category.__name__ == name and part in str(w.message)


@pytest.mark.parametrize("path", TUTORIALS, ids=[p.stem for p in TUTORIALS])
def test_tutorial_runs(path, tmp_path, monkeypatch):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    blocks = python_blocks(path)
    assert blocks, f"{path.name} has no ```python blocks to run"
    monkeypatch.chdir(tmp_path)
    namespace = {"__name__": f"tutorial_{path.stem}"}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        for i, block in enumerate(blocks):
            code = compile(block, f"{path.name}[block {i}]", "exec")
            exec(code, namespace)
    plt.close("all")
    expected = EXPECTED_WARNINGS.get(path.stem, [])
    for name, part in expected:
        assert any(_is(w, name, part) for w in caught), \
            f"{path.name} says it raises {name} ({part!r}), but it did not"
    unexplained = []
    for w in caught:
        if any(_is(w, name, part) for name, part in expected):
            continue
        if w.category.__module__.startswith("mdft") or issubclass(w.category, RuntimeWarning):
            unexplained.append(f"{w.category.__name__}: {w.message}")
        else:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    assert not unexplained, \
        f"{path.name} raised warnings its text does not explain: {unexplained}"
