"""Trajectory association and error metrics: ATE and RPE through evo, the filter's consistency.

Alignment (Umeyama), the absolute and the relative pose error are evo's (github.com/MichaelGrupp/evo,
PyPI `evo`), the same code as `evo_ape` and `evo_rpe`, so the numbers printed here are the ones those
commands give on the TUM files (`evaluate gt` writes the ground truth). What stays here is vislam's
own: how estimate and ground truth are paired (by time, time since the start, or index; one-to-one),
and the consistency statistics.
"""

import numpy as np
from evo import EvoException
from evo.core import metrics as evo_metrics
from evo.core import sync as evo_sync
from evo.core.trajectory import PosePath3D

from . import ToolError
from .geometry import body_twists, hat3, make_pose


def associate(est_times, gt_times, mode="auto", max_dt=0.02):
    """Pair estimate and ground-truth samples.

    mode: 'time'     nearest absolute time within max_dt (s), each GT sample used once
          'relative' the same after subtracting each sequence's first time
          'index'    i-th estimate with i-th GT
          'auto'     'time' if it pairs at least half the estimate, else 'relative'
    Nearest-time matching is evo's (evo.core.sync, what evo_ape does with TUM files).
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
        offset = est_times[0] - gt_times[0]
    elif mode == "time":
        offset = 0.0
    else:
        raise ToolError(f"unknown association mode '{mode}'")
    e, g = evo_sync.matching_time_indices(est_times, gt_times, max_dt, offset)
    e, g = np.asarray(e, dtype=int), np.asarray(g, dtype=int)
    # A GT sample matched twice keeps its first estimate, so pairs stay one-to-one and ordered.
    _, first = np.unique(g, return_index=True)
    keep = np.sort(first)
    return e[keep], g[keep], mode


def _path(poses_or_positions):
    """An evo path from (N, 4, 4) poses or (N, 3) positions (then with identity rotations)."""
    a = np.asarray(poses_or_positions, dtype=float)
    if a.ndim == 2 and a.shape[1] == 3:
        a = np.array([make_pose(np.eye(3), p) for p in a])
    if a.ndim != 3 or a.shape[1:] != (4, 4):
        raise ToolError(f"a trajectory is (N, 4, 4) poses or (N, 3) positions, got shape {a.shape}")
    return PosePath3D(poses_se3=list(a))


def _statistics(metric):
    """evo's statistics of a processed metric as plain floats, with the pair count."""
    stats = {k: float(v) for k, v in metric.get_all_statistics().items() if k != "sse"}
    stats["pairs"] = int(metric.error.shape[0])
    return stats


def ate(est_positions, gt_positions, with_scale=False, do_align=True):
    """Absolute trajectory error of positions after Umeyama alignment of the estimate onto GT.

    evo's APE on the translation part after evo's alignment (evo_ape -a, or -as with with_scale).
    est_positions, gt_positions: (N, 3) positions or (N, 4, 4) poses, paired row by row.
    Returns a dict of statistics (m: rmse, mean, median, max, min, std; pairs), the per-sample
    errors, and the alignment (4x4 rigid part, scale): aligned = scale * R p + t.
    """
    est, ref = _path(est_positions), _path(gt_positions)
    if est.num_poses != ref.num_poses:
        raise ToolError(f"ATE needs paired samples, got {est.num_poses} estimate and {ref.num_poses} GT")
    r, t, s = np.eye(3), np.zeros(3), 1.0
    try:
        if do_align:
            r, t, s = est.align(ref, correct_scale=with_scale)
        ape = evo_metrics.APE(evo_metrics.PoseRelation.translation_part)
        ape.process_data((ref, est))
    except EvoException as exc:
        raise ToolError(f"cannot compute the ATE: {exc}") from exc
    return _statistics(ape), np.asarray(ape.error, dtype=float), make_pose(r, t), float(s)


