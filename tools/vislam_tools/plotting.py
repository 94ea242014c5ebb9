"""Top-down (world x-y) figures and animations of a run. Headless: matplotlib's Agg backend."""

from dataclasses import dataclass
from typing import Optional

import numpy as np
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402  (backend must be chosen first)

from . import ToolError  # noqa: E402

# PLY vertex properties that may carry the time a landmark was first seen (for animations).
LANDMARK_TIME_PROPERTIES = ("first_utime", "utime", "first_time", "time", "first_seen", "t")

COLORS = {"slam": "tab:red", "dr": "tab:blue", "gt": "tab:green", "map": "0.35"}


@dataclass
class Scene:
    """Everything drawn, already in the estimate's world frame. Paths are (N, 3) positions."""
    slam_times: np.ndarray
    slam_xyz: np.ndarray
    dr_times: Optional[np.ndarray] = None
    dr_xyz: Optional[np.ndarray] = None
    gt_times: Optional[np.ndarray] = None
    gt_xyz: Optional[np.ndarray] = None
    landmarks: Optional[np.ndarray] = None        # (L, 3)
    landmark_times: Optional[np.ndarray] = None   # (L,) s, same clock as the paths, or None
    title: str = ""


def landmark_times_from_ply(props):
    """First-seen time (s) per vertex if the PLY declares one, else None."""
    for name in LANDMARK_TIME_PROPERTIES:
        if name in props:
            values = np.asarray(props[name], dtype=float)
            return values * 1e-6 if "utime" in name else values
    return None


def _view_limits(scene, margin_frac=0.08):
    """Axis box around the paths; landmarks widen it only moderately so outliers do not shrink the paths."""
    paths = [p[:, :2] for p in (scene.slam_xyz, scene.dr_xyz, scene.gt_xyz) if p is not None and len(p)]
    pts = np.vstack(paths)
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    extent = max(float(np.max(hi - lo)), 1.0)
    if scene.landmarks is not None and len(scene.landmarks):
        grow = max(0.25 * extent, 20.0)
        lm = scene.landmarks[:, :2]
        inside = np.all((lm >= lo - grow) & (lm <= hi + grow), axis=1)
        if inside.any():
            lo = np.minimum(lo, lm[inside].min(axis=0))
            hi = np.maximum(hi, lm[inside].max(axis=0))
    pad = margin_frac * max(float(np.max(hi - lo)), 1.0)
    return lo - pad, hi + pad


def _save(fig, out_path, dpi):
    """Lay out, write and close a figure; a write failure is a ToolError."""
    fig.tight_layout()
    try:
        fig.savefig(out_path, dpi=dpi)
    except OSError as exc:
        raise ToolError(f"cannot write {out_path}: {exc}") from exc
    finally:
        plt.close(fig)


def _setup_axes(ax, scene, lo, hi):
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_aspect("equal", adjustable="box")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.grid(True, linewidth=0.3, alpha=0.5)
    if scene.title:
        ax.set_title(scene.title, fontsize=10)


def plot_topdown(scene, out_path, dpi=120):
    """Write a PNG (or any matplotlib format, by extension) of the whole run."""
    fig, ax = plt.subplots(figsize=(8, 7))
    lo, hi = _view_limits(scene)
    if scene.landmarks is not None and len(scene.landmarks):
        ax.scatter(scene.landmarks[:, 0], scene.landmarks[:, 1], s=1.5, c=COLORS["map"], marker=".",
                   linewidths=0, label=f"landmarks ({len(scene.landmarks)})", zorder=1)
    if scene.gt_xyz is not None:
        ax.plot(scene.gt_xyz[:, 0], scene.gt_xyz[:, 1], "-", color=COLORS["gt"], lw=1.6,
                label="ground truth (aligned)", zorder=2)
    if scene.dr_xyz is not None:
        ax.plot(scene.dr_xyz[:, 0], scene.dr_xyz[:, 1], "-", color=COLORS["dr"], lw=1.2,
                label="dead reckoning", zorder=3)
    ax.plot(scene.slam_xyz[:, 0], scene.slam_xyz[:, 1], "-", color=COLORS["slam"], lw=1.6,
            label="VI-SLAM", zorder=4)
    ax.scatter(scene.slam_xyz[0, 0], scene.slam_xyz[0, 1], marker="s", s=60, c="k", label="start", zorder=5)
    ax.scatter(scene.slam_xyz[-1, 0], scene.slam_xyz[-1, 1], marker="o", s=60, c="k", label="end", zorder=5)
    _setup_axes(ax, scene, lo, hi)
    ax.legend(loc="best", fontsize=8, markerscale=1.0)
    _save(fig, out_path, dpi)


