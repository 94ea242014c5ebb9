"""vislam_tools.faults: each fault does what it says to the sample log, and nothing else."""

import math
import struct

import pytest

from conftest import REPO
from vislam_tools import ToolError
from vislam_tools.faults import HOUR_US, INT64_MAX, INT64_MIN, inject, read_log

SAMPLE = REPO / "data" / "sample.lcmlog"


@pytest.fixture(scope="module")
def clean(vislam_types):
    return read_log(SAMPLE)


def imu_utimes(vislam, events):
    return [vislam.imu_t.decode(e.data).utime for e in events if e.channel == "VISLAM_IMU"]


def test_bad_header_sets_the_length_and_keeps_the_rest(tmp_path, clean):
    out = tmp_path / "f.lcmlog"
    info = inject(SAMPLE, out, "bad-header", step=100)
    raw = out.read_bytes()
    assert len(raw) == SAMPLE.stat().st_size
    assert struct.unpack_from(">I", raw, info["offset"])[0] == 0xEDA1DA01
    assert struct.unpack_from(">I", raw, info["offset"] + 24)[0] == 0x7FFFFFFF
    assert raw[:info["offset"]] == SAMPLE.read_bytes()[:info["offset"]]
    assert info["frames_after"] == 99


def test_truncate_and_garbage(tmp_path, clean):
    info = inject(SAMPLE, tmp_path / "t.lcmlog", "truncate", step=100)
    size = (tmp_path / "t.lcmlog").stat().st_size
    assert info["offset"] < size < SAMPLE.stat().st_size
    with pytest.raises(ToolError):
        read_log(tmp_path / "t.lcmlog")
    info = inject(SAMPLE, tmp_path / "g.lcmlog", "garbage", step=100)
    raw = (tmp_path / "g.lcmlog").read_bytes()
    assert len(raw) == SAMPLE.stat().st_size + 4096
    assert raw[info["offset"] + 4096:] == SAMPLE.read_bytes()[info["offset"]:]


def test_empty_and_junk_file(tmp_path, clean):
    inject(SAMPLE, tmp_path / "e.lcmlog", "empty")
    assert (tmp_path / "e.lcmlog").stat().st_size == 0
    inject(SAMPLE, tmp_path / "j.lcmlog", "junk-file")
    assert (tmp_path / "j.lcmlog").stat().st_size == SAMPLE.stat().st_size


@pytest.mark.parametrize("fault,want", [("imu-hour", None), ("imu-max", INT64_MAX), ("imu-min", INT64_MIN)])
def test_one_imu_stamp(tmp_path, vislam_types, clean, fault, want):
    inject(SAMPLE, tmp_path / "f.lcmlog", fault, step=100)
    before = imu_utimes(vislam_types, clean)
    after = imu_utimes(vislam_types, read_log(tmp_path / "f.lcmlog"))
    changed = [k for k in range(len(before)) if before[k] != after[k]]
    assert changed == [100]
    assert after[100] == (before[100] + HOUR_US if want is None else want)


def test_shift_twice_velocity_no_imu(tmp_path, vislam_types, clean):
    before = imu_utimes(vislam_types, clean)
    inject(SAMPLE, tmp_path / "s.lcmlog", "shift", step=100)
    shifted = read_log(tmp_path / "s.lcmlog")
    after = imu_utimes(vislam_types, shifted)
    assert after[:100] == before[:100]
    assert all(a == b - HOUR_US for a, b in zip(after[100:], before[100:]))
    frames = [vislam_types.stereo_frame_t.decode(e.data).utime for e in shifted if e.channel == "VISLAM_FEATURES"]
    assert frames[150] < frames[99]

    inject(SAMPLE, tmp_path / "t.lcmlog", "twice")
    assert imu_utimes(vislam_types, read_log(tmp_path / "t.lcmlog")) == before + before

    inject(SAMPLE, tmp_path / "v.lcmlog", "velocity", step=100)
    imu = [vislam_types.imu_t.decode(e.data) for e in read_log(tmp_path / "v.lcmlog") if e.channel == "VISLAM_IMU"]
    assert imu[100].linear_velocity[0] == 1e300 and imu[99].linear_velocity[0] < 1e3

    inject(SAMPLE, tmp_path / "n.lcmlog", "no-imu", step=50, count=100)
    events = read_log(tmp_path / "n.lcmlog")
    assert imu_utimes(vislam_types, events) == before[:50] + before[150:]
    assert sum(e.channel == "VISLAM_FEATURES" for e in events) == 200


def test_corrupt_inserts_damaged_copies_before_the_originals(tmp_path, vislam_types, clean):
    info = inject(SAMPLE, tmp_path / "c.lcmlog", "corrupt", step=100, count=8)
    events = read_log(tmp_path / "c.lcmlog")  # headers stay valid
    assert len(events) == len(clean) + 8
    assert info["copies"] == 8
    start = [i for i, e in enumerate(clean) if e.channel == "VISLAM_IMU"][100]
    copies = events[start:start + 16:2]
    originals = events[start + 1:start + 17:2]
    assert [e.data for e in originals] == [e.data for e in clean[start:start + 8]]
    assert all(c.data != o.data for c, o in zip(copies, originals))
    nan_copy = copies[3]  # every fourth damage is NaN values in a well-formed message
    msg = (vislam_types.stereo_frame_t if nan_copy.channel == "VISLAM_FEATURES" else vislam_types.imu_t).decode(
        nan_copy.data)
    values = msg.u_left if nan_copy.channel == "VISLAM_FEATURES" else msg.linear_velocity
    assert any(math.isnan(v) for v in values)


def test_step_out_of_range(tmp_path, clean):
    with pytest.raises(ToolError):
        inject(SAMPLE, tmp_path / "x.lcmlog", "velocity", step=200)


def test_jump_moves_the_burst_frames_back_and_forth_and_nothing_else(tmp_path, vislam_types, clean):
    info = inject(SAMPLE, tmp_path / "j.lcmlog", "jump", step=100, count=6, pixels=40.0)
    assert info["frames_moved"] == 6
    events = read_log(tmp_path / "j.lcmlog")
    assert len(events) == len(clean)
    before = [vislam_types.stereo_frame_t.decode(e.data) for e in clean if e.channel == "VISLAM_FEATURES"]
    after = [vislam_types.stereo_frame_t.decode(e.data) for e in events if e.channel == "VISLAM_FEATURES"]
    for k, (b, a) in enumerate(zip(before, after)):
        du = {round(x - y, 9) for x, y in zip(a.u_left[:a.num_features], b.u_left[:b.num_features])}
        dr = {round(x - y, 9) for x, y in zip(a.u_right[:a.num_features], b.u_right[:b.num_features])}
        want = {(-40.0 if (k - 100) % 2 == 0 else 40.0)} if 100 <= k < 106 else {0.0}
        assert du == want and dr == want, k
        assert a.v_left == b.v_left and a.v_right == b.v_right and a.id == b.id
    assert [e.data for e in events if e.channel != "VISLAM_FEATURES"] == \
        [e.data for e in clean if e.channel != "VISLAM_FEATURES"]
