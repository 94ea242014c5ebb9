import json

import numpy as np
import pytest

from vislam_tools import ToolError
from vislam_tools.conditions import (GIVEN_ANGULAR_STD, GIVEN_LINEAR_STD, clean_velocities, keep_every, main,
                                     make_condition, observations_per_step, sparse_tracker)
from vislam_tools.geometry import integrate_dead_reckoning, se3_exp, se3_inv
from vislam_tools.metrics import ate
from vislam_tools.trajio import load_npz, read_ground_truth, load_calibration

T, M, N_GT = 40, 30, 36  # steps in the dataset, track ids, ground-truth poses (fewer, as on 0027)


def _cam_T_imu():
    # The seed's rig: camera z forward = IMU x, camera x right = IMU -y, plus a lever arm.
    r = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])
    t = np.eye(4)
    t[:3, :3] = r @ se3_exp(np.array([0, 0, 0, 0.01, -0.02, 0.015]))[:3, :3]
    t[:3, 3] = [0.05, -0.3, -0.8]
    return t


@pytest.fixture()
def synthetic(tmp_path):
    """A dataset and a KITTI ground truth of a curvy 3-D drive, with random features."""
    rng = np.random.default_rng(5)
    ts = 1000.0 + np.cumsum(np.r_[0.0, rng.uniform(0.099, 0.109, T - 1)])
    cam_T_imu = _cam_T_imu()
    true_v = np.vstack([rng.uniform(4, 8, T), rng.normal(0, 0.3, T), rng.normal(0, 0.2, T)])
    true_w = np.vstack([rng.normal(0, 0.05, T), rng.normal(0, 0.05, T), rng.uniform(-0.6, 0.6, T)])
    w_T_imu = integrate_dead_reckoning(ts, true_v, true_w)
    # KITTI poses: left camera in the frame of camera 0, from any world frame
    offset = se3_exp(np.array([3.0, -1.0, 2.0, 0.2, -0.1, 0.7]))
    w_T_cam = offset @ w_T_imu @ se3_inv(cam_T_imu)
    c0_T_cam = se3_inv(w_T_cam[0]) @ w_T_cam
    gt_path = tmp_path / "gt.txt"
    with open(gt_path, "w") as f:
        for i in range(N_GT):
            f.write(" ".join(f"{x:.17g}" for x in np.r_[ts[i] - ts[0], c0_T_cam[i, :3, :4].reshape(-1)]) + "\n")
    feats = -np.ones((4, M, T))
    seen = rng.random((M, T)) < 0.5
    feats[:, seen] = rng.uniform(0, 1200, (4, int(seen.sum())))
    path = tmp_path / "syn.npz"
    np.savez(path, time_stamps=ts[None, :], linear_velocity=true_v + rng.normal(0, 0.5, (3, T)),
             rotational_velocity=true_w + rng.normal(0, 0.05, (3, T)), features=feats,
             K=np.array([[700.0, 0, 600], [0, 700, 180], [0, 0, 1]]), b=np.float64(0.54), cam_T_imu=cam_T_imu)
    return path, gt_path, true_v, true_w


def test_clean_velocities_reproduce_the_ground_truth(synthetic, tmp_path):
    path, gt_path, true_v, true_w = synthetic
    out = tmp_path / "clean.npz"
    assert main([str(path), str(out), "--velocities", "clean", "--gt", str(gt_path)]) == 0
    d = load_npz(out)
    assert d["time_stamps"].shape == (1, N_GT)
    assert d["linear_velocity"].shape == d["rotational_velocity"].shape == (3, N_GT)
    assert d["features"].shape == (4, M, N_GT)
    # the twists that made the drive come back (the last one of the cut output holds the one before)
    np.testing.assert_allclose(d["linear_velocity"][:, :-1], true_v[:, :N_GT - 1], atol=1e-9)
    np.testing.assert_allclose(d["rotational_velocity"][:, :-1], true_w[:, :N_GT - 1], atol=1e-9)
    np.testing.assert_array_equal(d["linear_velocity"][:, -1], d["linear_velocity"][:, -2])
    # dead reckoning equals the ground truth as evaluate reads it, pose by pose, with no alignment
    poses = integrate_dead_reckoning(d["time_stamps"][0], d["linear_velocity"], d["rotational_velocity"])
    gt = read_ground_truth(gt_path, load_calibration(path))
    np.testing.assert_allclose(poses, gt.poses, atol=1e-9)
    stats, _, _, _ = ate(poses[:, :3, 3], gt.poses[:, :3, 3])
    assert stats["rmse"] < 1e-9
    # everything else is the input's, cut to the ground truth's length
    src = np.load(path)
    np.testing.assert_array_equal(d["features"], src["features"][:, :, :N_GT])
    for k in ("K", "b", "cam_T_imu"):
        np.testing.assert_array_equal(d[k], src[k])


