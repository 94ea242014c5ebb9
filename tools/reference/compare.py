"""Run vislam-run and the NumPy reference filter on the same log; print per-step times and how far
the two trajectories are apart.

    tools/reference/compare LOG [--preset default|seed] [--config FILE] [--max-landmarks N]
                            [--max-steps N] [--set KEY=VALUE ...] [--tolerance M] [--json OUT]

vislam-run runs the whole log with --timing (its percentiles come from the vl_latency histogram,
at most 6.25% above the true value); the reference runs the first --max-steps frames (all by
default) in this process with one BLAS thread, timed with time.perf_counter. The agreement is over
the poses both have: position difference (m) and rotation difference (the angle of R_c^T R_ref,
rad). The C poses are read from its TUM file, printed to 1e-9. Exit status 1 when --tolerance is
given and the largest position difference exceeds it (or the two have different frames).
"""

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from vislam_tools import ToolError
from vislam_tools.geometry import so3_log
from vislam_tools.trajio import read_tum
from vislam_tools.vislam_config import read_config

from . import vl_reference

REPO = Path(__file__).resolve().parents[2]


def _build_dir():
    return Path(os.environ.get("VISLAM_BUILD_DIR") or os.environ.get("VL_BUILD_DIR") or REPO / "build")


def _override(cfg, assignment):
    """KEY=VALUE on top of the configuration (true/false, mode names, or a number)."""
    key, _, value = assignment.partition("=")
    if key not in cfg:
        raise ToolError(f"--set {assignment}: no configuration key '{key}'")
    cfg[key] = value == "true" if value in ("true", "false") else (value if key == "mode" else float(value))


def _percentiles(seconds):
    us = np.array(seconds) * 1e6
    if us.size == 0:
        return {"count": 0}
    return {"count": int(us.size), "median_us": float(np.median(us)), "p99_us": float(np.percentile(us, 99)),
            "max_us": float(us.max())}


def agreement(c_traj, ref):
    """Position and rotation differences over the frames both trajectories have, in order."""
    n = min(len(c_traj), len(ref.utimes))
    times_equal = bool(np.array_equal(np.round(c_traj.times[:n] * 1e6).astype(np.int64),
                                      np.array(ref.utimes[:n], dtype=np.int64)))
    dp = np.linalg.norm(c_traj.positions[:n] - np.array(ref.positions[:n]).reshape(-1, 3), axis=1)
    # The log map, not arccos of the trace, which cannot resolve angles under about 1e-8 rad.
    dr = np.array([np.linalg.norm(so3_log(c_traj.poses[i, :3, :3].T @ ref.rotations[i])) for i in range(n)])
    return {"frames_compared": n, "frames_c": len(c_traj), "frames_reference": len(ref.utimes),
            "times_equal": times_equal,
            "position_max_m": float(dp.max()) if n else 0.0,
            "position_rms_m": float(np.sqrt(np.mean(dp ** 2))) if n else 0.0,
            "rotation_max_rad": float(dr.max()) if n else 0.0,
            "rotation_rms_rad": float(np.sqrt(np.mean(dr ** 2))) if n else 0.0,
            "first_frame_over_1e-6_m": int(np.argmax(dp > 1e-6)) if (dp > 1e-6).any() else None}


