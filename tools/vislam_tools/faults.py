"""Fault injection: write a faulty copy of an LCM log, or play a foreign process on the pose channel.

    vislam-faults inject IN.lcmlog OUT.lcmlog FAULT [--step K] [--count N] [--seed S] [--offset-us D]
                         [--pixels P]
    vislam-faults info IN.lcmlog [--step K]
    vislam-faults foreign-poses [--lcm-url URL] [--features-channel C] [--pose-channel C] [--seconds T]

A step is one IMU sample and the frame after it (npz2lcm and vislam-sim write them in that order);
step K is the K-th IMU event of the log, counted from 0. The log is read and written with this
module's own reader of the LCM log format, so a damaged output never depends on liblcm.

Faults of the log file itself (the readers must report them and go on, never crash):
    bad-header   the data length of step K's IMU event set to 0x7fffffff
    truncate     the file cut in the middle of step K's frame event
    garbage      4 KiB of junk inserted before step K
    empty        an empty file
    junk-file    random bytes only (as long as the input)
Faults of the contents (the estimator's time and plausibility checks):
    corrupt      N copies of the events from step K on, each damaged (bit flips, cut payload, junk
                 payload, NaN values; in turn) and inserted before its clean original; headers stay valid
    imu-hour     step K's IMU sample stamped 1 h ahead
    imu-max      step K's IMU sample stamped INT64_MAX
    imu-min      step K's IMU sample stamped INT64_MIN (use --step 0 for the first sample)
    shift        every IMU and frame utime from step K on moved by --offset-us (default -1 h)
    twice        the log followed by itself (the same inputs replayed twice)
    velocity     step K's IMU linear velocity set to 1e300 m/s
    no-imu       the IMU samples of steps K..K+N-1 removed (N = --count, default 100)
    jump         the frames of steps K..K+N-1 (N = --count, default 24) with every observation moved
                 by -P, +P, -P, ... px in u (left and right alike; P = --pixels, default 150): a
                 tracker or camera gone wrong for a while, each frame a different rotation's worth
"""

import argparse
import math
import random
import struct
import sys
import time

from . import ToolError, channels, cli
from .lcmtypes import load, load_lcm

SYNC = 0xEDA1DA01
HEADER = struct.Struct(">IqqiI")
HOUR_US = 3_600_000_000
INT64_MAX = 2**63 - 1
INT64_MIN = -(2**63)

LOG_FAULTS = ("bad-header", "truncate", "garbage", "empty", "junk-file")
CONTENT_FAULTS = ("corrupt", "imu-hour", "imu-max", "imu-min", "shift", "twice", "velocity", "no-imu", "jump")


class Event:
    """One log event: its header fields and raw bytes."""

    __slots__ = ("number", "timestamp", "channel", "data")

    def __init__(self, number, timestamp, channel, data):
        self.number = number
        self.timestamp = timestamp
        self.channel = channel
        self.data = data

    def encode(self, data_length=None):
        ch = self.channel.encode("ascii")
        n = len(self.data) if data_length is None else data_length
        return HEADER.pack(SYNC, self.number, self.timestamp, len(ch), n & 0xFFFFFFFF) + ch + self.data


def read_log(path):
    """Every event of a well-formed log; raises ToolError on the first malformed byte."""
    try:
        raw = open(path, "rb").read()
    except OSError as exc:
        raise ToolError(f"cannot read {path}: {exc.strerror}") from exc
    events, pos = [], 0
    while pos < len(raw):
        if len(raw) - pos < HEADER.size:
            raise ToolError(f"{path}: offset {pos}: cut header")
        sync, number, timestamp, clen, dlen = HEADER.unpack_from(raw, pos)
        end = pos + HEADER.size + clen + dlen
        if sync != SYNC or clen <= 0 or end > len(raw):
            raise ToolError(f"{path}: offset {pos}: not a valid event (inject needs a clean input log)")
        channel = raw[pos + HEADER.size:pos + HEADER.size + clen].decode("ascii")
        events.append(Event(number, timestamp, channel, raw[pos + HEADER.size + clen:end]))
        pos = end
    return events


def write_log(path, chunks):
    with open(path, "wb") as f:
        for c in chunks:
            f.write(c if isinstance(c, (bytes, bytearray)) else c.encode())


def step_indices(events, imu_channel):
    """Index in events of every IMU event, in order (one per step)."""
    return [i for i, e in enumerate(events) if e.channel == imu_channel]


def frame_after(events, index, features_channel):
    for i in range(index + 1, len(events)):
        if events[i].channel == features_channel:
            return i
    raise ToolError(f"no frame after event {index}")


def _step(steps, k):
    if not 0 <= k < len(steps):
        raise ToolError(f"--step {k}: the log has steps 0..{len(steps) - 1}")
    return steps[k]


