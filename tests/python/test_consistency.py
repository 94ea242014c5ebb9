import json

import numpy as np
import pytest

from vislam_tools import ToolError
from vislam_tools.evaluate import main
from vislam_tools.geometry import make_pose, se3_exp, so3_exp
from vislam_tools.metrics import CHI2_3DOF_95, consistency
from vislam_tools.trajio import read_covariance, write_tum

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
N = 4000
SIGMA = np.array([0.5, 0.2, 1.5])  # anisotropic, so an error in the wrong frame would show


def truth_and_estimate(seed=1, scale=1.0):
    """A turning drive (truth) and an estimate whose body-frame position error is N(0, SIGMA^2) * scale."""
    rng = np.random.default_rng(seed)
    truth = [np.eye(4)]
    for k in range(N - 1):
        truth.append(truth[-1] @ se3_exp(np.array([1.0, 0.0, 0.1, 0.02, 0.03, 0.3 * np.sin(k / 50)])))
    truth = np.array(truth)
    est = truth.copy()
    e_body = rng.normal(size=(N, 3)) * SIGMA * scale
    # p_true = p_est + R_est e_body, with a small rotation error too (the rotation is the estimate's)
    for i in range(N):
        est[i, :3, :3] = truth[i, :3, :3] @ so3_exp(rng.normal(size=3) * 0.01)
        est[i, :3, 3] = truth[i, :3, 3] - est[i, :3, :3] @ e_body[i]
    var = np.tile(SIGMA ** 2, (N, 1))
    return truth, est, var, e_body


def test_consistent_errors_give_nees_3_and_997_permille_inside():
    truth, est, var, e_body = truth_and_estimate()
    s, e, sigma, nees, used = consistency(est, truth[:, :3, 3], var)
    np.testing.assert_allclose(e, e_body, atol=1e-12)  # rotated into the body frame exactly
    np.testing.assert_allclose(sigma, np.sqrt(var))
    assert s["frames_used"] == N and used.all()
    assert s["nees_mean"] == pytest.approx(3.0, rel=0.06)
    assert s["nees_over_chi2_95"] == pytest.approx(0.05, abs=0.015)
    for ax in "xyz":
        assert s["inside_3sigma"][ax] == pytest.approx(0.9973, abs=0.004)
    # errors twice as large: NEES x4, fewer inside
    s2 = consistency(truth_and_estimate(scale=2.0)[1], truth[:, :3, 3], var)[0]
    assert s2["nees_mean"] == pytest.approx(12.0, rel=0.06)
    assert s2["inside_3sigma"]["x"] == pytest.approx(0.866, abs=0.02)


def test_world_frame_error_would_not_pass():
    # The same errors read in the world frame are inconsistent with body-frame variances.
    truth, est, var, _ = truth_and_estimate()
    world = est.copy()
    world[:, :3, :3] = np.eye(3)
    assert consistency(world, truth[:, :3, 3], var)[0]["nees_mean"] > 5.0


def test_frames_without_variance_are_left_out():
    truth, est, var, _ = truth_and_estimate()
    var[0] = 0.0  # the first pose: known exactly
    s, _, sigma, nees, used = consistency(est, truth[:, :3, 3], var)
    assert s["frames_used"] == N - 1 and not used[0]
    assert np.isnan(nees[0]) and np.all(np.isnan(sigma[0]))
    with pytest.raises(ToolError):
        consistency(est, truth[:, :3, 3], np.zeros_like(var))
    with pytest.raises(ToolError):
        consistency(est, truth[:5, :3, 3], var)


def _write_cov(path, times, var):
    with open(path, "w") as f:
        for t, v in zip(times, var):
            f.write(f"{t:.6f} " + " ".join(f"{x:.9g}" for x in np.r_[v, 1e-4, 1e-4, 1e-4]) + "\n")


@pytest.fixture()
def files(tmp_path):
    truth, est, var, _ = truth_and_estimate()
    times = 1000.0 + np.arange(N) * 0.1
    var[0] = 0.0
    est_path, cov_path, gt_path = tmp_path / "est.tum", tmp_path / "est.cov", tmp_path / "gt.tum"
    write_tum(est_path, times, est)
    _write_cov(cov_path, times, var)
    write_tum(gt_path, times, truth)
    moved = tmp_path / "gt_moved.tum"  # the truth in another world frame: only se3 alignment fits it
    write_tum(moved, times, make_pose(so3_exp([0.1, -0.2, 1.2]), [30.0, -4.0, 2.0]) @ truth)
    return {"est": est_path, "cov": cov_path, "gt": gt_path, "moved": moved, "dir": tmp_path}


def test_cli_prints_writes_json_and_figure(files, capsys):
    out, js = files["dir"] / "c.png", files["dir"] / "c.json"
    assert main(["consistency", "--estimate", str(files["est"]), "--covariance", str(files["cov"]),
                 "--gt", str(files["gt"]), "--align", "none", "--out", str(out), "--json", str(js)]) == 0
    text = capsys.readouterr().out
    assert "inside 3 sigma" in text and "position NEES" in text
    assert out.read_bytes()[:8] == PNG_MAGIC
    res = json.loads(js.read_text())
    assert res["frames_used"] == N - 1 and res["alignment"] == "none"
    assert res["nees_mean"] == pytest.approx(3.0, rel=0.06)
    assert res["nees_chi2_95"] == pytest.approx(CHI2_3DOF_95)


def test_cli_se3_alignment_absorbs_a_moved_world(files):
    js = {}
    for name, gt, align in (("none", "gt", "none"), ("se3", "moved", "se3"), ("bad", "moved", "none")):
        js[name] = files["dir"] / f"{name}.json"
        assert main(["consistency", "--estimate", str(files["est"]), "--covariance", str(files["cov"]),
                     "--gt", str(files[gt]), "--align", align, "--json", str(js[name])]) == 0
    r = {k: json.loads(v.read_text()) for k, v in js.items()}
    assert r["se3"]["nees_mean"] == pytest.approx(r["none"]["nees_mean"], rel=0.05)
    assert r["bad"]["nees_mean"] > 100 * r["none"]["nees_mean"]


def test_cli_refuses_files_of_different_runs(files, capsys):
    cov = files["dir"] / "short.cov"
    cov.write_text("".join(files["cov"].read_text().splitlines(keepends=True)[:10]))
    assert main(["consistency", "--estimate", str(files["est"]), "--covariance", str(cov),
                 "--gt", str(files["gt"])]) == 1
    assert "have no line of the same time" in capsys.readouterr().err


def test_read_covariance_checks_columns(tmp_path):
    p = tmp_path / "c.txt"
    p.write_text("1.0 1 2 3 4 5 6\n# comment\n2.0 1 2 3 4 5 6\n")
    t, v = read_covariance(p)
    assert t.tolist() == [1.0, 2.0] and v.shape == (2, 6)
    p.write_text("1.0 1 2 3\n")
    with pytest.raises(ToolError, match="7 numbers"):
        read_covariance(p)