def animate_topdown(scene, out_path, max_frames=100, fps=10, dpi=90, hold_frames=None):
    """Write an animated GIF of the paths growing over time (landmarks appear when first seen if known).

    Frames are rendered by blitting only the moving artists over a once-drawn background and are
    assembled with Pillow on one shared palette: a full matplotlib redraw per frame (what
    FuncAnimation + PillowWriter does) costs ~10x more and would take most of a minute.
    """
    from PIL import Image

    t_all = scene.slam_times
    if len(t_all) < 2:
        raise ToolError("animation needs at least two estimate poses")
    n_frames = int(max(2, min(max_frames, len(t_all))))
    frame_times = np.linspace(t_all[0], t_all[-1], n_frames)
    if hold_frames is None:
        hold_frames = max(1, fps)  # about a second on the final picture
    fig, ax = plt.subplots(figsize=(6, 5), dpi=dpi)
    lo, hi = _view_limits(scene)
    _setup_axes(ax, scene, lo, hi)

    lm_scatter = None
    if scene.landmarks is not None and len(scene.landmarks):
        lm_scatter = ax.scatter(np.empty(0), np.empty(0), s=1.5, c=COLORS["map"], marker=".",
                                linewidths=0, label="landmarks", animated=True)
    lines = []
    for times, xyz, key, label in ((scene.gt_times, scene.gt_xyz, "gt", "ground truth (aligned)"),
                                   (scene.dr_times, scene.dr_xyz, "dr", "dead reckoning"),
                                   (scene.slam_times, scene.slam_xyz, "slam", "VI-SLAM")):
        if xyz is None:
            continue
        (line,) = ax.plot([], [], "-", color=COLORS[key], lw=1.4, label=label, animated=True)
        lines.append((times, xyz, line))
    (head,) = ax.plot([], [], "o", color="k", ms=5, label="current", animated=True)
    ax.scatter(scene.slam_xyz[0, 0], scene.slam_xyz[0, 1], marker="s", s=40, c="k", label="start")
    clock = ax.text(0.02, 0.02, "", transform=ax.transAxes, fontsize=9, animated=True,
                    bbox={"facecolor": "white", "alpha": 0.7, "edgecolor": "none"})
    ax.legend(loc="upper right", fontsize=7)
    fig.tight_layout()
    canvas = fig.canvas
    canvas.draw()
    background = canvas.copy_from_bbox(fig.bbox)

    def render(t):
        canvas.restore_region(background)
        if lm_scatter is not None:
            if scene.landmark_times is not None:
                visible = scene.landmarks[scene.landmark_times <= t]
            else:
                visible = scene.landmarks
            lm_scatter.set_offsets(visible[:, :2] if len(visible) else np.empty((0, 2)))
            ax.draw_artist(lm_scatter)
        for times, xyz, line in lines:
            n = int(np.searchsorted(times, t, side="right"))
            line.set_data(xyz[:n, 0], xyz[:n, 1])
            ax.draw_artist(line)
        n = max(int(np.searchsorted(scene.slam_times, t, side="right")), 1)
        head.set_data(scene.slam_xyz[n - 1:n, 0], scene.slam_xyz[n - 1:n, 1])
        ax.draw_artist(head)
        clock.set_text(f"t = {t - t_all[0]:6.1f} s")
        ax.draw_artist(clock)
        rgba = np.asarray(canvas.buffer_rgba())
        return Image.fromarray(rgba[:, :, :3].copy())

    try:
        frames = [render(t) for t in frame_times]
    finally:
        plt.close(fig)
    # One palette from the last (fullest) frame keeps colours steady and the file small.
    palette = frames[-1].quantize(colors=128, method=Image.Quantize.MEDIANCUT)
    frames = [f.quantize(palette=palette, dither=Image.Dither.NONE) for f in frames]
    durations = [int(round(1000 / fps))] * (len(frames) - 1) + [int(round(1000 / fps)) * (1 + hold_frames)]
    try:
        frames[0].save(out_path, format="GIF", save_all=True, append_images=frames[1:],
                       duration=durations, loop=0, optimize=False)
    except (OSError, ValueError) as exc:
        raise ToolError(f"cannot write {out_path}: {exc}") from exc


