"""Plots of estimates against truth (matplotlib, Agg backend, arrays in, PNG out)."""

from __future__ import annotations

import warnings
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402


def marker_error_over_time(times: np.ndarray, err_mm: np.ndarray, labels: list[str], path: str | Path,
                           title: str = "3D marker error") -> None:
    """Heatmap of the error of every marker over time, plus the median and worst marker."""
    fig, (ax0, ax1) = plt.subplots(2, 1, figsize=(10, 8), height_ratios=[3, 1], sharex=True)
    e = np.where(np.isfinite(err_mm), err_mm, np.nan)
    vmax = max(float(np.nanpercentile(e, 99)) if np.isfinite(e).any() else 1.0, 0.5)
    im = ax0.imshow(e.T, aspect="auto", origin="lower", cmap="magma", vmin=0, vmax=vmax,
                    extent=(times[0], times[-1], -0.5, len(labels) - 0.5), interpolation="nearest")
    ax0.set_yticks(range(len(labels)))
    ax0.set_yticklabels(labels, fontsize=6)
    ax0.set_title(f"{title} (grey = missing)")
    ax0.set_facecolor("0.6")
    fig.colorbar(im, ax=ax0, label="error (mm)", pad=0.01)
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # frames with no marker: a gap in the line
        ax1.plot(times, np.nanmedian(e, axis=1), label="median over markers")
        ax1.plot(times, np.nanmax(e, axis=1), label="worst marker", alpha=0.7)
    ax1.set_xlabel("time (s)")
    ax1.set_ylabel("mm")
    ax1.legend(fontsize=8)
    ax1.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def reprojection_residuals(residuals_px: dict[str, np.ndarray], path: str | Path) -> None:
    """Distribution of 2D residuals (px) per camera: detections vs reprojected 3D estimates."""
    names = list(residuals_px)
    fig, ax = plt.subplots(figsize=(7, 4))
    data = [np.asarray(residuals_px[n])[np.isfinite(residuals_px[n])] for n in names]
    ax.boxplot([d if d.size else [np.nan] for d in data], showfliers=True, flierprops={"markersize": 2})
    ax.set_xticks(range(1, len(names) + 1))
    ax.set_xticklabels(names)
    for i, d in enumerate(data, 1):
        if d.size:  # above the plot area, clear of whiskers and outliers
            ax.text(i, 1.01, f"rms {np.sqrt(np.mean(d**2)):.3f} px", ha="center", va="bottom", fontsize=8,
                    transform=ax.get_xaxis_transform())
    ax.set_ylabel("reprojection residual (px)")
    ax.set_title("Per-camera reprojection residuals", pad=18)
    ax.grid(alpha=0.3, axis="y")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def angle_traces(times: np.ndarray, est_rad: np.ndarray, true_rad: np.ndarray, names: list[str], path: str | Path,
                 max_joints: int = 12, extra: dict[str, np.ndarray] | None = None, title: str = "Joint angles") -> None:
    """Estimated (and optional extra, e.g. a baseline) against true angles for the joints that move most."""
    rng_ = np.nanmax(true_rad, axis=0) - np.nanmin(true_rad, axis=0)
    order = np.argsort(-np.nan_to_num(rng_))[:max_joints]
    n = len(order)
    cols = 3
    rows = int(np.ceil(n / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(12, 2.4 * rows), squeeze=False, sharex=True)
    for ax, j in zip(axes.ravel(), order):
        ax.plot(times, np.degrees(true_rad[:, j]), "k-", lw=2, label="ground truth")
        ax.plot(times, np.degrees(est_rad[:, j]), "C1-", lw=1, label="estimate")
        for k, (label, arr) in enumerate((extra or {}).items()):
            ax.plot(times, np.degrees(arr[:, j]), f"C{k + 2}-", lw=1, alpha=0.8, label=label)
        ax.set_title(names[j], fontsize=9)
        ax.grid(alpha=0.3)
    for ax in axes.ravel()[n:]:
        ax.axis("off")
    axes[0, 0].legend(fontsize=7)
    for ax in axes[-1]:
        ax.set_xlabel("time (s)")
    fig.suptitle(f"{title} (deg)")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def seed_spread(values: dict[str, np.ndarray], path: str | Path, ci: dict[str, tuple[float, float]] | None = None,
                title: str = "Spread across seeds", cols: int = 4) -> None:
    """One panel per metric: a box of its per-seed values (shape (n_seeds,), NaN = none), every
    seed as a dot (jittered sideways), and the mean with its confidence interval ``ci[metric]``."""
    names = list(values)
    rows = max(1, int(np.ceil(len(names) / cols)))
    fig, axes = plt.subplots(rows, cols, figsize=(3.0 * cols, 2.6 * rows), squeeze=False)
    jitter = np.random.default_rng(0)  # display only: fixed, so the same values give the same picture
    for ax, name in zip(axes.ravel(), names):
        v = np.asarray(values[name], float)
        fin = v[np.isfinite(v)]
        if fin.size:
            ax.boxplot([fin], widths=0.5, showfliers=False, medianprops={"color": "C1"})
            ax.plot(1 + jitter.uniform(-0.12, 0.12, fin.size), fin, "o", color="C0", ms=3.5, alpha=0.7)
            lo, hi = (ci or {}).get(name, (np.nan, np.nan))
            if np.isfinite(lo) and np.isfinite(hi):
                m = fin.mean()  # a BCa interval of a skewed sample may sit beside its mean: clip the bars at it
                ax.errorbar([1.38], [m], yerr=[[max(0.0, m - lo)], [max(0.0, hi - m)]], fmt="D", color="C3", ms=4, capsize=3)
        n_nan = int(v.size - fin.size)
        ax.set_title(name + (f" ({n_nan} NaN)" if n_nan else ""), fontsize=8)
        ax.set_xticks([1, 1.38])
        ax.set_xticklabels([f"{fin.size} seeds", "mean, CI"], fontsize=7)
        ax.set_xlim(0.5, 1.6)
        ax.tick_params(axis="y", labelsize=7)
        ax.grid(alpha=0.3, axis="y")
    for ax in axes.ravel()[len(names):]:
        ax.axis("off")
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
