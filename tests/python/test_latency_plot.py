"""vislam_tools.latency_plot draws vislam-latency's JSON (synthetic samples here)."""

import json

import numpy as np

from vislam_tools.latency_plot import cdf, histogram_cdf, main

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def test_cdf_and_histogram_cdf():
    x, f = cdf([3.0, 1.0, 2.0, 2.0])
    assert list(x) == [1.0, 2.0, 2.0, 3.0]
    assert f[-1] == 1.0 and f[0] == 0.25
    edges, g = histogram_cdf([[10, 1], [20, 2], [40, 1]])
    assert list(edges) == [10, 20, 40]
    assert np.allclose(g, [0.25, 0.75, 1.0])
    assert len(histogram_cdf([])[0]) == 0


def test_plot_writes_a_png(tmp_path):
    rng = np.random.default_rng(1)
    report = {
        "log": "x.lcmlog", "window": 128, "steps": 100, "rate": "max", "cpu": 1, "budget_us": 100000,
        "samples": {
            "step_us": sorted(rng.uniform(100, 2000, 100).tolist()),
            "e2e_us": sorted(rng.uniform(200, 3000, 100).tolist()),
            "lcm_overhead_us": rng.uniform(50, 300, 100).tolist(),
            "jitter_hist_us": [[60, 900], [120, 90], [2000, 10]],
        },
    }
    src, out = tmp_path / "l.json", tmp_path / "l.png"
    src.write_text(json.dumps(report))
    assert main([str(src), str(out)]) == 0
    assert out.read_bytes()[:8] == PNG_MAGIC
    assert main([str(src)]) == 2
