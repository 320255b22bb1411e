"""What :func:`write_study` writes: per-video logs (JSON and arrays) from which every count can be
re-derived, ``tables.json``, ``losses.csv``, the plots, the sample frames and the report."""

from __future__ import annotations

from dataclasses import asdict
import csv
import json
import re
from pathlib import Path

import numpy as np

from eval import tracking_metrics as tm
from simbench.studies.trackers.config import ERROR_CATEGORIES, PAPER_COST, PAPER_ERRORS, PAPER_LOSSES, StudyConfig
from simbench.studies.trackers.plots import plot_cost, plot_errors, plot_losses, write_sample_frames
from simbench.studies.trackers.report import format_report
from simbench.studies.trackers.study import StudyResult
from simbench.studies.trackers.tracking import VideoResult


def _safe(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_]+", "_", name)


def video_stem(category: str, index: int) -> str:
    return f"{category}_{index:02d}"


def _json_default(o):
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def _nan_to_none(x: float) -> float | None:
    return None if not np.isfinite(x) else float(x)


def video_log(r: VideoResult, config: StudyConfig) -> dict:
    """The per-video JSON log: drawn parameters and, per tracker, each label's loss."""
    F, M = r.video.visible.shape
    n_lab = next(iter(r.runs.values())).tracks.xy.shape[1] if r.runs else M
    out = {
        "category": r.category, "index": r.index, "seed": config.seed, "render_seed": r.render_seed,
        "n_frames": F, "n_markers": M, "n_labels": n_lab, "params": r.params,
        "barrier": None if r.barrier is None else asdict(r.barrier),
        "visible_frames": r.video.visible.sum(axis=0).tolist(),
        "mean_detections_per_frame": float(np.mean([len(d) for d in r.video.detections])),
        "mean_subframes": r.video.mean_subframes, "seconds": r.seconds,
        "loss_radius_px": config.loss_radius_px, "trackers": {},
    }
    for name, run in r.runs.items():
        out["trackers"][name] = {
            "video_lost": run.lost,
            "label_lost": run.losses.lost.tolist(),
            "first_loss_frame": run.losses.first_frame.tolist(),
            "loss_reason": run.losses.reason_names(),
            "loss_frames": run.losses.bad_frames.tolist(),
            "lost_at_end": run.losses.at_end.tolist(),
            "video_lost_strict": tm.video_lost(run.losses_strict),
            "label_lost_strict": run.losses_strict.lost.tolist(),
            "n_prediction_errors": int(len(run.errors)),
            "mean_prediction_error_px": _nan_to_none(float(np.mean(run.errors))) if len(run.errors) else None,
            "in_error_table": (r.category in ERROR_CATEGORIES) and not run.lost,
        }
    return out


def save_video_arrays(r: VideoResult, path: Path) -> None:
    """Per-video arrays (``.npz``) from which the losses and errors can be recomputed."""
    dets = r.video.detections
    n = max((len(d) for d in dets), default=0)
    padded = np.full((len(dets), n, 2), np.nan)
    for f, d in enumerate(dets):
        padded[f, :len(d)] = d
    arrays = {"true_xy": r.video.true_xy, "visible": r.video.visible, "visible_area": r.video.visible_area,
              "visible_fraction": r.video.visible_fraction,
              "detections": padded, "trackers": np.array(list(r.runs))}
    for name, run in r.runs.items():
        k = _safe(name)
        t = run.tracks
        arrays.update({f"{k}__predicted": t.predicted, f"{k}__measured": t.xy, f"{k}__estimate": t.estimate,
                       f"{k}__status": t.status, f"{k}__search_radius": t.search_radius,
                       f"{k}__loss_flags": run.losses.flags, f"{k}__loss_flags_strict": run.losses_strict.flags})
    np.savez_compressed(path, **arrays)


def load_video_arrays(path: Path) -> dict[str, np.ndarray]:
    """Read a per-video ``.npz`` back (keys as written by :func:`save_video_arrays`)."""
    with np.load(path) as z:
        return {k: z[k] for k in z.files}