def test_clean_imu_velocities_are_the_real_imus(synthetic, tmp_path):
    """clean-imu takes the ground truth through cam_T_imu with its translation t replaced by -R t: a
    point r = t + R^T t away (IMU axes), so its velocities are the clean ones less w x r, while every
    other array, cam_T_imu included, stays the dataset's."""
    path, gt_path, _, _ = synthetic
    clean, imu = tmp_path / "clean.npz", tmp_path / "imu.npz"
    assert main([str(path), str(clean), "--velocities", "clean", "--gt", str(gt_path)]) == 0
    assert main([str(path), str(imu), "--velocities", "clean-imu", "--gt", str(gt_path)]) == 0
    c, d = load_npz(clean), load_npz(imu)
    T = np.asarray(d["cam_T_imu"], float)
    R, t = T[:3, :3], T[:3, 3]
    r = R.T @ (t - (-R @ t))
    w = c["rotational_velocity"]
    np.testing.assert_allclose(d["rotational_velocity"], w, atol=1e-12)
    np.testing.assert_allclose(c["linear_velocity"] - d["linear_velocity"], np.cross(w.T, r).T, atol=1e-9)
    assert np.max(np.abs(c["linear_velocity"] - d["linear_velocity"])) > 1e-3  # the drive turns: they differ
    np.testing.assert_array_equal(d["cam_T_imu"], np.load(path)["cam_T_imu"])
    assert main([str(path), str(imu), "--velocities", "clean-imu"]) == 1  # needs --gt


def test_clean_velocities_need_two_poses_and_enough_steps():
    ts = np.arange(5) * 0.1
    with pytest.raises(ToolError):
        clean_velocities(ts, np.eye(4)[None], np.eye(4))
    with pytest.raises(ToolError, match="only 5 steps"):
        clean_velocities(ts, np.repeat(np.eye(4)[None], 6, axis=0), np.eye(4))


def test_keep_every_keeps_ids_divisible_by_k(synthetic):
    feats = np.load(synthetic[0])["features"]
    for k in (1, 5, 10, 20):
        out = keep_every(feats, k)
        ids = np.arange(M)
        np.testing.assert_array_equal(out[:, ids % k == 0], feats[:, ids % k == 0])
        assert np.all(out[:, ids % k != 0] == -1)
    with pytest.raises(ToolError):
        keep_every(feats, 0)
    assert observations_per_step(keep_every(feats, 1)) == pytest.approx(np.all(feats != -1, axis=0).sum() / T)


def test_noise_scale_gives_the_stated_total_std():
    class Big:  # enough samples to measure a standard deviation to about 1 %
        files = ["time_stamps", "linear_velocity", "rotational_velocity", "features", "K", "b", "cam_T_imu"]

        def __init__(self):
            n = 200000
            self.d = dict(time_stamps=np.arange(n)[None] * 0.1, linear_velocity=np.zeros((3, n)),
                          rotational_velocity=np.zeros((3, n)), features=-np.ones((4, 1, n)), K=np.eye(3),
                          b=np.float64(0.5), cam_T_imu=np.eye(4))

        def __getitem__(self, k):
            return self.d[k]

    arrays, s = make_condition(Big(), noise_scale=4.0, seed=3)
    extra = np.sqrt(15.0)
    assert s["added_noise"] == pytest.approx([GIVEN_LINEAR_STD * extra, GIVEN_ANGULAR_STD * extra])
    assert np.std(arrays["linear_velocity"]) == pytest.approx(GIVEN_LINEAR_STD * extra, rel=0.01)
    assert np.std(arrays["rotational_velocity"]) == pytest.approx(GIVEN_ANGULAR_STD * extra, rel=0.01)
    arrays1, _ = make_condition(Big(), noise_scale=1.0)
    assert np.all(arrays1["linear_velocity"] == 0)  # x1 is the given data itself


