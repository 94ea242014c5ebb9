"""Markdown tables for tools/bench.sh from the files its runs leave behind.

Each subcommand reads a tab-separated list of runs (written by bench.sh; one run per line,
columns described below) and prints a Markdown table on stdout. A missing or unreadable
input file gives "n/a" in its cells, never an exception, so one failed run does not hide
the others.

  ate ROWS        label, data, settings, ate.json[, stats.json]
  starts ROWS     label, settings, start step, ate.json: one row per label with the ATE from each
                  start and their mean; then the best mean and the labels within 1.3x of it
  window ROWS     max_landmarks, ate.json (0027), stats.json (0027), stats.json (0034)
  timing ROWS     label, stats.json (vislam-run --timing --stats-json)
  callgrind DIR   per-call costs from the dumps of callgrind --dump-after=vl_update
  daemon ROWS     label, vislamd --stats-json, vislam-replay --summary-json
  latency ROWS    label, vislam-latency --json
  soak LOOPS STATS bench.sh's loops.tsv (loop, log, daemon RSS in KiB, replay exit, summary json) and
                  the daemon's --stats-json
  conditions ROWS drive, velocities, K, truth, conditions summary.json, ate.json (dead reckoning),
                  ate.json (default); --json OUT (cell -> numbers), --png OUT (figure)
"""

import argparse
import glob
import json
import math
import os
import re
import sys


def load_json(path):
    """The JSON in path, or None when it cannot be read."""
    try:
        with open(path) as f:
            return json.load(f)
    except (OSError, ValueError):
        return None


def _rows(path):
    rows = []
    with open(path) as f:
        for line in f:
            line = line.rstrip("\n")
            if line:
                rows.append(line.split("\t"))
    return rows


def fmt(x, digits=3):
    """A figure for the reports' tables: "n/a" for a missing or non-finite value, integers as they are."""
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "n/a"
    if isinstance(x, int):
        return str(x)
    return f"{x:.{digits}f}"


def dig(d, *keys):
    """d[k1][k2]..., or None where a key is missing."""
    for k in keys:
        if not isinstance(d, dict) or k not in d:
            return None
        d = d[k]
    return d


def _table(header, rows):
    out = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    out += ["| " + " | ".join(str(c) for c in r) + " |" for r in rows]
    return "\n".join(out)


def _rpe(ate, delta):
    for r in dig(ate, "rpe") or []:
        if r.get("delta") == delta:
            return f"{fmt(r.get('trans_rmse'))} / {fmt(r.get('rot_rmse_deg'), 2)}"
    return "n/a"


def cmd_ate(args):
    header = ["run", "data", "settings", "ATE RMSE (m)", "ATE max (m)",
              "RPE 1 step: m / deg", "RPE 10 steps: m / deg",
              "obs. used", "gated", "re-assoc. frames", "num. failures"]
    rows = []
    for r in _rows(args.rows):
        label, data, settings, ate_path = r[:4]
        ate = load_json(ate_path)
        stats = load_json(r[4]) if len(r) > 4 and r[4] else None
        c = dig(stats, "core_counters") or {}
        rows.append([label, data, settings,
                     fmt(dig(ate, "ate", "rmse")), fmt(dig(ate, "ate", "max")),
                     _rpe(ate, 1), _rpe(ate, 10),
                     fmt(c.get("observations_used")), fmt(c.get("observations_gated")),
                     fmt(c.get("frames_reassociated")), fmt(c.get("numerical_failures"))])
    print(_table(header, rows))