def main(argv=None):
    ap = argparse.ArgumentParser(prog="tools/reference/compare", description=__doc__.split("\n\n")[0])
    ap.add_argument("log", help="LCM log (tools/npz2lcm, vislam-sim)")
    ap.add_argument("--preset", choices=("default", "seed"), default="default")
    ap.add_argument("--config", help="INI file for both (vislam-run --config)")
    ap.add_argument("--max-landmarks", type=int, default=128, help="window (default 128)")
    ap.add_argument("--max-steps", type=int, help="compare only the first N frames (the reference stops there)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="change one value for the reference only (to see how far it moves the result)")
    ap.add_argument("--tolerance", type=float, help="exit 1 when the largest position difference exceeds this (m)")
    ap.add_argument("--trajectory", help="also write the reference's TUM trajectory here")
    ap.add_argument("--json", help="write the figures as JSON here")
    ap.add_argument("--build-dir", type=Path, default=None, help="where bin/vislam-run is (default: build)")
    a = ap.parse_args(argv)
    try:
        vislam_run = (a.build_dir or _build_dir()) / "bin" / "vislam-run"
        if not vislam_run.is_file():
            raise ToolError(f"{vislam_run} not found: build first (cmake --build build)")
        opts = ["--max-landmarks", str(a.max_landmarks)]
        if a.preset != "default":
            opts += ["--preset", a.preset]
        if a.config:
            opts += ["--config", a.config]
        cfg = read_config(vislam_run, a.preset if a.preset != "default" else None, a.config, a.max_landmarks)
        for s in a.set:
            _override(cfg, s)
        with tempfile.TemporaryDirectory() as tmp:
            tum, stats = Path(tmp) / "c.tum", Path(tmp) / "c.json"
            subprocess.run([str(vislam_run), a.log, "--trajectory", str(tum), "--timing", "--stats-json", str(stats),
                            "--quiet"] + opts, check=True, stderr=subprocess.DEVNULL)
            c_traj = read_tum(tum)
            c_timing = json.loads(stats.read_text())["timing"]
        ref = vl_reference.run(vl_reference.read_log(a.log), cfg, a.max_steps)
    except (ToolError, vl_reference.ReferenceError, subprocess.CalledProcessError, OSError) as exc:
        print(f"compare: {exc}", file=sys.stderr)
        return 2
    if a.trajectory:
        vl_reference.write_tum(a.trajectory, ref)
    agree = agreement(c_traj, ref)
    timing = {"c": c_timing, "reference": {"update": _percentiles(ref.update_seconds),
                                           "propagate": _percentiles(ref.propagate_seconds)}}
    cu, ru = c_timing["vl_update"], timing["reference"]["update"]
    ratio = {"update_median": ru["median_us"] / max(cu["median_us"], 1),
             "update_max": ru["max_us"] / max(cu["max_us"], 1)}
    print(f"log {a.log}, preset {a.preset}, window {a.max_landmarks}"
          + (f", reference changed: {' '.join(a.set)}" if a.set else ""))
    print(f"  frames: C {agree['frames_c']}, reference {agree['frames_reference']}, "
          f"compared {agree['frames_compared']} (same times: {agree['times_equal']})")
    print(f"  per-step time of the update (us): C median {cu['median_us']}, max {cu['max_us']}; "
          f"reference median {ru['median_us']:.0f}, max {ru['max_us']:.0f}; "
          f"ratio {ratio['update_median']:.1f}x (median), {ratio['update_max']:.1f}x (max)")
    cp, rp = c_timing["vl_propagate"], timing["reference"]["propagate"]
    print(f"  per-step time of the prediction (us): C median {cp['median_us']}, max {cp['max_us']}; "
          f"reference median {rp['median_us']:.0f}, max {rp['max_us']:.0f}")
    print(f"  agreement: position max {agree['position_max_m']:.3g} m, rms {agree['position_rms_m']:.3g} m; "
          f"rotation max {agree['rotation_max_rad']:.3g} rad, rms {agree['rotation_rms_rad']:.3g} rad")
    if a.json:
        Path(a.json).write_text(json.dumps({"log": a.log, "preset": a.preset, "max_landmarks": a.max_landmarks,
                                            "set": a.set, "agreement": agree, "timing": timing,
                                            "ratio": ratio, "reference_counters": ref.counters}, indent=1) + "\n")
    bad = not agree["times_equal"] or (a.max_steps is None and agree["frames_c"] != agree["frames_reference"])
    if a.tolerance is not None and (bad or agree["position_max_m"] > a.tolerance):
        print(f"compare: the trajectories differ by more than {a.tolerance} m", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