def test_noise_is_deterministic_per_seed(synthetic, tmp_path):
    path, gt_path, _, _ = synthetic
    outs = []
    for name, seed in (("a", 7), ("b", 7), ("c", 8)):
        out = tmp_path / f"{name}.npz"
        assert main([str(path), str(out), "--velocities", "clean", "--gt", str(gt_path),
                     "--velocity-noise", "0.05,0.005", "--seed", str(seed)]) == 0
        outs.append(np.load(out)["linear_velocity"])
    np.testing.assert_array_equal(outs[0], outs[1])
    assert not np.array_equal(outs[0], outs[2])


def test_given_with_density_and_summary(synthetic, tmp_path):
    path = synthetic[0]
    out, summ = tmp_path / "g.npz", tmp_path / "g.json"
    assert main([str(path), str(out), "--velocity-noise-scale", "2", "--keep-every", "5",
                 "--summary-json", str(summ)]) == 0
    d, src = np.load(out), np.load(path)
    assert sorted(d.files) == sorted(src.files)
    assert d["time_stamps"].shape == (1, T)  # given velocities: nothing cut
    assert not np.array_equal(d["linear_velocity"], src["linear_velocity"])
    s = json.loads(summ.read_text())
    assert s["keep_every"] == 5 and s["noise_scale"] == 2.0
    assert s["observations_per_step"] == pytest.approx(observations_per_step(keep_every(src["features"], 5)))


def test_sparse_tracker_keeps_its_tracks_and_fills_free_places(synthetic):
    feats = np.load(synthetic[0])["features"]
    observed = np.all(feats != -1, axis=0)
    for n in (1, 3, 8):
        out = sparse_tracker(feats, n, np.random.default_rng(3))
        kept = np.all(out != -1, axis=0)
        np.testing.assert_array_equal(out[:, kept], feats[:, kept])  # kept observations unchanged
        assert np.all(kept <= observed)
        counts = kept.sum(axis=0)
        assert counts.max() <= n
        started = np.zeros(M, dtype=bool)
        for t in range(T):
            if t > 0:
                # a kept track continues while its id is observed, and once dropped never comes back
                assert np.all(kept[kept[:, t - 1] & observed[:, t], t])
                assert not np.any(kept[:, t] & started & ~kept[:, t - 1])
            # free places are filled while unkept, never-kept ids are there to take
            free_candidates = observed[:, t] & ~started & ~kept[:, t]
            assert counts[t] == n or not free_candidates.any()
            started |= kept[:, t]
    a = sparse_tracker(feats, 3, np.random.default_rng(3))
    np.testing.assert_array_equal(a, sparse_tracker(feats, 3, np.random.default_rng(3)))
    assert not np.array_equal(a, sparse_tracker(feats, 3, np.random.default_rng(4)))
    with pytest.raises(ToolError):
        sparse_tracker(feats, 0, np.random.default_rng(0))


def test_max_tracks_after_the_noise_and_in_the_summary(synthetic, tmp_path):
    path = synthetic[0]
    out, summ, plain = tmp_path / "s.npz", tmp_path / "s.json", tmp_path / "p.npz"
    args = [str(path), "--velocity-noise-scale", "2", "--seed", "9"]
    assert main([args[0], str(out)] + args[1:] + ["--max-tracks", "4", "--summary-json", str(summ)]) == 0
    assert main([args[0], str(plain)] + args[1:]) == 0
    d, p = np.load(out), np.load(plain)
    # the tracker draws after the noise, so the velocities are the same as without it
    np.testing.assert_array_equal(d["linear_velocity"], p["linear_velocity"])
    s = json.loads(summ.read_text())
    assert s["max_tracks"] == 4
    assert s["observations_per_step"] <= 4


@pytest.mark.parametrize("extra, message", [
    (["--velocities", "clean"], "needs --gt"),
    (["--velocity-noise-scale", "0.5"], "must be >= 1"),
    (["--velocity-noise-scale", "2", "--velocity-noise", "0.1,0.01"], "not both"),
    (["--keep-every", "0"], ">= 1"),
    (["--max-tracks", "0"], "--max-tracks must be >= 1"),
])
def test_errors_are_messages(synthetic, tmp_path, capsys, extra, message):
    assert main([str(synthetic[0]), str(tmp_path / "x.npz")] + extra) == 1
    assert message in capsys.readouterr().err


def test_bad_noise_pair_is_a_usage_error(synthetic, tmp_path):
    with pytest.raises(SystemExit) as exc:
        main([str(synthetic[0]), str(tmp_path / "x.npz"), "--velocity-noise", "0.1"])
    assert exc.value.code == 2
