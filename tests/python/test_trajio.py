import numpy as np
import pytest

from vislam_tools import ToolError
from vislam_tools.geometry import make_pose, se3_inv, so3_exp
from vislam_tools.trajio import (Calibration, read_ground_truth, read_kitti, read_map, read_ply, read_tum,
                                 sniff_trajectory_format, write_tum)

RNG = np.random.default_rng(3)


def random_poses(n):
    return np.array([make_pose(so3_exp(RNG.normal(size=3)), RNG.normal(size=3) * 5) for _ in range(n)])


def test_tum_write_read_round_trip(tmp_path):
    times = 1317386425.5625 + np.arange(5) * 0.1
    poses = random_poses(5)
    path = tmp_path / "t.tum"
    write_tum(path, times, poses)
    traj = read_tum(path)
    np.testing.assert_allclose(traj.times, times, atol=1e-6)
    np.testing.assert_allclose(traj.poses, poses, atol=1e-7)


def test_tum_parsing_comments_order_and_repeated_times(tmp_path):
    path = tmp_path / "t.tum"
    path.write_text("# time tx ty tz qx qy qz qw\n"
                    "2.0 1 2 3 0 0 0 1\n"
                    "\n"
                    "1.0 0 0 0 0 0 0.7071067811865476 0.7071067811865476\n"
                    "2.0 4 5 6 0 0 0 1\n")
    traj = read_tum(path)
    np.testing.assert_array_equal(traj.times, [1.0, 2.0])
    np.testing.assert_allclose(traj.poses[0][:3, :3], [[0, -1, 0], [1, 0, 0], [0, 0, 1]], atol=1e-12)
    # Repeated time: the later line (e.g. the post-update pose) wins.
    np.testing.assert_array_equal(traj.positions[1], [4, 5, 6])


@pytest.mark.parametrize("text", ["1 2 3\n", "1 2 3 4 5 6 7 x\n", "1 0 0 0 0 0 0 0\n", ""])
def test_tum_rejects_malformed_input(tmp_path, text):
    path = tmp_path / "bad.tum"
    path.write_text(text)
    with pytest.raises(ToolError):
        read_tum(path)


def test_missing_file_is_a_tool_error(tmp_path):
    with pytest.raises(ToolError, match="cannot read"):
        read_tum(tmp_path / "nope.tum")


def kitti_line(p, t=None):
    nums = ([t] if t is not None else []) + list(p[:3, :4].reshape(-1))
    return " ".join(f"{x:.12g}" for x in nums) + "\n"


def test_kitti_parsing_with_and_without_time(tmp_path):
    poses = random_poses(4)
    with_time = tmp_path / "k13.txt"
    with_time.write_text("".join(kitti_line(p, 0.1 * i) for i, p in enumerate(poses)))
    times, parsed = read_kitti(with_time)
    np.testing.assert_allclose(times, [0.0, 0.1, 0.2, 0.3])
    np.testing.assert_allclose(parsed, poses, atol=1e-10)
    no_time = tmp_path / "k12.txt"
    no_time.write_text("".join(kitti_line(p) for p in poses))
    times, parsed = read_kitti(no_time)
    assert times is None
    np.testing.assert_allclose(parsed, poses, atol=1e-10)
    assert sniff_trajectory_format(with_time) == "kitti"
    assert sniff_trajectory_format(no_time) == "kitti"


def test_kitti_rotations_are_made_exact(tmp_path):
    poses = random_poses(5)
    path = tmp_path / "k.txt"
    path.write_text("".join(" ".join(f"{x:.6e}" for x in p[:3, :4].reshape(-1)) + "\n" for p in poses))
    _, parsed = read_kitti(path)
    r = parsed[:, :3, :3]
    np.testing.assert_allclose(np.einsum("nji,njk->nik", r, r), np.broadcast_to(np.eye(3), r.shape), atol=1e-14)
    np.testing.assert_allclose(np.linalg.det(r), 1.0, atol=1e-14)
    np.testing.assert_allclose(parsed, poses, atol=1e-5)


def test_kitti_rejects_mixed_column_counts(tmp_path):
    p = np.eye(4)
    path = tmp_path / "k.txt"
    path.write_text(kitti_line(p, 0.0) + kitti_line(p))
    with pytest.raises(ToolError, match="earlier lines"):
        read_kitti(path)


def test_kitti_ground_truth_becomes_imu_poses_in_imu0_frame(tmp_path):
    cam_T_imu = make_pose(so3_exp([1.2, -1.2, 1.2]), [1.1, -0.3, 0.7])
    imu_poses = np.concatenate([np.eye(4)[None], random_poses(5)])  # w_T_i, w = IMU frame at step 0
    # What KITTI stores: c0_T_c(i) = cam_T_imu * w_T_i(i) * imu_T_cam.
    cam_poses = cam_T_imu @ imu_poses @ se3_inv(cam_T_imu)
    path = tmp_path / "gt.txt"
    path.write_text("".join(kitti_line(p, 0.1 * i) for i, p in enumerate(cam_poses)))
    step_times = 100.0 + np.arange(6) * 0.1
    gt = read_ground_truth(path, Calibration(cam_T_imu, t0=100.0, step_times=step_times))
    np.testing.assert_allclose(gt.poses, imu_poses, atol=1e-9)
    np.testing.assert_allclose(gt.times, step_times)
    # Without step times the time column is offset by the first step's time.
    gt = read_ground_truth(path, Calibration(cam_T_imu, t0=100.0))
    np.testing.assert_allclose(gt.times, step_times, atol=1e-12)
    with pytest.raises(ToolError, match="--calib"):
        read_ground_truth(path, None)


