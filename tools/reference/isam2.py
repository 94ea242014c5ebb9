"""GTSAM's incremental smoother (iSAM2) on the same measurements as vislam, for comparison.

    tools/reference/isam2 LOG --trajectory ONLINE.tum [--smoothed FINAL.tum] [--batch BATCH.tum]
                          [--json STATS.json] [--pixel-sigma PX] [--huber K] ...

Optional: needs `pip install gtsam` (4.3.0) in the project's venv; it is not in
tools/requirements.txt, so CI does not install it.

The graph, one pose X_k (world-from-IMU, as vislam's) per camera frame:
- a prior fixing X_0 at the identity (vislam starts there);
- a between factor X_{k-1}^-1 X_k = exp(tau hat(u)) from the held velocity sample, the seed's motion
  model, with covariance tau^2 diag(sigma_w^2 I, sigma_v^2 I) (GTSAM orders [rotation, translation]);
  sigma_v, sigma_w default to vislam's configured noise (0.5 m/s, 0.05 rad/s);
- a GenericStereoFactor3D per observation on [u_left, u_right, (v_left + v_right) / 2] with a Huber
  loss, to a Point3 landmark in the world; the sensor pose is imu_T_cam;
- a smooth-motion prior on every three consecutive poses (smooth_motion_factor): the velocities
  carry white noise, the vehicle's motion does not;
- tracks cut at the stale frames: a frame that repeats the previous frame's pixels exactly for every
  id the two share (vislam's frames_repeated rule) shows the previous image for those ids, so their
  observations there are not used and every track carried through it restarts as a new landmark
  (the tracker resumes them displaced); the tracks it starts are used.
A landmark enters at its second observation (a track of one frame adds nothing about the poses),
triangulated from its first with the pose estimate of that frame, if its disparity is at least
--min-disparity and its depth at most --max-depth (vislam's admission rule), with a weak prior at
that point (--landmark-prior).

Each frame is one iSAM2 update (plus --extra-updates); the trajectory written with --trajectory is
the online one: X_k as estimated right after frame k, causal like vislam's. --smoothed writes every
X_k from the final estimate, --batch after a Levenberg-Marquardt refinement of the whole graph.
"""

import argparse
import json
import sys
import time

import numpy as np

from vislam_tools.geometry import se3_exp, se3_inv

from .vl_reference import read_log, tum_line


def _gtsam():
    try:
        import gtsam
    except ImportError:
        sys.exit("isam2: the Python module gtsam is not installed: "
                 ".venv/bin/pip install gtsam==4.3.0 (optional, not in tools/requirements.txt)")
    return gtsam


def stale(obs, prev):
    """The frame repeats the previous one: every id the two share has the same four pixels."""
    common = 0
    for o in obs:
        q = prev.get(int(o[0]))
        if q is None:
            continue
        if not np.array_equal(q, o[1:]):
            return False
        common += 1
    return common > 0


def smooth_motion_factor(gtsam, keys, dt1, dt2, model):
    """The smooth-motion prior on three consecutive poses: the body twist over one interval equals the
    next one, Log(X_a^-1 X_b) / dt1 - Log(X_b^-1 X_c) / dt2 ~ N(0, diag(sigma_w^2, sigma_v^2)), so
    the velocity changes by about the sigmas per frame. Jacobians from GTSAM's between and Logmap."""

    def error(factor, values, H):
        a, b, c = (values.atPose3(key) for key in factor.keys())
        J = [np.zeros((6, 6), order="F") for _ in range(6)]  # d(ab)/da, d(ab)/db, dLog, d(bc)/db, d(bc)/dc, dLog
        l1 = gtsam.Pose3.Logmap(a.between(b, J[0], J[1]), J[2])
        l2 = gtsam.Pose3.Logmap(b.between(c, J[3], J[4]), J[5])
        if H is not None:
            H[0] = J[2] @ J[0] / dt1
            H[1] = J[2] @ J[1] / dt1 - J[5] @ J[3] / dt2
            H[2] = -J[5] @ J[4] / dt2
        return l1 / dt1 - l2 / dt2

    return gtsam.CustomFactor(model, gtsam.KeyVector(keys), error)


