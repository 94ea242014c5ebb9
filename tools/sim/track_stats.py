#!/usr/bin/env python3
"""Track statistics of the seed datasets, to set the simulator's realistic rates.

Reads ../shared/data/{0022,0027,0034}.npz (and gt/kitti_odometry_07.txt for 0027) and prints,
per drive: observations per frame, track lengths, disparities, stale frames (every observation's
pixels equal to the previous frame's), re-associated ids (an id whose pixels jump far from what
its neighbours in the image do), and on 0027, through the ground truth, one-step reprojection
errors (outliers and tracks on moving objects) and which ground-truth pose each frame shows
(what a stale frame really is). Prints summary statistics only; nothing is written.

    /work/main/.venv/bin/python tools/sim/track_stats.py [--data DIR] [--drives 0022,0027,0034]
"""
import argparse
import os
import sys

import numpy as np

# An id's one-frame motion that differs from its image neighbours' by more than this is a jump.
JUMP_PX = 25.0
NEIGHBOURS = 6


def load(path):
    d = np.load(path)
    f = d["features"]  # (4, M, T)
    return {
        "f": f,
        "valid": f[0] >= 0,  # (M, T)
        "K": d["K"],
        "b": float(d["b"]),
        "cam_T_imu": d["cam_T_imu"],
        "t": d["time_stamps"].ravel(),
    }


def load_lcmlog(path, build_dir):
    """The same arrays from an LCM log (vislam-sim's or npz2lcm's), for comparing the simulator."""
    sys.path.insert(0, os.path.join(build_dir, "lcm_types", "python"))
    import lcm  # noqa: E402  (the project venv has it)
    from vislam import calibration_t, stereo_frame_t  # noqa: E402  (generated at build time)
    calib, frames = None, []
    for ev in lcm.EventLog(path, "r"):
        if ev.channel.endswith("CALIB") and calib is None:
            calib = calibration_t.decode(ev.data)
        elif ev.channel.endswith("FEATURES"):
            m = stereo_frame_t.decode(ev.data)
            n = m.num_features
            obs = np.array([m.u_left[:n], m.v_left[:n], m.u_right[:n], m.v_right[:n]], dtype=float).T
            frames.append((m.utime, np.array(m.id[:n], dtype=np.int64), obs))
    ids = np.unique(np.concatenate([fr[1] for fr in frames]))
    col = {int(i): j for j, i in enumerate(ids)}
    f = np.full((4, len(ids), len(frames)), -1.0)
    for t, (_, fid, obs) in enumerate(frames):
        f[:, [col[int(i)] for i in fid], t] = obs.T
    K = np.array([[calib.fx, 0, calib.cx], [0, calib.fy, calib.cy], [0, 0, 1]])
    return {"f": f, "valid": f[0] >= 0, "K": K, "b": float(calib.baseline),
            "cam_T_imu": np.array(calib.cam_T_imu, dtype=float).reshape(4, 4),
            "t": np.array([fr[0] for fr in frames]) * 1e-6}


def tum_cam_poses(path, cam_T_imu):
    """Left-camera poses in the world from a TUM file of IMU poses: w_T_cam = w_T_i * imu_T_cam."""
    rows = np.loadtxt(path)
    P = np.zeros((len(rows), 4, 4))
    for i, (_, x, y, z, qx, qy, qz, qw) in enumerate(rows):
        R = np.array([
            [1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy - qz * qw), 2 * (qx * qz + qy * qw)],
            [2 * (qx * qy + qz * qw), 1 - 2 * (qx * qx + qz * qz), 2 * (qy * qz - qx * qw)],
            [2 * (qx * qz - qy * qw), 2 * (qy * qz + qx * qw), 1 - 2 * (qx * qx + qy * qy)]])
        P[i, :3, :3] = R
        P[i, :3, 3] = (x, y, z)
        P[i, 3, 3] = 1.0
    return P @ np.linalg.inv(cam_T_imu)


def pct(x):
    return 100.0 * x


def runs_of(flags):
    """Lengths of the runs of True in a boolean sequence."""
    out, n = [], 0
    for v in flags:
        if v:
            n += 1
        elif n:
            out.append(n)
            n = 0
    if n:
        out.append(n)
    return out


def stale_frames(D):
    f, valid = D["f"], D["valid"]
    T = valid.shape[1]
    stale = np.zeros(T, bool)
    for k in range(1, T):
        # New ids may start on a stale frame (the tracker detects on the repeated image); the
        # ids it continues carry exactly the previous pixels.
        ids = np.nonzero(valid[:, k] & valid[:, k - 1])[0]
        if len(ids) == 0:
            continue
        if np.array_equal(f[:, ids, k], f[:, ids, k - 1]):
            stale[k] = True
    return stale