def cmd_starts(args):
    """One drive run from several starts per setting: a steadier measure than one run, whose ATE
    moves by tenths of a metre with any change of which observations are used."""
    labels, settings, starts, ates = [], {}, [], {}
    for label, setting, start, ate_path in (r[:4] for r in _rows(args.rows)):
        if label not in settings:
            labels.append(label)
            settings[label] = setting
        if start not in starts:
            starts.append(start)
        ates[label, start] = dig(load_json(ate_path), "ate", "rmse")
    means = {}
    for label in labels:
        v = [ates.get((label, s)) for s in starts]
        means[label] = sum(v) / len(v) if v and all(x is not None for x in v) else None
    header = ["run", "settings"] + [f"from step {s}" for s in starts] + ["mean ATE (m)"]
    print(_table(header, [[label, settings[label]] + [fmt(ates.get((label, s))) for s in starts] +
                          [fmt(means[label])] for label in labels]))
    known = {k: m for k, m in means.items() if m is not None}
    if known:
        best = min(known, key=known.get)
        within = [k for k in labels if k in known and known[k] <= 1.3 * known[best]]
        print(f"\nBest mean: {known[best]:.3f} m ({best}); within 1.3x of it: {len(within)} of {len(labels)}"
              + ("" if len(known) == len(labels) else f" ({len(labels) - len(known)} with a failed run)")
              + "; outside: " + (", ".join(f"{k} ({known[k] / known[best]:.2f}x)" for k in labels
                                          if k in known and k not in within) or "none") + ".")
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"starts": starts, "runs": {k: {"settings": settings[k], "mean": means[k],
                                                      "ate": [ates.get((k, s)) for s in starts]}
                                                  for k in labels}}, f, indent=2)
            f.write("\n")


def _timing(stats, fn):
    t = dig(stats, "timing", fn) or {}
    return [fmt(t.get(k), 1) for k in ("median_us", "p99_us", "p999_us", "max_us")]


def cmd_window(args):
    header = ["max_landmarks", "ATE 0027 (m)", "vl_update 0034 median / p99 / p99.9 / max (us)",
              "vl_propagate 0034 median (us)", "landmarks deferred / evicted 0027",
              "landmarks deferred / evicted 0034", "obs. deferred 0027 / 0034", "window peak 0034"]
    rows = []
    for n, ate_path, s27_path, s34_path in _rows(args.rows):
        ate, s27, s34 = load_json(ate_path), load_json(s27_path), load_json(s34_path)

        def de(s):
            c = dig(s, "core_counters") or {}
            return f"{fmt(c.get('landmarks_deferred'))} / {fmt(c.get('landmarks_evicted'))}"

        rows.append([n, fmt(dig(ate, "ate", "rmse")), " / ".join(_timing(s34, "vl_update")),
                     _timing(s34, "vl_propagate")[0], de(s27), de(s34),
                     f"{fmt(dig(s27, 'core_counters', 'observations_deferred'))} / "
                     f"{fmt(dig(s34, 'core_counters', 'observations_deferred'))}",
                     fmt(dig(s34, "core_counters", "window_peak"))])
    print(_table(header, rows))


def cmd_timing(args):
    header = ["run", "steps", "vl_update median", "p99", "p99.9", "max",
              "vl_propagate median", "p99", "p99.9", "max"]
    rows = []
    worst = None
    for label, path in _rows(args.rows):
        s = load_json(path)
        n = dig(s, "timing", "vl_update", "count")
        rows.append([label, fmt(n)] + _timing(s, "vl_update") + _timing(s, "vl_propagate"))
        for fn in ("vl_update", "vl_propagate"):
            m = dig(s, "timing", fn, "max_us")
            if m is not None and (worst is None or m > worst[0]):
                worst = (m, fn, label)
    print(_table(header, rows))
    print()
    print("(wall time per call, us)")
    if worst:
        print()
        print(f"Worst single call over all runs: {worst[0]:.1f} us ({worst[1]}, {worst[2]}).")
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"worst_us": worst[0] if worst else None}, f)


# callgrind writes names once and refers to them by "(id)" afterwards, also across the files
# of one run, so the id table is kept over all dumps.
_NAME_RE = re.compile(r"^(c?fn)=\((\d+)\)(?: (.*))?$")


def _parse_dump(path, names):
    """Inclusive Ir of the calls to vl_update and vl_propagate in one dump, from whichever caller
    (the programs call them through vl_session) other than the two themselves."""
    cost = {"vl_update": 0, "vl_propagate": 0}
    calls = {"vl_update": 0, "vl_propagate": 0}
    fn = None
    pending = None  # callee name whose cost line comes after its calls= line
    expect_cost = False
    with open(path) as f:
        for line in f:
            if expect_cost:
                expect_cost = False
                parts = line.split()
                if pending and len(parts) >= 2:
                    cost[pending] += int(parts[-1])
                pending = None
                continue
            m = _NAME_RE.match(line.rstrip("\n"))
            if m:
                kind, ident, name = m.groups()
                if name:
                    names[ident] = name
                name = names.get(ident, "?")
                if kind == "fn":
                    fn = name
                    pending = None
                else:
                    pending = name if (name in cost and fn not in cost) else None
                continue
            if line.startswith("calls="):
                if pending:
                    calls[pending] += int(line.split("=")[1].split()[0])
                expect_cost = True
    return cost, calls


