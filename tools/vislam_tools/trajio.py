"""File formats: TUM and KITTI trajectories, point maps (PLY, or vislamd's VISLAM_LANDMARKS recorded), calibration
from .npz or .lcmlog."""

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

import numpy as np

from . import ToolError
from .geometry import (make_pose, nearest_rotation, quat_to_rot, quat_wxyz_to_xyzw, quat_xyzw_to_wxyz, rot_to_quat,
                       se3_inv)


@dataclass
class Trajectory:
    """Timed poses: times (N,) in seconds, poses (N, 4, 4) world-from-body."""
    times: np.ndarray
    poses: np.ndarray
    name: str = ""

    def __len__(self):
        return self.times.shape[0]

    @property
    def positions(self):
        return self.poses[:, :3, 3]


def _numeric_rows(path, what):
    """Yield (line number, float array) for each non-blank, non-comment line."""
    try:
        text = Path(path).read_text()
    except OSError as exc:
        raise ToolError(f"cannot read {what} file {path}: {exc.strerror}") from exc
    for lineno, line in enumerate(text.splitlines(), start=1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        try:
            yield lineno, np.array([float(x) for x in line.replace(",", " ").split()])
        except ValueError as exc:
            raise ToolError(f"{path}:{lineno}: not a line of numbers ({exc})") from exc


def read_tum(path):
    """TUM trajectory: `time tx ty tz qx qy qz qw` per line (seconds, metres).

    Lines with a repeated time keep the last pose given for that time (e.g. a pose after an
    IMU propagation followed by one after the camera update at the same time stamp).
    """
    times, poses = [], []
    for lineno, row in _numeric_rows(path, "TUM"):
        if row.size != 8:
            raise ToolError(f"{path}:{lineno}: TUM lines need 8 numbers "
                            f"(time tx ty tz qx qy qz qw), got {row.size}")
        try:
            r = quat_to_rot(quat_xyzw_to_wxyz(row[4:8]))
        except ValueError as exc:
            raise ToolError(f"{path}:{lineno}: {exc}") from exc
        times.append(row[0])
        poses.append(make_pose(r, row[1:4]))
    if not times:
        raise ToolError(f"{path}: no poses")
    times = np.array(times)
    poses = np.array(poses)
    order = np.argsort(times, kind="stable")
    times, poses = times[order], poses[order]
    keep = np.append(times[1:] != times[:-1], True)  # last line of each run of equal times
    return Trajectory(times[keep], poses[keep], Path(path).name)


def write_tum(path, times, poses):
    """Write a TUM trajectory (evo-compatible)."""
    with open(path, "w") as f:
        for t, p in zip(times, poses):
            q = quat_wxyz_to_xyzw(rot_to_quat(p[:3, :3]))
            f.write(f"{t:.6f} {p[0, 3]:.9g} {p[1, 3]:.9g} {p[2, 3]:.9g} "
                    f"{q[0]:.9g} {q[1]:.9g} {q[2]:.9g} {q[3]:.9g}\n")


def read_kitti(path):
    """KITTI odometry poses: 12 numbers (3x4 [R|t] row-major) or 13 (time first) per line.

    Each rotation is replaced by the rotation nearest it (the printed ones are rounded).
    Returns (times or None, poses (N, 4, 4)).
    """
    times, poses = [], []
    ncols = None
    for lineno, row in _numeric_rows(path, "KITTI"):
        if row.size not in (12, 13):
            raise ToolError(f"{path}:{lineno}: KITTI lines need 12 or 13 numbers, got {row.size}")
        if ncols is None:
            ncols = row.size
        elif row.size != ncols:
            raise ToolError(f"{path}:{lineno}: {row.size} numbers where earlier lines had {ncols}")
        if ncols == 13:
            times.append(row[0])
            row = row[1:]
        p = np.eye(4)
        p[:3, :4] = row.reshape(3, 4)
        poses.append(p)
    if not poses:
        raise ToolError(f"{path}: no poses")
    poses = np.array(poses)
    # The files print 7 digits, so a rotation is orthonormal only to about 1e-7, and the angle of a
    # one-step relative rotation (arccos of a trace near 3) would be off by up to about 0.01 deg.
    poses[:, :3, :3] = nearest_rotation(poses[:, :3, :3])
    return (np.array(times) if ncols == 13 else None), poses


def sniff_trajectory_format(path):
    """'tum' or 'kitti' from the count of numbers on the first data line."""
    for lineno, row in _numeric_rows(path, "trajectory"):
        if row.size == 8:
            return "tum"
        if row.size in (12, 13):
            return "kitti"
        raise ToolError(f"{path}:{lineno}: {row.size} numbers per line is neither TUM (8) nor KITTI (12/13)")
    raise ToolError(f"{path}: empty trajectory file")


_PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}


