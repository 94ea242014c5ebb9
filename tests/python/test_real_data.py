"""Checks against the seed datasets in ../shared/data (skipped when absent)."""

import json
import subprocess

import numpy as np
import pytest

from conftest import evo_rmse
from vislam_tools import lcmtypes
from vislam_tools.evaluate import main as evaluate
from vislam_tools.evaluate import read_frame_stats
from vislam_tools.geometry import integrate_dead_reckoning
from vislam_tools.metrics import associate, ate
from vislam_tools.npz2lcm import convert
from vislam_tools.trajio import load_calibration, read_ground_truth


def test_dead_reckoning_ate_on_0027_matches_readme(shared_data):
    gt_path = shared_data / "gt" / "kitti_odometry_07.txt"
    if not gt_path.is_file():
        pytest.skip(f"ground truth {gt_path} absent")
    d = np.load(shared_data / "0027.npz")
    ts = d["time_stamps"][0]
    poses = integrate_dead_reckoning(ts, d["linear_velocity"], d["rotational_velocity"])
    gt = read_ground_truth(gt_path, load_calibration(shared_data / "0027.npz"))
    e, g, mode = associate(ts, gt.times)
    assert mode == "time" and len(e) == 1101
    # GT step 0 is the identity in the IMU-0 frame, like the dead-reckoning start.
    np.testing.assert_allclose(gt.poses[0], np.eye(4), atol=1e-6)
    stats, _, _, _ = ate(poses[e, :3, 3], gt.positions[g])
    assert stats["rmse"] == pytest.approx(16.4, abs=0.5)  # README: about 16 m


def test_evo_ape_on_the_written_ground_truth_agrees_on_0027(shared_data, tmp_path):
    gt_path = shared_data / "gt" / "kitti_odometry_07.txt"
    if not gt_path.is_file():
        pytest.skip(f"ground truth {gt_path} absent")
    npz = shared_data / "0027.npz"
    dr, gt, js = tmp_path / "dr.tum", tmp_path / "gt.tum", tmp_path / "ate.json"
    assert evaluate(["deadreckon", "--data", str(npz), "--out", str(dr)]) == 0
    assert evaluate(["gt", "--gt", str(gt_path), "--calib", str(npz), "--out", str(gt)]) == 0
    assert evaluate(["ate", "--estimate", str(dr), "--gt", str(gt_path), "--calib", str(npz), "--json", str(js)]) == 0
    res = json.loads(js.read_text())
    assert res["pairs"] == 1101
    assert evo_rmse("evo_ape", ["tum", gt, dr, "-a"], tmp_path) == pytest.approx(res["ate"]["rmse"], abs=1e-6)


def test_velocities_of_0027_against_the_truth_match_the_data_readme(shared_data, tmp_path):
    """`evaluate velocities` on 0027 against KITTI 07: the noise the data README states (about 0.5 m/s
    and 0.05 rad/s per sample; measured 0.51 and 0.053), its angular offsets (about 0.005 rad/s on
    each axis), and the horizontal lever arm of the velocities' point in the data's body frame
    (-1.47, 1.50 m), which the seed's cam_T_imu translation puts there (KITTI's calibration: -1.87,
    1.46)."""
    gt_path = shared_data / "gt" / "kitti_odometry_07.txt"
    if not gt_path.is_file():
        pytest.skip(f"ground truth {gt_path} absent")
    npz, gt, js = shared_data / "0027.npz", tmp_path / "gt.tum", tmp_path / "v.json"
    assert evaluate(["gt", "--gt", str(gt_path), "--calib", str(npz), "--out", str(gt)]) == 0
    assert evaluate(["velocities", "--velocities", str(npz), "--reference", str(gt), "--json", str(js)]) == 0
    res = json.loads(js.read_text())
    assert res["intervals"] == 1100
    np.testing.assert_allclose(res["linear_sample_std"], 0.5, rtol=0.05)
    np.testing.assert_allclose(res["angular_sample_std"], 0.05, rtol=0.1)
    np.testing.assert_allclose(res["angular_offset"], 0.005, atol=0.002)
    np.testing.assert_allclose(res["velocity_sensor"][:2], [-1.47, 1.50], atol=0.2)


def test_npz2lcm_converts_the_start_of_0027(vislam_types, shared_data, tmp_path):
    out = tmp_path / "0027.lcmlog"
    s = convert(shared_data / "0027.npz", out, max_steps=20)
    assert s["steps"] == 20 and s["events"] == 41 and s["observations"] > 20 * 30
    lcm = lcmtypes.load_lcm()
    log = lcm.EventLog(str(out), "r")
    n_obs = 0
    for ev in log:
        if ev.channel == "VISLAM_FEATURES":
            n_obs += vislam_types.stereo_frame_t.decode(ev.data).num_features
    log.close()
    assert n_obs == s["observations"]
    cal = load_calibration(out)
    np.testing.assert_array_equal(cal.cam_T_imu, np.load(shared_data / "0027.npz")["cam_T_imu"])


def test_pixel_prior_10x_too_large_on_0027(build_dir, shared_data, tmp_path):
    """Issue 6's noise sweep on the real drive with all tracks: from a pixel prior 10x too large
    (15 px against the default 1.5) the estimate leaves it within a few dozen frames, and the drive
    ends within 1.3x of the default's ATE (1.83 against 1.64 m; the slow average alone measured
    2.15 m, and 6.4 px still at frame 40)."""
    gt_path = shared_data / "gt" / "kitti_odometry_07.txt"
    if not gt_path.is_file():
        pytest.skip(f"ground truth {gt_path} absent")
    run = build_dir / "bin" / "vislam-run"
    npz = shared_data / "0027.npz"
    log = tmp_path / "0027.lcmlog"
    convert(npz, log)
    ini = tmp_path / "pixel_x10.ini"
    ini.write_text("[noise]\npixel = 15\n")
    rmse = {}
    for name, extra in (("default", []), ("x10", ["--config", str(ini)])):
        tum, stats, js = tmp_path / f"{name}.tum", tmp_path / f"{name}.stats", tmp_path / f"{name}.json"
        subprocess.run([str(run), str(log), "--trajectory", str(tum), "--frame-stats", str(stats), "--quiet",
                        *extra], check=True)
        assert evaluate(["ate", "--estimate", str(tum), "--gt", str(gt_path), "--calib", str(npz),
                         "--json", str(js)]) == 0
        rmse[name] = json.loads(js.read_text())["ate"]["rmse"]
        if name == "x10":
            pixel = read_frame_stats(stats)[1]["pixel_noise"]
            assert pixel[0] == pytest.approx(15.0)
            assert pixel[40] < 5.0
    assert rmse["x10"] < 1.3 * rmse["default"]
