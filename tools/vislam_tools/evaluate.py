"""Trajectory evaluation for vislam: ATE/RPE against ground truth, figures, animations.

Trajectories are TUM files (`time tx ty tz qx qy qz qw`, seconds and metres, world-from-IMU), the
format evo reads. Alignment, ATE and RPE are evo's; `evaluate gt` writes the ground truth as TUM so
that evo_ape / evo_rpe / evo_traj run on the same files and give the same numbers.
"""

import argparse
import json
import sys

import numpy as np

from . import ToolError, cli
from .geometry import integrate_dead_reckoning, se3_inv
from .metrics import (CHI2_3DOF_95, CHI2_6DOF_99, associate, ate, consistency, reprojection_check, rpe,
                      segment_differences, velocity_calibration)
from .trajio import (Trajectory, load_calibration, load_npz, read_covariance, read_ground_truth, read_map,
                     read_tum, read_velocities, write_tum)

EPILOG = """\
Formats:
  TUM     one pose per line: time tx ty tz qx qy qz qw (s, m, unit quaternion; world-from-IMU).
          What evo reads: write the ground truth with `evaluate gt`, then evo runs directly.
  KITTI   13 numbers per line: time, then the 3x4 [R|t] of the left camera at step i in the
          camera-0 frame (12 numbers without the time also accepted). Converted to IMU poses with
          cam_T_imu from --calib: w_T_i = imu_T_cam * c0_T_cam(i) * cam_T_imu.
  PLY     landmark map: element vertex with float x, y, z (more properties allowed; a
          first_utime/utime/time property makes animated landmarks appear when first seen).

Examples:
  evaluate deadreckon --data ../shared/data/0027.npz --out /tmp/dr.tum
  evaluate ate --estimate slam.tum --gt ../shared/data/gt/kitti_odometry_07.txt --calib ../shared/data/0027.npz
  evaluate gt --gt ../shared/data/gt/kitti_odometry_07.txt --calib ../shared/data/0027.npz --out gt.tum
  evo_ape tum gt.tum slam.tum -a                                  # the same ATE as evaluate ate
  evo_rpe tum gt.tum slam.tum -a --delta 10 --all_pairs [-r angle_deg]   # its RPE over 10 steps
  evo_traj tum slam.tum --ref gt.tum -a --plot_mode xy --save_plot traj.png
  evaluate plot --estimate slam.tum --dead-reckoning dr.tum --map map.ply --out fig.png
  evaluate animate --estimate slam.tum --map map.ply --out run.gif
  evaluate consistency --estimate slam.tum --covariance slam.cov --gt ../shared/data/gt/kitti_odometry_07.txt \\
      --calib ../shared/data/0027.npz --out consistency.png
"""

CONSISTENCY_EPILOG = """\
Per frame: the position error in the body frame, e = R_est^T (p_gt - p_est), against the filter's
own standard deviation (vislam-run --covariance: the diagonal of the pose covariance over a right,
body-frame perturbation, so its position part is the body-frame error to first order). Printed:
the fraction of frames with |e| <= 3 sigma per axis (about 0.997 for a consistent filter) and the
mean position NEES, e^T diag(var)^-1 e (3 for a consistent filter; the file has no correlations
between axes, so this NEES uses the diagonal only).

Alignment caveat: with --align se3 (the default) the ground truth is first moved onto the estimate
by the rigid Umeyama fit of the whole trajectory, as for the ATE. That fit spreads the drift over
the run: early errors grow and late ones shrink, and it uses knowledge the filter never had. The
filter's covariance is relative to its first pose (known exactly); --align none compares in that
frame (for KITTI ground truth, the IMU frame at step 0, the estimator's start), which is the
honest test of a filter started at the truth.
"""