def rpe(est_poses, gt_poses, delta):
    """Relative pose error over every pair (i, i + delta) of associated samples.

    E_i = (G_i^-1 G_{i+d})^-1 (P_i^-1 P_{i+d}), independent of any world-frame alignment: evo's RPE
    with all pairs (evo_rpe --delta D --all_pairs), translation (m) and rotation angle (deg).
    Returns dict with translation and rotation RMSE / mean / max, or None if too short.
    """
    n = len(est_poses)
    if delta < 1 or n <= delta:
        return None
    est, ref = _path(est_poses), _path(gt_poses)
    out = {"delta": int(delta)}
    for relation, key, unit in ((evo_metrics.PoseRelation.translation_part, "trans", ""),
                                (evo_metrics.PoseRelation.rotation_angle_deg, "rot", "_deg")):
        metric = evo_metrics.RPE(relation, delta, evo_metrics.Unit.frames, all_pairs=True)
        try:
            metric.process_data((ref, est))
        except EvoException as exc:
            raise ToolError(f"cannot compute the RPE over {delta} steps: {exc}") from exc
        stats = _statistics(metric)
        out["pairs"] = stats["pairs"]
        for stat in ("rmse", "mean", "max"):
            out[f"{key}_{stat}{unit}"] = stats[stat]
    return out


# 0.95 quantile of chi-square with 3 degrees of freedom: a consistent filter's position NEES
# exceeds it in about 5 % of the frames.
CHI2_6DOF_99 = 16.812  # chi-square quantile, 6 degrees of freedom, 99 %
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


def segment_differences(ref_poses, other_poses, length):
    """Where two trajectories part: their relative motions over consecutive segments compared.

    ref_poses, other_poses: (N, 4, 4) world-from-body poses, paired row by row. The trajectory is
    cut into segments of `length` poses (the last may be shorter); for each, the motion
    D = T_start^-1 T_end of both (in the body frame at the segment's start, so no alignment is
    needed and an error made earlier does not count again) and their difference:
    translation |t_other - t_ref| (m), rotation angle of R_ref^T R_other (rad), length ratio
    |t_other| / |t_ref|. Returns a dict of arrays, one entry per segment: start, end (row
    indices), ref_distance (m), ref_turn (rad), d_translation (m), d_rotation (rad), scale.
    """
    ref_poses = np.asarray(ref_poses, dtype=float)
    other_poses = np.asarray(other_poses, dtype=float)
    if ref_poses.shape != other_poses.shape or ref_poses.shape[0] < 2:
        raise ToolError("segments: two paired trajectories of at least 2 poses each are needed")
    if length < 1:
        raise ToolError("segments: the segment length must be at least 1 pose")
    n = ref_poses.shape[0]
    starts = np.arange(0, n - 1, length)
    ends = np.minimum(starts + length, n - 1)
    out = {k: np.zeros(len(starts)) for k in ("ref_distance", "ref_turn", "d_translation", "d_rotation", "scale")}
    for k, (a, b) in enumerate(zip(starts, ends)):
        d_ref = np.linalg.solve(ref_poses[a], ref_poses[b])
        d_other = np.linalg.solve(other_poses[a], other_poses[b])
        dist = np.linalg.norm(d_ref[:3, 3])
        out["ref_distance"][k] = dist
        out["ref_turn"][k] = _rotation_angle(d_ref[:3, :3])
        out["d_translation"][k] = np.linalg.norm(d_other[:3, 3] - d_ref[:3, 3])
        out["d_rotation"][k] = _rotation_angle(d_ref[:3, :3].T @ d_other[:3, :3])
        out["scale"][k] = np.linalg.norm(d_other[:3, 3]) / dist if dist > 0 else np.nan
    out["start"], out["end"] = starts, ends
    return out


def _rotation_angle(r):
    """Angle (rad) of a rotation matrix."""
    return float(np.arccos(np.clip((np.trace(r) - 1.0) * 0.5, -1.0, 1.0)))


