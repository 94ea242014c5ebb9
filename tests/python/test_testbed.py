"""tools/testbed: the summary and compare arithmetic on hand-made results, and the sim suite end to end."""

import json
import math
import os
from pathlib import Path

import pytest

from vislam_tools import testbed

REPO = Path(__file__).resolve().parents[2]


def _cell(suite, name, vislam, dr=None, group="", obs=None):
    return {"suite": suite, "name": name, "group": group, "truth_kind": "tum", "truth": "", "dr": dr is not None,
            "vislam_ate": vislam, "dr_ate": dr, "obs_per_frame": obs, "log": "", "notes": []}


def _result(cells):
    return {"bin": "b", "data": "d", "config": None, "notes": [], "cells": cells,
            "summary": testbed.summarize(cells), "wall_seconds": 1.0}


def test_geometric_mean_and_mean_skip_missing_values():
    assert testbed.geometric_mean([1.0, 4.0, None, 16.0]) == pytest.approx(4.0)
    assert testbed.geometric_mean([None, None]) is None
    assert testbed.geometric_mean([0.0, 3.0]) == 0.0  # a pseudo-truth against itself
    assert testbed.mean([1.0, None, 2.0]) == pytest.approx(1.5)
    assert testbed.mean([]) is None


def test_summary_per_suite():
    cells = [_cell("conditions", "a", 2.0, dr=1.0), _cell("conditions", "b", 8.0, dr=16.0),
             _cell("conditions", "c", None, dr=3.0), _cell("conditions", "d", 3.0, dr=3.0),
             _cell("grid", "g1", 1.0), _cell("grid", "g2", 9.0),
             _cell("sim", "s1", 0.5), _cell("sim", "s2", 2.0),
             _cell("starts", "t0", 1.0), _cell("starts", "t75", 2.0), _cell("starts", "t150", 6.0)]
    # realistic: two densities x clean/0.1x/1x x 2 seeds; the 0.1x cells stay out of the figure
    for d, base in (("d70", 1.0), ("d3", 4.0)):
        for noise, f in (("clean", 1.0), ("0.1x", 100.0), ("1x", 2.0)):
            for seed, jitter in ((1, 0.5), (2, 1.5)):
                cells.append(_cell("realistic", f"{d}_{noise}_s{seed}", base * f * jitter, dr=10.0 * seed,
                                   group=f"{d} {noise}", obs=60.0))
    s = testbed.summarize(cells)
    c = s["conditions"]
    assert c["value"] == pytest.approx((2.0 * 8.0 * 3.0) ** (1 / 3))  # the n/a cell left out
    assert (c["cells"], c["missing"], c["compared_with_dr"], c["worse_than_dr"]) == (4, 1, 3, 1)
    assert s["grid"]["value"] == pytest.approx(3.0) and s["grid"]["missing"] == 0
    assert s["sim"]["value"] == pytest.approx(1.0)
    assert s["starts"]["value"] == pytest.approx(3.0)
    r = s["realistic"]
    means = {m["group"]: m for m in r["cell_means"]}
    assert means["d3 1x"]["vislam_ate"] == pytest.approx(8.0)  # (4 + 12) / 2
    assert means["d3 1x"]["dr_ate"] == pytest.approx(15.0)
    assert means["d70 0.1x"]["vislam_ate"] == pytest.approx(100.0)  # printed, not in the figure
    assert r["value"] == pytest.approx((1.0 * 2.0 * 4.0 * 8.0) ** 0.25)
    assert (r["summary_cells"], r["summary_cells_missing"], r["missing"]) == (4, 0, 0)
    report = testbed.render_report(_result(cells))
    assert report.index("| conditions |") < report.index("## conditions")
    assert "vislam worse than dead reckoning in 1 of 3" in report and "**1 cell(s) n/a**" in report
    assert "| c | sim truth | n/a | 3.000 | n/a |" in report


def test_realistic_cell_with_a_missing_seed_is_na():
    cells = [_cell("realistic", "d6_clean_s1", 2.0, dr=3.0, group="d6 clean"),
             _cell("realistic", "d6_clean_s2", None, dr=3.0, group="d6 clean"),
             _cell("realistic", "d6_1x_s1", 4.0, dr=5.0, group="d6 1x")]
    r = testbed.summarize(cells)["realistic"]
    assert r["cell_means"][0]["vislam_ate"] is None and r["cell_means"][0]["dr_ate"] == pytest.approx(3.0)
    assert r["value"] == pytest.approx(4.0)
    assert (r["missing"], r["summary_cells_missing"]) == (1, 1)


