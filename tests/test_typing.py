"""Type hints of the public API: complete, and consistent with the code (mypy).

mypy comes with the ``test`` extra; where it is not installed the mypy test is skipped with
that reason. Its settings are in pyproject.toml (``[tool.mypy]``); docs/decisions.md says
why they are what they are.
"""

import importlib
import inspect
import pkgutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("mdft", "irl", "orchestration")

#: Modules whose public functions and methods must be fully annotated. A module joins
#: when its public signatures are complete; none leaves.
ANNOTATED = {
    "mdft.model", "mdft.simulate", "mdft.stopping", "mdft.simulation_result", "mdft.decide",
    "mdft.closed_form", "mdft.effects", "mdft.plot",
    "irl.mdp", "irl.gridworld", "irl.planning", "irl.demonstrations", "irl.io", "irl.metrics",
    "irl.gym", "irl.scobee", "irl.plot",
}


def test_mypy_finds_no_errors():
    pytest.importorskip("mypy", reason="mypy (the test extra) is not installed")
    run = subprocess.run([sys.executable, "-m", "mypy"], cwd=ROOT, capture_output=True,
                         text=True)
    assert run.returncode == 0, f"mypy reports errors:\n{run.stdout}{run.stderr}"
    assert "Success" in run.stdout


def public_modules():
    """Each package, and each of its public submodules (no leading underscore)."""
    for package in PACKAGES:
        module = importlib.import_module(package)
        yield module
        for info in pkgutil.iter_modules(module.__path__):
            if not info.name.startswith("_"):
                yield importlib.import_module(f"{package}.{info.name}")


def public_callables():
    """(qualified name, function) of every public function and public method."""
    for module in public_modules():
        for name in getattr(module, "__all__", []):
            obj = getattr(module, name)
            package = module.__name__
            if inspect.isfunction(obj):
                yield f"{package}.{name}", obj
            elif inspect.isclass(obj) and not issubclass(obj, BaseException):
                for attr, value in vars(obj).items():
                    if isinstance(value, (staticmethod, classmethod)):
                        value = value.__func__
                    if isinstance(value, property):
                        value = value.fget
                        if getattr(value, "__name__", "") == "<lambda>":
                            continue  # property(lambda self: ..., doc=...): typed in its doc
                    public = not attr.startswith("_") or attr == "__init__"
                    # dataclasses write their own __init__ from the annotated fields
                    generated = getattr(value, "__qualname__", "").startswith("__create_fn__")
                    if public and inspect.isfunction(value) and not generated:
                        yield f"{package}.{name}.{attr}", value


def missing_annotations(function) -> list[str]:
    signature = inspect.signature(function)
    missing = [name for name, p in signature.parameters.items()
               if p.annotation is inspect.Parameter.empty and name not in ("self", "cls")]
    if signature.return_annotation is inspect.Signature.empty:
        missing.append("return")
    return missing


def test_public_api_is_fully_annotated():
    for module in ANNOTATED:
        importlib.import_module(module)  # a misspelt name would silently check nothing
    checked, gaps = 0, {}
    for name, function in public_callables():
        if function.__module__ not in ANNOTATED:
            continue
        checked += 1
        if missing := missing_annotations(function):
            gaps[name] = missing
    assert checked > 80
    assert not gaps, f"public functions with missing type hints: {gaps}"


def test_missing_annotations_finds_gaps():
    def untyped(a, b: int, *, c=1):
        return a

    def typed(a: int, *, c: float = 1.0) -> int:
        return a

    assert missing_annotations(untyped) == ["a", "c", "return"]
    assert missing_annotations(typed) == []