def plot_consistency(times, e_body, sigma, nees, out_path, title="", chi2_95=None, dpi=120):
    """Per-axis body-frame position error against +-3 sigma over time, and the position NEES."""
    t = np.asarray(times, dtype=float) - float(times[0])
    fig, axes = plt.subplots(4, 1, figsize=(9, 9), sharex=True)
    for i, (ax, name) in enumerate(zip(axes[:3], ("x (forward)", "y (left)", "z (up)"))):
        band = 3.0 * sigma[:, i]
        ax.fill_between(t, -band, band, color="tab:blue", alpha=0.2, linewidth=0, label="±3σ (filter)")
        ax.plot(t, band, "-", color="tab:blue", lw=0.6)
        ax.plot(t, -band, "-", color="tab:blue", lw=0.6)
        ax.plot(t, e_body[:, i], "-", color="tab:red", lw=0.9, label="error")
        ax.set_ylabel(f"{name} (m)")
        ax.grid(True, linewidth=0.3, alpha=0.5)
    axes[0].legend(loc="upper left", fontsize=8)
    ax = axes[3]
    ax.semilogy(t, nees, "-", color="k", lw=0.8, label="position NEES (diagonal)")
    ax.axhline(3.0, color="tab:green", lw=1.0, label="expected 3")
    if chi2_95 is not None:
        ax.axhline(chi2_95, color="tab:orange", lw=1.0, ls="--", label="χ²(3) 95 %")
    ax.set_ylabel("NEES")
    ax.set_xlabel("time (s)")
    ax.grid(True, linewidth=0.3, alpha=0.5)
    ax.legend(loc="upper left", fontsize=8)
    if title:
        axes[0].set_title(title, fontsize=10)
    _save(fig, out_path, dpi)


# Dead reckoning closer than this to the truth (clean velocities) makes the ratio meaningless.
RATIO_DR_EXACT = 1e-3  # m
RATIO_RANGE = (0.02, 50.0)  # drawn range of the ratio; bars beyond it are clipped and labelled


