"""The study's plots (losses, prediction errors, cost) and its annotated sample frames."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
from matplotlib.figure import Figure
from matplotlib.patches import Circle, Rectangle

from mocap.tracker_trials import CATEGORIES
from simbench.studies.trackers.config import IMAGE_H, IMAGE_W, PAPER_COST, PAPER_ERRORS, PAPER_LOSSES, TABLE_TITLES
from simbench.studies.trackers.study import StudyResult
from simbench.studies.trackers.videos import Barrier


_COLOURS = ["#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f"]


def _figure(w: float, h: float):
    return Figure(figsize=(w, h), dpi=110, layout="constrained")


def plot_losses(result: StudyResult, path: Path) -> None:
    """Grouped bars: videos with a loss per category and tracker; the paper's as diamonds."""
    fig = _figure(8, 4)
    ax = fig.add_subplot()
    cats = [c for c in CATEGORIES if c in result.losses]
    names = result.trackers
    width = 0.8 / len(names)
    x = np.arange(len(cats))
    for k, n in enumerate(names):
        xs = x - 0.4 + width * (k + 0.5)
        ax.bar(xs, [result.losses[c][n] for c in cats], width, label=n, color=_COLOURS[k % len(_COLOURS)])
        paper = [PAPER_LOSSES.get(c, {}).get(n, np.nan) for c in cats]
        if np.isfinite(paper).any():
            ax.plot(xs, paper, "D", mfc="none", mec="k", ms=6, label="paper" if k == 0 else None)
    ax.set_xticks(x, cats)
    ax.set_ylabel(f"videos with a loss (of {result.config.videos_per_category})")
    ax.set_title("Table I: losses per category (bars: bench, diamonds: seed 000)")
    ax.legend(fontsize=8, ncols=2)
    fig.savefig(path)


def plot_errors(result: StudyResult, path: Path) -> None:
    """Box plots of the prediction errors per tracker, one panel per category."""
    cats = list(result.error_samples)
    if not cats:
        return
    fig = _figure(4 * len(cats), 4)
    axes = fig.subplots(1, len(cats), squeeze=False)[0]
    for ax, c in zip(axes, cats):
        names = result.trackers
        data = [result.error_samples[c][n] for n in names]
        pos = [i for i, d in enumerate(data) if len(d)]
        if pos:
            ax.violinplot([data[i] for i in pos], positions=pos, showmedians=True, showextrema=False)
        ax.plot(range(len(names)), [result.errors[c][n].interval.mean for n in names], "o", color="k", label="mean (bench)")
        paper = [PAPER_ERRORS[c].get(n, (0, np.nan, np.nan, np.nan))[2] for n in names]
        ax.plot(range(len(names)), paper, "D", mfc="none", mec="r", label="mean (seed 000)")
        ax.set_xticks(range(len(names)), names, rotation=20, fontsize=8)
        ax.set_yscale("symlog", linthresh=1.0)
        ax.set_ylim(bottom=0.0)
        ax.set_title(TABLE_TITLES[c], fontsize=9)
        ax.set_ylabel("prediction error, px")
    axes[0].legend(fontsize=7)
    fig.savefig(path)


def plot_cost(result: StudyResult, path: Path) -> None:
    """Median per-frame cost against marker count (5-95 % band); the paper's medians dashed."""
    fig = _figure(7, 4)
    ax = fig.add_subplot()
    for k, n in enumerate(result.trackers):
        rows = sorted((r for r in result.cost.rows if r.tracker == n), key=lambda r: r.n_markers)
        m = [r.n_markers for r in rows]
        col = _COLOURS[k % len(_COLOURS)]
        ax.plot(m, [r.median_ms for r in rows], "o-", color=col, label=f"{n} (bench)")
        ax.fill_between(m, [r.p5_ms for r in rows], [r.p95_ms for r in rows], color=col, alpha=0.12)
        if n in PAPER_COST:
            pm = sorted(PAPER_COST[n])
            ax.plot(pm, [PAPER_COST[n][q][1] for q in pm], "--", color=col, label=f"{n} (seed 000)")
    ax.set_yscale("log")
    ax.set_xlabel("markers")
    ax.set_ylabel("per-frame tracking cost, ms")
    ax.set_title(f"Tables V-VII: median and 5-95 % over {result.cost.n_frames} frames")
    ax.legend(fontsize=7, ncols=2)
    fig.savefig(path)


def write_sample_frames(result: StudyResult, folder: Path) -> dict[str, tuple[str, str]]:
    """Per category, the first video's sample frame raw and annotated (true path dashed,
    each tracker's estimate and search circle); returns category -> (raw, annotated) names."""
    out = {}
    for r in result.videos:
        v = r.video
        if v.sample_image is None:
            continue
        f = v.sample_frame
        raw = f"{r.category}.png"
        cv2.imwrite(str(folder / raw), cv2.cvtColor(v.sample_image, cv2.COLOR_RGB2BGR))
        fig = _figure(6.4, 4.8)
        ax = fig.add_subplot()
        ax.imshow(np.clip(v.sample_image.astype(np.float32) * 3.0, 0, 255).astype(np.uint8))
        n_lab = next(iter(r.runs.values())).tracks.predicted.shape[1] if r.runs else v.true_xy.shape[1]
        for m in range(v.true_xy.shape[1]):
            ax.plot(v.true_xy[:, m, 0], v.true_xy[:, m, 1], "--", color="w", lw=0.6, alpha=0.7)
            if m >= n_lab:  # an unlabelled marker, as seed 000's Fig. 5
                ax.annotate("NULL", v.true_xy[f, m], xytext=(6, -6), textcoords="offset points", color="y", fontsize=7)
        for k, (name, run) in enumerate(r.runs.items()):
            col = _COLOURS[k % len(_COLOURS)]
            for m in range(n_lab):
                p = run.tracks.predicted[f, m]
                e = run.tracks.estimate[f, m]
                rad = run.tracks.search_radius[f, m]
                if np.isfinite(p).all() and np.isfinite(rad):
                    ax.add_patch(_circle(p, rad, col))
                if np.isfinite(e).all():
                    ax.plot(*e, "o", color=col, ms=4, label=name if m == 0 else None)
        if r.barrier is not None:
            b = r.barrier
            ax.add_patch(_rect(b))
        ax.set_xlim(0, IMAGE_W)
        ax.set_ylim(IMAGE_H, 0)
        ax.set_title(f"{r.category} video {r.index}, frame {f} (x3 brightness)", fontsize=9)
        ax.legend(fontsize=7, loc="best")
        ax.set_axis_off()
        ann = f"{r.category}_annotated.png"
        fig.savefig(folder / ann)
        out[r.category] = (raw, ann)
    return out


def _circle(centre: np.ndarray, radius: float, colour: str):
    return Circle((float(centre[0]), float(centre[1])), float(radius), fill=False, ec=colour, lw=0.8)


def _rect(b: Barrier):
    return Rectangle((b.centre_px[0] - b.width_px / 2, b.centre_px[1] - b.height_px / 2), b.width_px, b.height_px,
                     fill=False, ec="y", lw=0.6, ls=":")
