import numpy as np
import pytest

from vislam_tools import ToolError
from vislam_tools.geometry import (integrate_dead_reckoning, make_pose, nearest_rotation, quat_to_rot,
                                   quat_wxyz_to_xyzw, quat_xyzw_to_wxyz, rot_to_quat, se3_exp, se3_inv,
                                   se3_log, so3_exp, so3_log, hat6)
from vislam_tools.metrics import ate

RNG = np.random.default_rng(7)


def random_rotation():
    return so3_exp(RNG.normal(size=3))


def expm_series(a):
    """Reference matrix exponential (scaling and squaring + Taylor), independent of se3_exp."""
    a = a / 2 ** 10
    out, term = np.eye(a.shape[0]), np.eye(a.shape[0])
    for k in range(1, 25):
        term = term @ a / k
        out = out + term
    for _ in range(10):
        out = out @ out
    return out


def test_ate_alignment_recovers_known_rigid_transform_exactly():
    gt = RNG.normal(size=(50, 3)) * 10
    r, t = random_rotation(), np.array([3.0, -2.0, 7.5])
    est = (gt - t) @ r  # gt = R est + t
    stats, _, t_align, s = ate(est, gt)
    assert s == 1.0 and stats["rmse"] < 1e-9
    np.testing.assert_allclose(t_align[:3, :3], r, atol=1e-12)
    np.testing.assert_allclose(t_align[:3, 3], t, atol=1e-10)


def test_ate_with_scale_recovers_similarity():
    gt = RNG.normal(size=(30, 3))
    r, t, s = random_rotation(), np.array([1.0, 2.0, 3.0]), 2.5
    est = (gt - t) @ r / s  # gt = s R est + t
    stats, _, t_align, s_est = ate(est, gt, with_scale=True)
    assert s_est == pytest.approx(s, rel=1e-12) and stats["rmse"] < 1e-9
    np.testing.assert_allclose(t_align[:3, :3], r, atol=1e-12)
    np.testing.assert_allclose(t_align[:3, 3], t, atol=1e-10)


def test_ate_never_aligns_by_a_reflection():
    gt = RNG.normal(size=(20, 3))
    stats, _, t_align, _ = ate(gt * np.array([1.0, 1.0, -1.0]), gt)
    assert np.linalg.det(t_align[:3, :3]) == pytest.approx(1.0)
    assert stats["rmse"] > 0.1  # a mirror image cannot be aligned away


def test_ate_rejects_bad_input_with_a_tool_error():
    with pytest.raises(ToolError):
        ate(np.zeros((5, 3)), np.zeros((4, 3)))
    with pytest.raises(ToolError):
        ate(np.zeros((5, 2)), np.zeros((5, 2)))
    with pytest.raises(ToolError):  # all samples at one point: no alignment exists
        ate(np.zeros((5, 3)), np.ones((5, 3)))


def test_ate_is_zero_for_rigidly_transformed_copy():
    gt = np.cumsum(RNG.normal(size=(200, 3)), axis=0)
    est = (gt - 5.0) @ random_rotation().T + np.array([10.0, -4.0, 1.0])
    stats, err, _, _ = ate(est, gt)
    assert stats["rmse"] < 1e-9
    assert stats["max"] < 1e-9
    assert stats["pairs"] == 200


def test_ate_of_known_offset_without_alignment():
    gt = RNG.normal(size=(10, 3))
    stats, _, _, _ = ate(gt + np.array([3.0, 4.0, 0.0]), gt, do_align=False)
    assert stats["rmse"] == pytest.approx(5.0)
    assert stats["median"] == pytest.approx(5.0)


def test_quaternion_of_known_rotations():
    rz90 = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    np.testing.assert_allclose(rot_to_quat(rz90), [np.sqrt(0.5), 0, 0, np.sqrt(0.5)], atol=1e-15)
    np.testing.assert_allclose(rot_to_quat(np.eye(3)), [1, 0, 0, 0])
    np.testing.assert_allclose(quat_to_rot([0, 1, 0, 0]), np.diag([1.0, -1.0, -1.0]), atol=1e-15)
    # Unnormalized input is normalized.
    np.testing.assert_allclose(quat_to_rot([2, 0, 0, 0]), np.eye(3))