def _add_gt_args(p, required, scale=True, pairing=True):
    p.add_argument("--gt", required=required, metavar="GT",
                   help="ground truth: KITTI odometry poses (.txt) or TUM (e.g. the simulator's truth)")
    p.add_argument("--gt-format", choices=("auto", "tum", "kitti"), default="auto",
                   help="ground-truth format (default: by the count of numbers per line)")
    p.add_argument("--calib", metavar="DATA.npz|LOG.lcmlog",
                   help="cam_T_imu and step times: a seed dataset or an LCM log with a *CALIB event "
                        "(needed for KITTI ground truth)")
    if not pairing:
        return
    p.add_argument("--associate", choices=("auto", "time", "relative", "index"), default="auto",
                   help="pair estimate and GT poses by absolute time, by time since each one's first "
                        "pose, or by line index; auto = time, else relative (default auto)")
    p.add_argument("--max-dt", type=float, default=0.02, metavar="S",
                   help="largest time difference accepted when pairing (default 0.02 s)")
    if scale:
        p.add_argument("--scale", action="store_true",
                       help="Sim(3) alignment (also estimate scale); default is rigid SE(3)")


VELOCITIES_DESCRIPTION = """\
What a trajectory of the drive says about its velocity samples. Over each interval between two
consecutive poses of the reference, its body twist is compared with the samples' motion (the
trapezoid of the two samples, or the held one), and fitted as

    linear  = v + w x p + b_v + noise      angular = w + b_w + noise

with v, w the reference's: p is where the linear velocity is measured in the body frame (vislam's
[estimator] velocity_sensor_x/_y/_z), b_v and b_w constant offsets (what vislam's offset states
learn). The residuals' std gives each sample's noise, the reference's own error included: an upper
bound for [noise] linear_velocity and angular_velocity. Both ways of taking an interval's motion
from the samples are fitted (the trapezoid of its two samples, vislam's default, and the first one
held, interpolate_velocities = false); the one with the smaller residual is reported unless
--sampling names one. Offset states are suggested off (estimate_input_offsets = false) when the
six offsets together are not told from zero (their chi-square under its 99 % quantile, 16.8): on
velocities without biases they only take up the images' errors (README, Setting it up for your
sensors).

Against ground truth this is a calibration of the velocity sensor. Against vislam's own trajectory
it says what the images ask of the velocities (a lever arm or offsets the vision disagrees with).
A value is printed as significant when it lies over 3 of its standard errors from 0. The standard
errors take the intervals' errors as independent: a reference whose errors are correlated in time
(a filter's) makes them too small.

Example (0027, KITTI ground truth):
  evaluate gt --gt ../shared/data/gt/kitti_odometry_07.txt --calib ../shared/data/0027.npz --out gt.tum
  evaluate velocities --velocities ../shared/data/0027.npz --reference gt.tum
"""


def cmd_velocities(args):
    times, lin, ang = read_velocities(args.velocities)
    ref = read_tum(args.reference)
    fits = {mode: velocity_calibration(ref.times, ref.poses, times, lin, ang, held=mode == "held", max_dt=args.max_dt)
            for mode in ("trapezoid", "held")}
    misfit = {mode: float(np.sum(r["linear_std"] ** 2)) for mode, r in fits.items()}
    mode = min(misfit, key=misfit.get) if args.sampling == "auto" else args.sampling
    res = fits[mode]

    def row(name, value, se, unit):
        flag = ["*" if abs(v) > 3.0 * e else " " for v, e in zip(value, se)]
        cells = "  ".join(f"{v:+9.4f} +- {e:.4f}{f}" for v, e, f in zip(value, se, flag))
        return f"{name:<22} {cells}  {unit}"

    print(f"{res['intervals']} intervals of {ref.name} against {args.velocities} ({mode}; linear residual "
          f"{np.sqrt(misfit['trapezoid']):.4f} m/s with the trapezoid, {np.sqrt(misfit['held']):.4f} with the samples "
          f"held); x, y, z; * over 3 standard errors from 0")
    print(row("velocity sensor p", res["velocity_sensor"], res["velocity_sensor_se"], "m"))
    print(row("linear offset b_v", res["linear_offset"], res["linear_offset_se"], "m/s"))
    print(row("angular offset b_w", res["angular_offset"], res["angular_offset_se"], "rad/s"))
    print(f"{'sample noise, linear':<22} " + "  ".join(f"{v:9.4f}{'':14}" for v in res["linear_sample_std"]) + "  m/s")
    print(f"{'sample noise, angular':<22} " + "  ".join(f"{v:9.4f}{'':14}" for v in res["angular_sample_std"])
          + "  rad/s")
    p, se = res["velocity_sensor"], res["velocity_sensor_se"]
    chi2 = res["offsets_chi2"]
    print("[estimator]")
    print(f"interpolate_velocities = {'false' if mode == 'held' else 'true'}")
    print(f"; estimate_input_offsets: keep (the offsets against zero: chi-square {chi2:.1f} over {CHI2_6DOF_99})"
          if chi2 > CHI2_6DOF_99 else "estimate_input_offsets = false")
    for axis, v, e in zip("xyz", p, se):
        print(f"velocity_sensor_{axis} = {v:.3f}" if abs(v) > 3.0 * e else f"; velocity_sensor_{axis}: not "
              f"significant ({v:+.3f} +- {e:.3f})")
    print("[noise]")
    print(f"linear_velocity = {float(np.sqrt(np.mean(res['linear_sample_std'] ** 2))):.3g}")
    print(f"angular_velocity = {float(np.sqrt(np.mean(res['angular_sample_std'] ** 2))):.3g}")
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"sampling": mode, **{k: (v.tolist() if isinstance(v, np.ndarray) else v)
                                            for k, v in res.items()}}, f, indent=1)
    return 0