def same_id_set(D, k):
    return np.array_equal(D["valid"][:, k], D["valid"][:, k - 1])


def jumps(D, stale):
    """Per frame k (k >= 1): ids seen at k-1 and k, and which of them jump."""
    f, valid = D["f"], D["valid"]
    T = valid.shape[1]
    per_frame = []  # (k, n_pairs, n_jumps)
    jump_ids = []
    for k in range(1, T):
        ids = np.nonzero(valid[:, k] & valid[:, k - 1])[0]
        if len(ids) < NEIGHBOURS + 1:
            continue
        a = f[0:2, ids, k - 1].T
        b = f[0:2, ids, k].T
        flow = b - a
        d2 = ((a[:, None, :] - a[None, :, :]) ** 2).sum(-1)
        np.fill_diagonal(d2, np.inf)
        nn = np.argsort(d2, axis=1)[:, :NEIGHBOURS]
        local = np.median(flow[nn], axis=1)
        res = np.linalg.norm(flow - local, axis=1)
        j = res > JUMP_PX
        per_frame.append((k, len(ids), int(j.sum())))
        jump_ids.extend(ids[j].tolist())
    return per_frame, jump_ids


def track_lengths(valid):
    return valid.sum(axis=1)


def gt_cam_poses(path, n):
    rows = np.loadtxt(path)
    P = np.zeros((len(rows), 4, 4))
    P[:, :3, :] = rows[:, 1:13].reshape(-1, 3, 4)
    P[:, 3, 3] = 1.0
    return P[:n]


def triangulate(D, k, ids):
    """Points in the left camera frame at step k from stereo (rectified)."""
    K, b = D["K"], D["b"]
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    ul, vl, ur = D["f"][0, ids, k], D["f"][1, ids, k], D["f"][2, ids, k]
    disp = ul - ur
    z = fx * b / np.where(disp > 0, disp, np.nan)
    x = (ul - cx) * z / fx
    y = (vl - cy) * z / fy
    return np.stack([x, y, z], 1)


def project(D, pc):
    K = D["K"]
    with np.errstate(invalid="ignore", divide="ignore"):
        u = K[0, 0] * pc[:, 0] / pc[:, 2] + K[0, 2]
        v = K[1, 1] * pc[:, 1] / pc[:, 2] + K[1, 2]
    return np.stack([u, v], 1)


def transform(T, p):
    return p @ T[:3, :3].T + T[:3, 3]


def moved_points(D, W, k, k2, pose_k, pose_k2, ids, depth_max=60.0):
    """The tracks ids (seen at k and k2) triangulated at frame k (camera at pose_k), 1 to depth_max m
    deep, in the camera at pose_k2: the ids kept and their points."""
    pc = triangulate(D, k, ids)
    ok = np.isfinite(pc[:, 2]) & (pc[:, 2] > 1.0) & (pc[:, 2] < depth_max)
    return ids[ok], transform(np.linalg.inv(W[pose_k2]) @ W[pose_k], pc[ok])


def one_step_errors(D, W, k, k2, pose_k, pose_k2):
    """Left-pixel errors of points triangulated at frame k (camera at pose_k), seen at frame k2."""
    valid = D["valid"]
    ids = np.nonzero(valid[:, k] & valid[:, k2])[0]
    if len(ids) == 0:
        return ids, np.zeros(0)
    ids, q = moved_points(D, W, k, k2, pose_k, pose_k2, ids)
    err = np.linalg.norm(project(D, q) - D["f"][0:2, ids, k2].T, axis=1)
    return ids, err


def step_residuals(D, W, k, k2, pose_k, pose_k2, sel):
    """u, v and disparity residuals (px) at frame k2 of the tracks sel seen at k and k2: triangulated
    at k (camera at pose_k), moved to pose_k2."""
    valid, f, K, b = D["valid"], D["f"], D["K"], D["b"]
    ids, q = moved_points(D, W, k, k2, pose_k, pose_k2, np.intersect1d(np.nonzero(valid[:, k] & valid[:, k2])[0], sel))
    uv = project(D, q)
    disp = K[0, 0] * b / q[:, 2]
    seen = f[:, ids, k2]
    return np.column_stack([uv[:, 0] - seen[0], uv[:, 1] - seen[1], disp - (seen[0] - seen[2])])


