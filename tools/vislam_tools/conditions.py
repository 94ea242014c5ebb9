"""Build a test condition from a seed dataset: a modified .npz with the same arrays and format.

The output converts with tools/npz2lcm like the seed datasets. One condition is a choice of
velocities (the given, noisy ones, or clean ones derived from the ground truth), extra Gaussian
velocity noise, and a feature density: every K-th track id kept, or the tracks a sparse tracker of
at most N tracks at once would keep.

Clean velocities: the ground truth is KITTI left-camera poses; with w_T_i = w_T_cam * cam_T_imu
and the seed's motion model w_T_i(t+1) = w_T_i(t) exp(tau_t hat(u_t)), the body-frame twist is
u_t = log(w_T_i(t)^-1 w_T_i(t+1)) / tau_t, [v; w] ordering, tau_t from the dataset's time stamps.
"""

import argparse
import json
import sys

import numpy as np

from . import ToolError, cli
from .geometry import body_twists
from .trajio import load_npz, read_kitti

# The noise of the given velocities against the clean recordings (the data README's figures).
GIVEN_LINEAR_STD = 0.5  # m/s per sample
GIVEN_ANGULAR_STD = 0.05  # rad/s per sample

EPILOG = f"""\
Velocities:
  given   the dataset's own velocities (noise about {GIVEN_LINEAR_STD} m/s, {GIVEN_ANGULAR_STD} rad/s per sample and a
          small offset); --velocity-noise-scale X adds independent noise so the total standard
          deviation is X times that: extra std = base * sqrt(X^2 - 1).
  clean   derived from --gt (KITTI odometry left-camera poses, line i = step i) through the
          dataset's cam_T_imu. The output is cut to the ground truth's length N (steps 0..N-1)
          when the dataset has more steps; velocity N-1 is never integrated (it would move the
          pose past the last step) and holds velocity N-2. Dead reckoning of the output
          reproduces the ground-truth IMU poses. --velocity-noise SIGMA_V,SIGMA_W adds noise.
  clean-imu  the same, of the real IMU: the seed datasets' cam_T_imu has as its translation t
          the camera's position in the IMU frame, which puts its "IMU" 2.6 m from the real one;
          these velocities go through cam_T_imu with the translation -R t instead (the real
          IMU's place), as a recording of clean velocities would be. The output keeps the
          dataset's cam_T_imu, so the estimator and the evaluation see the seed's frame and the
          velocities differ from clean by w x r (README, The seed data's cam_T_imu).
Every noise is white Gaussian, independent per axis and sample, from numpy's default_rng(--seed).

Density:
  --keep-every K   the tracks whose id is a multiple of K: a uniform thinning, every track as long
                   as it was.
  --max-tracks N   a sparse tracker: at most N tracks at once. A kept track continues for as long
                   as its id is observed; on each frame the free places go to ids observed there
                   and never kept before, drawn at random (after the noise, from the same --seed).
                   Such a tracker keeps what lasts, so long tracks (far points, objects moving with
                   the vehicle) weigh more than in a thinning. Applied after --keep-every.

Examples:
  conditions ../shared/data/0027.npz out/c.npz --velocities clean --gt ../shared/data/gt/kitti_odometry_07.txt
  conditions ../shared/data/0027.npz out/c.npz --velocity-noise-scale 2 --keep-every 5 --seed 1
  conditions ../shared/data/0027.npz out/c.npz --max-tracks 3 --seed 1
  tools/npz2lcm out/c.npz out/c.lcmlog
"""


def _pair(text):
    parts = text.split(",")
    try:
        values = [float(x) for x in parts]
    except ValueError:
        values = []
    if len(values) != 2 or not all(np.isfinite(v) and v >= 0 for v in values):
        raise argparse.ArgumentTypeError(f"expected SIGMA_V,SIGMA_W (two numbers >= 0), got '{text}'")
    return tuple(values)