def build_parser():
    parser = argparse.ArgumentParser(
        prog="evaluate", description=__doc__.splitlines()[0],
        formatter_class=argparse.RawDescriptionHelpFormatter, epilog=EPILOG)
    cli.add_version(parser)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True

    p = sub.add_parser("ate", help="absolute trajectory error (Umeyama-aligned) and relative pose error",
                       formatter_class=argparse.RawDescriptionHelpFormatter, epilog=EPILOG)
    p.add_argument("--estimate", required=True, metavar="EST.tum", help="estimated trajectory (TUM)")
    _add_gt_args(p, required=True)
    p.add_argument("--rpe-deltas", default="1,10", metavar="D1,D2",
                   help="RPE step deltas between paired poses (default 1,10)")
    p.add_argument("--json", metavar="OUT.json", help="also write the numbers as JSON")

    for name, what in (("plot", "top-down figure (PNG/PDF/SVG by extension)"),
                       ("animate", "animated GIF of the run")):
        p = sub.add_parser(name, help=what, formatter_class=argparse.RawDescriptionHelpFormatter,
                           epilog=EPILOG)
        p.add_argument("--estimate", required=True, metavar="SLAM.tum", help="SLAM trajectory (TUM)")
        p.add_argument("--dead-reckoning", metavar="DR.tum", help="dead-reckoning trajectory (TUM)")
        p.add_argument("--map", metavar="MAP", help="landmark map: vislam-run --map's PLY, or an LCM log that "
                       "recorded vislamd's VISLAM_LANDMARKS")
        _add_gt_args(p, required=False)
        p.add_argument("--title", default=None, help="figure title (default: file names, ATE if GT)")
        p.add_argument("--out", required=True, metavar="FIG.png" if name == "plot" else "RUN.gif")
        if name == "plot":
            p.add_argument("--dpi", type=int, default=120)
        else:
            p.add_argument("--max-frames", type=int, default=100, help="frames drawn (default 100)")
            p.add_argument("--fps", type=int, default=10, help="GIF frame rate (default 10)")
            p.add_argument("--dpi", type=int, default=90, help="GIF resolution (default 90: 540x450 px)")

    p = sub.add_parser("consistency", help="position error against the filter's 3 sigma over time, NEES",
                       formatter_class=argparse.RawDescriptionHelpFormatter, epilog=CONSISTENCY_EPILOG)
    p.add_argument("--estimate", required=True, metavar="EST.tum", help="estimated trajectory (TUM)")
    p.add_argument("--covariance", required=True, metavar="COV.txt",
                   help="vislam-run --covariance output of the same run (time and 6 variances per line)")
    _add_gt_args(p, required=True, scale=False)
    p.add_argument("--align", choices=("se3", "none"), default="se3",
                   help="rigid Umeyama alignment of the whole trajectory, or none (default se3; see below)")
    p.add_argument("--out", metavar="FIG.png", help="figure: error and +-3 sigma per axis, and the NEES")
    p.add_argument("--title", default=None, help="figure title")
    p.add_argument("--json", metavar="OUT.json", help="also write the numbers as JSON")
    p.add_argument("--dpi", type=int, default=120)

    p = sub.add_parser("gt", help="write the ground truth as TUM, world-from-IMU at the step times (for evo)",
                       description="The ground truth as `evaluate ate` reads it (KITTI camera poses\n"
                       "converted to IMU poses through cam_T_imu, in the frame of the IMU at step 0,\n"
                       "stamped with the dataset's step times), written as TUM so that evo_ape, evo_rpe\n"
                       "and evo_traj compare it with a vislam trajectory directly.",
                       formatter_class=argparse.RawDescriptionHelpFormatter, epilog=EPILOG)
    _add_gt_args(p, required=True, pairing=False)
    p.add_argument("--out", required=True, metavar="GT.tum")

    p = sub.add_parser("segments", help="where two trajectories part: their motions per segment compared",
                       description=SEGMENTS_DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--reference", required=True, metavar="REF.tum", help="trajectory compared against (TUM)")
    p.add_argument("--estimate", required=True, action="append", metavar="EST.tum",
                   help="trajectory compared with the reference (TUM); repeat for more than one")
    p.add_argument("--length", type=int, default=10, metavar="K", help="poses per segment (default 10)")
    p.add_argument("--frame-stats", metavar="FS.txt",
                   help="vislam-run --frame-stats of the first estimate's run: per-segment counters in the table")
    p.add_argument("--top", type=int, default=10, metavar="N", help="segments printed, largest first (default 10)")
    p.add_argument("--csv", metavar="OUT.csv", help="every segment as CSV")
    p.add_argument("--max-dt", type=float, default=0.02, help="s, time pairing tolerance (default 0.02)")

    p = sub.add_parser("reprojection", help="how well each trajectory's motion explains the stereo tracks",
                       description=REPROJECTION_DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--data", required=True, metavar="DATA.npz", help="seed dataset (features, K, b, cam_T_imu)")
    p.add_argument("--estimate", required=True, action="append", metavar="EST.tum",
                   help="trajectory (TUM, paired with the dataset's frames by time); repeat for more")
    p.add_argument("--length", type=int, default=1, metavar="K", help="frames per segment (default 1)")
    p.add_argument("--min-disparity", type=float, default=3.0, help="px, tracks triangulated (default 3)")

    p = sub.add_parser("velocities", help="the velocity sensor's lever arm, offsets and noise, against a trajectory",
                       description=VELOCITIES_DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--velocities", required=True, metavar="DATA.npz|LOG.lcmlog",
                   help="the velocity samples: a seed dataset, or an LCM log's VISLAM_IMU events")
    p.add_argument("--reference", required=True, metavar="REF.tum",
                   help="world-from-body trajectory of the same drive: ground truth (evaluate gt, vislam-sim "
                        "--truth) or a vislam-run trajectory")
    p.add_argument("--sampling", choices=("auto", "trapezoid", "held"), default="auto",
                   help="an interval's motion: the trapezoid of the samples at both ends (interpolate_velocities "
                        "= true), the sample at its start held (false), or whichever fits better (default auto)")
    p.add_argument("--max-dt", type=float, default=0.02, metavar="S",
                   help="largest time difference between a pose and its sample (default 0.02 s)")
    p.add_argument("--json", metavar="OUT.json", help="also write the numbers as JSON")

    p = sub.add_parser("deadreckon", help="integrate a dataset's velocities into a TUM trajectory",
                       description="w_T_i(t+1) = w_T_i(t) exp(tau_t hat(u_t)), w_T_i(0) = I; one line per step.")
    p.add_argument("--data", required=True, metavar="DATA.npz", help="seed dataset")
    p.add_argument("--out", required=True, metavar="DR.tum")
    p.add_argument("--max-steps", type=int, default=None, metavar="N")
    return parser


def _write_json(path, res):
    """Write the results as JSON; a write failure is a ToolError."""
    try:
        with open(path, "w") as f:
            json.dump(res, f, indent=2)
            f.write("\n")
    except OSError as exc:
        raise ToolError(f"cannot write {path}: {exc.strerror}") from exc


def _associated_ground_truth(est, args):
    """The ground truth of args.gt and the estimate/GT index pairs; fewer than 3 pairs is a ToolError."""
    calib = load_calibration(args.calib) if args.calib else None
    gt = read_ground_truth(args.gt, calib, args.gt_format)
    ei, gi, mode = associate(est.times, gt.times, args.associate, args.max_dt)
    if len(ei) < 3:
        raise ToolError(f"only {len(ei)} estimate/GT pairs (association '{mode}', max dt {args.max_dt} s): "
                        "check the time stamps, or use --associate relative|index")
    return gt, ei, gi, mode


def evaluate_against_gt(est, args):
    """Associate, align and measure. Returns (results dict, aligned-GT-in-estimate-frame Trajectory)."""
    gt, ei, gi, mode = _associated_ground_truth(est, args)
    est_p = est.poses[ei]
    gt_p = gt.poses[gi]
    stats, err, t_align, scale = ate(est_p[:, :3, 3], gt_p[:, :3, 3], with_scale=args.scale)
    results = {
        "estimate": args.estimate if hasattr(args, "estimate") else "",
        "ground_truth": args.gt,
        "association": mode,
        "pairs": int(len(ei)),
        "estimate_poses": int(len(est)),
        "gt_poses": int(len(gt)),
        "alignment": "sim3" if args.scale else "se3",
        "scale": float(scale),
        "ate": stats,
        "rpe": [],
        "align_T": t_align.tolist(),
    }
    deltas = [int(x) for x in getattr(args, "rpe_deltas", "1,10").split(",") if x.strip()]
    for d in deltas:
        r = rpe(est_p, gt_p, d)
        if r is not None:
            results["rpe"].append(r)
    # GT drawn in the estimate's frame so the SLAM, dead-reckoning and map layers stay as published.
    inv = se3_inv(t_align)
    gt_in_est = (gt.poses[:, :3, 3] @ inv[:3, :3].T + inv[:3, 3]) / scale
    gt_aligned = Trajectory(gt.times, gt.poses.copy(), "ground truth")
    gt_aligned.poses[:, :3, 3] = gt_in_est
    return results, gt_aligned


def cmd_ate(args):
    est = read_tum(args.estimate)
    res, _ = evaluate_against_gt(est, args)
    a = res["ate"]
    print(f"pairs: {res['pairs']} of {res['estimate_poses']} estimate / {res['gt_poses']} GT poses "
          f"(association: {res['association']}, alignment: {res['alignment']}"
          + (f", scale {res['scale']:.4f}" if args.scale else "") + ")")
    print(f"ATE  rmse {a['rmse']:.3f} m  mean {a['mean']:.3f} m  median {a['median']:.3f} m  "
          f"max {a['max']:.3f} m")
    for r in res["rpe"]:
        print(f"RPE  delta {r['delta']:>3} steps: trans rmse {r['trans_rmse']:.4f} m, "
              f"rot rmse {r['rot_rmse_deg']:.4f} deg ({r['pairs']} pairs)")
    if args.json:
        _write_json(args.json, res)
    return 0


def _scene(args):
    from .plotting import Scene, landmark_times_from_ply
    est = read_tum(args.estimate)
    scene = Scene(est.times, est.positions)
    names = [args.estimate.rsplit("/", 1)[-1]]
    if args.dead_reckoning:
        dr = read_tum(args.dead_reckoning)
        scene.dr_times, scene.dr_xyz = dr.times, dr.positions
    if args.map:
        props = read_map(args.map)
        scene.landmarks = np.column_stack([props["x"], props["y"], props["z"]])
        scene.landmark_times = landmark_times_from_ply(props)
    ate_text = ""
    if args.gt:
        res, gt_aligned = evaluate_against_gt(est, args)
        scene.gt_times, scene.gt_xyz = gt_aligned.times, gt_aligned.positions
        ate_text = f"ATE {res['ate']['rmse']:.2f} m ({res['pairs']} poses)"
        print(f"ATE rmse {res['ate']['rmse']:.3f} m over {res['pairs']} pairs")
    if args.title is not None:
        scene.title = args.title
    else:
        scene.title = "  ".join(x for x in (names[0], ate_text) if x)
    return scene


def cmd_plot(args):
    from .plotting import plot_topdown
    plot_topdown(_scene(args), args.out, dpi=args.dpi)
    print(f"wrote {args.out}")
    return 0


def cmd_animate(args):
    from .plotting import animate_topdown
    if args.max_frames < 2 or args.fps < 1:
        raise ToolError("--max-frames must be >= 2 and --fps >= 1")
    animate_topdown(_scene(args), args.out, max_frames=args.max_frames, fps=args.fps, dpi=args.dpi)
    print(f"wrote {args.out}")
    return 0


def cmd_consistency(args):
    est = read_tum(args.estimate)
    cov_times, cov_var = read_covariance(args.covariance)
    # Both files print the time exactly from the same microsecond stamp: pair on it.
    cov_index = {int(u): i for i, u in enumerate(np.round(cov_times * 1e6).astype(np.int64))}
    est_us = np.round(est.times * 1e6).astype(np.int64)
    rows = np.array([cov_index.get(int(u), -1) for u in est_us])
    if np.any(rows < 0):
        raise ToolError(f"{int(np.sum(rows < 0))} of {len(est)} poses of {args.estimate} have no line of the "
                        f"same time in {args.covariance}: use the files of one vislam-run run")
    gt, ei, gi, mode = _associated_ground_truth(est, args)
    est_p = est.poses[ei]
    gt_pos = gt.poses[gi, :3, 3]
    if args.align == "se3":
        _, _, t_align, _ = ate(est_p[:, :3, 3], gt_pos)
        inv = se3_inv(t_align)
        gt_pos = gt_pos @ inv[:3, :3].T + inv[:3, 3]  # the truth in the estimate's frame
    res, e_body, sigma, nees, _ = consistency(est_p, gt_pos, cov_var[rows[ei], :3])
    res.update(estimate=args.estimate, covariance=args.covariance, ground_truth=args.gt, association=mode,
               alignment=args.align, nees_chi2_95=CHI2_3DOF_95)
    inside = res["inside_3sigma"]
    print(f"pairs: {len(ei)} of {len(est)} estimate / {len(gt)} GT poses (association: {mode}, "
          f"alignment: {args.align}); {res['frames_used']} frames with a positive variance")
    print("inside 3 sigma (body frame): " + ", ".join(f"{ax} {100 * inside[ax]:.1f} %" for ax in "xyz"))
    print("error rms / sigma rms (m): " + ", ".join(
        f"{ax} {res['error_rms_body'][ax]:.3f} / {res['sigma_rms_body'][ax]:.3f}" for ax in "xyz"))
    print(f"position NEES (3 dof, diagonal): mean {res['nees_mean']:.2f}, median {res['nees_median']:.2f} "
          f"(expected 3); over the chi2 95 % bound {CHI2_3DOF_95:.2f} in {100 * res['nees_over_chi2_95']:.1f} % "
          "of the frames (expected 5 %)")
    if args.json:
        _write_json(args.json, res)
    if args.out:
        from .plotting import plot_consistency
        title = args.title
        if title is None:
            title = (f"{args.estimate.rsplit('/', 1)[-1]}: body-frame position error vs 3σ "
                     f"(alignment {args.align}; NEES mean {res['nees_mean']:.1f})")
        plot_consistency(est.times[ei], e_body, sigma, nees, args.out, title, CHI2_3DOF_95, dpi=args.dpi)
        print(f"wrote {args.out}")
    return 0


def cmd_gt(args):
    calib = load_calibration(args.calib) if args.calib else None
    gt = read_ground_truth(args.gt, calib, args.gt_format)
    try:
        write_tum(args.out, gt.times, gt.poses)
    except OSError as exc:
        raise ToolError(f"cannot write {args.out}: {exc.strerror}") from exc
    print(f"wrote {args.out}: {len(gt)} poses")
    return 0


def cmd_deadreckon(args):
    data = load_npz(args.data)
    ts = np.asarray(data["time_stamps"], dtype=float).reshape(-1)
    n = ts.shape[0] if args.max_steps is None else min(ts.shape[0], max(args.max_steps, 1))
    poses = integrate_dead_reckoning(ts[:n], data["linear_velocity"][:, :n], data["rotational_velocity"][:, :n])
    try:
        write_tum(args.out, ts[:n], poses)
    except OSError as exc:
        raise ToolError(f"cannot write {args.out}: {exc.strerror}") from exc
    print(f"wrote {args.out}: {n} poses")
    return 0


SEGMENTS_DESCRIPTION = """\
Where two trajectories part, without ground truth. Poses are paired by time (every estimate with
the reference); the paired run is cut into segments of K poses, and for each the motion over the
segment, T_start^-1 T_end, of every estimate is compared with the reference's: d_trans (m, the
difference of the two translations in the body frame at the segment's start), d_rot (deg, the
angle between the two rotations) and scale (the length of the estimate's translation over the
reference's). An error made in one segment does not count again in the next, unlike the ATE.
Printed: the totals and the N segments of the first estimate with the largest d_trans; with
--frame-stats (vislam-run --frame-stats of the first estimate's run) also the segment's counters:
observations used, gated, frames re-associated, repeated, tracks broken, and the noises in use at
its end (linear m/s, angular rad/s, pixel px).
"""

REPROJECTION_DESCRIPTION = """\
Which trajectory the images agree with, without ground truth. For each segment of K frames (a
stale frame, one repeating the previous frame's pixels for every shared track, stands for the
frame whose image it shows), the tracks seen at both ends are triangulated at the start (stereo,
disparity >= --min-disparity), moved by the trajectory's camera motion over the segment and
projected into the end's left and right images. Printed per trajectory: the median over segments
of each segment's median track error (px, the largest of u left, v, u right), and the fraction of
segments under 2 px; and the same for the pose fitted to the pixels alone (robust least squares),
the floor the tracks allow.
"""

SEGMENT_COUNTERS = ("observations_used", "observations_gated", "frames_reassociated", "frames_repeated",
                    "tracks_broken")
SEGMENT_NOISES = ("linear_velocity_noise", "angular_velocity_noise", "pixel_noise")


def read_frame_stats(path):
    """vislam-run --frame-stats: (times (N,), {column name: (N,) array})."""
    try:
        with open(path) as f:
            header = f.readline().split()
    except OSError as exc:
        raise ToolError(f"cannot read {path}: {exc.strerror}") from exc
    if len(header) < 2 or header[0] != "#" or header[1] != "time":
        raise ToolError(f"{path}: not a vislam-run --frame-stats file (no '# time ...' header)")
    names = header[1:]
    try:
        rows = np.loadtxt(path, comments="#", ndmin=2)
    except ValueError as exc:
        raise ToolError(f"{path}: {exc}") from exc
    if rows.shape[0] == 0 or rows.shape[1] != len(names):
        raise ToolError(f"{path}: {len(names)} columns named, rows have {rows.shape[1] if rows.size else 0}")
    return rows[:, 0], {name: rows[:, i] for i, name in enumerate(names)}


def cmd_segments(args):
    ref = read_tum(args.reference)
    ests = [read_tum(p) for p in args.estimate]
    # Reference rows every estimate pairs with, and each estimate's row for them.
    common = np.arange(len(ref))
    pairs = []
    for est in ests:
        e, r, _ = associate(est.times, ref.times, "time", args.max_dt)
        pairs.append(dict(zip(r.tolist(), e.tolist())))
        common = np.intersect1d(common, r)
    if len(common) < 2:
        raise ToolError("segments: fewer than 2 reference poses pair with every estimate by time")
    res = [segment_differences(ref.poses[common], est.poses[[pr[i] for i in common]], args.length)
           for est, pr in zip(ests, pairs)]
    starts, ends = res[0]["start"], res[0]["end"]
    t0 = ref.times[common[0]]
    extra = {}
    if args.frame_stats:
        ft, cols = read_frame_stats(args.frame_stats)
        missing = [c for c in SEGMENT_COUNTERS + SEGMENT_NOISES if c not in cols]
        if missing:
            raise ToolError(f"{args.frame_stats}: no column {', '.join(missing)}")
        e0 = [pairs[0][i] for i in common]
        fi, ei, _ = associate(ft, ests[0].times[e0], "time", args.max_dt)
        row = dict(zip(ei.tolist(), fi.tolist()))
        if len(row) < len(e0):
            raise ToolError(f"{args.frame_stats}: {len(e0) - len(row)} poses of {args.estimate[0]} have no line")
        a = np.array([row[int(i)] for i in starts])
        b = np.array([row[int(i)] for i in ends])
        for c in SEGMENT_COUNTERS:
            extra[c] = cols[c][b] - cols[c][a]
        for c in SEGMENT_NOISES:
            extra[c] = cols[c][b]

    names = [est.name for est in ests]
    header = ["start_time", "start", "end", "ref_distance", "ref_turn_deg"]
    for k in range(len(ests)):
        header += [f"d_trans_{k}", f"d_rot_deg_{k}", f"scale_{k}"]
    header += list(extra)
    table = [ref.times[common[starts]] - t0, starts, ends, res[0]["ref_distance"], np.degrees(res[0]["ref_turn"])]
    for r in res:
        table += [r["d_translation"], np.degrees(r["d_rotation"]), r["scale"]]
    table += list(extra.values())
    table = np.column_stack(table)
    if args.csv:
        try:
            np.savetxt(args.csv, table, delimiter=",", header=",".join(header), comments="", fmt="%.6g")
        except OSError as exc:
            raise ToolError(f"cannot write {args.csv}: {exc.strerror}") from exc

    print(f"reference {ref.name}: {len(common)} poses paired, {len(starts)} segments of {args.length}, "
          f"{res[0]['ref_distance'].sum():.1f} m, turning {np.degrees(res[0]['ref_turn']).sum():.0f} deg")
    for k, (name, r) in enumerate(zip(names, res)):
        rot = np.degrees(r["d_rotation"])
        print(f"[{k}] {name}: d_trans sum {r['d_translation'].sum():.2f} m, "
              f"rms {np.sqrt(np.mean(r['d_translation'] ** 2)):.3f} m; "
              f"d_rot sum {rot.sum():.2f} deg, rms {np.sqrt(np.mean(rot ** 2)):.3f} deg; "
              f"length ratio {r['scale'][np.isfinite(r['scale'])].mean():.4f}")
    order = np.argsort(-res[0]["d_translation"])[:max(args.top, 0)]
    if len(order):
        print("largest d_trans of [0] (t from the first pose, s):")
        print("  " + "  ".join(header))
        for i in order:
            print("  " + "  ".join(f"{v:.4g}" for v in table[i]))
    return 0


def cmd_reprojection(args):
    if args.length < 1:
        raise ToolError("reprojection: the segment length must be at least 1 frame")
    data = load_npz(args.data)
    k = np.asarray(data["K"], dtype=float)
    trajs = [read_tum(p) for p in args.estimate]
    res = reprojection_check(np.asarray(data["features"], dtype=float),
                             np.asarray(data["time_stamps"], dtype=float).reshape(-1), k[0, 0], k[1, 1], k[0, 2],
                             k[1, 2], float(data["b"]), np.asarray(data["cam_T_imu"], dtype=float),
                             [(t.times, t.poses) for t in trajs], args.length, args.min_disparity)
    m = res["median"]
    if m.shape[0] == 0:
        raise ToolError("reprojection: no segment with 8 tracks seen at both ends and paired with every estimate")
    print(f"{m.shape[0]} segments of {args.length} frames")
    for name, col in zip([t.name for t in trajs] + ["pixels' own fit"], m.T):
        print(f"{name}: median track error {np.median(col):.2f} px (mean of segment medians {col.mean():.2f}), "
              f"segments under 2 px {np.mean(col < 2.0):.3f}")
    return 0


def main(argv=None):
    args = build_parser().parse_args(argv)
    handlers = {"ate": cmd_ate, "plot": cmd_plot, "animate": cmd_animate, "deadreckon": cmd_deadreckon,
                "consistency": cmd_consistency, "gt": cmd_gt, "segments": cmd_segments,
                "reprojection": cmd_reprojection, "velocities": cmd_velocities}
    try:
        return handlers[args.command](args)
    except ToolError as exc:
        print(f"evaluate: error: {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    cli.run(main)
