"""The Markdown report of one run (``report.md`` with its plots)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from eval import marker_metrics


def reprojection_residuals_by_camera(capture, calibration) -> dict[str, np.ndarray]:
    """Residual (px) between each tracked detection and the reprojection of its 3D estimate."""
    xyz = capture.trajectories.xyz
    F, M, _ = xyz.shape
    out = {}
    for ci, cam in enumerate(calibration):
        proj = cam.project(xyz.reshape(-1, 3)).reshape(F, M, 2)
        d = np.linalg.norm(proj - capture.tracks.xy[:, ci], axis=-1)
        out[cam.name] = d[np.isfinite(d)]
    return out


def _table(metrics: dict[str, float]) -> str:
    lines = ["| metric | value |", "|---|---|"]
    for k in sorted(metrics):
        v = metrics[k]
        s = f"{v:.4g}" if isinstance(v, float) else str(v)
        lines.append(f"| `{k}` | {s} |")
    return "\n".join(lines)


def write_run_report(out: Path, scenario, gt, capture, metrics: dict[str, float], timings: dict[str, float],
                     extra_sections: list[str] | None = None, calibration=None) -> Path:
    """Write ``report.md`` and its PNG plots into ``out``.

    ``calibration`` is the one the pipeline used (default: the exact one): reprojection
    residuals are what the pipeline itself would see, so they use its calibration.
    """
    from eval import plots  # matplotlib: here, not at the top (see simbench/pipelines/calibration.py)

    figs = out / "plots"
    figs.mkdir(exist_ok=True)
    parts = [f"# simbench run: {scenario.name}", "", scenario.description or "", "",
             f"{gt.n_frames} frames at {gt.fps:g} Hz, {len(gt.camera_names)} cameras, "
             f"{len(gt.marker_names)} markers, sensor mode `{scenario.sensor.mode}`, "
             f"exposure {scenario.sensor.exposure_ms} ms (blur {'on' if scenario.sensor.motion_blur else 'off'}), "
             f"tracker `{scenario.markers_pipeline.tracker}`, calibration `{scenario.markers_pipeline.calibration}`.",
             "", "![contact sheet](contact_sheet.png)", "", "## Metrics", "", _table(metrics), ""]
    if capture is not None:
        traj = capture.trajectories
        idx = [traj.labels.index(n) for n in gt.marker_names]
        err = marker_metrics.per_marker_error_mm(traj.xyz[:, idx], gt.markers_3d)
        plots.marker_error_over_time(gt.times, err, gt.marker_names, figs / "marker_error.png")
        parts += ["## 3D marker error over time", "", "![marker error](plots/marker_error.png)", ""]
        worst = np.nanmax(np.where(np.isfinite(err), err, -1), axis=0)
        order = np.argsort(-worst)[:5]
        parts += ["Worst markers (max error, mm): " + ", ".join(f"{gt.marker_names[i]} {worst[i]:.2f}" for i in order), ""]
        res = reprojection_residuals_by_camera(capture, calibration if calibration is not None else gt.calibration())
        plots.reprojection_residuals(res, figs / "reprojection.png")
        parts += ["## Reprojection residuals per camera", "", "![reprojection](plots/reprojection.png)", ""]
        fit = capture.skeleton
        if fit is not None:
            hinge_idx = [fit.hinge_names.index(h) for h in gt.hinge_names]
            plots.angle_traces(gt.times, fit.joint_angles_rad[:, hinge_idx], gt.qpos[:, 7:], gt.hinge_names,
                               figs / "joint_angles.png")
            parts += ["## Joint angles against ground truth", "",
                      "The 12 joints that move most. `skeleton.joint_angle_rmse_deg` scores the joints the marker set "
                      "determines (predicted error under 1 deg for 1 mm marker noise); "
                      "`skeleton.joint_angle_rmse_all_deg` scores all 33.", "",
                      "![joint angles](plots/joint_angles.png)", ""]
        parts += ["## Pipeline timings", "", "| stage | ms |", "|---|---|"]
        parts += [f"| {k} | {v:.1f} |" for k, v in capture.timings_ms.items()]
        parts += [""]
    parts += list(extra_sections or [])
    parts += ["## Wall time", "", "| phase | s |", "|---|---|"] + [f"| {k} | {v:.2f} |" for k, v in timings.items()] + [""]
    parts += ["## Files", "", "- `videos/*.mp4`: what each camera saw", "- `ground_truth/`: exact truth (format in `simbench/stage/ground_truth.py`)",
              "- `exports/`: `markers.c3d`, `markers.trc`, `markers.csv`, `skeleton.bvh`, `calibration.yml`, `label_template.csv`",
              "- `metrics.json`", ""]
    path = out / "report.md"
    path.write_text("\n".join(parts))
    return path