def _damage(vislam, event, kind, rng):
    """A damaged copy of event's payload; its header stays valid (lengths match)."""
    data = bytearray(event.data)
    if kind == 0:  # bit flips past the fingerprint
        for _ in range(8):
            if len(data) > 8:
                data[rng.randrange(8, len(data))] ^= 1 << rng.randrange(8)
    elif kind == 1:  # cut payload
        data = data[: max(1, len(data) // 2)]
    elif kind == 2:  # junk payload
        data = bytearray(rng.getrandbits(8) for _ in range(len(data)))
    else:  # NaN values in a well-formed message
        for typ in (vislam.imu_t, vislam.stereo_frame_t, vislam.calibration_t):
            try:
                msg = typ.decode(bytes(data))
            except ValueError:
                continue
            if typ is vislam.imu_t:
                msg.linear_velocity = [math.nan] * 3
            elif typ is vislam.stereo_frame_t:
                msg.u_left = [math.nan] * len(msg.u_left)
            else:
                msg.fx = math.nan
            data = bytearray(msg.encode())
            break
    return Event(event.number, event.timestamp, event.channel, bytes(data))


def inject(in_path, out_path, fault, step=100, count=None, seed=1, offset_us=-HOUR_US, pixels=150.0,
           imu_channel=channels.IMU, features_channel=channels.FEATURES):
    """Write the faulty copy; returns a dict describing what was done (fault_utime: the first utime
    the fault touches, for no-imu the last sample removed; frames_after: frames of the input with a
    utime after it)."""
    rng = random.Random(seed)
    if fault == "empty":
        write_log(out_path, [])
        return {"fault": fault}
    events = read_log(in_path)
    if fault == "junk-file":
        size = sum(len(e.encode()) for e in events)
        write_log(out_path, [bytes(rng.getrandbits(8) for _ in range(size))])
        return {"fault": fault, "bytes": size}
    vislam = load()
    steps = step_indices(events, imu_channel)
    k_index = _step(steps, step)
    fault_utime = vislam.imu_t.decode(events[k_index].data).utime
    chunks = [e for e in events]
    info = {"fault": fault, "step": step, "fault_utime": fault_utime}

    if fault == "bad-header":
        chunks[k_index] = events[k_index].encode(data_length=0x7FFFFFFF)
        info["offset"] = sum(len(e.encode()) for e in events[:k_index])
    elif fault == "truncate":
        f_index = frame_after(events, k_index, features_channel)
        prefix = b"".join(e.encode() for e in events[:f_index])
        cut = events[f_index].encode()
        chunks = [prefix + cut[: len(cut) // 2]]
        info["offset"] = len(prefix)
    elif fault == "garbage":
        junk = bytes(rng.getrandbits(8) for _ in range(4096))
        chunks = events[:k_index] + [junk] + events[k_index:]
        info["offset"] = sum(len(e.encode()) for e in events[:k_index])
    elif fault == "corrupt":
        n = 10 if count is None else count
        out = events[:k_index]
        for j, e in enumerate(events[k_index:]):
            if j < n:
                out.append(_damage(vislam, e, j % 4, rng))
            out.append(e)
        chunks = out
        info["copies"] = min(n, len(events) - k_index)
    elif fault in ("imu-hour", "imu-max", "imu-min", "velocity"):
        msg = vislam.imu_t.decode(events[k_index].data)
        if fault == "imu-hour":
            msg.utime += HOUR_US
        elif fault == "imu-max":
            msg.utime = INT64_MAX
        elif fault == "imu-min":
            msg.utime = INT64_MIN
        else:
            msg.linear_velocity = [1e300, 0.0, 0.0]
        e = events[k_index]
        chunks[k_index] = Event(e.number, e.timestamp, e.channel, msg.encode())
    elif fault == "shift":
        for i in range(k_index, len(events)):
            e = events[i]
            typ = {imu_channel: vislam.imu_t, features_channel: vislam.stereo_frame_t}.get(e.channel)
            if typ is None:
                continue
            msg = typ.decode(e.data)
            msg.utime += offset_us
            chunks[i] = Event(e.number, e.timestamp + offset_us, e.channel, msg.encode())
        info["offset_us"] = offset_us
    elif fault == "twice":
        chunks = events + events
        info["fault_utime"] = vislam.imu_t.decode(events[steps[0]].data).utime
    elif fault == "no-imu":
        n = 100 if count is None else count
        removed = steps[step:step + n]
        drop = set(removed)
        chunks = [e for i, e in enumerate(events) if i not in drop]
        info["removed"] = len(drop)
        # "after the fault" is after the IMU comes back
        fault_utime = vislam.imu_t.decode(events[removed[-1]].data).utime
        info["fault_utime"] = fault_utime
    elif fault == "jump":
        n = 24 if count is None else count
        moved = 0
        for k in steps[step:step + n]:
            i = frame_after(events, k, features_channel)
            msg = vislam.stereo_frame_t.decode(events[i].data)
            shift = pixels if moved % 2 else -pixels
            msg.u_left = [u + shift for u in msg.u_left]
            msg.u_right = [u + shift for u in msg.u_right]
            chunks[i] = Event(events[i].number, events[i].timestamp, events[i].channel, msg.encode())
            moved += 1
        info["frames_moved"] = moved
    else:
        raise ToolError(f"unknown fault {fault}; one of {', '.join(LOG_FAULTS + CONTENT_FAULTS)}")
    write_log(out_path, chunks)
    frames = [vislam.stereo_frame_t.decode(e.data).utime for e in events if e.channel == features_channel]
    info["frames_after"] = sum(1 for u in frames if u > fault_utime)
    return info


def foreign_poses(lcm_url=None, features_channel=channels.FEATURES, pose_channel=channels.POSE, seconds=60.0):
    """Answers every frame on features_channel with NaN poses on pose_channel, as a stray process
    would: one with the frame's utime and source FEATURES, one finite with a utime nobody sent."""
    vislam = load()
    lcm_mod = load_lcm()
    lc = lcm_mod.LCM(lcm_url) if lcm_url else lcm_mod.LCM()
    sent = [0]

    def on_frame(_channel, data):
        try:
            frame = vislam.stereo_frame_t.decode(data)
        except ValueError:
            return
        nan_pose = vislam.pose_t()
        nan_pose.utime = frame.utime
        nan_pose.source = vislam.pose_t.SOURCE_FEATURES
        nan_pose.sequence = 10**12 + sent[0]
        nan_pose.position = [math.nan] * 3
        nan_pose.orientation = [math.nan, 0.0, 0.0, 0.0]
        lc.publish(pose_channel, nan_pose.encode())
        stray = vislam.pose_t()
        stray.utime = frame.utime + 1
        stray.source = vislam.pose_t.SOURCE_FEATURES
        stray.sequence = 10**12 + sent[0]
        stray.orientation = [1.0, 0.0, 0.0, 0.0]
        lc.publish(pose_channel, stray.encode())
        sent[0] += 2

    lc.subscribe(features_channel, on_frame)
    # A test starts the replay once this line is out: frames sent before the subscription are lost.
    print(f"foreign-poses: listening on {features_channel}", flush=True)
    deadline = time.monotonic() + seconds
    try:
        while time.monotonic() < deadline:
            lc.handle_timeout(100)
    except KeyboardInterrupt:
        pass
    return sent[0]


def build_parser():
    p = argparse.ArgumentParser(prog="vislam-faults", description=__doc__.split("\n")[0],
                                epilog="Faults: " + ", ".join(LOG_FAULTS + CONTENT_FAULTS))
    cli.add_version(p)
    sub = p.add_subparsers(dest="command", required=True)
    i = sub.add_parser("inject", help="write a faulty copy of a log")
    i.add_argument("input", metavar="IN.lcmlog")
    i.add_argument("output", metavar="OUT.lcmlog")
    i.add_argument("fault", choices=LOG_FAULTS + CONTENT_FAULTS)
    i.add_argument("--step", type=int, default=100, help="the step the fault hits (default 100)")
    i.add_argument("--count", type=int, default=None, help="corrupt: copies (10); no-imu: steps (100); jump: frames (24)")
    i.add_argument("--seed", type=int, default=1)
    i.add_argument("--offset-us", type=int, default=-HOUR_US, help="shift: utime offset, us (default -1 h)")
    i.add_argument("--pixels", type=float, default=150.0, help="jump: how far each frame's observations move, px (default 150)")
    i.add_argument("--imu-channel", default=channels.IMU)
    i.add_argument("--features-channel", default=channels.FEATURES)
    n = sub.add_parser("info", help="steps of a log and the utime of a step")
    n.add_argument("input", metavar="IN.lcmlog")
    n.add_argument("--step", type=int, default=100)
    n.add_argument("--imu-channel", default=channels.IMU)
    f = sub.add_parser("foreign-poses", help="answer every frame with NaN poses (a stray process)")
    f.add_argument("--lcm-url", default=None)
    f.add_argument("--features-channel", default=channels.FEATURES)
    f.add_argument("--pose-channel", default=channels.POSE)
    f.add_argument("--seconds", type=float, default=60.0, help="how long to answer (default 60)")
    return p


def main(argv=None):
    args = build_parser().parse_args(argv)
    try:
        if args.command == "inject":
            info = inject(args.input, args.output, args.fault, step=args.step, count=args.count, seed=args.seed,
                          offset_us=args.offset_us, pixels=args.pixels, imu_channel=args.imu_channel,
                          features_channel=args.features_channel)
            print(" ".join(f"{k}={v}" for k, v in info.items()))
        elif args.command == "info":
            vislam = load()
            events = read_log(args.input)
            steps = step_indices(events, args.imu_channel)
            k = _step(steps, args.step)
            print(f"steps={len(steps)} step={args.step} utime={vislam.imu_t.decode(events[k].data).utime}")
        else:
            n = foreign_poses(args.lcm_url, args.features_channel, args.pose_channel, args.seconds)
            print(f"foreign poses published: {n}")
    except ToolError as exc:
        print(f"vislam-faults: {exc}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    cli.run(main)
