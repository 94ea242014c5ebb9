"""Shared pytest setup: import vislam_tools from <repo>/tools, find generated LCM types and seed data
the same way the tools do (VISLAM_LCM_PYTHON_DIR, else $VISLAM_BUILD_DIR or <repo>/build)."""

import os
import subprocess
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
def build_dir(vislam_types):
    """The build directory with vislam-run ($VISLAM_BUILD_DIR, else <repo>/build), or skip."""
    build = Path(os.environ.get("VISLAM_BUILD_DIR") or os.environ.get("VL_BUILD_DIR") or REPO / "build")
    if not (build / "bin" / "vislam-run").is_file():
        pytest.skip(f"{build}/bin/vislam-run not built")
    return build


@pytest.fixture(scope="session")
def shared_data():
    """Directory of the seed datasets, or skip when it is absent."""
    if not (SHARED_DATA / "0027.npz").is_file():
        pytest.skip(f"seed datasets not found in {SHARED_DATA} (expected ../shared/data next to the repo)")
    return SHARED_DATA


def evo_rmse(tool, args, home):
    """Run one of evo's command line tools (evo_ape, evo_rpe) from this Python's environment, with
    HOME at home (evo keeps its settings in ~/.evo), and return the rmse it prints; skip without evo."""
    exe = Path(sys.executable).parent / tool
    if not exe.is_file():
        pytest.skip(f"{exe} not installed (pip install -r tools/requirements.txt)")
    res = subprocess.run([str(exe)] + [str(a) for a in args], capture_output=True, text=True, timeout=120,
                         env={"HOME": str(home), "PATH": "/usr/bin:/bin"})
    assert res.returncode == 0, res.stdout + res.stderr
    rows = dict(line.split() for line in res.stdout.splitlines() if len(line.split()) == 2)
    return float(rows["rmse"])
