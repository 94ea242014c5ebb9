"""Convert a seed dataset (.npz, see ../shared/data/README.md) into an LCM event log.

The log replays with lcm-logplayer. Events, all with event utime = message utime:
    <prefix>CALIB     vislam.calibration_t   once, first, at the first step's time
    <prefix>IMU       vislam.imu_t           every step, before that step's features
    <prefix>FEATURES  vislam.stereo_frame_t  every step (possibly with 0 features)
With --imu-per-step R, R - 1 more IMU samples follow each step's features (not the last
step's), evenly spaced up to the next step, the velocities linear between the two steps':
a log with an R times faster IMU, for measuring the estimator's cost per frame period.
"""

import argparse
import sys

import numpy as np

from . import ToolError, channels, cli
from .lcmtypes import load, load_lcm
from .trajio import load_npz


def build_parser():
    p = argparse.ArgumentParser(
        prog="npz2lcm",
        description="Convert a seed dataset (.npz) into an LCM event log readable by lcm-logplayer.",
        epilog="Channels: <prefix>CALIB (vislam.calibration_t, once), then per step <prefix>IMU "
               "(vislam.imu_t) and <prefix>FEATURES (vislam.stereo_frame_t). Event utime = "
               "round(time_stamps[t] * 1e6).")
    cli.add_version(p)
    p.add_argument("input", metavar="IN.npz", help="seed dataset")
    p.add_argument("output", metavar="OUT.lcmlog", help="LCM event log to write (overwritten)")
    p.add_argument("--max-steps", type=int, default=None, metavar="N", help="convert at most N steps")
    p.add_argument("--start-step", type=int, default=0, metavar="K", help="first step to convert (default 0)")
    p.add_argument("--imu-per-step", type=int, default=1, metavar="R",
                   help="IMU samples per step: R - 1 more, interpolated, between steps (default 1)")
    p.add_argument("--channel-prefix", default=channels.PREFIX,
                   help=f"channel name prefix (default {channels.PREFIX})")
    return p


