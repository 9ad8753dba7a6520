"""Shared fixtures: a headless Matplotlib backend and the data sets as the packages ship them."""

import os
import shutil
from pathlib import Path

import pytest

os.environ.setdefault("MPLBACKEND", "Agg")

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="session")
def shared_data(tmp_path_factory) -> Path:
    """A data folder laid out as ``data/`` beside the repository, built from the bundled copies.

    ``mdft-thesis/`` is ``mdft/data/thesis`` and ``paper/`` is ``irl/data`` (the same files,
    byte for byte), so every test of the data runs on a fresh clone and tests what is shipped.
    """
    root = tmp_path_factory.mktemp("data")
    shutil.copytree(ROOT / "mdft" / "data" / "thesis", root / "mdft-thesis")
    shutil.copytree(ROOT / "irl" / "data", root / "paper")
    return root