def cmd_callgrind(args):
    def part(p):
        m = re.search(r"\.(\d+)$", p)
        return int(m.group(1)) if m else 0

    files = sorted(glob.glob(os.path.join(args.dir, "callgrind.out*")), key=part)
    names = {}
    per_update, per_propagate, per_pair = [], [], []
    tot = {"vl_update": 0, "vl_propagate": 0}
    ncalls = {"vl_update": 0, "vl_propagate": 0}
    for p in files:
        cost, calls = _parse_dump(p, names)
        for k in tot:
            tot[k] += cost[k]
            ncalls[k] += calls[k]
        # A dump closes at the end of each vl_update: it holds one update and the
        # propagation(s) before it.
        if calls["vl_update"] == 1:
            per_update.append(cost["vl_update"])
            per_pair.append(cost["vl_update"] + cost["vl_propagate"])
        if calls["vl_propagate"] == 1:
            per_propagate.append(cost["vl_propagate"])
    steps = ncalls["vl_update"] + ncalls["vl_propagate"]
    if not files or steps == 0:
        print("callgrind: no usable dump in " + args.dir)
        return 1

    def mean(v):
        return sum(v) / len(v) if v else None

    def mi(x):
        return "n/a" if x is None else f"{x / 1e6:.3f}"

    header = ["", "calls", "total Ir", "mean Ir / call (M)", "max Ir / call (M)"]
    rows = [
        ["vl_update", ncalls["vl_update"], f"{tot['vl_update']:,}", mi(mean(per_update)),
         mi(max(per_update) if per_update else None)],
        ["vl_propagate", ncalls["vl_propagate"], f"{tot['vl_propagate']:,}", mi(mean(per_propagate)),
         mi(max(per_propagate) if per_propagate else None)],
        ["core, per step (update or propagate)", steps, f"{tot['vl_update'] + tot['vl_propagate']:,}",
         mi((tot["vl_update"] + tot["vl_propagate"]) / steps), "n/a"],
        ["propagate + update of one frame", len(per_pair), "", mi(mean(per_pair)),
         mi(max(per_pair) if per_pair else None)],
    ]
    print(_table(header, rows))
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"steps": steps, "total_ir": tot, "calls": ncalls,
                       "max_update_ir": max(per_update) if per_update else None,
                       "max_propagate_ir": max(per_propagate) if per_propagate else None,
                       "dumps": len(files)}, f, indent=2)
    return 0


def _daemon_summary(path):
    """vislamd's --stats-json (PATH), with the LD_PRELOAD allocation counter's report beside it."""
    stats = load_json(path) or {}
    d = {}
    for key, lat in stats.get("step_latency", {}).items():
        d[key] = {"n": lat.get("count"), "p50": lat.get("median_us"), "p90": lat.get("p90_us"),
                  "p99": lat.get("p99_us"), "p999": lat.get("p999_us"), "max": lat.get("max_us"),
                  "mean": lat.get("mean_us")}
    for key in ("budget_us", "overruns", "steps"):
        if key in stats:
            d[key] = stats[key]
    core = stats.get("core_counters", {})
    for key in ("timeline_changes", "divergence_resets"):
        if key in core:
            d[key] = core[key]
    # The LD_PRELOAD counter's own report beside the daemon's (VL_ALLOC_REPORT, "key value" lines).
    alloc = {}
    try:
        with open(os.path.splitext(path)[0] + ".alloc") as f:
            alloc = dict(line.split(None, 1) for line in f if line.strip())
    except (OSError, ValueError):
        pass
    if alloc.get("alloc.armed", "").strip() == "1":
        d["alloc_process"] = int(alloc["alloc.process_after_arm"])
        d["alloc_main"] = int(alloc["alloc.armed_thread_after_arm"])
    return d


