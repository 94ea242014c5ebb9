"""The NumPy reference filter (tools/reference/vl_reference.py) computes what the C core computes.

Both run on the first frames of data/sample.lcmlog through tools/reference/compare; their poses must
agree to 1e-8 m and 1e-8 rad (measured: under 1e-9, the TUM file's print resolution). A change to the
math of either filter moves the poses far more than that: the last test changes the reference's pixel
noise by one part in a million and checks that the comparison catches it.
"""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
COMPARE = REPO / "tools" / "reference" / "compare"
SAMPLE = REPO / "data" / "sample.lcmlog"
TOLERANCE = 1e-8  # m and rad


@pytest.fixture(scope="module")
def build_dir(vislam_types):
    build = Path(os.environ.get("VISLAM_BUILD_DIR") or os.environ.get("VL_BUILD_DIR") or REPO / "build")
    if not (build / "bin" / "vislam-run").is_file():
        pytest.skip(f"{build}/bin/vislam-run not built")
    return build


def compare(build_dir, tmp_path, *args):
    """Runs the comparison; returns (exit status, its JSON figures)."""
    out = tmp_path / "compare.json"
    proc = subprocess.run([str(COMPARE), str(SAMPLE), "--build-dir", str(build_dir), "--json", str(out),
                           "--tolerance", str(TOLERANCE), *args], capture_output=True, text=True,
                          env={**os.environ, "VISLAM_PYTHON": sys.executable})
    assert out.is_file(), proc.stderr
    return proc.returncode, json.loads(out.read_text())


@pytest.mark.parametrize("preset,steps", [("default", 50), ("seed", 30)])
def test_reference_agrees_with_vislam(build_dir, tmp_path, preset, steps):
    rc, fig = compare(build_dir, tmp_path, "--preset", preset, "--max-steps", str(steps))
    agree = fig["agreement"]
    assert agree["frames_compared"] == steps and agree["times_equal"]
    assert agree["position_max_m"] < TOLERANCE
    assert agree["rotation_max_rad"] < TOLERANCE
    assert fig["reference_counters"]["observations_used"] > 20 * steps  # the vision is in use
    assert rc == 0


def test_comparison_catches_a_change_of_the_math(build_dir, tmp_path):
    rc, fig = compare(build_dir, tmp_path, "--max-steps", "20", "--set", "pixel=1.5000015")
    assert fig["agreement"]["position_max_m"] > 10 * TOLERANCE
    assert rc == 1