def robust_std(x):
    return 1.4826 * float(np.median(np.abs(x - np.median(x))))


def report(name, D, W):
    f, valid = D["f"], D["valid"]
    M, T = valid.shape
    print(f"== {name}: {T} frames, {M} ids")
    n = valid.sum(axis=0)
    print(f"observations/frame: mean {n.mean():.1f} median {np.median(n):.0f} "
          f"p5 {np.percentile(n, 5):.0f} p95 {np.percentile(n, 95):.0f} min {n.min()} max {n.max()}")
    L = track_lengths(valid)
    L = L[L > 0]
    gaps = 0
    for i in range(M):
        idx = np.nonzero(valid[i])[0]
        if len(idx) > 1:
            gaps += int((np.diff(idx) > 1).any())
    print(f"track length (frames): mean {L.mean():.1f} median {np.median(L):.0f} "
          f"p10 {np.percentile(L, 10):.0f} p90 {np.percentile(L, 90):.0f} max {L.max()}; "
          f"length 1: {pct((L == 1).mean()):.1f}%; ids with a gap: {gaps}")
    disp = (f[0] - f[2])[valid]
    print(f"disparity (px): median {np.median(disp):.1f} p5 {np.percentile(disp, 5):.2f} "
          f"p95 {np.percentile(disp, 95):.1f}; <2 px {pct((disp < 2).mean()):.1f}% "
          f"<5 px {pct((disp < 5).mean()):.1f}% <=0 px {pct((disp <= 0).mean()):.2f}%")
    dv = (f[1] - f[3])[valid]
    print(f"v_left - v_right (px): median {np.median(dv):.2f} std {dv.std():.2f} "
          f"|.|>2 px {pct((np.abs(dv) > 2).mean()):.2f}%")

    stale = stale_frames(D)
    ks = np.nonzero(stale)[0]
    runs = runs_of(stale)
    same_set = sum(same_id_set(D, k) for k in ks)
    new_ids = sum(int((valid[:, k] & ~valid[:, k - 1]).sum()) for k in ks)
    ended = sum(int((valid[:, k - 1] & ~valid[:, k]).sum()) for k in ks)
    new_all = sum(int((valid[:, k] & ~valid[:, k - 1]).sum()) for k in range(1, T))
    ended_all = sum(int((valid[:, k - 1] & ~valid[:, k]).sum()) for k in range(1, T))
    print(f"stale frames: {len(ks)} ({pct(len(ks) / T):.1f}%), runs {len(runs)}, "
          f"run lengths {dict(zip(*[x.tolist() for x in np.unique(runs, return_counts=True)])) if runs else {}}; "
          f"same id set as k-1: {same_set}; per stale frame: new ids {new_ids / max(1, len(ks)):.1f}, "
          f"ended ids {ended / max(1, len(ks)):.1f} (all frames: new {new_all / (T - 1):.1f}, "
          f"ended {ended_all / (T - 1):.1f})")
    first = np.array([np.nonzero(valid[i])[0][0] for i in range(M) if valid[i].any()])
    print(f"  tracks that start on a stale frame: {pct(stale[first].mean()):.1f}% "
          f"(frame 0: {pct((first == 0).mean()):.1f}%)")
    if len(ks) > 1:
        gaps_between = np.diff(ks)
        print(f"  frames between stale frames: median {np.median(gaps_between):.0f} "
              f"min {gaps_between.min()} max {gaps_between.max()}")
    dt = np.diff(D["t"])
    if len(ks):
        print(f"  dt into stale frames: mean {dt[ks - 1].mean():.4f} s; overall mean {dt.mean():.4f} s")

    new_elsewhere = sum(int((valid[:, k] & ~valid[:, k - 1]).sum()) for k in range(1, T) if not stale[k])
    print(f"  new ids on frames that are not stale: {new_elsewhere}")
    if len(ks):
        print(f"  observations on the frame before a stale frame: median {np.median(n[ks - 1]):.0f} "
              f"max {n[ks - 1].max()} (every frame: median {np.median(n):.0f}) -> the tracker detects when "
              f"its tracks fall under a threshold, and its detection frames are the stale ones")
    per_frame, _ = jumps(D, stale)
    pairs = sum(p for _, p, _ in per_frame)
    nj = sum(j for _, _, j in per_frame)
    print(f"flow residual against the 6 image neighbours > {JUMP_PX:.0f} px: {pct(nj / pairs):.2f}% of "
          f"continuations (an upper bound on re-associations: near points beside far ones move apart "
          f"by parallax; the ground truth on 0027 separates them)")

    if W is None:
        return
    W = W[:T]
    Tg = len(W)
    stale = stale[:Tg]
    print(f"-- ground truth: {Tg} poses (left camera)")
    e3 = e10 = etot = 0
    track_err = {}
    for k in range(Tg - 1):
        if stale[k + 1] or stale[k]:
            continue
        ids, err = one_step_errors(D, W, k, k + 1, k, k + 1)
        etot += len(err)
        e3 += int((err > 3).sum())
        e10 += int((err > 10).sum())
        for i, e in zip(ids, err):
            track_err.setdefault(i, []).append(e)
    print(f"one-step reprojection (triangulated at k with GT k, projected with GT k+1; depth 1-60 m; "
          f"no stale frame involved): {etot} obs, >3 px {pct(e3 / etot):.2f}%, >10 px {pct(e10 / etot):.2f}%")
    allerr = np.concatenate([np.array(v) for v in track_err.values()])
    print(f"  error median {np.median(allerr):.2f} px, p90 {np.percentile(allerr, 90):.2f}, "
          f"p99 {np.percentile(allerr, 99):.1f}")
    long_tracks = {i: np.array(v) for i, v in track_err.items() if len(v) >= 4}
    bad = [i for i, v in long_tracks.items() if np.median(v) > 3.0]
    print(f"  tracks with >= 4 steps whose median one-step error > 3 px (moving objects or consistent "
          f"mismatches): {len(bad)} of {len(long_tracks)} ({pct(len(bad) / max(1, len(long_tracks))):.1f}%)")
    # Single outliers: an error > 10 px in an otherwise good track, not at a jump.
    single = sum(int(((v > 10) & (np.median(v) < 2.0)).sum()) for v in long_tracks.values())
    print(f"  isolated >10 px errors inside good tracks: {single} ({pct(single / etot):.2f}% of obs)")

    classify_steps(D, W, stale)
    if stale.any():
        stale_geometry(D, W, stale)


