"""Markdown tables of the reference runs for tools/bench.sh (section `reference`).

  python -m reference.summary compare ROWS   ROWS: label, compare.json (tools/reference/compare --json)
  python -m reference.summary isam2 ROWS     ROWS: label, truth, vislam ate.json, iSAM2 online ate.json,
                                             smoothed ate.json, batch ate.json, isam2 stats json

Rows are tab-separated; a missing or unreadable file gives "n/a" in its cells.
"""

import sys

from vislam_tools.bench_report import dig as _get
from vislam_tools.bench_report import load_json as _load


def _fmt(x, spec):
    return "n/a" if x is None else format(x, spec)


def _rows(path):
    with open(path) as f:
        return [line.rstrip("\n").split("\t") for line in f if line.strip()]


def compare(rows):
    print("| log | frames | C update median / max (us) | reference median / max (us) | ratio median / max "
          "| position max / rms (m) | rotation max / rms (rad) |")
    print("|---|---|---|---|---|---|---|")
    for label, path in rows:
        d = _load(path) or {}
        a, c, r = d.get("agreement", {}), _get(d, "timing", "c", "vl_update"), _get(d, "timing", "reference", "update")
        print(f"| {label} | {a.get('frames_compared', 'n/a')} "
              f"| {_fmt(_get(c, 'median_us'), '.0f')} / {_fmt(_get(c, 'max_us'), '.0f')} "
              f"| {_fmt(_get(r, 'median_us'), '.0f')} / {_fmt(_get(r, 'max_us'), '.0f')} "
              f"| {_fmt(_get(d, 'ratio', 'update_median'), '.0f')}x / {_fmt(_get(d, 'ratio', 'update_max'), '.0f')}x "
              f"| {_fmt(a.get('position_max_m'), '.2g')} / {_fmt(a.get('position_rms_m'), '.2g')} "
              f"| {_fmt(a.get('rotation_max_rad'), '.2g')} / {_fmt(a.get('rotation_rms_rad'), '.2g')} |")


def isam2(rows):
    print("| drive | scored against | vislam default | iSAM2 online | iSAM2 smoothed | iSAM2 + batch "
          "| iSAM2 step median / max (ms) |")
    print("|---|---|---|---|---|---|---|")
    for label, truth, v, online, smoothed, batch, stats in rows:
        s = _load(stats)
        cells = [_fmt(_get(_load(p), "ate", "rmse"), ".2f") for p in (v, online, smoothed, batch)]
        median, worst = _get(s, "step_us", "median"), _get(s, "step_us", "max")
        step = f"{_fmt(median and median / 1e3, '.1f')} / {_fmt(worst and worst / 1e3, '.0f')}"
        print(f"| {label} | {truth} | " + " | ".join(cells) + f" | {step} |")


def main(argv=None):
    argv = sys.argv[1:] if argv is None else argv
    if len(argv) != 2 or argv[0] not in ("compare", "isam2"):
        print(__doc__, file=sys.stderr)
        return 2
    {"compare": compare, "isam2": isam2}[argv[0]](_rows(argv[1]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
