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