def test_compare_counts_ratio_and_top_moves(tmp_path, capsys):
    a_cells = [_cell("grid", f"g{i}", float(i)) for i in range(1, 13)] + [_cell("grid", "gone", 1.0),
                                                                          _cell("sim", "s", 1.0)]
    b_cells = [_cell("grid", f"g{i}", float(i) * (1 + i / 10) if i <= 10 else float(i) + 5e-7) for i in range(1, 13)]
    b_cells[0]["vislam_ate"] = 0.5  # g1: 1 -> 0.5, better
    b_cells += [_cell("grid", "gone", None), _cell("sim", "s", 1.0)]
    a, b = _result(a_cells), _result(b_cells)
    r = testbed.compare(a, b)
    g = r["grid"]
    assert g["ratio"] == pytest.approx(b["summary"]["grid"]["value"] / a["summary"]["grid"]["value"])
    assert (g["better"], g["worse"], g["unchanged"], g["na"]) == (1, 9, 2, 1)
    assert len(g["moves"]) == testbed.TOP_MOVES
    assert g["moves"][0]["name"] == "g1" and g["moves"][0]["log_ratio"] == pytest.approx(math.log(0.5))
    assert g["moves"][1]["name"] == "g10"  # x2.0, then g9 at x1.9
    assert r["sim"]["ratio"] == pytest.approx(1.0) and r["sim"]["unchanged"] == 1
    pa, pb = tmp_path / "a.json", tmp_path / "b.json"
    pa.write_text(json.dumps(a))
    pb.write_text(json.dumps(b))
    assert testbed.main(["compare", str(pa), str(pb)]) == 0
    out = capsys.readouterr().out
    assert "| grid |" in out and "| g1 | 1.000 | 0.500 | 0.500 |" in out


def test_compare_by_kind_counts_each_run_once(tmp_path, capsys):
    def real(suite, name, ate, obs):
        c = _cell(suite, name, ate, obs=obs)
        c["truth_kind"] = "kitti"
        return c

    def cells(k):
        # one dense given run in three suites, a sparse clean one, a simulated sparse clean one
        return [real("conditions", "0027_given_K1_s1", 2.0 * k, 68.0), real("grid", "0027_given_K1_s1", 2.0 * k, 68.0),
                real("sweep", "0027_given_K1_s1 default", 2.0 * k, 68.0),
                real("sweep", "0027_given_K1_s1 pixel x10", 3.0, 68.0),
                real("conditions", "0027_clean_K20_s1", 4.0 / k, 3.4),
                _cell("realistic", "realistic_d3_clean_s1", 1.0, group="d3 clean", obs=3.3)]

    a, b = _result(cells(1.0)), _result(cells(2.0))
    kinds = testbed.by_kind(a, b)
    assert set(kinds) == {"real, dense, given", "real, sparse, clean", "simulated, sparse, clean"}
    dense = kinds["real, dense, given"]
    assert dense["runs"] == 2  # the default once, the pixel x10 setting once
    assert dense["ratio"] == pytest.approx(math.sqrt(2.0)) and (dense["worse"], dense["unchanged"]) == (1, 1)
    assert kinds["real, sparse, clean"]["ratio"] == pytest.approx(0.5) and kinds["real, sparse, clean"]["better"] == 1
    assert kinds["simulated, sparse, clean"]["unchanged"] == 1
    pa, pb = tmp_path / "a.json", tmp_path / "b.json"
    pa.write_text(json.dumps(a))
    pb.write_text(json.dumps(b))
    assert testbed.main(["compare", str(pa), str(pb)]) == 0
    assert "| real, dense, given | 2 | 1.414 | 0 | 1 | 1 |" in capsys.readouterr().out


def test_compare_refuses_a_file_that_is_not_a_testbed_result(tmp_path, capsys):
    bad = tmp_path / "x.json"
    bad.write_text("{}")
    assert testbed.main(["compare", str(bad), str(bad)]) == 1
    assert "not a testbed.json" in capsys.readouterr().err