def read_ply(path):
    """Read the vertex element of a PLY file into {property name: float64 array}.

    ASCII and binary (little/big endian) are supported for vertex properties that are scalars;
    other elements (faces...) are skipped when they come after the vertices. x, y, z are required.
    """
    try:
        raw = Path(path).read_bytes()
    except OSError as exc:
        raise ToolError(f"cannot read PLY file {path}: {exc.strerror}") from exc
    end = raw.find(b"end_header")
    if not raw.startswith(b"ply") or end < 0:
        raise ToolError(f"{path}: not a PLY file (missing 'ply' magic or 'end_header')")
    body_start = raw.index(b"\n", end) + 1
    header = raw[:end].decode("ascii", errors="replace").splitlines()
    fmt = None
    elements = []  # [name, count, [(prop, type)]]
    for line in header:
        parts = line.split()
        if not parts or parts[0] in ("comment", "obj_info", "ply"):
            continue
        if parts[0] == "format":
            fmt = parts[1]
        elif parts[0] == "element":
            elements.append([parts[1], int(parts[2]), []])
        elif parts[0] == "property":
            if not elements:
                raise ToolError(f"{path}: property before any element")
            if parts[1] == "list":
                elements[-1][2].append((parts[-1], "list"))
            else:
                if parts[1] not in _PLY_TYPES:
                    raise ToolError(f"{path}: unknown PLY property type '{parts[1]}'")
                elements[-1][2].append((parts[2], parts[1]))
    if fmt not in ("ascii", "binary_little_endian", "binary_big_endian"):
        raise ToolError(f"{path}: unsupported PLY format '{fmt}'")
    names = [e[0] for e in elements]
    if "vertex" not in names:
        raise ToolError(f"{path}: no 'element vertex' in header")
    vi = names.index("vertex")
    for e in elements[:vi]:
        if any(t == "list" for _, t in e[2]):
            raise ToolError(f"{path}: cannot skip list element '{e[0]}' placed before the vertices")
    _, count, props = elements[vi]
    if any(t == "list" for _, t in props):
        raise ToolError(f"{path}: list properties on vertices are not supported")
    prop_names = [p for p, _ in props]
    for req in ("x", "y", "z"):
        if req not in prop_names:
            raise ToolError(f"{path}: vertex property '{req}' missing (have {prop_names})")

    if fmt == "ascii":
        lines = raw[body_start:].decode("ascii", errors="replace").splitlines()
        skip = sum(e[1] for e in elements[:vi])
        rows = [ln.split() for ln in lines[skip:skip + count]]
        if len(rows) < count:
            raise ToolError(f"{path}: header declares {count} vertices, file has {len(rows)}")
        try:
            data = np.array(rows, dtype=float).reshape(count, len(props))
        except ValueError as exc:
            raise ToolError(f"{path}: malformed vertex line ({exc})") from exc
        return {name: data[:, i].copy() for i, name in enumerate(prop_names)}

    endian = "<" if fmt == "binary_little_endian" else ">"
    offset = body_start
    for e in elements[:vi]:
        offset += e[1] * sum(np.dtype(endian + _PLY_TYPES[t]).itemsize for _, t in e[2])
    dtype = np.dtype([(name, endian + _PLY_TYPES[t]) for name, t in props])
    if len(raw) - offset < count * dtype.itemsize:
        raise ToolError(f"{path}: file too short for {count} vertices")
    rec = np.frombuffer(raw, dtype=dtype, count=count, offset=offset)
    return {name: rec[name].astype(float) for name in prop_names}


_LCM_SYNC = b"\xed\xa1\xda\x01"  # the first bytes of every LCM log event


def _open_lcmlog(path):
    """The generated `vislam` types and an lcm.EventLog reading path, or ToolError."""
    from .lcmtypes import load, load_lcm
    vislam = load()
    lcm = load_lcm()
    try:
        return vislam, lcm.EventLog(str(path), "r")
    except (IOError, OSError) as exc:
        raise ToolError(f"cannot open LCM log {path}: {exc}") from exc