def classify_steps(D, W, stale):
    """Runs of one-step errors > 10 px along each track (no stale frame involved): one step alone is
    an id handed to another point (it continues consistently), two in a row one mismatched
    observation (error into and out of it), three or more a track that is wrong throughout."""
    valid = D["valid"]
    Tg = len(W)
    errs = {}
    for k in range(Tg - 1):
        if stale[k] or stale[k + 1]:
            continue
        ids, err = one_step_errors(D, W, k, k + 1, k, k + 1)
        for i, e in zip(ids, err):
            errs.setdefault(int(i), {})[k] = e
    steps = sum(len(v) for v in errs.values())
    runs = {1: 0, 2: 0, 3: 0}
    frames_with_jump = set()
    for i, by_k in errs.items():
        ks = sorted(by_k)
        k_prev, run, start = None, 0, None
        for k in ks + [None]:
            big = k is not None and by_k[k] > 10.0 and (k_prev is None or k == k_prev + 1 or run == 0)
            if big:
                if run == 0:
                    start = k
                run += 1
            else:
                if run:
                    runs[min(run, 3)] += 1
                    if run == 1:
                        frames_with_jump.add(start + 1)
                run = 0
                if k is not None and by_k[k] > 10.0:
                    run, start = 1, k
            k_prev = k
    print(f"  runs of one-step errors > 10 px along a track: single {runs[1]} "
          f"({pct(runs[1] / steps):.2f}% of steps, {runs[1] / Tg:.3f} per frame, in "
          f"{pct(len(frames_with_jump) / Tg):.1f}% of frames) = ids handed to another point; "
          f"pairs {runs[2]} ({pct(runs[2] / steps):.2f}% of obs) = single mismatched observations; "
          f"3 or more {runs[3]}")