def tracker_key(name: str) -> str:
    """Prefix of a tracker's arrays in the per-video ``.npz``."""
    return _safe(name)


def tables_dict(result: StudyResult) -> dict:
    """All seven tables (ours and the paper's) as plain data (``tables.json``)."""
    cfg = result.config
    errs = {}
    for c, row in result.errors.items():
        errs[c] = {}
        for n, s in row.items():
            errs[c][n] = {"samples": s.n, "lower": _nan_to_none(s.interval.lower), "mean": _nan_to_none(s.interval.mean),
                          "upper": _nan_to_none(s.interval.upper),
                          "shapiro_w": _nan_to_none(s.normality.statistic), "shapiro_p": _nan_to_none(s.normality.p_value),
                          "normal": s.normality.normal}
            v = result.errors_across_videos.get(c, {}).get(n)
            if v is not None:  # the videos as replicates: mean of per-video means, bootstrap CI across videos
                errs[c][n]["across_videos"] = {"videos": v.n_finite, "mean": _nan_to_none(v.mean),
                                               "ci95": [_nan_to_none(v.ci_low), _nan_to_none(v.ci_high)],
                                               "video_means": [_nan_to_none(x) for x in v.values]}
    cost = {n: {str(r.n_markers): {"p5_ms": r.p5_ms, "median_ms": r.median_ms, "p95_ms": r.p95_ms, "max_ms": r.max_ms}
                for r in result.cost.rows if r.tracker == n} for n in result.trackers}
    return {
        "config": {k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(cfg).items()},
        "trackers": result.trackers,
        "table_I_losses": result.losses,
        "table_I_losses_strict": result.losses_strict,
        "table_I_losses_unrecovered": result.losses_unrecovered,
        "total_losses": result.total_losses(),
        "tables_II_IV_prediction_error_px": errs,
        "tables_V_VII_cost_ms": cost,
        "paper": {"table_I_losses": PAPER_LOSSES, "tables_II_IV": PAPER_ERRORS,
                  "tables_V_VII": {n: {str(m): v for m, v in d.items()} for n, d in PAPER_COST.items()}},
        "seconds": result.seconds,
    }


def write_study(result: StudyResult, out_dir: str | Path) -> Path:
    """Write logs, tables, plots, sample frames and ``report.md`` into ``out_dir``; return the report path."""
    out = Path(out_dir)
    (out / "videos").mkdir(parents=True, exist_ok=True)
    (out / "plots").mkdir(exist_ok=True)
    (out / "frames").mkdir(exist_ok=True)
    cfg = result.config
    rows = []
    for r in result.videos:
        stem = video_stem(r.category, r.index)
        (out / "videos" / f"{stem}.json").write_text(json.dumps(video_log(r, cfg), indent=1, default=_json_default))
        save_video_arrays(r, out / "videos" / f"{stem}.npz")
        for name, run in r.runs.items():
            for m in range(len(run.losses.lost)):
                rows.append([r.category, r.index, name, m, int(run.losses.lost[m]), int(run.losses.first_frame[m]),
                             run.losses.reason_names()[m], int(run.losses.bad_frames[m]), int(run.losses.at_end[m]),
                             int(run.losses_strict.lost[m])])
    with open(out / "losses.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["category", "video", "tracker", "label", "lost", "first_loss_frame", "reason", "loss_frames",
                    "lost_at_end", "lost_strict"])
        w.writerows(rows)
    (out / "tables.json").write_text(json.dumps(tables_dict(result), indent=1, default=_json_default))
    plot_losses(result, out / "plots" / "losses.png")
    plot_errors(result, out / "plots" / "prediction_errors.png")
    plot_cost(result, out / "plots" / "cost.png")
    frames = write_sample_frames(result, out / "frames")
    report = out / "report.md"
    report.write_text(format_report(result, frames))
    return report
