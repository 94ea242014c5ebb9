"""bench_report latency: one row per vislam-latency --json run, n/a for a failed one."""

import json

from vislam_tools import bench_report


def test_latency_table(tmp_path, capsys):
    report = {
        "steps": 400, "overruns": 2,
        "step_us": {"min": 18.0, "p50": 700.0, "p99": 1500.0, "p999": 2000.0, "max": 2100.0},
        "e2e_us": {"min": 90.0, "p50": 850.0, "p99": 1600.0, "p999": 2500.0, "max": 2600.0},
        "lcm_overhead_us": {"min": 40.0, "p50": 95.0, "p99": 180.0, "p999": 240.0, "max": 250.0},
        "e2e_frames": {"expected": 400, "returned": 400},
        "jitter_floor_us": {"p99": 60.0, "max": 900.0},
        "work": {"p50": 25.4e6, "max": 50.6e6},
        "costliest_step": {"us_ratio_to_p50": 3.0, "work_ratio_to_p50": 1.98},
    }
    ok = tmp_path / "ok.json"
    ok.write_text(json.dumps(report))
    rows = tmp_path / "rows.tsv"
    rows.write_text(f"good\t{ok}\nfailed\t{tmp_path / 'missing.json'}\n")
    assert bench_report.main(["latency", str(rows)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == 4
    assert "| good | 400 | 18 / 700 / 1500 / 2000 / 2100 | 850 / 1600 / 2500 / 2600 | 95 / 180 / 250 | 400 of 400 " \
        "| 60 / 900 | 2 |" in lines[2]
    assert "25.4 / 50.6" in lines[2] and "3.00 / 1.98" in lines[2]
    assert lines[3].startswith("| failed | n/a |")