def run(events, a):
    """Feeds the log to iSAM2 frame by frame; returns (frame times in us, online poses, isam, stats)."""
    gtsam = _gtsam()
    X, L = gtsam.symbol_shorthand.X, gtsam.symbol_shorthand.L
    params = gtsam.ISAM2Params()
    params.setRelinearizeThreshold(a.relinearize_threshold)
    params.relinearizeSkip = 1
    isam = gtsam.ISAM2(params)
    pixel = gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Huber.Create(a.huber),
                                           gtsam.noiseModel.Isotropic.Sigma(3, a.pixel_sigma))
    landmark_prior = gtsam.noiseModel.Isotropic.Sigma(3, a.landmark_prior)
    smooth = gtsam.noiseModel.Diagonal.Sigmas(np.array([a.smooth_angular] * 3 + [a.smooth_linear] * 3))
    dts, last_frame_t = [], None
    cal = K = imu_T_cam = None
    held = last_t = None
    delta, tau_sum2 = np.eye(4), 0.0
    k = -1
    epoch = 0                      # incremented at each stale frame: landmark (id, epoch) is one track piece
    landmarks, first_seen = {}, {}  # (id, epoch) -> L index; (id, epoch) -> (frame, StereoPoint2, disparity)
    prev = {}
    times, online, step_s = [], [], []
    n_stale = n_obs = 0
    for ev in events:
        if ev[0] == "calib":
            if cal is None:
                cal = ev[2]
                K = gtsam.Cal3_S2Stereo(cal.fx, cal.fy, 0.0, cal.cx, cal.cy, cal.baseline)
                imu_T_cam = gtsam.Pose3(se3_inv(cal.cam_T_imu))
            continue
        if cal is None:
            continue
        t = ev[1]
        if held is not None and t > last_t:
            tau = (t - last_t) * 1e-6
            delta = delta @ se3_exp(tau * held)
            tau_sum2 += tau * tau
        if held is not None or ev[0] == "imu":
            last_t = t
        if ev[0] == "imu":
            held = np.concatenate([ev[2], ev[3]])
            continue
        if held is None:
            continue
        t0 = time.perf_counter()
        k += 1
        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        if k == 0:
            values.insert(X(0), gtsam.Pose3())
            graph.add(gtsam.PriorFactorPose3(X(0), gtsam.Pose3(), gtsam.noiseModel.Isotropic.Sigma(6, 1e-6)))
        else:
            cov = np.diag([a.angular_sigma ** 2] * 3 + [a.linear_sigma ** 2] * 3) * max(tau_sum2, 1e-12)
            graph.add(gtsam.BetweenFactorPose3(X(k - 1), X(k), gtsam.Pose3(delta),
                                               gtsam.noiseModel.Gaussian.Covariance(cov)))
            values.insert(X(k), gtsam.Pose3(online[-1] @ delta))
        delta, tau_sum2 = np.eye(4), 0.0
        if k >= 2 and a.smooth_linear > 0.0 and a.smooth_angular > 0.0:
            graph.add(smooth_motion_factor(gtsam, [X(k - 2), X(k - 1), X(k)], dts[-1], (t - last_frame_t) * 1e-6,
                                           smooth))
        if k >= 1:
            dts.append((t - last_frame_t) * 1e-6)
        last_frame_t = t
        obs = ev[2]
        repeated = stale(obs, prev)
        if repeated:
            epoch += 1
            n_stale += 1
            first_seen = {}
        for o in obs:
            oid, disparity = int(o[0]), o[1] - o[3]
            if oid < 0 or not disparity > 0.0 or (repeated and oid in prev):
                continue
            key = (oid, epoch)
            meas = gtsam.StereoPoint2(o[1], o[3], 0.5 * (o[2] + o[4]))
            if key in landmarks:
                graph.add(gtsam.GenericStereoFactor3D(meas, pixel, X(k), L(landmarks[key]), K, imu_T_cam))
                n_obs += 1
                continue
            if key not in first_seen:
                first_seen[key] = (k, meas, disparity)
                continue
            k0, m0, d0 = first_seen.pop(key)
            depth = cal.fx * cal.baseline / d0
            if d0 < a.min_disparity or depth > a.max_depth:
                first_seen[key] = (k, meas, disparity)  # try again from this observation
                continue
            pose0 = online[k0] if k0 < k else values.atPose3(X(k)).matrix()
            cam = gtsam.StereoCamera(gtsam.Pose3(pose0).compose(imu_T_cam), K)
            idx = len(landmarks)
            landmarks[key] = idx
            values.insert(L(idx), cam.backproject(m0))
            graph.add(gtsam.PriorFactorPoint3(L(idx), cam.backproject(m0), landmark_prior))
            graph.add(gtsam.GenericStereoFactor3D(m0, pixel, X(k0), L(idx), K, imu_T_cam))
            graph.add(gtsam.GenericStereoFactor3D(meas, pixel, X(k), L(idx), K, imu_T_cam))
            n_obs += 2
        prev = {int(o[0]): o[1:].copy() for o in obs}
        isam.update(graph, values)
        for _ in range(a.extra_updates):
            isam.update()
        online.append(isam.calculateEstimatePose3(X(k)).matrix())
        times.append(t)
        step_s.append(time.perf_counter() - t0)
        if a.max_steps and k + 1 >= a.max_steps:
            break
    us = np.array(step_s) * 1e6
    stats = {"frames": len(times), "stale_frames": n_stale, "landmarks": len(landmarks),
             "stereo_factors": n_obs,
             "step_us": {"median": float(np.median(us)), "p99": float(np.percentile(us, 99)),
                         "max": float(us.max()), "mean": float(us.mean())} if us.size else {}}
    return times, online, isam, stats