@pytest.mark.parametrize("angle", [0.0, 1e-9, 0.3, 2.0, np.pi - 1e-6, np.pi])
def test_quaternion_round_trip(angle):
    for _ in range(20):
        axis = RNG.normal(size=3)
        axis /= np.linalg.norm(axis)
        r = so3_exp(axis * angle)
        q = rot_to_quat(r)
        assert np.linalg.norm(q) == pytest.approx(1.0)
        assert q[0] >= 0
        np.testing.assert_allclose(quat_to_rot(q), r, atol=1e-12)


def test_quaternion_order_conversions():
    q = np.array([0.1, 0.2, 0.3, 0.4])
    np.testing.assert_array_equal(quat_wxyz_to_xyzw(q), [0.2, 0.3, 0.4, 0.1])
    np.testing.assert_array_equal(quat_xyzw_to_wxyz(quat_wxyz_to_xyzw(q)), q)
    with pytest.raises(ValueError):
        quat_to_rot([0, 0, 0, 0])


@pytest.mark.parametrize("angle", [0.0, 1e-7, 0.5, 3.0, np.pi])
def test_so3_log_inverts_exp(angle):
    axis = np.array([1.0, -2.0, 0.5])
    axis /= np.linalg.norm(axis)
    phi = axis * angle
    np.testing.assert_allclose(so3_exp(so3_log(so3_exp(phi))), so3_exp(phi), atol=1e-9)
    assert np.linalg.norm(so3_log(so3_exp(phi))) == pytest.approx(angle, abs=1e-7)


@pytest.mark.parametrize("u", [[1.0, 0.2, -0.3, 0.0, 0.0, 0.0], [1.0, 0.2, -0.3, 0.1, -0.4, 0.9],
                               [0.0, 0.0, 0.0, 1e-9, 0.0, 0.0]])
def test_se3_exp_matches_matrix_exponential(u):
    np.testing.assert_allclose(se3_exp(np.array(u)), expm_series(hat6(np.array(u))), atol=1e-12)


@pytest.mark.parametrize("u", [[1.0, 0.2, -0.3, 0.0, 0.0, 0.0], [1.0, 0.2, -0.3, 0.1, -0.4, 0.9],
                               [0.5, -2.0, 0.1, 1e-9, 0.0, 2e-9], [0.3, 0.1, 0.2, 0.0, 3.0, 0.0]])
def test_se3_log_inverts_se3_exp(u):
    np.testing.assert_allclose(se3_log(se3_exp(np.array(u))), u, atol=1e-10)


def test_se3_inv():
    t = make_pose(random_rotation(), [1.0, 2.0, 3.0])
    np.testing.assert_allclose(se3_inv(t) @ t, np.eye(4), atol=1e-14)
    stack = np.stack([t, np.eye(4)])
    np.testing.assert_allclose(se3_inv(stack)[0], np.linalg.inv(t), atol=1e-12)


def test_dead_reckoning_drives_a_circle():
    # 1 m/s forward with a 0.1 rad/s yaw: a circle of radius 10 m about (0, 10).
    n = 101
    ts = np.arange(n) * 0.1
    v = np.tile([[1.0], [0.0], [0.0]], (1, n))
    w = np.tile([[0.0], [0.0], [0.1]], (1, n))
    poses = integrate_dead_reckoning(ts, v, w)
    np.testing.assert_allclose(poses[0], np.eye(4))
    radii = np.linalg.norm(poses[:, :2, 3] - np.array([0.0, 10.0]), axis=1)
    np.testing.assert_allclose(radii, 10.0, atol=1e-9)
    assert np.linalg.norm(so3_log(poses[-1][:3, :3])) == pytest.approx(1.0)


def test_nearest_rotation_repairs_a_rounded_rotation():
    r = random_rotation()
    rounded = np.array([[float(f"{x:.6e}") for x in row] for row in r])  # KITTI's 7 digits
    assert np.abs(rounded.T @ rounded - np.eye(3)).max() > 1e-9
    fixed = nearest_rotation(rounded)
    np.testing.assert_allclose(fixed.T @ fixed, np.eye(3), atol=1e-14)
    np.testing.assert_allclose(fixed, r, atol=1e-6)