def plot_conditions(cells, out_path, dpi=120):
    """Test-bed cells: vislam ATE / dead-reckoning ATE as grouped bars (one group per drive and
    velocity condition, one bar per feature density), log scale, with the ratio-1 line; and the
    absolute vislam ATE as a heat map. cells: dicts with drive, velocities, keep_every, dr_ate,
    vislam_ate, truth."""
    groups = []
    for c in cells:
        key = (c["drive"], c["velocities"])
        if key not in groups:
            groups.append(key)
    ks = sorted({c["keep_every"] for c in cells})
    by = {(c["drive"], c["velocities"], c["keep_every"]): c for c in cells}

    def value(c, what):
        if c is None or c.get("vislam_ate") is None or c.get("dr_ate") is None:
            return np.nan
        if what == "ratio":
            return c["vislam_ate"] / c["dr_ate"] if c["dr_ate"] > 0 else np.inf
        return c["vislam_ate"]

    def note(c):
        # cells whose ratio says nothing: the pseudo-truth's own run, and exact dead reckoning
        if c is None or c.get("vislam_ate") is None or c.get("dr_ate") is None:
            return "n/a"
        if c["truth"] != "ground truth" and c["vislam_ate"] < 1e-6:
            return "ref."
        if c["dr_ate"] < RATIO_DR_EXACT:
            return "DR≈0"
        return ""

    ratio = np.array([[value(by.get(g + (k,)), "ratio") for k in ks] for g in groups])
    notes = [[note(by.get(g + (k,))) for k in ks] for g in groups]
    ate = np.array([[value(by.get(g + (k,)), "ate") for k in ks] for g in groups])
    labels = []
    for drive, vel in groups:
        pseudo = any(c["truth"] != "ground truth" for c in cells if (c["drive"], c["velocities"]) == (drive, vel))
        labels.append(f"{drive}\n{vel}" + ("\n(pseudo-truth)" if pseudo else ""))
    fig, (ax, hm) = plt.subplots(2, 1, figsize=(max(8.0, 1.1 * len(groups) + 2), 9),
                                 gridspec_kw={"height_ratios": [3, 2]})
    width = 0.8 / max(len(ks), 1)
    x = np.arange(len(groups))
    cmap = plt.get_cmap("viridis")
    lo, hi = RATIO_RANGE
    for j, k in enumerate(ks):
        xs = x + (j - (len(ks) - 1) / 2) * width
        shown = np.array([np.nan if notes[i][j] else ratio[i, j] for i in range(len(groups))])
        ax.bar(xs, np.clip(shown, lo, hi), width, color=cmap(j / max(len(ks) - 1, 1)),
               label="all tracks" if k == 1 else f"1 track in {k}")
        for i in range(len(groups)):
            text = notes[i][j] or (f"{ratio[i, j]:.3g}" if not lo <= ratio[i, j] <= hi else "")
            if text:
                ax.text(xs[i], lo * 1.15, text, rotation=90, ha="center", va="bottom", fontsize=6)
    ax.axhline(1.0, color="k", lw=1.0, ls="--", label="= dead reckoning")
    ax.set_yscale("log")
    ax.set_ylim(lo, hi)
    ax.set_xticks(x)
    ax.set_xticklabels(labels, fontsize=7)
    ax.set_ylabel("ATE vislam / ATE dead reckoning")
    ax.set_title("vislam default against dead reckoning per cell (below 1: vislam is better)", fontsize=10)
    ax.grid(True, axis="y", which="both", linewidth=0.3, alpha=0.5)
    ax.legend(fontsize=8, ncol=len(ks) + 1, loc="upper left")
    finite = ate[np.isfinite(ate)]
    im = hm.imshow(ate.T, aspect="auto", cmap="magma_r",
                   norm=matplotlib.colors.LogNorm(vmin=max(finite.min(), 1e-2), vmax=max(finite.max(), 1e-1))
                   if finite.size and finite.max() > 0 else None)
    for i in range(len(groups)):
        for j in range(len(ks)):
            if np.isfinite(ate[i, j]):
                hm.text(i, j, "ref." if notes[i][j] == "ref." else f"{ate[i, j]:.1f}", ha="center", va="center", fontsize=7,
                        color="w" if finite.size and ate[i, j] > np.sqrt(finite.min() * finite.max()) else "k")
    hm.set_xticks(x)
    hm.set_xticklabels(labels, fontsize=7)
    hm.set_yticks(np.arange(len(ks)))
    hm.set_yticklabels(["all" if k == 1 else f"1 in {k}" for k in ks], fontsize=8)
    hm.set_ylabel("tracks kept")
    hm.set_title("ATE of the vislam default (m)", fontsize=10)
    fig.colorbar(im, ax=hm, label="m")
    _save(fig, out_path, dpi)
