"""The README's test command is exactly what CI runs."""

from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_ci_runs_the_readme_test_command():
    ci = (ROOT / ".ci" / "run").read_text().splitlines()
    command = [line for line in ci if line.startswith("python3 -m venv")]
    assert len(command) == 1, "the CI script must run exactly one README command"
    assert command[0] in (ROOT / "README.md").read_text()


def test_readme_examples_run(tmp_path, monkeypatch):
    """The ```python blocks of the README run, in order, as a user would paste them."""
    import re

    blocks = re.findall(r"^```python\n(.*?)^```", (ROOT / "README.md").read_text(), re.S | re.M)
    assert blocks, "the README shows no Python example"
    monkeypatch.chdir(tmp_path)
    namespace: dict = {}
    for i, block in enumerate(blocks):
        exec(compile(block, f"README.md[block {i}]", "exec"), namespace)
    assert abs(namespace["mc"].probabilities.sum() - 1.0) < 1e-12
    assert namespace["result"].converged