def convert(input_path, output_path, start_step=0, max_steps=None, prefix=channels.PREFIX, err=None,
            imu_per_step=1):
    """Write the log; returns a summary dict. Warnings go to err (default: sys.stderr)."""
    err = sys.stderr if err is None else err
    vislam = load()
    lcm = load_lcm()
    data = load_npz(input_path)
    ts = np.asarray(data["time_stamps"], dtype=float).reshape(-1)
    lin = np.asarray(data["linear_velocity"], dtype=float)
    ang = np.asarray(data["rotational_velocity"], dtype=float)
    feats = np.asarray(data["features"], dtype=float)
    k = np.asarray(data["K"], dtype=float)
    n_steps = ts.shape[0]
    if lin.shape != (3, n_steps) or ang.shape != (3, n_steps):
        raise ToolError(f"{input_path}: velocities must be (3, {n_steps}), got {lin.shape} and {ang.shape}")
    if feats.ndim != 3 or feats.shape[0] != 4 or feats.shape[2] != n_steps:
        raise ToolError(f"{input_path}: features must be (4, M, {n_steps}), got {feats.shape}")
    if start_step < 0 or start_step >= n_steps:
        raise ToolError(f"--start-step {start_step} outside 0..{n_steps - 1}")
    stop = n_steps if max_steps is None else min(n_steps, start_step + max(max_steps, 0))
    if stop <= start_step:
        raise ToolError("nothing to convert (--max-steps must be >= 1)")
    if imu_per_step < 1:
        raise ToolError("--imu-per-step must be >= 1")
    if np.any(np.diff(ts[start_step:stop]) <= 0):
        raise ToolError(f"{input_path}: time_stamps are not strictly increasing")

    utimes = np.round(ts * 1e6).astype(np.int64)
    cap = vislam.stereo_frame_t.MAX_FEATURES
    # A landmark counts as observed only when all four coordinates are present.
    observed = np.all(feats[:, :, start_step:stop] != -1, axis=0)  # (M, steps)
    partial = int(np.count_nonzero(np.any(feats[:, :, start_step:stop] != -1, axis=0) & ~observed))
    if partial:
        print(f"npz2lcm: warning: {partial} observations with only some coordinates == -1 were skipped",
              file=err)

    calib = vislam.calibration_t()
    calib.utime = int(utimes[start_step])
    calib.fx, calib.fy, calib.cx, calib.cy = float(k[0, 0]), float(k[1, 1]), float(k[0, 2]), float(k[1, 2])
    calib.baseline = float(data["b"])
    calib.cam_T_imu = [float(x) for x in np.asarray(data["cam_T_imu"], dtype=float).reshape(16)]

    ch_calib, ch_imu, ch_feat = (channels.with_prefix(c, prefix)
                                 for c in (channels.CALIBRATION, channels.IMU, channels.FEATURES))
    zeros_i = [0] * cap
    zeros_d = [0.0] * cap
    events = observations = dropped = frames_clipped = 0
    try:
        log = lcm.EventLog(str(output_path), "w", overwrite=True)
    except (IOError, OSError) as exc:
        raise ToolError(f"cannot write {output_path}: {exc}") from exc
    try:
        log.write_event(calib.utime, ch_calib, calib.encode())
        events += 1
        imu = vislam.imu_t()
        frame = vislam.stereo_frame_t()
        for col, t in enumerate(range(start_step, stop)):
            utime = int(utimes[t])
            imu.utime = utime
            imu.linear_velocity = lin[:, t].tolist()
            imu.angular_velocity = ang[:, t].tolist()
            log.write_event(utime, ch_imu, imu.encode())

            ids = np.flatnonzero(observed[:, col])
            if ids.size > cap:
                dropped += ids.size - cap
                frames_clipped += 1
                ids = ids[:cap]
            n = int(ids.size)
            obs = feats[:, ids, t]
            frame.utime = utime
            frame.num_features = n
            frame.id = ids.tolist() + zeros_i[n:]
            frame.u_left = obs[0].tolist() + zeros_d[n:]
            frame.v_left = obs[1].tolist() + zeros_d[n:]
            frame.u_right = obs[2].tolist() + zeros_d[n:]
            frame.v_right = obs[3].tolist() + zeros_d[n:]
            log.write_event(utime, ch_feat, frame.encode())
            events += 2
            observations += n
            for j in range(1, imu_per_step if t + 1 < stop else 1):
                w = j / imu_per_step
                imu.utime = int(utimes[t] + round(w * (utimes[t + 1] - utimes[t])))
                imu.linear_velocity = ((1.0 - w) * lin[:, t] + w * lin[:, t + 1]).tolist()
                imu.angular_velocity = ((1.0 - w) * ang[:, t] + w * ang[:, t + 1]).tolist()
                log.write_event(imu.utime, ch_imu, imu.encode())
                events += 1
    finally:
        log.close()
    if dropped:
        print(f"npz2lcm: warning: {frames_clipped} frames had more than {cap} observations; "
              f"dropped {dropped} observations", file=err)
    return {
        "steps": stop - start_step,
        "events": events,
        "observations": observations,
        "dropped": dropped,
        "duration": float(ts[stop - 1] - ts[start_step]),
    }


def main(argv=None):
    args = build_parser().parse_args(argv)
    try:
        s = convert(args.input, args.output, args.start_step, args.max_steps, args.channel_prefix,
                    imu_per_step=args.imu_per_step)
    except ToolError as exc:
        print(f"npz2lcm: error: {exc}", file=sys.stderr)
        return 1
    print(f"npz2lcm: wrote {args.output}: {s['steps']} steps, {s['events']} events, "
          f"{s['observations']} observations, {s['duration']:.1f} s")
    return 0


if __name__ == "__main__":
    cli.run(main)
