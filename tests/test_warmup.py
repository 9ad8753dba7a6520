"""Kernels are cached on disk, and one call compiles or loads every kernel the public layer calls."""

import logging
import re
from pathlib import Path

import numba
import pytest

import irl
import mdft
from irl import _kernels as irl_kernels
from mdft import _kernels as mdft_kernels
from mdft import _lattice

ROOT = Path(__file__).resolve().parents[1]


def _dispatchers(module):
    return {name: obj for name, obj in vars(module).items()
            if isinstance(obj, numba.core.registry.CPUDispatcher)}


def _called_from_python(package, module_name):
    """Kernels that the package's Python modules (public or private, the kernel module itself
    aside) call as ``<module_name>.<kernel>(``."""
    names = set()
    for path in (ROOT / package).glob("*.py"):
        if path.stem == module_name:
            continue
        names |= set(re.findall(rf"\b{module_name}\.(\w+)\(", path.read_text()))
    return names


@pytest.mark.parametrize("module", [mdft_kernels, _lattice, irl_kernels])
def test_every_kernel_is_cached_on_disk(module):
    kernels = _dispatchers(module)
    assert kernels
    for name, kernel in kernels.items():
        assert type(kernel._cache).__name__ != "NullCache", name
    assert mdft._numba.JIT_OPTIONS["cache"] and irl._numba.JIT_OPTIONS["cache"]


@pytest.mark.parametrize(
    "package, warm, modules",
    [("mdft", mdft.warmup, {"_kernels": mdft_kernels, "_lattice": _lattice}),
     ("irl", irl.warmup, {"_kernels": irl_kernels})],
)
def test_warmup_reaches_every_kernel_the_public_layer_calls(package, warm, modules, caplog):
    calls = []
    with caplog.at_level(logging.INFO, logger=f"{package}.warmup"):
        report = warm(progress=lambda done, total, step: calls.append((done, total, step)))
    total = len(report.steps)
    assert calls == [(i, total, s) for i, s in enumerate(report.steps)] + [(total, total, "done")]
    assert len(report.seconds) == total and report.total_seconds == pytest.approx(
        sum(report.seconds))
    messages = [r.getMessage() for r in caplog.records]
    assert any("compiling or loading" in m for m in messages)
    assert "kernels ready in" in messages[-1]
    for module_name, module in modules.items():
        called = _called_from_python(package, module_name)
        assert called
        kernels = _dispatchers(module)
        for name in called:
            assert kernels[name].signatures, f"{package}.{module_name}.{name} was not compiled"
    assert report.summary().splitlines()[-1].startswith("total")
    assert report.to_dict()["steps"] == list(report.steps)
    assert len(repr(report)) < 300


def test_warmup_rejects_a_bad_progress():
    for warm in (mdft.warmup, irl.warmup):
        with pytest.raises(TypeError, match=r"progress must be None or a callable progress\(done, "
                                            r"total, step\) \(got 'yes'\)"):
            warm(progress="yes")
