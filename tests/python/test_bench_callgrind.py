"""bench_report callgrind: the core's two entry points counted from whichever caller reaches them."""

import json

from vislam_tools import bench_report

# Two dumps of one run, as `valgrind --tool=callgrind --dump-after=vl_update` writes them: names are
# given once, with their ids, and only the ids afterwards (also in later files). The programs reach
# the core through vl_session_input; main calls it, not the core.
DUMP_1 = """# callgrind format
version: 1
events: Ir
fn=(1) main
10 500
cfn=(2) vl_session_input
calls=2 0
10 9050000
fn=(2)
20 20000
cfn=(3) vl_propagate
calls=1 0
20 30000
cfn=(4) vl_update
calls=1 0
20 9000000
fn=(4)
30 9000000
"""
DUMP_2 = """# callgrind format
version: 1
events: Ir
fn=(1)
10 500
cfn=(2)
calls=2 0
10 11040000
fn=(2)
20 20000
cfn=(3)
calls=1 0
20 40000
cfn=(4)
calls=1 0
20 11000000
fn=(4)
30 8000000
cfn=(3)
calls=1 0
30 3000000
"""


def test_callgrind_counts_the_core_through_the_session(tmp_path, capsys):
    d = tmp_path / "callgrind"
    d.mkdir()
    (d / "callgrind.out.1").write_text(DUMP_1)
    (d / "callgrind.out.2").write_text(DUMP_2)
    out = tmp_path / "cg.json"
    assert bench_report.main(["callgrind", str(d), "--json", str(out)]) == 0
    j = json.loads(out.read_text())
    # The session's calls count; a call the core makes to itself (vl_update -> vl_propagate in
    # the second dump) is inside vl_update's inclusive cost already and does not count again.
    assert j["calls"] == {"vl_update": 2, "vl_propagate": 2}
    assert j["total_ir"] == {"vl_update": 20000000, "vl_propagate": 70000}
    assert j["max_update_ir"] == 11000000 and j["max_propagate_ir"] == 40000
    assert j["steps"] == 4 and j["dumps"] == 2
    table = capsys.readouterr().out
    assert "| vl_update | 2 | 20,000,000 | 10.000 | 11.000 |" in table


def test_callgrind_without_the_core_is_reported(tmp_path, capsys):
    d = tmp_path / "callgrind"
    d.mkdir()
    (d / "callgrind.out.1").write_text("fn=(1) main\n10 500\n")
    assert bench_report.main(["callgrind", str(d)]) == 1
    assert "no usable dump" in capsys.readouterr().out
