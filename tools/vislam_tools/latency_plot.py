"""The latency figure of vislam-latency: CDFs of the in-process step time, of the end-to-end
latency through vislamd and of its LCM overhead (end to end less vislamd's own step), beside the
machine's own jitter floor measured in the same run.

    python -m vislam_tools.latency_plot LATENCY.json OUT.png

LATENCY.json is vislam-latency --json's output: its "samples" hold the step and end-to-end
times and the LCM overhead per frame (us), and the jitter probe's histogram as [bucket upper
edge (us), count] pairs.
"""

import json
import sys

import numpy as np
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402  (backend must be chosen first)


def cdf(values):
    """Sorted values and the fraction of samples at or below each."""
    v = np.sort(np.asarray(values, dtype=float))
    return v, np.arange(1, len(v) + 1) / max(len(v), 1)


def histogram_cdf(pairs):
    """The CDF of a histogram given as [upper edge, count] pairs (edges ascending)."""
    if not pairs:
        return np.array([]), np.array([])
    edges = np.array([p[0] for p in pairs], dtype=float)
    counts = np.array([p[1] for p in pairs], dtype=float)
    return edges, np.cumsum(counts) / counts.sum()


def plot(report, out_path):
    """Draws the CDFs (log-scaled time, and the tail as 1 - F on a log scale) into out_path."""
    samples = report.get("samples", {})
    series = [
        ("step (vl_update, in-process)", cdf(samples.get("step_us", [])), "tab:blue"),
        ("end to end (vislamd over LCM)", cdf(samples.get("e2e_us", [])), "tab:red"),
        ("LCM overhead (end to end - vislamd's step)", cdf(samples.get("lcm_overhead_us", [])), "tab:green"),
        ("jitter floor (1 kHz probe wake-up lateness)", histogram_cdf(samples.get("jitter_hist_us", [])), "0.4"),
    ]
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.5))
    for label, (x, f), color in series:
        if len(x) == 0:
            continue
        axes[0].step(x, f, where="post", label=label, color=color)
        tail = np.clip(1.0 - f + 1.0 / len(f), 1e-6, 1.0)
        axes[1].step(x, tail, where="post", label=label, color=color)
    budget = report.get("budget_us")
    for ax in axes:
        ax.set_xscale("log")
        ax.set_xlabel("latency (us)")
        ax.grid(True, which="both", alpha=0.3)
        if budget:
            ax.axvline(budget, color="k", linestyle=":", label=f"budget {budget} us")
    axes[0].set_ylabel("fraction of samples at or below")
    axes[1].set_yscale("log")
    axes[1].set_ylabel("fraction above (tail)")
    axes[0].legend(loc="lower right", fontsize=8)
    fig.suptitle(
        f"{report.get('log', '')}: window {report.get('window')}, {report.get('steps')} steps, "
        f"rate {report.get('rate')}, CPU {report.get('cpu')}"
        f"{', SCHED_FIFO' if report.get('rt_granted') else ''}{', loaded' if report.get('load') else ''}"
        f"{', 2 threads' if report.get('threads') == 2 else ''}"
    )
    fig.tight_layout()
    fig.savefig(out_path, dpi=110)
    plt.close(fig)


def main(argv=None):
    args = sys.argv[1:] if argv is None else argv
    if len(args) != 2 or args[0] in ("-h", "--help"):
        print(__doc__.strip())
        return 0 if args and args[0] in ("-h", "--help") else 2
    with open(args[0]) as f:
        report = json.load(f)
    plot(report, args[1])
    return 0


if __name__ == "__main__":
    sys.exit(main())
