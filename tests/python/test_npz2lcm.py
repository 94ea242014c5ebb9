import os
import subprocess
import sys

import numpy as np
import pytest

from conftest import REPO
from vislam_tools import ToolError, lcmtypes
from vislam_tools.npz2lcm import convert, main
from vislam_tools.trajio import load_calibration

T, M = 6, 300


@pytest.fixture()
def synthetic_npz(tmp_path):
    rng = np.random.default_rng(11)
    ts = 1317386425.5625024 + np.cumsum(np.r_[0.0, rng.uniform(0.099, 0.109, T - 1)])
    feats = -np.ones((4, M, T))
    observed = {0: [0, 5, 17], 1: [5, 17, 299], 2: list(range(260)), 3: [42], 4: [], 5: [298, 1]}
    for t, ids in observed.items():
        for j in ids:
            feats[:, j, t] = rng.uniform(0, 1200, 4)
    feats[0, 100, 1] = 12.5  # partial observation (other rows -1): not a valid observation
    k = np.array([[707.0912, 0, 601.8873], [0, 708.5, 183.1104], [0, 0, 1]])
    cam_T_imu = np.arange(16, dtype=float).reshape(4, 4)
    path = tmp_path / "syn.npz"
    np.savez(path, time_stamps=ts[None, :], linear_velocity=rng.normal(size=(3, T)),
             rotational_velocity=rng.normal(size=(3, T)), features=feats, K=k, b=np.float64(0.537),
             cam_T_imu=cam_T_imu)
    return path, np.load(path), observed


def read_events(path):
    lcm = lcmtypes.load_lcm()
    log = lcm.EventLog(str(path), "r")
    events = [(ev.timestamp, ev.channel, ev.data) for ev in log]
    log.close()
    return events


def test_round_trip_every_field(vislam_types, synthetic_npz, tmp_path, capsys):
    npz_path, d, observed = synthetic_npz
    out = tmp_path / "syn.lcmlog"
    summary = convert(npz_path, out)
    err = capsys.readouterr().err
    assert "dropped 4 observations" in err
    assert "1 observations with only some coordinates" in err
    assert summary["steps"] == T
    assert summary["events"] == 1 + 2 * T
    assert summary["observations"] == sum(min(len(v), 256) for v in observed.values())

    events = read_events(out)
    assert [c for _, c, _ in events] == ["VISLAM_CALIB"] + ["VISLAM_IMU", "VISLAM_FEATURES"] * T
    utimes = np.round(d["time_stamps"][0] * 1e6).astype(np.int64)

    cal = vislam_types.calibration_t.decode(events[0][2])
    assert events[0][0] == cal.utime == utimes[0]
    assert (cal.fx, cal.fy, cal.cx, cal.cy) == (707.0912, 708.5, 601.8873, 183.1104)
    assert cal.baseline == 0.537
    assert list(cal.cam_T_imu) == list(range(16))

    for t in range(T):
        ev_utime, _, data = events[1 + 2 * t]
        imu = vislam_types.imu_t.decode(data)
        assert ev_utime == imu.utime == utimes[t]
        assert list(imu.linear_velocity) == list(d["linear_velocity"][:, t])
        assert list(imu.angular_velocity) == list(d["rotational_velocity"][:, t])

        ev_utime, _, data = events[2 + 2 * t]
        fr = vislam_types.stereo_frame_t.decode(data)
        assert ev_utime == fr.utime == utimes[t]
        ids = sorted(observed[t])[:256]
        assert fr.num_features == len(ids)
        assert list(fr.id[:len(ids)]) == ids
        for row, field in enumerate(("u_left", "v_left", "u_right", "v_right")):
            values = getattr(fr, field)
            assert list(values[:len(ids)]) == list(d["features"][row, ids, t]), field
            assert all(v == 0.0 for v in values[len(ids):])  # padding
        assert all(i == 0 for i in fr.id[len(ids):])


def test_start_step_max_steps_and_prefix(vislam_types, synthetic_npz, tmp_path):
    npz_path, d, _ = synthetic_npz
    out = tmp_path / "part.lcmlog"
    assert main([str(npz_path), str(out), "--start-step", "3", "--max-steps", "2",
                 "--channel-prefix", "TEST_"]) == 0
    events = read_events(out)
    assert [c for _, c, _ in events] == ["TEST_CALIB", "TEST_IMU", "TEST_FEATURES", "TEST_IMU", "TEST_FEATURES"]
    utimes = np.round(d["time_stamps"][0] * 1e6).astype(np.int64)
    assert [u for u, _, _ in events] == [utimes[3]] * 3 + [utimes[4]] * 2
    fr = vislam_types.stereo_frame_t.decode(events[2][2])
    assert fr.num_features == 1 and fr.id[0] == 42
    assert vislam_types.stereo_frame_t.decode(events[4][2]).num_features == 0


