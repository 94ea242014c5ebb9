"""Rotation and rigid-transform helpers (numpy; scipy for the nearest rotation).

Conventions: 4x4 homogeneous matrices; twists are [v (m/s), w (rad/s)] as in the seed project;
quaternions are (w, x, y, z) unless a function name says `xyzw` (the TUM file order).
"""

import numpy as np
from scipy.spatial.transform import Rotation

_EPS = 1e-10


def hat3(w):
    """3-vector -> 3x3 skew-symmetric matrix."""
    wx, wy, wz = w
    return np.array([[0.0, -wz, wy], [wz, 0.0, -wx], [-wy, wx, 0.0]])


def hat6(u):
    """Twist [v, w] -> 4x4 se(3) matrix."""
    m = np.zeros((4, 4))
    m[:3, :3] = hat3(u[3:6])
    m[:3, 3] = u[0:3]
    return m


def so3_exp(phi):
    """Rodrigues: rotation vector (rad) -> 3x3 rotation."""
    phi = np.asarray(phi, dtype=float)
    theta = np.linalg.norm(phi)
    k = hat3(phi)
    if theta < 1e-8:
        return np.eye(3) + k + 0.5 * k @ k
    return (np.eye(3) + np.sin(theta) / theta * k
            + (1.0 - np.cos(theta)) / theta ** 2 * k @ k)


def so3_log(r):
    """3x3 rotation -> rotation vector (rad), valid up to and including angle pi."""
    cos_theta = np.clip((np.trace(r) - 1.0) * 0.5, -1.0, 1.0)
    theta = np.arccos(cos_theta)
    axis_sin = np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]]) * 0.5
    if theta < 1e-6:
        return axis_sin
    if np.pi - theta < 1e-4:
        # Near pi the antisymmetric part vanishes: take the axis from the symmetric part.
        b = (r + np.eye(3)) * 0.5
        i = int(np.argmax(np.diag(b)))
        axis = b[:, i] / np.sqrt(max(b[i, i], _EPS))
        axis /= np.linalg.norm(axis)
        if np.dot(axis, axis_sin) < 0:
            axis = -axis
        return axis * theta
    return axis_sin * (theta / np.sin(theta))


def se3_exp(u):
    """Twist [v, w] (already multiplied by the time step) -> 4x4 SE(3) matrix."""
    u = np.asarray(u, dtype=float)
    v, phi = u[:3], u[3:6]
    theta = np.linalg.norm(phi)
    k = hat3(phi)
    if theta < 1e-8:
        jac = np.eye(3) + 0.5 * k + k @ k / 6.0
    else:
        jac = (np.eye(3) + (1.0 - np.cos(theta)) / theta ** 2 * k
               + (theta - np.sin(theta)) / theta ** 3 * k @ k)
    t = np.eye(4)
    t[:3, :3] = so3_exp(phi)
    t[:3, 3] = jac @ v
    return t


def se3_log(t):
    """4x4 SE(3) matrix -> twist [v, w] (the inverse of se3_exp, rotation angle below pi)."""
    t = np.asarray(t, dtype=float)
    phi = so3_log(t[:3, :3])
    theta = np.linalg.norm(phi)
    k = hat3(phi)
    if theta < 1e-6:
        jac_inv = np.eye(3) - 0.5 * k + k @ k / 12.0
    else:
        jac_inv = (np.eye(3) - 0.5 * k
                   + (1.0 / theta ** 2 - (1.0 + np.cos(theta)) / (2.0 * theta * np.sin(theta))) * k @ k)
    return np.concatenate([jac_inv @ t[:3, 3], phi])


def se3_inv(t):
    """Inverse of a 4x4 rigid transform (or a stack of them, shape (..., 4, 4))."""
    t = np.asarray(t, dtype=float)
    out = np.zeros_like(t)
    rt = np.swapaxes(t[..., :3, :3], -1, -2)
    out[..., :3, :3] = rt
    out[..., :3, 3] = -np.einsum("...ij,...j->...i", rt, t[..., :3, 3])
    out[..., 3, 3] = 1.0
    return out


