"""One version for the three packages, taken from pyproject.toml."""

import importlib.metadata
import tomllib
from pathlib import Path

import irl
import mdft
import orchestration
from mdft import _version

ROOT = Path(__file__).resolve().parents[1]


def test_versions_agree_with_pyproject():
    declared = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["version"]
    assert mdft.__version__ == irl.__version__ == orchestration.__version__ == declared


def test_changelog_has_the_current_version():
    text = (ROOT / "CHANGELOG.md").read_text()
    assert f"## [{mdft.__version__}]" in text


def test_installed_metadata_is_the_fallback(tmp_path, monkeypatch):
    # Outside a source checkout the distribution's metadata answers, then "0+unknown".
    monkeypatch.setattr(_version, "__file__", str(tmp_path / "mdft" / "_version.py"))
    monkeypatch.setattr(importlib.metadata, "version", lambda name: f"9.9-{name}")
    assert _version.distribution_version() == "9.9-pymdft"

    def missing(name):
        raise importlib.metadata.PackageNotFoundError(name)

    monkeypatch.setattr(importlib.metadata, "version", missing)
    assert _version.distribution_version() == "0+unknown"