def build_parser():
    p = argparse.ArgumentParser(
        prog="conditions", description=__doc__.splitlines()[0],
        formatter_class=argparse.RawDescriptionHelpFormatter, epilog=EPILOG)
    cli.add_version(p)
    p.add_argument("input", metavar="IN.npz", help="seed dataset")
    p.add_argument("output", metavar="OUT.npz", help="modified dataset to write (overwritten)")
    p.add_argument("--velocities", choices=("given", "clean", "clean-imu"), default="given",
                   help="the dataset's velocities, or clean ones from --gt (clean-imu: of the real IMU; "
                        "default given)")
    p.add_argument("--gt", metavar="KITTI.txt", help="ground truth for --velocities clean and clean-imu")
    p.add_argument("--velocity-noise", type=_pair, default=None, metavar="SIGMA_V,SIGMA_W",
                   help="add Gaussian noise: std per sample, m/s and rad/s")
    p.add_argument("--velocity-noise-scale", type=float, default=None, metavar="X",
                   help="--velocities given only: add noise so the total std is X (>= 1) times "
                        f"{GIVEN_LINEAR_STD} m/s, {GIVEN_ANGULAR_STD} rad/s")
    p.add_argument("--keep-every", type=int, default=1, metavar="K",
                   help="keep the tracks whose id j has j %% K == 0, remove the others (default 1: all)")
    p.add_argument("--max-tracks", type=int, default=None, metavar="N",
                   help="keep the tracks a sparse tracker of at most N tracks at once would have "
                        "(see Density below)")
    p.add_argument("--seed", type=int, default=0, metavar="S",
                   help="seed of the noise and of --max-tracks' draws (default 0)")
    p.add_argument("--summary-json", metavar="FILE",
                   help="also write what was done and the observations per step as JSON")
    return p


def clean_velocities(time_stamps, w_T_cam, cam_T_imu):
    """Body-frame velocities (3, N) and (3, N) that reproduce the IMU poses of N camera poses.

    time_stamps: (>= N,) s; w_T_cam: (N, 4, 4) left-camera poses; cam_T_imu: 4x4.
    Velocity t (t < N-1) moves pose t to pose t+1 over tau_t; velocity N-1 repeats N-2.
    """
    w_T_cam = np.asarray(w_T_cam, dtype=float)
    n = w_T_cam.shape[0]
    if n < 2:
        raise ToolError("clean velocities need at least 2 ground-truth poses")
    ts = np.asarray(time_stamps, dtype=float).reshape(-1)[:n]
    if ts.shape[0] < n:
        raise ToolError(f"the ground truth has {n} poses but the dataset only {ts.shape[0]} steps")
    tau = np.diff(ts)
    if np.any(tau <= 0):
        raise ToolError("time_stamps are not strictly increasing")
    twists = body_twists(ts, w_T_cam @ np.asarray(cam_T_imu, dtype=float))  # (N-1, 6)
    twists = np.vstack([twists, twists[-1:]])
    return twists[:, :3].T.copy(), twists[:, 3:].T.copy()


def real_imu_transform(cam_T_imu):
    """cam_T_imu with its translation t replaced by -R t: the seed datasets' t is the camera's
    position in the IMU frame, so this is the transform to the real IMU (README, The seed data's
    cam_T_imu)."""
    out = np.array(cam_T_imu, dtype=float, copy=True)
    out[:3, 3] = -out[:3, :3] @ out[:3, 3]
    return out


def keep_every(features, k):
    """Features (4, M, T) with the tracks of ids j % k != 0 set to -1 (a copy)."""
    if k < 1:
        raise ToolError(f"--keep-every must be >= 1, got {k}")
    out = np.array(features, dtype=float, copy=True)
    drop = np.arange(out.shape[1]) % k != 0
    out[:, drop, :] = -1.0
    return out


def sparse_tracker(features, n, rng):
    """Features (4, M, T) as a tracker of at most n tracks at once keeps them (a copy): a kept track
    continues while its id is observed (every coordinate != -1); each frame's free places go to ids
    observed there and never kept before, drawn from rng."""
    if n < 1:
        raise ToolError(f"--max-tracks must be >= 1, got {n}")
    f = np.asarray(features, dtype=float)
    observed = np.all(f != -1, axis=0)
    kept = np.zeros_like(observed)
    ever = np.zeros(observed.shape[0], dtype=bool)
    current = np.zeros(0, dtype=np.int64)
    for t in range(observed.shape[1]):
        current = current[observed[current, t]]
        if current.size < n:
            new = rng.permutation(np.flatnonzero(observed[:, t] & ~ever))[:n - current.size]
            ever[new] = True
            current = np.concatenate([current, new])
        kept[current, t] = True
    out = np.array(f, copy=True)
    out[:, ~kept] = -1.0
    return out


def observations_per_step(features):
    """Mean count of complete observations (all four coordinates != -1) per step."""
    f = np.asarray(features)
    if f.shape[2] == 0:
        return 0.0
    return float(np.count_nonzero(np.all(f != -1, axis=0)) / f.shape[2])