def write_tum(path, times, poses):
    with open(path, "w") as f:
        for t, T in zip(times, poses):
            f.write(tum_line(t, T[:3, :3], T[:3, 3]))


def main(argv=None):
    ap = argparse.ArgumentParser(prog="tools/reference/isam2", description=__doc__.split("\n\n")[0])
    ap.add_argument("log", help="LCM log (tools/npz2lcm, vislam-sim)")
    ap.add_argument("--trajectory", required=True, help="online trajectory (TUM): X_k right after frame k")
    ap.add_argument("--smoothed", help="every X_k from the final iSAM2 estimate (TUM)")
    ap.add_argument("--batch", help="every X_k after a Levenberg-Marquardt refinement of the whole graph (TUM)")
    ap.add_argument("--json", help="counts and per-step time")
    ap.add_argument("--pixel-sigma", type=float, default=1.5, help="px (default 1.5, vislam's prior)")
    ap.add_argument("--huber", type=float, default=1.345, help="Huber threshold in sigmas (default 1.345)")
    ap.add_argument("--linear-sigma", type=float, default=0.5, help="m/s per sample (default 0.5)")
    ap.add_argument("--angular-sigma", type=float, default=0.05, help="rad/s per sample (default 0.05)")
    ap.add_argument("--smooth-linear", type=float, default=0.2,
                    help="m/s: how much the linear velocity may change from one frame to the next in the "
                    "smooth-motion prior (default 0.2; 0 turns the prior off)")
    ap.add_argument("--smooth-angular", type=float, default=0.05,
                    help="rad/s: the same for the angular velocity (default 0.05)")
    ap.add_argument("--min-disparity", type=float, default=1.0, help="px (default 1)")
    ap.add_argument("--max-depth", type=float, default=150.0, help="m (default 150)")
    ap.add_argument("--landmark-prior", type=float, default=30.0,
                    help="m: a weak prior on each landmark at its triangulated point (default 30), so a point "
                    "whose factors all fail (behind the camera) cannot leave the system indeterminate")
    ap.add_argument("--relinearize-threshold", type=float, default=0.1)
    ap.add_argument("--extra-updates", type=int, default=0, help="further iSAM2 iterations per frame")
    ap.add_argument("--max-steps", type=int, help="stop after N frames")
    a = ap.parse_args(argv)
    gtsam = _gtsam()
    t0 = time.perf_counter()
    times, online, isam, stats = run(read_log(a.log), a)
    stats["run_s"] = time.perf_counter() - t0
    write_tum(a.trajectory, times, online)
    X = gtsam.symbol_shorthand.X
    if a.smoothed or a.batch:
        est = isam.calculateEstimate()
        if a.smoothed:
            write_tum(a.smoothed, times, [est.atPose3(X(k)).matrix() for k in range(len(times))])
        if a.batch:
            t1 = time.perf_counter()
            lm = gtsam.LevenbergMarquardtOptimizer(isam.getFactorsUnsafe(), est, gtsam.LevenbergMarquardtParams())
            refined = lm.optimize()
            stats["batch_s"] = time.perf_counter() - t1
            write_tum(a.batch, times, [refined.atPose3(X(k)).matrix() for k in range(len(times))])
    print(f"isam2: {stats['frames']} frames ({stats['stale_frames']} stale), {stats['landmarks']} landmarks, "
          f"{stats['stereo_factors']} stereo factors; per-step time median "
          f"{stats['step_us'].get('median', 0):.0f} us, max {stats['step_us'].get('max', 0):.0f} us; "
          f"{stats['run_s']:.1f} s in all")
    if a.json:
        with open(a.json, "w") as f:
            json.dump(stats, f, indent=1)
            f.write("\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