def cmd_daemon(args):
    header = ["log", "steps", "budget (us)", "overruns",
              "step latency p50 / p99 / p99.9 / max (us)", "update p99 / max (us)",
              "end-to-end p50 / p99 / max (us)", "poses back", "allocs after start-up: process / main thread"]
    rows = []
    for label, log, summary in _rows(args.rows):
        d = _daemon_summary(log)
        r = load_json(summary) or {}
        a, u = d.get("all", {}), d.get("update", {})
        lat = r.get("latency_us", {})
        rows.append([label, fmt(d.get("steps")), fmt(d.get("budget_us")), fmt(d.get("overruns")),
                     " / ".join(fmt(a.get(k)) for k in ("p50", "p99", "p999", "max")),
                     " / ".join(fmt(u.get(k)) for k in ("p99", "max")),
                     " / ".join(fmt(lat.get(k)) for k in ("p50", "p99", "max")),
                     f"{fmt(r.get('frames_returned'))} of {fmt(r.get('frames_expected'))}",
                     f"{fmt(d.get('alloc_process'))} / {fmt(d.get('alloc_main'))}"])
    print(_table(header, rows))


def cmd_latency(args):
    """One row per vislam-latency --json run: step, end-to-end and LCM-overhead percentiles beside the
    jitter floor."""
    header = ["run", "steps", "step min / p50 / p99 / p99.9 / max (us)", "end to end p50 / p99 / p99.9 / max (us)",
              "LCM overhead p50 / p99 / max (us)", "poses back", "jitter floor p99 / max (us)", "overruns", "work p50 / max (Mflop)",
              "costliest step: x median time / x median work"]
    rows = []
    for label, path in _rows(args.rows):
        d = load_json(path) or {}
        st, e2e, jit, w = d.get("step_us") or {}, d.get("e2e_us") or {}, d.get("jitter_floor_us") or {}, \
            d.get("work") or {}
        lcm = d.get("lcm_overhead_us") or {}
        c = d.get("costliest_step") or {}
        frames = d.get("e2e_frames") or {}
        mflop = [None if w.get(k) is None else w[k] / 1e6 for k in ("p50", "max")]
        rows.append([label, fmt(d.get("steps")),
                     " / ".join(fmt(st.get(k), 0) for k in ("min", "p50", "p99", "p999", "max")),
                     " / ".join(fmt(e2e.get(k), 0) for k in ("p50", "p99", "p999", "max")),
                     " / ".join(fmt(lcm.get(k), 0) for k in ("p50", "p99", "max")),
                     f"{fmt(frames.get('returned'))} of {fmt(frames.get('expected'))}",
                     " / ".join(fmt(jit.get(k), 0) for k in ("p99", "max")),
                     fmt(d.get("overruns")), " / ".join(fmt(m, 1) for m in mflop),
                     f"{fmt(c.get('us_ratio_to_p50'), 2)} / {fmt(c.get('work_ratio_to_p50'), 2)}"])
    print(_table(header, rows))


def cmd_soak(args):
    loops = _rows(args.loops)[1:]  # the first line names the columns
    header = ["loop", "log", "sensor time (s)", "frames answered", "end-to-end p99 / max (us)",
              "daemon RSS (KiB)", "replay exit"]
    rows, sensor_s, expected, returned, rss = [], 0.0, 0, 0, []
    for loop, log, rss_kb, rc, summary in loops:
        r = load_json(summary) or {}
        lat = r.get("latency_us", {})
        sensor_s += r.get("log_s") or 0.0
        expected += r.get("frames_expected") or 0
        returned += r.get("frames_returned") or 0
        if rss_kb.isdigit():
            rss.append(int(rss_kb))
        rows.append([loop, log, fmt(r.get("log_s"), 1), f"{fmt(r.get('frames_returned'))} of "
                     f"{fmt(r.get('frames_expected'))}", " / ".join(fmt(lat.get(k)) for k in ("p99", "max")),
                     rss_kb, rc])
    print(_table(header, rows))
    d = _daemon_summary(args.stats)
    print()
    print(f"Sensor time {sensor_s:.0f} s ({sensor_s / 3600:.2f} h) in {len(loops)} replays; frames answered "
          f"{returned} of {expected} ({expected - returned} without a pose, at the timeline switches); "
          f"daemon RSS after the first replay {fmt(rss[0] if rss else None)} KiB, after the last "
          f"{fmt(rss[-1] if rss else None)} KiB, largest {fmt(max(rss) if rss else None)} KiB; timeline "
          f"changes {fmt(d.get('timeline_changes'))}, divergence resets {fmt(d.get('divergence_resets'))}; "
          f"heap allocations after start-up {fmt(d.get('alloc_process'))} in the process, "
          f"{fmt(d.get('alloc_main'))} in the main (estimation) thread.")


