import numpy as np
import pytest

from vislam_tools.geometry import make_pose, se3_exp, so3_exp
from vislam_tools.metrics import associate, rpe


def test_associate_by_absolute_time_with_tolerance():
    gt = np.arange(10) * 0.1 + 100.0
    est = np.array([100.001, 100.2, 100.35, 100.7005, 200.0])
    e, g, mode = associate(est, gt, "time", max_dt=0.02)
    assert mode == "time"
    np.testing.assert_array_equal(e, [0, 1, 3])
    np.testing.assert_array_equal(g, [0, 2, 7])


def test_associate_auto_falls_back_to_relative_time():
    gt = np.arange(10) * 0.1              # e.g. seconds from start
    est = 1e9 + 0.3 + np.arange(5) * 0.1  # UNIX time: no absolute overlap
    e, g, mode = associate(est, gt, "auto")
    assert mode == "relative"
    np.testing.assert_array_equal(e, np.arange(5))
    np.testing.assert_array_equal(g, np.arange(5))


def test_associate_by_index_and_one_to_one():
    e, g, mode = associate(np.arange(7.0), np.arange(4.0), "index")
    assert mode == "index" and len(e) == 4
    e, g, _ = associate(np.array([1.0, 1.001, 1.002]), np.array([1.0]), "time")
    np.testing.assert_array_equal(e, [0])
    np.testing.assert_array_equal(g, [0])


def test_rpe_zero_for_same_trajectory_in_another_world_frame():
    poses = [np.eye(4)]
    rng = np.random.default_rng(1)
    for _ in range(30):
        poses.append(poses[-1] @ se3_exp(rng.normal(size=6) * 0.2))
    poses = np.array(poses)
    moved = make_pose(so3_exp([0.3, -0.2, 1.0]), [5.0, 1.0, -2.0]) @ poses
    for d in (1, 10):
        r = rpe(moved, poses, d)
        assert r["trans_rmse"] < 1e-9 and r["rot_rmse_deg"] < 1e-5
        assert r["pairs"] == len(poses) - d
    assert rpe(poses, poses, 31) is None


def test_rpe_measures_a_known_step_error():
    gt = np.array([np.eye(4), make_pose(np.eye(3), [1.0, 0.0, 0.0])])
    est = np.array([np.eye(4), make_pose(so3_exp([0.0, 0.0, np.radians(2.0)]), [1.0, 0.5, 0.0])])
    r = rpe(est, gt, 1)
    assert r["trans_rmse"] == pytest.approx(0.5)
    assert r["rot_rmse_deg"] == pytest.approx(2.0)
