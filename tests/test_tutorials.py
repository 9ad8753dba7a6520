"""Every tutorial in docs/tutorials runs: its ```python blocks are executed in order.

A tutorial that no longer runs is a failing test. Each tutorial runs in a fresh namespace
inside a temporary working directory, so the figures it writes do not litter the tree.
"""

import os
import re
from pathlib import Path

import pytest

TUTORIALS = sorted((Path(__file__).resolve().parents[1] / "docs" / "tutorials").glob("*.md"))
BLOCK = re.compile(r"^```python\n(.*?)^```", re.DOTALL | re.MULTILINE)


def python_blocks(path: Path) -> list[str]:
    return BLOCK.findall(path.read_text())


@pytest.mark.parametrize("path", TUTORIALS, ids=[p.stem for p in TUTORIALS])
def test_tutorial_runs(path, tmp_path, monkeypatch):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    blocks = python_blocks(path)
    assert blocks, f"{path.name} has no ```python blocks to run"
    monkeypatch.chdir(tmp_path)
    namespace = {"__name__": f"tutorial_{path.stem}"}
    for i, block in enumerate(blocks):
        code = compile(block, f"{path.name}[block {i}]", "exec")
        exec(code, namespace)
    plt.close("all")
