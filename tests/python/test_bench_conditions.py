import json

import pytest

from vislam_tools import bench_report

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def _json(path, obj):
    path.write_text(json.dumps(obj))
    return str(path)


@pytest.fixture()
def rows(tmp_path):
    """Rows as tools/bench.sh --section conditions writes them, one with a failed run."""
    lines = []
    cells = [("0027", "given", 1, "ground truth", 68.4, 16.4, 4.1),
             ("0027", "given", 10, "ground truth", 7.0, 16.4, 11.7),
             ("0027", "clean", 1, "ground truth", 68.4, 1e-6, 3.8),
             ("0027", "clean", 10, "ground truth", 7.0, 1e-6, None),
             ("0034", "given", 1, "pseudo-truth (vislam, all tracks)", 66.9, 47.8, 0.0),
             ("0034", "given", 10, "pseudo-truth (vislam, all tracks)", 7.0, 47.8, 20.2)]
    for i, (drive, vel, k, truth, obs, dr, slam) in enumerate(cells):
        s = _json(tmp_path / f"{i}.summary.json", {"observations_per_step": obs})
        d = _json(tmp_path / f"{i}_dr.ate.json", {"ate": {"rmse": dr}})
        v = _json(tmp_path / f"{i}_slam.ate.json", {"ate": {"rmse": slam}}) if slam is not None \
            else str(tmp_path / "missing.json")
        lines.append("\t".join([drive, vel, str(k), truth, s, d, v]))
    p = tmp_path / "rows.tsv"
    p.write_text("\n".join(lines) + "\n")
    return p


def test_conditions_table_json_and_figure(rows, tmp_path, capsys):
    out_json, out_png = tmp_path / "c.json", tmp_path / "c.png"
    assert bench_report.main(["conditions", str(rows), "--json", str(out_json), "--png", str(out_png)]) == 0
    text = capsys.readouterr().out
    assert "| 0027 | given | all | 68.4 | 16.40 | 4.10 | 0.25 | ground truth |" in text
    assert "(DR exact)" in text and "(reference)" in text
    assert "| 0027 | clean | 1 in 10 | 7.0 | 0.00 | n/a | n/a | ground truth |" in text
    assert "| 0027 | given | 4.10 / 16.40 | 11.70 / 16.40 |" in text  # the pivot by density
    cells = json.loads(out_json.read_text())
    assert cells["0027/given/K10"] == {"drive": "0027", "velocities": "given", "keep_every": 10,
                                       "truth": "ground truth", "obs_per_frame": 7.0, "dr_ate": 16.4,
                                       "vislam_ate": 11.7}
    assert cells["0027/clean/K10"]["vislam_ate"] is None
    assert out_png.read_bytes()[:8] == PNG_MAGIC


def test_starts_table_means_and_the_cells_within_1_3x(tmp_path, capsys):
    """Rows as tools/bench.sh --section sweep writes them for its runs from several starts."""
    ates = {"default": (2.0, 1.0), "x10": (3.0, 2.0), "x0.1": (1.5, 1.5), "broken": (1.0, None)}
    lines = []
    for label, values in ates.items():
        for start, a in zip((0, 75), values):
            path = _json(tmp_path / f"{label}{start}.json", {"ate": {"rmse": a}}) if a is not None \
                else str(tmp_path / "missing.json")
            lines.append("\t".join([label, f"[noise] {label}", str(start), path]))
    rows = tmp_path / "starts.tsv"
    rows.write_text("\n".join(lines) + "\n")
    out_json = tmp_path / "s.json"
    assert bench_report.main(["starts", str(rows), "--json", str(out_json)]) == 0
    text = capsys.readouterr().out
    assert "| run | settings | from step 0 | from step 75 | mean ATE (m) |" in text
    assert "| default | [noise] default | 2.000 | 1.000 | 1.500 |" in text
    assert "| broken | [noise] broken | 1.000 | n/a | n/a |" in text  # a failed run: no mean
    assert "Best mean: 1.500 m (default); within 1.3x of it: 2 of 4 (1 with a failed run); " \
           "outside: x10 (1.67x)." in text
    d = json.loads(out_json.read_text())
    assert d["starts"] == ["0", "75"]
    assert d["runs"]["x10"] == {"settings": "[noise] x10", "mean": 2.5, "ate": [3.0, 2.0]}
    assert d["runs"]["broken"]["mean"] is None
