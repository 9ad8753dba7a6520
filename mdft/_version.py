"""The version of the ``pymdft`` distribution, read from one place.

``pyproject.toml`` holds the version. In a source checkout (the file sits beside
the package) it is read from there, so that a clone always reports its own
version; in an installed copy it comes from the distribution's metadata.
"""

from __future__ import annotations

import importlib.metadata
import tomllib
from pathlib import Path

DISTRIBUTION = "pymdft"


def distribution_version() -> str:
    """Return the version of ``pymdft``, ``"0+unknown"`` if it cannot be found."""
    pyproject = Path(__file__).resolve().parents[1] / "pyproject.toml"
    try:
        project = tomllib.loads(pyproject.read_text(encoding="utf-8")).get("project", {})
        if project.get("name") == DISTRIBUTION and isinstance(project.get("version"), str):
            return project["version"]
    except (OSError, ValueError):
        pass
    try:
        return importlib.metadata.version(DISTRIBUTION)
    except importlib.metadata.PackageNotFoundError:
        return "0+unknown"


__version__ = distribution_version()