def stale_geometry(D, W, stale):
    """What a stale frame k is: which GT motion the tracks show across it, split into tracks that
    existed before k (old) and tracks that start at k (new)."""
    valid, f = D["valid"], D["f"]
    Tg = len(W)
    ks = [k for k in np.nonzero(stale)[0] if 2 <= k < Tg - 2]

    def med(k, k2, pa, pb, sel):
        ids, e = one_step_errors(D, W, k, k2, pa, pb)
        e = e[np.isin(ids, sel)]
        return float(np.median(e)) if len(e) else np.nan

    rows = {}
    for k in ks:
        old = np.nonzero(valid[:, k - 1] & valid[:, k] & valid[:, k + 1])[0]
        new = np.nonzero(~valid[:, k - 1] & valid[:, k] & valid[:, k + 1])[0]
        cand = {
            "old k-1 -> k+1 as GT k-1 -> k+1 (on time)": med(k - 1, k + 1, k - 1, k + 1, old),
            "old k-1 -> k+1 as GT k-1 -> k (one step lost)": med(k - 1, k + 1, k - 1, k, old),
            "old k+1 -> k+2 as GT k+1 -> k+2 (on time after)": med(k + 1, k + 2, k + 1, k + 2, old),
            "old k+1 -> k+2 as GT k -> k+1 (still behind)": med(k + 1, k + 2, k, k + 1, old),
            "new k -> k+1 as GT k -> k+1 (on time)": med(k, k + 1, k, k + 1, new),
            "new k -> k+1 as GT k-1 -> k (image k is k-1's)": med(k, k + 1, k - 1, k, new),
        }
        for key, val in cand.items():
            rows.setdefault(key, []).append(val)
    print(f"stale frames with ground truth: {len(ks)}; median one-step error (px) of:")
    for key, vals in rows.items():
        print(f"  {key:50s} {np.nanmedian(vals):6.2f}")
    a = np.array(rows["old k-1 -> k+1 as GT k-1 -> k+1 (on time)"])
    b = np.array(rows["old k-1 -> k+1 as GT k-1 -> k (one step lost)"])
    print(f"  old tracks lose one step across the stale frame in {int(np.sum(b < a))} of {len(ks)}")
    same = sum(np.array_equal(f[:, valid[:, k - 1] & valid[:, k], k],
                              f[:, valid[:, k - 1] & valid[:, k], k - 1]) for k in ks)
    print(f"  old tracks' pixels at k equal k-1's exactly in {same} of {len(ks)}")
    # The scatter about the one-step-lost motion (the simulator's stale_jump): the carried tracks
    # across the stale frame against every track over an ordinary step, as robust stds.
    across = [step_residuals(D, W, k - 1, k + 1, k - 1, k, np.nonzero(valid[:, k - 1] & valid[:, k])[0])
              for k in ks]
    ordinary = [step_residuals(D, W, k, k + 1, k, k + 1, np.arange(valid.shape[0]))
                for k in range(Tg - 1) if not (stale[k] or stale[k + 1])]
    a, o = np.concatenate(across), np.concatenate(ordinary)
    sa = [robust_std(a[:, j]) for j in range(3)]
    so = [robust_std(o[:, j]) for j in range(3)]
    jump = [float(np.sqrt(max(0.0, x * x - y * y))) for x, y in zip(sa, so)]
    print(f"  carried tracks across the stale frame (as GT k-1 -> k), robust std u / v / disparity: "
          f"{sa[0]:.2f} / {sa[1]:.2f} / {sa[2]:.2f} px ({len(a)} obs); over an ordinary step "
          f"{so[0]:.2f} / {so[1]:.2f} / {so[2]:.2f} px; the jump (their difference in quadrature) "
          f"{jump[0]:.2f} / {jump[1]:.2f} / {jump[2]:.2f} px")


def main():
    here = os.path.dirname(os.path.abspath(__file__))
    default_data = os.path.normpath(os.path.join(here, "..", "..", "..", "shared", "data"))
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", default=default_data)
    ap.add_argument("--drives", default="0022,0027,0034")
    ap.add_argument("--lcmlog", help="measure this LCM log (e.g. vislam-sim's) instead of the drives")
    ap.add_argument("--truth", help="with --lcmlog: its TUM truth (IMU poses), for the ground-truth part")
    ap.add_argument("--build", default=os.path.normpath(os.path.join(here, "..", "..", "build")),
                    help="build directory holding the generated LCM Python types")
    a = ap.parse_args()
    if a.lcmlog:
        D = load_lcmlog(a.lcmlog, a.build)
        report(os.path.basename(a.lcmlog), D, tum_cam_poses(a.truth, D["cam_T_imu"]) if a.truth else None)
        return 0
    for name in a.drives.split(","):
        path = os.path.join(a.data, name + ".npz")
        if not os.path.exists(path):
            print(f"{path}: missing, skipped", file=sys.stderr)
            continue
        D = load(path)
        gt = os.path.join(a.data, "gt", "kitti_odometry_07.txt") if name == "0027" else None
        report(name, D, gt_cam_poses(gt, D["valid"].shape[1]) if gt and os.path.exists(gt) else None)
    return 0


if __name__ == "__main__":
    sys.exit(main())