def make_condition(data, velocities="given", gt_w_T_cam=None, velocity_noise=None, noise_scale=None,
                   keep=1, seed=0, max_tracks=None):
    """The modified arrays (a dict of every array of `data`) and a summary dict."""
    arrays = {k: np.asarray(data[k]) for k in data.files}
    ts = np.asarray(arrays["time_stamps"], dtype=float)
    n_steps = ts.reshape(-1).shape[0]
    lin = np.asarray(arrays["linear_velocity"], dtype=float)
    ang = np.asarray(arrays["rotational_velocity"], dtype=float)
    summary = {"velocities": velocities, "keep_every": int(keep), "seed": int(seed),
               "input_steps": int(n_steps)}
    if velocity_noise is not None and noise_scale is not None:
        raise ToolError("give --velocity-noise or --velocity-noise-scale, not both")
    if velocities in ("clean", "clean-imu"):
        if gt_w_T_cam is None:
            raise ToolError(f"--velocities {velocities} needs --gt (KITTI odometry poses)")
        if noise_scale is not None:
            raise ToolError("--velocity-noise-scale scales the given velocities' noise: "
                            "use --velocity-noise SIGMA_V,SIGMA_W with clean velocities")
        n = gt_w_T_cam.shape[0]
        if n > n_steps:
            raise ToolError(f"the ground truth has {n} poses, more than the dataset's {n_steps} steps")
        cam_T_imu = arrays["cam_T_imu"] if velocities == "clean" else real_imu_transform(arrays["cam_T_imu"])
        lin, ang = clean_velocities(ts, gt_w_T_cam, cam_T_imu)
        ts = ts.reshape(-1)[:n].reshape(1, n) if ts.ndim == 2 else ts[:n]
        arrays["time_stamps"] = ts
        arrays["features"] = np.asarray(arrays["features"])[:, :, :n]
        summary["truncated_to"] = int(n)
    elif velocities != "given":
        raise ToolError(f"unknown --velocities '{velocities}'")
    sigma = (0.0, 0.0)
    if noise_scale is not None:
        if not np.isfinite(noise_scale) or noise_scale < 1.0:
            raise ToolError(f"--velocity-noise-scale must be >= 1 (the given data already has x1), got {noise_scale}")
        f = float(np.sqrt(noise_scale ** 2 - 1.0))
        sigma = (GIVEN_LINEAR_STD * f, GIVEN_ANGULAR_STD * f)
        summary["noise_scale"] = float(noise_scale)
    elif velocity_noise is not None:
        sigma = (float(velocity_noise[0]), float(velocity_noise[1]))
    rng = np.random.default_rng(seed)
    if sigma[0] > 0 or sigma[1] > 0:
        lin = lin + rng.normal(0.0, sigma[0], lin.shape) if sigma[0] > 0 else lin
        ang = ang + rng.normal(0.0, sigma[1], ang.shape) if sigma[1] > 0 else ang
    summary["added_noise"] = [sigma[0], sigma[1]]
    arrays["linear_velocity"] = np.asarray(lin, dtype=float)
    arrays["rotational_velocity"] = np.asarray(ang, dtype=float)
    if keep != 1:
        arrays["features"] = keep_every(arrays["features"], keep)
    if max_tracks is not None:
        arrays["features"] = sparse_tracker(arrays["features"], max_tracks, rng)
        summary["max_tracks"] = int(max_tracks)
    summary["steps"] = int(np.asarray(arrays["time_stamps"]).reshape(-1).shape[0])
    summary["observations_per_step"] = observations_per_step(arrays["features"])
    return arrays, summary


def main(argv=None):
    args = build_parser().parse_args(argv)
    try:
        data = load_npz(args.input)
        gt = None
        if args.gt is not None:
            if args.velocities == "given":
                raise ToolError("--gt is only used with --velocities clean or clean-imu")
            _, gt = read_kitti(args.gt)
        arrays, summary = make_condition(data, args.velocities, gt, args.velocity_noise,
                                         args.velocity_noise_scale, args.keep_every, args.seed, args.max_tracks)
        try:
            with open(args.output, "wb") as f:
                np.savez(f, **arrays)
            if args.summary_json:
                summary.update(input=args.input, output=args.output)
                with open(args.summary_json, "w") as f:
                    json.dump(summary, f, indent=2)
                    f.write("\n")
        except OSError as exc:
            raise ToolError(f"cannot write {exc.filename}: {exc.strerror}") from exc
    except ToolError as exc:
        print(f"conditions: error: {exc}", file=sys.stderr)
        return 1
    noise = summary["added_noise"]
    print(f"conditions: wrote {args.output}: {summary['steps']} steps, velocities {args.velocities}"
          f" + noise {noise[0]:.4g} m/s, {noise[1]:.4g} rad/s, every {args.keep_every} track(s) kept,"
          + (f" at most {args.max_tracks} at once," if args.max_tracks is not None else "") +
          f" {summary['observations_per_step']:.1f} observations per step")
    return 0


if __name__ == "__main__":
    cli.run(main)