def stale_sources(features):
    """For each frame, the frame whose image it shows: a frame repeating the previous frame's pixels
    exactly for every track the two share (a stale image, vislam's frames_repeated rule) shows
    that frame's image. features: (4, M, N) of the seed datasets, -1 where a track is not seen."""
    n = features.shape[2]
    src = np.arange(n)
    for j in range(1, n):
        seen = (features[0, :, j] != -1) & (features[0, :, j - 1] != -1)
        if seen.any() and np.array_equal(features[:, seen, j], features[:, seen, j - 1]):
            src[j] = src[j - 1]
    return src


def reprojection_check(features, frame_times, fx, fy, cx, cy, baseline, cam_T_imu, trajectories, length=1,
                       min_disparity=3.0):
    """How well each trajectory's relative motion explains the stereo tracks, segment by segment.

    For each segment of `length` frames (both ends moved to the frame whose image they show, see
    stale_sources), the tracks seen at both ends with at least min_disparity px at the start are
    triangulated there, moved by the trajectory's camera motion over the segment and projected
    into the end's left and right images; a track's error is its largest pixel difference (u left,
    v, u right). Also the pose fitted to the pixels alone (robust least squares, Huber at 2 px,
    from the first trajectory's motion), the floor the tracks allow. trajectories: list of
    (times, (N, 4, 4) world-from-IMU poses). Returns a dict: "start" (frame indices of the
    segments checked), "median" (segments x (trajectories + 1)): each segment's median track error
    (px), the last column the pixels' own fit.
    """
    from scipy.optimize import least_squares

    from .geometry import se3_exp, se3_inv
    imu_T_cam = se3_inv(cam_T_imu)
    src = stale_sources(features)
    pairs = []
    for times, _ in trajectories:
        e, g, _ = associate(times, frame_times, "time", 0.02)
        pairs.append(dict(zip(g.tolist(), e.tolist())))

    def project(c_T, X):
        Y = X @ c_T[:3, :3].T + c_T[:3, 3]
        return np.column_stack([fx * Y[:, 0] / Y[:, 2] + cx, fy * Y[:, 1] / Y[:, 2] + cy,
                                fx * (Y[:, 0] - baseline) / Y[:, 2] + cx])

    starts, medians = [], []
    for a in range(0, features.shape[2] - length, length):
        sa, sb = src[a], src[a + length]
        if sa == sb or any(sa not in p or sb not in p for p in pairs):
            continue
        fa, fb = features[:, :, sa], features[:, :, sb]
        disparity = fa[0] - fa[2]
        use = (fa[0] != -1) & (fb[0] != -1) & (disparity >= min_disparity)
        if use.sum() < 8:
            continue
        z = fx * baseline / disparity[use]
        X = np.column_stack([(fa[0, use] - cx) * z / fx, ((fa[1, use] + fa[3, use]) / 2 - cy) * z / fy, z])
        seen = np.column_stack([fb[0, use], (fb[1, use] + fb[3, use]) / 2, fb[2, use]])
        row = []
        for (_, poses), p in zip(trajectories, pairs):
            c_T = se3_inv(poses[p[sb]] @ imu_T_cam) @ poses[p[sa]] @ imu_T_cam
            row.append(np.median(np.abs(project(c_T, X) - seen).max(axis=1)))
            if len(row) == 1:
                guess = c_T
        fit = least_squares(lambda x: (project(se3_exp(x) @ guess, X) - seen).ravel(), np.zeros(6),
                            loss="huber", f_scale=2.0)
        row.append(np.median(np.abs(project(se3_exp(fit.x) @ guess, X) - seen).max(axis=1)))
        starts.append(a)
        medians.append(row)
    return {"start": np.array(starts, dtype=int), "median": np.array(medians).reshape(-1, len(trajectories) + 1)}


