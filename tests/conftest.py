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


@pytest.fixture(scope="session")
def small_world():
    """A 4 x 4 gridworld with slip and two constrained cells, for orchestration tests."""
    import irl

    return irl.GridWorld(4, 0, 15, constrained_states=(5, 6), p_slip=0.1)


@pytest.fixture(scope="session")
def small_prefs(small_world):
    """Action preferences of ``small_world``'s nominal and true constrained MDPs."""
    import orchestration

    return orchestration.action_preferences(small_world.nominal_mdp, small_world.constrained_mdp)
