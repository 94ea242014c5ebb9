"""Locate and import the Python message types that lcm-gen writes at build time.

Search order (first hit wins):
    1. $VISLAM_LCM_PYTHON_DIR                      (explicit override, e.g. a scratch lcm-gen output)
    2. $VISLAM_BUILD_DIR/lcm_types/python          (the build directory the wrappers use;
                                                    $VL_BUILD_DIR, set by tools/test.sh, also works)
    3. <repo>/build/lcm_types/python               (default build directory)
"""

import importlib
import os
import sys
from pathlib import Path

from . import ToolError

REPO_ROOT = Path(__file__).resolve().parents[2]


def types_dir():
    """Directory expected to hold the generated `vislam` and `bot_core` Python packages."""
    override = os.environ.get("VISLAM_LCM_PYTHON_DIR")
    if override:
        return Path(override)
    build = os.environ.get("VISLAM_BUILD_DIR") or os.environ.get("VL_BUILD_DIR")
    build_dir = Path(build) if build else REPO_ROOT / "build"
    return build_dir / "lcm_types" / "python"


def load():
    """Import and return the generated `vislam` package, or raise ToolError saying how to get it."""
    where = types_dir()
    if (where / "vislam" / "__init__.py").is_file():
        entry = str(where.resolve())
        if entry not in sys.path:
            # Front of the path so an explicit override beats whatever PYTHONPATH holds.
            sys.path.insert(0, entry)
    else:
        raise ToolError(
            f"generated LCM Python types not found in {where}: build first: cmake --build build "
            "(or set VISLAM_BUILD_DIR to your build directory, or VISLAM_LCM_PYTHON_DIR to an "
            "lcm-gen --python output directory)")
    try:
        vislam = importlib.import_module("vislam")
        for name in ("calibration_t", "imu_t", "stereo_frame_t", "pose_t"):
            importlib.import_module(f"vislam.{name}")
    except ImportError as exc:
        raise ToolError(f"cannot import generated LCM types from {where}: {exc}; "
                        "rebuild: cmake --build build") from exc
    return vislam


def load_lcm():
    """Import the lcm Python module (EventLog), or raise ToolError."""
    try:
        return importlib.import_module("lcm")
    except ImportError as exc:
        raise ToolError("python module 'lcm' not found: use the project venv "
                        "(tools/test.sh creates .venv from tools/requirements.txt)") from exc