def test_imu_per_step_interpolates_between_steps(vislam_types, synthetic_npz, tmp_path):
    npz_path, d, _ = synthetic_npz
    out = tmp_path / "fast.lcmlog"
    assert main([str(npz_path), str(out), "--imu-per-step", "4", "--max-steps", "3"]) == 0
    events = read_events(out)
    step = ["VISLAM_IMU", "VISLAM_FEATURES"]
    assert [c for _, c, _ in events] == ["VISLAM_CALIB"] + (step + ["VISLAM_IMU"] * 3) * 2 + step
    utimes = np.round(d["time_stamps"][0] * 1e6).astype(np.int64)
    imus = [vislam_types.imu_t.decode(data) for _, c, data in events if c == "VISLAM_IMU"]
    assert [i.utime for i in imus[::4]] == list(utimes[:3])
    assert all(a.utime < b.utime for a, b in zip(imus, imus[1:]))
    for t in range(2):
        for j in range(4):
            w = j / 4
            imu = imus[4 * t + j]
            assert imu.utime == utimes[t] + round(w * (utimes[t + 1] - utimes[t]))
            np.testing.assert_allclose(imu.linear_velocity,
                                       (1 - w) * d["linear_velocity"][:, t] + w * d["linear_velocity"][:, t + 1])
            np.testing.assert_allclose(imu.angular_velocity, (1 - w) * d["rotational_velocity"][:, t]
                                       + w * d["rotational_velocity"][:, t + 1])
    with pytest.raises(ToolError, match="imu-per-step"):
        convert(npz_path, tmp_path / "bad.lcmlog", imu_per_step=0)


def test_calibration_read_back_from_log(vislam_types, synthetic_npz, tmp_path):
    npz_path, d, _ = synthetic_npz
    out = tmp_path / "syn.lcmlog"
    convert(npz_path, out)
    cal = load_calibration(out)
    np.testing.assert_array_equal(cal.cam_T_imu, d["cam_T_imu"])
    np.testing.assert_allclose(cal.step_times, d["time_stamps"][0], atol=1e-6)
    assert cal.t0 == pytest.approx(d["time_stamps"][0, 0], abs=1e-6)
    npz_cal = load_calibration(npz_path)
    np.testing.assert_array_equal(npz_cal.cam_T_imu, d["cam_T_imu"])
    assert npz_cal.baseline == 0.537


def test_bad_arguments_are_clear_errors(vislam_types, synthetic_npz, tmp_path, capsys):
    npz_path, _, _ = synthetic_npz
    with pytest.raises(ToolError, match="--start-step"):
        convert(npz_path, tmp_path / "x.lcmlog", start_step=T)
    assert main([str(tmp_path / "missing.npz"), str(tmp_path / "x.lcmlog")]) == 1
    assert "cannot read dataset" in capsys.readouterr().err


def wrapper_env(**extra):
    env = dict(os.environ, VISLAM_PYTHON=sys.executable)
    env.update(extra)
    return env


def test_wrapper_runs_and_prints_summary(vislam_types, synthetic_npz, tmp_path):
    npz_path, _, _ = synthetic_npz
    out = tmp_path / "w.lcmlog"
    env = wrapper_env(VISLAM_LCM_PYTHON_DIR=str(lcmtypes.types_dir()))
    res = subprocess.run([str(REPO / "tools" / "npz2lcm"), str(npz_path), str(out)], env=env,
                         capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    assert f"{T} steps, {1 + 2 * T} events" in res.stdout
    assert out.stat().st_size > 0


def test_wrapper_says_build_first_without_types(synthetic_npz, tmp_path):
    npz_path, _, _ = synthetic_npz
    env = wrapper_env(VISLAM_LCM_PYTHON_DIR=str(tmp_path / "no_types_here"))
    res = subprocess.run([str(REPO / "tools" / "npz2lcm"), str(npz_path), str(tmp_path / "x.lcmlog")],
                         env=env, capture_output=True, text=True, timeout=120)
    assert res.returncode == 1
    assert "build first: cmake --build build" in res.stderr
