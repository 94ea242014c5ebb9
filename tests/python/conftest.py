"""Shared pytest setup: import vislam_tools from <repo>/tools, find generated LCM types and seed data
the same way the tools do (VISLAM_LCM_PYTHON_DIR, else $VISLAM_BUILD_DIR or <repo>/build)."""

import os
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO / "tools"))

from vislam_tools import ToolError  # noqa: E402
from vislam_tools import lcmtypes  # noqa: E402

SHARED_DATA = Path(os.environ.get("VISLAM_SHARED_DATA_DIR", REPO.parent / "shared" / "data"))


@pytest.fixture(scope="session")
def vislam_types():
    """The generated `vislam` package, or skip with the reason."""
    try:
        return lcmtypes.load()
    except ToolError as exc:
        pytest.skip(str(exc))


@pytest.fixture(scope="session")
def shared_data():
    """Directory of the seed datasets, or skip when it is absent."""
    if not (SHARED_DATA / "0027.npz").is_file():
        pytest.skip(f"seed datasets not found in {SHARED_DATA} (expected ../shared/data next to the repo)")
    return SHARED_DATA