def test_tum_ground_truth_is_taken_as_is(tmp_path):
    path = tmp_path / "gt.tum"
    poses = random_poses(3)
    write_tum(path, [1.0, 2.0, 3.0], poses)
    gt = read_ground_truth(path)
    np.testing.assert_allclose(gt.poses, poses, atol=1e-7)


def test_ply_ascii_with_extra_properties_and_other_elements(tmp_path):
    path = tmp_path / "m.ply"
    path.write_text("ply\nformat ascii 1.0\ncomment made by a test\n"
                    "element vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
                    "property double first_utime\nproperty uchar red\n"
                    "element face 1\nproperty list uchar int vertex_indices\nend_header\n"
                    "1 2 3 1000000 255\n4 5 6 2000000 0\n-1.5 0 2.25 3000000 7\n3 0 1 2\n")
    props = read_ply(path)
    assert set(props) == {"x", "y", "z", "first_utime", "red"}
    np.testing.assert_array_equal(props["x"], [1, 4, -1.5])
    np.testing.assert_array_equal(props["z"], [3, 6, 2.25])
    np.testing.assert_array_equal(props["first_utime"], [1e6, 2e6, 3e6])


def test_ply_binary_little_endian(tmp_path):
    xyz = np.array([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]], dtype="<f4")
    ids = np.array([7, 9], dtype="<i4")
    rec = np.zeros(2, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("id", "<i4")])
    rec["x"], rec["y"], rec["z"], rec["id"] = xyz[:, 0], xyz[:, 1], xyz[:, 2], ids
    header = ("ply\nformat binary_little_endian 1.0\nelement vertex 2\nproperty float x\n"
              "property float y\nproperty float z\nproperty int id\nend_header\n").encode()
    path = tmp_path / "b.ply"
    path.write_bytes(header + rec.tobytes())
    props = read_ply(path)
    np.testing.assert_array_equal(props["y"], [2.0, 5.0])
    np.testing.assert_array_equal(props["id"], [7, 9])


@pytest.mark.parametrize("text, match", [
    ("ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nend_header\n1 2\n", "'z' missing"),
    ("ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\n"
     "end_header\n1 2 3\n", "declares 2"),
    ("hello\n", "not a PLY"),
])
def test_ply_errors(tmp_path, text, match):
    path = tmp_path / "bad.ply"
    path.write_text(text)
    with pytest.raises(ToolError, match=match):
        read_ply(path)


def _landmarks_batch(vislam, first, count, sequence):
    m = vislam.landmarks_t()
    m.utime, m.sequence, m.first_index, m.count = 1_317_384_000_100_000 + sequence, sequence, first, count
    m.world = sequence
    for i in range(count):
        m.id[i] = first + i
        m.position[i] = [1.0 + i, -2.0, 30.0 + 0.5 * i]
        m.covariance[i] = [4.0, 0.1, 0.2, 9.0, 0.3, 12.0]  # xx xy xz yy yz zz: trace 25
        m.observations[i] = 3 + i
        m.first_utime[i] = 1_317_384_000_000_000 + 100_000 * i
        m.last_utime[i] = m.first_utime[i] + 500_000
    return m


def test_map_from_a_recording_of_vislamd(tmp_path, vislam_types):
    """read_map reads a recorded VISLAM_LANDMARKS stream as vislam-run's PLY columns, in order;
    other channels and types are skipped; a PLY still reads as before."""
    import lcm
    from vislam_tools import channels
    path = tmp_path / "daemon.lcmlog"
    log = lcm.EventLog(str(path), "w", overwrite=True)
    log.write_event(1, channels.LANDMARKS, _landmarks_batch(vislam_types, 0, 3, 0).encode())
    log.write_event(2, channels.POSE, vislam_types.pose_t().encode())
    log.write_event(3, channels.LANDMARKS, _landmarks_batch(vislam_types, 3, 2, 1).encode())
    log.close()
    m = read_map(path)
    np.testing.assert_array_equal(m["id"], [0, 1, 2, 3, 4])
    np.testing.assert_allclose(m["x"], [1, 2, 3, 1, 2])
    np.testing.assert_allclose(m["z"], [30, 30.5, 31, 30, 30.5])
    np.testing.assert_allclose(m["sigma"], 5.0)
    np.testing.assert_array_equal(m["observations"], [3, 4, 5, 3, 4])
    np.testing.assert_allclose(m["first_time"], 1_317_384_000.0 + 0.1 * np.array([0, 1, 2, 0, 1]))
    np.testing.assert_array_equal(m["world"], [0, 0, 0, 1, 1])
    with pytest.raises(ToolError, match="no vislam.landmarks_t"):
        read_map(path, channel="CAR1_LANDMARKS")  # no such channel in the recording
    ply = tmp_path / "m.ply"
    ply.write_text("ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n"
                   "property float z\nend_header\n1 2 3\n")
    np.testing.assert_array_equal(read_map(ply)["z"], [3])