def _condition_cells(rows_path):
    cells = []
    for drive, vel, k, truth, summary_path, dr_path, slam_path in _rows(rows_path):
        summary = load_json(summary_path)
        cells.append({
            "cell": f"{drive}/{vel}/K{k}",
            "drive": drive,
            "velocities": vel,
            "keep_every": int(k),
            "truth": truth,
            "obs_per_frame": dig(summary, "observations_per_step"),
            "dr_ate": dig(load_json(dr_path), "ate", "rmse"),
            "vislam_ate": dig(load_json(slam_path), "ate", "rmse"),
        })
    return cells


def _ratio(c):
    if c["dr_ate"] is None or c["vislam_ate"] is None:
        return "n/a"
    if c["truth"] != "ground truth" and c["vislam_ate"] < 1e-6:
        return "(reference)"
    if c["dr_ate"] < 1e-3:
        return "(DR exact)"
    return fmt(c["vislam_ate"] / c["dr_ate"], 2)


def cmd_conditions(args):
    cells = _condition_cells(args.rows)
    header = ["drive", "velocities", "tracks kept", "obs. per frame", "ATE dead reckoning (m)",
              "ATE vislam default (m)", "vislam / DR", "truth"]
    rows = [[c["drive"], c["velocities"], "all" if c["keep_every"] == 1 else f"1 in {c['keep_every']}",
             fmt(c["obs_per_frame"], 1), fmt(c["dr_ate"], 2), fmt(c["vislam_ate"], 2), _ratio(c),
             c["truth"]] for c in cells]
    print(_table(header, rows))
    # the same, vislam ATE only, one line per drive and velocities, one column per density
    ks = sorted({c["keep_every"] for c in cells})
    lines = []
    for c in cells:
        key = (c["drive"], c["velocities"])
        if key not in lines:
            lines.append(key)
    by = {(c["drive"], c["velocities"], c["keep_every"]): c for c in cells}
    pivot = []
    for drive, vel in lines:
        row = [drive, vel]
        for k in ks:
            c = by.get((drive, vel, k))
            row.append("" if c is None else f"{fmt(c['vislam_ate'], 2)} / {fmt(c['dr_ate'], 2)}")
        pivot.append(row)
    print()
    print("ATE vislam / dead reckoning (m), by tracks kept:")
    print()
    print(_table(["drive", "velocities"] + ["all" if k == 1 else f"1 in {k}" for k in ks], pivot))
    if args.json:
        with open(args.json, "w") as f:
            json.dump({c["cell"]: {k: v for k, v in c.items() if k != "cell"} for c in cells}, f, indent=2)
            f.write("\n")
    if args.png:
        from .plotting import plot_conditions
        plot_conditions(cells, args.png)


def main(argv=None):
    ap = argparse.ArgumentParser(prog="bench_report", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    for name in ("ate", "starts", "window", "timing", "daemon"):
        p = sub.add_parser(name)
        p.add_argument("rows")
        p.add_argument("--json")
    p = sub.add_parser("conditions")
    p.add_argument("rows")
    p.add_argument("--json")
    p.add_argument("--png")
    p = sub.add_parser("soak")
    p.add_argument("loops")
    p.add_argument("stats")
    p = sub.add_parser("callgrind")
    p.add_argument("dir")
    p.add_argument("--json")
    p = sub.add_parser("latency")
    p.add_argument("rows")
    args = ap.parse_args(argv)
    return {"ate": cmd_ate, "starts": cmd_starts, "window": cmd_window, "timing": cmd_timing,
            "callgrind": cmd_callgrind, "daemon": cmd_daemon, "conditions": cmd_conditions,
            "soak": cmd_soak, "latency": cmd_latency}[args.cmd](args) or 0


if __name__ == "__main__":
    sys.exit(main())