def _map_from_lcmlog(path, channel=None):
    """The landmarks of every vislam.landmarks_t event (on channel, else on any *LANDMARKS channel),
    in the order received, as read_ply's columns of vislam-run's map, and each one's world (the
    estimator's re-initializations before it: after one, positions are in another frame)."""
    vislam, log = _open_lcmlog(path)
    rows = []
    for ev in log:
        if not (ev.channel == channel if channel else ev.channel.endswith("LANDMARKS")):
            continue
        try:
            msg = vislam.landmarks_t.decode(ev.data)
        except ValueError:
            continue  # same channel suffix, other type
        for i in range(max(0, min(msg.count, vislam.landmarks_t.MAX_LANDMARKS))):
            c = msg.covariance[i]  # xx, xy, xz, yy, yz, zz
            rows.append((*msg.position[i], msg.id[i], math.sqrt(max(c[0] + c[3] + c[5], 0.0)),
                         msg.observations[i], msg.first_utime[i] * 1e-6, msg.world))
    log.close()
    if not rows:
        raise ToolError(f"{path}: no vislam.landmarks_t event (record vislamd's VISLAM_LANDMARKS with lcm-logger)")
    data = np.array(rows, dtype=float)
    return {name: data[:, i].copy() for i, name in enumerate(("x", "y", "z", "id", "sigma", "observations",
                                                               "first_time", "world"))}


def read_map(path, channel=None):
    """A landmark map: vislam-run --map's PLY (any PLY with x, y, z), or an LCM log that recorded
    vislamd's VISLAM_LANDMARKS (the same columns). {property name: float64 array}."""
    p = Path(path)
    try:
        with open(p, "rb") as f:
            magic = f.read(4)
    except OSError as exc:
        raise ToolError(f"cannot read map {path}: {exc.strerror}") from exc
    if magic == _LCM_SYNC:
        return _map_from_lcmlog(p, channel)
    return read_ply(p)


@dataclass
class Calibration:
    """What evaluation needs from a dataset or log."""
    cam_T_imu: np.ndarray
    fx: float = 0.0
    fy: float = 0.0
    cx: float = 0.0
    cy: float = 0.0
    baseline: float = 0.0
    t0: Optional[float] = None  # time of the first step, s
    step_times: Optional[np.ndarray] = field(default=None)  # time of every step, s

    @property
    def imu_T_cam(self):
        return se3_inv(self.cam_T_imu)


def load_npz(path):
    """Open a seed dataset, checking the arrays this project uses."""
    try:
        data = np.load(path)
    except (OSError, ValueError) as exc:
        raise ToolError(f"cannot read dataset {path}: {exc}") from exc
    need = ("time_stamps", "linear_velocity", "rotational_velocity", "features", "K", "b", "cam_T_imu")
    missing = [k for k in need if k not in data.files]
    if missing:
        raise ToolError(f"{path}: missing arrays {missing} (see ../shared/data/README.md)")
    return data


def _calibration_from_npz(path):
    data = np.load(path)
    for k in ("cam_T_imu", "K", "b", "time_stamps"):
        if k not in data.files:
            raise ToolError(f"{path}: no '{k}' array")
    k = data["K"]
    ts = np.asarray(data["time_stamps"], dtype=float).reshape(-1)
    return Calibration(np.asarray(data["cam_T_imu"], dtype=float), float(k[0, 0]), float(k[1, 1]),
                       float(k[0, 2]), float(k[1, 2]), float(data["b"]), float(ts[0]), ts)


def _calibration_from_lcmlog(path):
    vislam, log = _open_lcmlog(path)
    calib = None
    imu_channel = None
    step_times = []
    for ev in log:
        if calib is None and ev.channel.endswith("CALIB"):
            try:
                msg = vislam.calibration_t.decode(ev.data)
            except ValueError:
                continue  # same channel suffix, other type: keep looking
            calib = Calibration(np.array(msg.cam_T_imu, dtype=float).reshape(4, 4), msg.fx, msg.fy,
                                msg.cx, msg.cy, msg.baseline, msg.utime * 1e-6)
            imu_channel = ev.channel[:-len("CALIB")] + "IMU"
        elif calib is not None and ev.channel == imu_channel:
            step_times.append(vislam.imu_t.decode(ev.data).utime * 1e-6)
    log.close()
    if calib is None:
        raise ToolError(f"{path}: no calibration_t event on a *CALIB channel")
    if step_times:
        calib.step_times = np.array(step_times)
    return calib