def test_missing_data_skips_the_data_suites(tmp_path):
    plan = testbed.build_plan(list(testbed.SUITES), str(tmp_path / "bin"), str(tmp_path / "nodata"),
                              str(tmp_path / "logs"))
    assert {c.suite for c in plan.cells} == {"sim", "realistic"}
    assert len([c for c in plan.cells if c.suite == "sim"]) == 10
    assert len([c for c in plan.cells if c.suite == "realistic"]) == 36
    assert sum("skipped" in n for n in plan.notes) == len(testbed.DATA_SUITES)


def test_plan_counts_and_shared_logs(tmp_path):
    data = tmp_path / "data"
    (data / "gt").mkdir(parents=True)
    for f in ("0022.npz", "0027.npz", "0034.npz", "gt/kitti_odometry_07.txt"):
        (data / f).write_text("")
    plan = testbed.build_plan(list(testbed.SUITES), str(tmp_path / "bin"), str(data), str(tmp_path / "logs"))
    count = {s: len([c for c in plan.cells if c.suite == s]) for s in testbed.SUITES}
    assert count == {"conditions": 30, "tracker": 18, "clean_imu": 7, "grid": 31, "sim": 10, "realistic": 36,
                     "starts": 8, "sweep": 104, "sweep_starts": 104}
    names = {c.name for c in plan.cells if c.suite == "conditions"}
    assert "0027_given_x2_K1_s1" in names and "0027_given_x2_K1_s1" in {c.name for c in plan.cells if c.suite == "grid"}
    # 24 + 2 x 4 (with the pseudo-truths' full-density logs) + the tracker's 12 + 2 x 3 (sharing the
    # full-density logs) + clean_imu's 7 + the grid's 18 new ones + 8 starts + 46 simulated; the
    # sweep's 8 drives are conditions cells
    assert len(plan.logs) == 24 + 8 + 12 + 6 + 7 + 18 + 8 + 46
    clean_imu = [c for c in plan.cells if c.suite == "clean_imu"]
    assert all(c.dr and c.truth_kind == "kitti" for c in clean_imu)
    argv = plan.logs["0027_clean_imu_N3_s1"].commands[0]
    assert argv[argv.index("--velocities") + 1] == "clean-imu" and argv[argv.index("--max-tracks") + 1] == "3"
    tracker = [c for c in plan.cells if c.suite == "tracker"]
    assert all(c.dr for c in tracker)
    assert {c.truth for c in tracker if c.truth_kind == "pseudo"} == {"0022_given_K1", "0034_given_K1"}
    argv = plan.logs["0027_clean_N3_s1"].commands[0]
    assert argv[argv.index("--max-tracks") + 1] == "3" and "--keep-every" not in argv
    sweep = [c for c in plan.cells if c.suite == "sweep"]
    assert {c.log for c in sweep} <= {c.log for c in plan.cells if c.suite == "conditions"}
    assert len({c.group for c in sweep}) == 8 and len({c.name for c in sweep}) == 104
    assert sorted({c.variant for c in sweep})[:3] == ["", "angular_velocity x0.1", "angular_velocity x0.3"]
    # the sweep over the starts runs on the starts' own logs (its default runs are theirs)
    over_starts = [c for c in plan.cells if c.suite == "sweep_starts"]
    assert {c.log for c in over_starts} == {c.log for c in plan.cells if c.suite == "starts"}
    assert {c.variant for c in over_starts} == {c.variant for c in sweep}


def test_sim_args_reach_every_simulated_log_under_their_own_key(tmp_path):
    plain = testbed.build_plan(["sim", "realistic"], str(tmp_path / "bin"), str(tmp_path / "nodata"),
                               str(tmp_path / "logs"))
    still = testbed.build_plan(["sim", "realistic"], str(tmp_path / "bin"), str(tmp_path / "nodata"),
                               str(tmp_path / "logs"), sim_args=["--moving-fraction", "0"])
    assert plain.logs.keys() == still.logs.keys() and len(still.logs) == 46
    for name, spec in still.logs.items():
        argv = spec.commands[0]
        assert argv[argv.index("--out") - 2:argv.index("--out")] == ["--moving-fraction", "0"]
        assert "--moving-fraction" not in plain.logs[name].commands[0]
        assert spec.path != plain.logs[name].path  # an ablation never reuses the plain drive's log
    parser = testbed.build_parser()
    assert parser.parse_args(["run", "--out", "o", "--sim-args", "--far-fraction 0 --seed 2"]).sim_args == [
        "--far-fraction", "0", "--seed", "2"]
    with pytest.raises(SystemExit):
        parser.parse_args(["run", "--out", "o", "--sim-args", "--out x.lcmlog"])


