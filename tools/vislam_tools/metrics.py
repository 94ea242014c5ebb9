"""Trajectory association and error metrics (ATE, RPE)."""

import numpy as np

from . import ToolError
from .geometry import make_pose, rotation_angle, se3_inv, umeyama


def _nearest(query, ref, max_dt):
    """For each query time, index of the nearest ref time (ref sorted) or -1 if farther than max_dt."""
    idx = np.clip(np.searchsorted(ref, query), 1, max(len(ref) - 1, 1))
    if len(ref) == 1:
        idx = np.zeros_like(idx)
    else:
        left = idx - 1
        use_left = np.abs(query - ref[left]) <= np.abs(ref[idx] - query)
        idx = np.where(use_left, left, idx)
    ok = np.abs(ref[idx] - query) <= max_dt
    return np.where(ok, idx, -1)


def associate(est_times, gt_times, mode="auto", max_dt=0.02):
    """Pair estimate and ground-truth samples.

    mode: 'time'     nearest absolute time within max_dt (s), each GT sample used once
          'relative' the same after subtracting each sequence's first time
          'index'    i-th estimate with i-th GT
          'auto'     'time' if it pairs at least half the estimate, else 'relative'
    Returns (est_idx, gt_idx, mode_used).
    """
    est_times = np.asarray(est_times, dtype=float)
    gt_times = np.asarray(gt_times, dtype=float)
    if mode == "index":
        n = min(len(est_times), len(gt_times))
        return np.arange(n), np.arange(n), "index"
    if mode == "auto":
        e, g, _ = associate(est_times, gt_times, "time", max_dt)
        if len(e) >= 0.5 * len(est_times):
            return e, g, "time"
        return associate(est_times, gt_times, "relative", max_dt)
    if mode == "relative":
        q = est_times - est_times[0]
        ref = gt_times - gt_times[0]
    elif mode == "time":
        q, ref = est_times, gt_times
    else:
        raise ToolError(f"unknown association mode '{mode}'")
    g = _nearest(q, ref, max_dt)
    e = np.nonzero(g >= 0)[0]
    g = g[e]
    # A GT sample matched twice keeps its first estimate, so pairs stay one-to-one and ordered.
    _, first = np.unique(g, return_index=True)
    keep = np.sort(first)
    return e[keep], g[keep], mode


def align(est_positions, gt_positions, with_scale=False):
    """Rigid (or similarity) transform taking estimate positions onto GT: returns (4x4 T, scale)."""
    r, t, s = umeyama(est_positions, gt_positions, with_scale)
    return make_pose(r, t), s


def ate(est_positions, gt_positions, with_scale=False, do_align=True):
    """Absolute trajectory error of positions after Umeyama alignment of the estimate onto GT.

    Returns a dict of statistics (m), the per-sample errors, and the alignment (4x4, scale).
    """
    est_positions = np.asarray(est_positions, dtype=float)
    gt_positions = np.asarray(gt_positions, dtype=float)
    if do_align:
        t, s = align(est_positions, gt_positions, with_scale)
    else:
        t, s = np.eye(4), 1.0
    aligned = s * est_positions @ t[:3, :3].T + t[:3, 3]
    err = np.linalg.norm(aligned - gt_positions, axis=1)
    stats = {
        "rmse": float(np.sqrt(np.mean(err ** 2))),
        "mean": float(np.mean(err)),
        "median": float(np.median(err)),
        "max": float(np.max(err)),
        "min": float(np.min(err)),
        "std": float(np.std(err)),
        "pairs": int(err.shape[0]),
    }
    return stats, err, t, s


def rpe(est_poses, gt_poses, delta):
    """Relative pose error over pairs (i, i + delta) of associated samples.

    E_i = (G_i^-1 G_{i+d})^-1 (P_i^-1 P_{i+d}); independent of any world-frame alignment.
    Returns dict with translation (m) and rotation (deg) RMSE / mean / max, or None if too short.
    """
    n = len(est_poses)
    if delta < 1 or n <= delta:
        return None
    est_rel = se3_inv(est_poses[:-delta]) @ est_poses[delta:]
    gt_rel = se3_inv(gt_poses[:-delta]) @ gt_poses[delta:]
    err = se3_inv(gt_rel) @ est_rel
    trans = np.linalg.norm(err[:, :3, 3], axis=1)
    rot = np.degrees([rotation_angle(e[:3, :3]) for e in err])
    return {
        "delta": int(delta),
        "pairs": int(trans.shape[0]),
        "trans_rmse": float(np.sqrt(np.mean(trans ** 2))),
        "trans_mean": float(np.mean(trans)),
        "trans_max": float(np.max(trans)),
        "rot_rmse_deg": float(np.sqrt(np.mean(rot ** 2))),
        "rot_mean_deg": float(np.mean(rot)),
        "rot_max_deg": float(np.max(rot)),
    }


# 0.95 quantile of chi-square with 3 degrees of freedom: a consistent filter's position NEES
# exceeds it in about 5 % of the frames.
CHI2_3DOF_95 = 7.814727903251178


def consistency(est_poses, gt_positions, position_var):
    """Body-frame position error of an estimate against its own reported variance.

    est_poses (N, 4, 4) world-from-body; gt_positions (N, 3) in the estimate's world frame (already
    aligned); position_var (N, 3) the diagonal of the position block of a right (body-frame)
    perturbation, T = T_hat exp(xi): to first order xi_rho = R_hat^T (p - p_hat).
    Frames with a non-positive variance (e.g. the exactly known first pose) are left out of the
    statistics. Returns (summary dict, e_body (N, 3), sigma (N, 3), nees (N,), used mask (N,)).
    The NEES uses the diagonal only (the file has no correlations between axes).
    """
    est_poses = np.asarray(est_poses, dtype=float)
    gt_positions = np.asarray(gt_positions, dtype=float)
    var = np.asarray(position_var, dtype=float)
    n = est_poses.shape[0]
    if gt_positions.shape != (n, 3) or var.shape != (n, 3):
        raise ToolError(f"consistency needs (N, 3) positions and variances for N = {n} poses, "
                        f"got {gt_positions.shape} and {var.shape}")
    diff = gt_positions - est_poses[:, :3, 3]
    e_body = np.einsum("nji,nj->ni", est_poses[:, :3, :3], diff)  # R^T d
    used = np.all(var > 0, axis=1) & np.all(np.isfinite(var), axis=1)
    if not used.any():
        raise ToolError("no frame has a positive position variance")
    sigma = np.sqrt(np.where(var > 0, var, np.nan))
    nees = np.full(n, np.nan)
    nees[used] = np.sum(e_body[used] ** 2 / var[used], axis=1)
    inside = np.abs(e_body[used]) <= 3.0 * sigma[used]
    m = int(used.sum())
    summary = {
        "frames": int(n),
        "frames_used": m,
        "inside_3sigma": {ax: float(inside[:, i].mean()) for i, ax in enumerate("xyz")},
        "nees_mean": float(np.mean(nees[used])),
        "nees_median": float(np.median(nees[used])),
        "nees_over_chi2_95": float(np.mean(nees[used] > CHI2_3DOF_95)),
        "nees_expected": 3.0,
        "error_rms_body": {ax: float(np.sqrt(np.mean(e_body[used, i] ** 2))) for i, ax in enumerate("xyz")},
        "sigma_rms_body": {ax: float(np.sqrt(np.mean(var[used, i]))) for i, ax in enumerate("xyz")},
    }
    return summary, e_body, sigma, nees, used