def velocity_calibration(ref_times, ref_poses, sample_times, lin, ang, held=False, max_dt=0.02):
    """What a trajectory says about the velocity samples that drove it: over each interval between two
    consecutive reference poses (world-from-body), the body twist that moves one to the other,
    u = log(T_i^-1 T_i+1) / dt, against the samples' own motion over it (the mean of the samples at
    both ends, the trapezoid vislam integrates by default; with held, the sample at its start).

    Model, per interval: lin = v + w x p + b_v + e_v, ang = w + b_w + e_w, with v, w the reference's,
    p the velocity sensor's position in the body frame (vislam's velocity_sensor_*), b_v, b_w constant
    offsets. p and b_v by least squares on the three linear rows of every interval; b_w by the mean.
    Standard errors from the pooled residual variance; offsets_chi2 tests the six offsets against zero
    together (chi-square with 6 degrees of freedom without offsets). The residuals' std per axis is that of an
    interval's measured motion against the reference's, the reference's own error included; a sample's
    (the trapezoid's mean of two halves its variance) is given as sample_std.

    Returns a dict, or raises ToolError when fewer than 20 intervals pair with samples.
    """
    lin, ang = np.asarray(lin, dtype=float), np.asarray(ang, dtype=float)
    ref_idx, sample_idx, _ = associate(ref_times, sample_times, "time", max_dt)
    sample_of = dict(zip(ref_idx.tolist(), sample_idx.tolist()))
    intervals = [i for i in range(len(ref_times) - 1) if i in sample_of and i + 1 in sample_of]
    n = len(intervals)
    if n < 20:
        raise ToolError(f"velocities: {n} intervals pair the trajectory with velocity samples (20 needed; "
                        f"is the trajectory of the same drive, and --max-dt {max_dt} s wide enough?)")
    first = np.array([sample_of[i] for i in intervals])
    last = np.array([sample_of[i + 1] for i in intervals])
    meas_v = lin[first] if held else 0.5 * (lin[first] + lin[last])
    meas_w = ang[first] if held else 0.5 * (ang[first] + ang[last])
    twists = body_twists(ref_times, ref_poses)[intervals]
    ref_v, ref_w = twists[:, :3], twists[:, 3:]
    A = np.zeros((3 * n, 6))
    for k in range(n):
        A[3 * k:3 * k + 3, :3] = hat3(ref_w[k])  # w x p
        A[3 * k:3 * k + 3, 3:] = np.eye(3)
    y = (meas_v - ref_v).reshape(-1)
    x, *_ = np.linalg.lstsq(A, y, rcond=None)
    res_v = (y - A @ x).reshape(n, 3)
    sigma2 = float(np.sum(res_v ** 2) / (3 * n - 6))
    cov = sigma2 * np.linalg.inv(A.T @ A)
    res_w = meas_w - ref_w
    b_w = res_w.mean(axis=0)
    b_w_se = res_w.std(axis=0, ddof=1) / np.sqrt(n)
    share = 1.0 if held else 0.5
    # The six offsets against zero at once, each block with its covariance: chi-square with 6
    # degrees of freedom when the samples carry none.
    chi2 = float(x[3:] @ np.linalg.solve(cov[3:, 3:], x[3:]) + np.sum((b_w / b_w_se) ** 2))
    return {
        "intervals": n,
        "velocity_sensor": x[:3], "velocity_sensor_se": np.sqrt(np.diag(cov))[:3],
        "linear_offset": x[3:], "linear_offset_se": np.sqrt(np.diag(cov))[3:],
        "angular_offset": b_w, "angular_offset_se": b_w_se, "offsets_chi2": chi2,
        "linear_std": res_v.std(axis=0, ddof=1), "angular_std": (res_w - b_w).std(axis=0, ddof=1),
        "linear_sample_std": res_v.std(axis=0, ddof=1) / np.sqrt(share),
        "angular_sample_std": (res_w - b_w).std(axis=0, ddof=1) / np.sqrt(share),
    }