def _build_bin():
    build = os.environ.get("VISLAM_BUILD_DIR") or os.environ.get("VL_BUILD_DIR") or str(REPO / "build")
    bin_dir = Path(build) / "bin"
    if not (bin_dir / "vislam-run").is_file() or not (bin_dir / "vislam-sim").is_file():
        pytest.skip(f"no vislam-run / vislam-sim in {bin_dir} (build first or set VISLAM_BUILD_DIR)")
    return bin_dir


def test_run_sim_suite_end_to_end(tmp_path, capsys):
    """The 10 simulated drives (about 10 s on two cores); a second run reuses the cached logs and
    gives the same figures (every run is deterministic)."""
    bin_dir = _build_bin()
    logs = tmp_path / "logs"
    args = ["run", "--suites", "sim", "--bin", str(bin_dir), "--data", str(tmp_path / "nodata"), "--logs", str(logs)]
    assert testbed.main(args + ["--out", str(tmp_path / "a")]) == 0
    report = capsys.readouterr().out
    assert report.startswith("# vislam accuracy test bed") and "| sim |" in report
    res = json.loads((tmp_path / "a" / "testbed.json").read_text())
    assert len(res["cells"]) == 10 and res["summary"]["sim"]["missing"] == 0
    assert 0 < res["summary"]["sim"]["value"] < 10
    assert all(c["obs_per_frame"] > 1 for c in res["cells"])
    cmds = (tmp_path / "a" / "commands.sh").read_text()
    assert "vislam-sim --seed 1 " in cmds and "vislam-run " in cmds and "# tools/evaluate ate" in cmds
    assert not [p for p in os.listdir(logs) if p.startswith(".tmp")]
    stamps = {p: p.stat().st_mtime_ns for p in logs.rglob("*.lcmlog")}
    assert testbed.main(args + ["--out", str(tmp_path / "b")]) == 0
    assert {p: p.stat().st_mtime_ns for p in logs.rglob("*.lcmlog")} == stamps
    assert "(cached)" in (tmp_path / "b" / "commands.sh").read_text()
    res_b = json.loads((tmp_path / "b" / "testbed.json").read_text())
    assert [c["vislam_ate"] for c in res_b["cells"]] == [c["vislam_ate"] for c in res["cells"]]
    capsys.readouterr()
    assert testbed.main(["compare", str(tmp_path / "a" / "testbed.json"), str(tmp_path / "b" / "testbed.json")]) == 0
    assert "| sim |" in capsys.readouterr().out


def test_failed_run_is_na_not_a_crash(tmp_path, capsys):
    """A vislam-run that fails (here: a stand-in that exits 1) leaves its cells n/a with a warning."""
    real = _build_bin()
    fake = tmp_path / "bin"
    fake.mkdir()
    (fake / "vislam-sim").symlink_to(real / "vislam-sim")
    (fake / "vislam-run").write_text("#!/bin/sh\necho 'vislam-run: broken on purpose' >&2\nexit 1\n")
    (fake / "vislam-run").chmod(0o755)
    plan = testbed.build_plan(["sim"], str(fake), str(tmp_path / "nodata"), str(tmp_path / "logs"))
    plan.cells = plan.cells[:1]
    warnings = []
    testbed.execute_plan(plan, str(tmp_path / "out"), jobs=1, warn=warnings.append)
    assert plan.cells[0].vislam_ate is None and "broken on purpose" in warnings[0]
    s = testbed.summarize([{"suite": c.suite, "vislam_ate": c.vislam_ate} for c in plan.cells])
    assert s["sim"]["missing"] == 1 and s["sim"]["value"] is None


def test_user_errors_are_one_line(tmp_path, capsys):
    assert testbed.main(["run", "--out", str(tmp_path / "o"), "--bin", str(tmp_path)]) == 1
    assert "no vislam-run in" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        testbed.main(["run", "--out", str(tmp_path / "o"), "--suites", "sim,nope"])
    assert "unknown suite(s) nope" in capsys.readouterr().err