def nearest_rotation(r):
    """The rotation nearest a 3x3 (or (N, 3, 3)) matrix that is one up to rounding, as scipy and evo
    read it (scipy's Rotation.from_matrix)."""
    return Rotation.from_matrix(np.asarray(r, dtype=float)).as_matrix()


def make_pose(r, p):
    """Rotation (3x3) and position (3) -> 4x4."""
    t = np.eye(4)
    t[:3, :3] = r
    t[:3, 3] = p
    return t


def quat_to_rot(q):
    """Quaternion (w, x, y, z), any norm > 0 -> 3x3 rotation."""
    q = np.asarray(q, dtype=float)
    n = np.linalg.norm(q)
    if n < _EPS:
        raise ValueError("zero-norm quaternion")
    w, x, y, z = q / n
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def rot_to_quat(r):
    """3x3 rotation -> unit quaternion (w, x, y, z) with w >= 0 (Shepperd's method, stable everywhere)."""
    r = np.asarray(r, dtype=float)
    tr = np.trace(r)
    if tr > 0:
        s = np.sqrt(tr + 1.0) * 2
        q = np.array([0.25 * s, (r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s])
    elif r[0, 0] > r[1, 1] and r[0, 0] > r[2, 2]:
        s = np.sqrt(1.0 + r[0, 0] - r[1, 1] - r[2, 2]) * 2
        q = np.array([(r[2, 1] - r[1, 2]) / s, 0.25 * s, (r[0, 1] + r[1, 0]) / s, (r[0, 2] + r[2, 0]) / s])
    elif r[1, 1] > r[2, 2]:
        s = np.sqrt(1.0 + r[1, 1] - r[0, 0] - r[2, 2]) * 2
        q = np.array([(r[0, 2] - r[2, 0]) / s, (r[0, 1] + r[1, 0]) / s, 0.25 * s, (r[1, 2] + r[2, 1]) / s])
    else:
        s = np.sqrt(1.0 + r[2, 2] - r[0, 0] - r[1, 1]) * 2
        q = np.array([(r[1, 0] - r[0, 1]) / s, (r[0, 2] + r[2, 0]) / s, (r[1, 2] + r[2, 1]) / s, 0.25 * s])
    q /= np.linalg.norm(q)
    return -q if q[0] < 0 else q


def quat_wxyz_to_xyzw(q):
    """(w, x, y, z) -> (x, y, z, w), the TUM order."""
    q = np.asarray(q, dtype=float)
    return np.concatenate([q[..., 1:4], q[..., 0:1]], axis=-1)


def quat_xyzw_to_wxyz(q):
    """(x, y, z, w) -> (w, x, y, z)."""
    q = np.asarray(q, dtype=float)
    return np.concatenate([q[..., 3:4], q[..., 0:3]], axis=-1)


def body_twists(times, poses):
    """The body twist [v, w] (N-1, 6) that moves each of N world-from-body poses to the next over its
    interval: log(T_i^-1 T_i+1) / (t_i+1 - t_i), the motion model's constant velocity (the inverse of
    integrate_dead_reckoning's step)."""
    poses = np.asarray(poses, dtype=float)
    rel = se3_inv(poses[:-1]) @ poses[1:]
    return np.array([se3_log(r) for r in rel]) / np.diff(np.asarray(times, dtype=float))[:, None]


def integrate_dead_reckoning(time_stamps, linear_velocity, rotational_velocity):
    """Seed motion model: w_T_i(t+1) = w_T_i(t) exp(tau_t hat(u_t)), w_T_i(0) = I.

    time_stamps (T,), velocities (3, T). Returns (T, 4, 4) world-from-IMU poses.
    """
    ts = np.asarray(time_stamps, dtype=float).reshape(-1)
    v = np.asarray(linear_velocity, dtype=float)
    w = np.asarray(rotational_velocity, dtype=float)
    n = ts.shape[0]
    poses = np.empty((n, 4, 4))
    poses[0] = np.eye(4)
    for k in range(n - 1):
        tau = ts[k + 1] - ts[k]
        u = np.concatenate([v[:, k], w[:, k]]) * tau
        poses[k + 1] = poses[k] @ se3_exp(u)
    return poses