def read_velocities(path):
    """The velocity samples of a seed .npz (time_stamps, linear_velocity, rotational_velocity) or of an
    .lcmlog (every vislam.imu_t on a *IMU channel): (times s, linear (N, 3) m/s, angular (N, 3) rad/s),
    in time order."""
    p = Path(path)
    if not p.is_file():
        raise ToolError(f"velocity source {path} does not exist")
    if p.suffix == ".npz":
        data = load_npz(p)
        times = np.asarray(data["time_stamps"], dtype=float).reshape(-1)
        lin = np.asarray(data["linear_velocity"], dtype=float).T
        ang = np.asarray(data["rotational_velocity"], dtype=float).T
    else:
        vislam, log = _open_lcmlog(p)
        rows = []
        for ev in log:
            if not ev.channel.endswith("IMU"):
                continue
            try:
                msg = vislam.imu_t.decode(ev.data)
            except ValueError:
                continue  # same channel suffix, other type
            rows.append((msg.utime * 1e-6, *msg.linear_velocity, *msg.angular_velocity))
        log.close()
        if not rows:
            raise ToolError(f"{path}: no vislam.imu_t event on a *IMU channel")
        a = np.array(rows, dtype=float)
        times, lin, ang = a[:, 0], a[:, 1:4], a[:, 4:7]
    order = np.argsort(times, kind="stable")
    return times[order], lin[order], ang[order]


def load_calibration(path):
    """cam_T_imu and step times from a seed .npz or from the calibration event of an .lcmlog."""
    p = Path(path)
    if not p.is_file():
        raise ToolError(f"calibration source {path} does not exist")
    if p.suffix == ".npz":
        return _calibration_from_npz(p)
    with open(p, "rb") as f:
        magic = f.read(4)
    if magic == _LCM_SYNC or p.suffix in (".lcmlog", ".log"):
        return _calibration_from_lcmlog(p)
    raise ToolError(f"{path}: calibration must come from a seed .npz or an LCM log (.lcmlog)")


def read_ground_truth(path, calib=None, fmt="auto"):
    """Ground truth as a world-from-IMU Trajectory.

    TUM: taken as is (the simulator writes IMU poses in its world frame).
    KITTI: left-camera poses in the camera-0 frame; converted to IMU poses in the frame of the
    IMU at step 0, i.e. w_T_i(i) = imu_T_cam * c0_T_c(i) * cam_T_imu, which matches an estimator
    that starts at the identity. Line i is step i; its time is the dataset's step time.
    """
    if fmt == "auto":
        fmt = sniff_trajectory_format(path)
    if fmt == "tum":
        traj = read_tum(path)
        traj.name = "ground truth"
        return traj
    if fmt != "kitti":
        raise ToolError(f"unknown ground-truth format '{fmt}'")
    if calib is None:
        raise ToolError("KITTI ground truth needs --calib DATA.npz|LOG.lcmlog for cam_T_imu")
    times, cam_poses = read_kitti(path)
    n = cam_poses.shape[0]
    if calib.step_times is not None and calib.step_times.shape[0] >= n:
        abs_times = calib.step_times[:n].copy()
    elif times is not None and calib.t0 is not None:
        abs_times = calib.t0 + times
    elif times is not None:
        abs_times = times.copy()
    else:
        raise ToolError(f"{path}: KITTI file has no time column and the calibration source has no step times")
    poses = calib.imu_T_cam @ cam_poses @ calib.cam_T_imu
    return Trajectory(abs_times, poses, "ground truth")


def read_covariance(path):
    """vislam-run --covariance: `time` and 6 variances per line. Returns (times (N,), var (N, 6))."""
    times, var = [], []
    for lineno, row in _numeric_rows(path, "covariance"):
        if row.size != 7:
            raise ToolError(f"{path}:{lineno}: covariance lines need 7 numbers (time and the 6 diagonal "
                            f"entries var_rho_xyz var_phi_xyz), got {row.size}")
        times.append(row[0])
        var.append(row[1:])
    if not times:
        raise ToolError(f"{path}: no covariance lines")
    return np.array(times), np.array(var)