def test_sweep_rows_best_within_and_worst():
    cells = []
    for group, values in (("a", {"": 2.0, "pixel x10": 2.7, "pixel x0.1": 1.9}),
                          ("b", {"": 5.0, "pixel x10": None, "pixel x0.1": 1.0})):
        for variant, v in values.items():
            cells.append(dict(_cell("sweep", f"{group} {variant or 'default'}", v), group=group, variant=variant))
    s = testbed.summarize(cells)["sweep"]
    a, b = s["rows"]
    assert a["best"] == pytest.approx(1.9) and a["within"] == 2 and a["worst"] == "pixel x10"
    assert a["worst_ratio"] == pytest.approx(2.7 / 1.9)
    assert b["best"] is None and b["within"] is None  # a run missing: no verdict on the drive
    assert s["rows_all_within"] == 0 and s["missing"] == 1
    assert s["value"] == pytest.approx((2.0 * 2.7 * 1.9 * 5.0 * 1.0) ** 0.2)
    report = testbed.render_report(_result(cells))
    assert "| a | 1.90 | 2 of 3 | pixel x10 (1.42) |" in report
    assert "| a | pixel | 1.90 | n/a | 2.00 | n/a | 2.70 |" in report
    assert "every run within 1.3x of their best: 0 of 2" in report


def test_sweep_over_starts_judges_each_runs_mean():
    """One start is one drive: a run is judged by its mean over the starts, and a start missing
    leaves that run's mean (and so the verdict) n/a."""
    starts = {"": (2.0, 1.0), "pixel x10": (2.0, 4.0), "pixel x0.1": (1.0, 2.0)}
    cells = [dict(_cell("sweep_starts", f"s{i} {variant or 'default'}", v), group=f"s{i}", variant=variant)
             for variant, values in starts.items() for i, v in enumerate(values)]
    s = testbed.summarize(cells)["sweep_starts"]
    (row,) = s["rows"]
    assert row["group"] == "0027 given, mean of 2 starts"
    assert row["values"] == pytest.approx({"": 1.5, "pixel x10": 3.0, "pixel x0.1": 1.5})
    assert row["best"] == pytest.approx(1.5) and row["within"] == 2 and row["worst"] == "pixel x10"
    assert s["rows_all_within"] == 0 and s["cells"] == 6
    assert s["value"] == pytest.approx((2.0 * 1.0 * 2.0 * 4.0 * 1.0 * 2.0) ** (1 / 6))
    cells[3]["vislam_ate"] = None  # pixel x10 on the second start
    (row,) = testbed.summarize(cells)["sweep_starts"]["rows"]
    assert row["values"]["pixel x10"] is None and row["within"] is None
    report = testbed.render_report(_result(cells))
    assert "## sweep_starts" in report and "| 0027 given, mean of 2 starts | n/a | n/a |" in report


def test_variant_config_replaces_or_adds_the_prior():
    base = "; mine\n[noise]\npixel = 0.8 ; measured\nlinear_velocity=0.2\n[landmarks]\nfirst_sight_below = 0\n"
    out = testbed.variant_config(base, "pixel", 8.0)
    assert "pixel = 8\n" in out and "0.8" not in out and out.count("pixel") == 1
    assert "linear_velocity=0.2" in out and "first_sight_below = 0" in out
    out = testbed.variant_config(base, "angular_velocity", 0.005)
    assert out.endswith("[noise]\nangular_velocity = 0.005\n") and "pixel = 0.8" in out
    assert testbed.variant_config("", "pixel", 15.0) == "\n[noise]\npixel = 15\n"


def test_sweep_configs_scale_the_prior_in_use(tmp_path):
    """The sweep's configuration files scale what vislam-run would use: its default, or --config's."""
    bin_dir = _build_bin()
    assert testbed.configured_noise(str(bin_dir), None) == pytest.approx(
        {"linear_velocity": 0.5, "angular_velocity": 0.05, "pixel": 1.5})
    mine = tmp_path / "mine.ini"
    mine.write_text("[noise]\npixel = 0.5\n")
    assert testbed.configured_noise(str(bin_dir), str(mine))["pixel"] == pytest.approx(0.5)
    plan = testbed.Plan(str(bin_dir), str(tmp_path), str(tmp_path / "logs"), str(REPO / "tools"))
    plan.cells = [testbed.Cell("sweep", "x", "x", "kitti", "", variant="pixel x10")]
    paths = testbed._variant_configs(plan, str(tmp_path / "out"), str(mine))
    assert open(paths["pixel x10"]).read() == "[noise]\npixel = 5\n"
