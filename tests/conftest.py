"""Shared fixtures: a headless Matplotlib backend and the location of the shared data sets."""

import os
from pathlib import Path

import pytest

os.environ.setdefault("MPLBACKEND", "Agg")

ROOT = Path(__file__).resolve().parents[1]
# The paper's worlds and the MDFT data sets live beside the repository (see README).
SHARED_DATA = Path(os.environ.get("PYMDFT_DATA", ROOT.parent / "shared" / "data"))


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """Folder of the shared data sets; the test is skipped, with the reason, where it is absent."""
    if not SHARED_DATA.is_dir():
        pytest.skip(f"shared data folder not found at {SHARED_DATA}; set PYMDFT_DATA")
    return SHARED_DATA


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
