"""``simbench run``: render a scenario, run the real pipeline on the frames, score it.

This is the only place that holds both the ground truth and the pipeline's output.
The pipeline gets what a user's session would have: the frames, a calibration (the
exact one, or one estimated by ``mocap calibrate`` on rendered calibration views), a
T-pose label template and the subject model; never the ground truth.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import mujoco
import numpy as np

from eval import marker_metrics, skeleton_metrics
from mocap.labelling import LabelTemplate, save_template
from mocap.marker_pipeline import DetectionStream, MarkerCapture, MarkerPipelineParams, capture_from_detections, export_capture
from mocap.detection import DetectionParams
from mocap.reconstruction import ReconstructionParams
from mocap.subject import SubjectModel
from simbench.bench import Bench
from simbench.rendering import AtomicOutputDir, RenderedSequence, render_frames, save_scenario_copy, write_render_outputs
from simbench.scenario import Scenario
from simbench.scenes.humanoid import humanoid_mjcf, tpose_qpos


@dataclass
class RunResult:
    metrics: dict[str, float]
    out_dir: Path | None
    sequence: RenderedSequence
    capture: MarkerCapture | None = None
    timings_s: dict[str, float] = field(default_factory=dict)


def label_template(bench: Bench) -> LabelTemplate:
    """The subject's markers in its T-pose, subject-local frame (what a user's template holds);
    for a real capture (no humanoid), its markers in the capture's reference frame."""
    reference = bench.capture_reference()
    if reference is not None:
        return reference.label_template()
    xml = humanoid_mjcf(bench.params, marker_set=bench.scenario.subject.markers)
    m = mujoco.MjModel.from_xml_string(xml)
    d = mujoco.MjData(m)
    d.qpos[:] = tpose_qpos(bench.params)
    d.qpos[0:2] = 0.0
    mujoco.mj_kinematics(m, d)
    pos = np.array([d.site_xpos[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, n)] for n in bench.marker_names])
    return LabelTemplate(tuple(bench.marker_names), pos)


def subject_model(bench: Bench) -> SubjectModel | None:
    """The humanoid's subject model; None for a real capture (no body: markers only)."""
    if bench.capture_reference() is not None:
        return None
    return SubjectModel.from_mjcf_text(humanoid_mjcf(bench.params, marker_set=bench.scenario.subject.markers),
                                       name=bench.scenario.name)


def pipeline_params(sc: Scenario) -> MarkerPipelineParams:
    cfg = sc.markers_pipeline
    return MarkerPipelineParams(
        detection=DetectionParams(mode=sc.sensor.mode),
        labelling=cfg.labelling,
        tracker=cfg.tracker,
        reconstruction=ReconstructionParams(smoothing=cfg.smoothing, max_gap_frames=cfg.max_gap_frames),
        solve_skeleton=cfg.solve_skeleton,
    )


def score_markers(gt, capture: MarkerCapture) -> dict[str, float]:
    traj = capture.trajectories
    idx = [traj.labels.index(n) for n in gt.marker_names]
    est = traj.xyz[:, idx]
    tracked = capture.tracks.predicted_xy[:, :, idx]
    metrics = marker_metrics.summarize_markers(est, gt.markers_3d, gt.marker_visible, tracked_xy=tracked,
                                               true_xy=gt.markers_2d, filled=traj.filled[:, idx])
    fit = capture.skeleton
    if fit is not None:
        mask = fit.well_constrained() if hasattr(fit, "well_constrained") else None
        hinge_idx = [fit.hinge_names.index(h) for h in gt.hinge_names]
        est_ang = fit.joint_angles_rad[:, hinge_idx]
        true_ang = gt.qpos[:, 7:]
        m = None if mask is None else np.asarray(mask)[..., hinge_idx]
        metrics["skeleton.joint_angle_rmse_deg"] = skeleton_metrics.joint_angle_rmse_deg(est_ang, true_ang, m)
        metrics["skeleton.joint_angle_rmse_all_deg"] = skeleton_metrics.joint_angle_rmse_deg(est_ang, true_ang)
        body_idx = [fit.body_names.index(b) for b in gt.joint_names]
        metrics["skeleton.joint_position_rmse_mm"] = skeleton_metrics.joint_position_rmse_mm(
            fit.joint_centres_m[:, body_idx], gt.joint_centres)
    return metrics


def run_scenario(scenario: Scenario, out: str | Path | None = None, progress=None, write_outputs: bool = True) -> RunResult:
    """Render, capture and score one scenario; write metrics.json, report and exports to ``out``."""
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    bench = Bench.from_scenario(scenario)
    C = len(bench.cameras)
    has_markers = len(bench.marker_names) > 0
    stream = DetectionStream(C, DetectionParams(mode=scenario.sensor.mode)) if has_markers else None
    keep = {0, scenario.n_frames // 2, scenario.n_frames - 1}
    kept_frames: dict[int, np.ndarray] = {}

    ctx = AtomicOutputDir(out) if (out is not None and write_outputs) else None
    tmp = ctx.__enter__() if ctx else None
    try:
        writer = write_render_outputs(bench, tmp, png=False) if tmp is not None else None

        def on_frame(fo):
            if writer is not None:
                writer[0](fo)
            if stream is not None:
                stream.add(list(fo.images))
            if fo.index in keep:
                kept_frames[fo.index] = fo.images.copy()

        shirt = scenario.subject.shirt
        try:
            seq = render_frames(bench, on_frame=on_frame, keep_frames=shirt, keep_ids=shirt, progress=progress)
        finally:
            if writer is not None:
                writer[1]()
        timings["render_s"] = time.perf_counter() - t0
        gt = seq.ground_truth
        metrics: dict[str, float] = {}
        capture = None
        calibration = gt.calibration()
        calib_report: list[str] = []
        if scenario.calibration_scene is not None:
            # Calibration session (simbench/calibration_run.py): render the board and wand
            # pictures, run the calibration tool, score it. Its estimate is in the true
            # world frame without alignment when the scene has a floor view (the floor
            # board defines the world), else rigidly aligned to the true camera centres.
            from simbench.calibration_run import run_calibration

            t1 = time.perf_counter()
            calib_metrics, calib_report, estimated = run_calibration(bench, tmp)
            timings["calibration_s"] = time.perf_counter() - t1
            metrics.update(calib_metrics)
            if scenario.markers_pipeline.calibration == "estimated":
                calibration = estimated
        if has_markers:
            t1 = time.perf_counter()
            template = label_template(bench)
            subject = subject_model(bench)
            reference = bench.capture_reference()  # a real capture: rigid clusters instead of a skeleton
            marker_model = reference.marker_model() if reference is not None else None
            rng = np.random.default_rng(np.random.SeedSequence([scenario.seed, 0x7AC]))
            capture = capture_from_detections(stream.detections, calibration, template, gt.times,
                                              pipeline_params(scenario), rng, subject, stream.ms, marker_model=marker_model)
            timings["pipeline_s"] = time.perf_counter() - t1
            metrics.update(score_markers(gt, capture))
        shirt_report: list[str] = []
        if shirt:
            # The colour-shirt pipeline of seed 001 (simbench/shirt_run.py).
            from simbench.shirt_run import run_shirt_capture

            t1 = time.perf_counter()
            shirt_metrics, shirt_report = run_shirt_capture(bench, seq.frames, gt, tmp)
            timings["shirt_pipeline_s"] = time.perf_counter() - t1
            metrics.update(shirt_metrics)
        metrics["run.frames"] = gt.n_frames
        metrics["run.cameras"] = C
        metrics["run.mean_subframes"] = float(gt.n_subframes.mean())
        timings["total_s"] = time.perf_counter() - t0
        if tmp is not None:
            gt.save(tmp / "ground_truth")
            cal = gt.calibration()
            cal.save_opencv_yaml(tmp / "calibration_ground_truth.yml")
            save_scenario_copy(scenario, tmp)
            if capture is not None:
                export_capture(capture, tmp / "exports", calibration, subject_model(bench))
                save_template(label_template(bench), tmp / "exports" / "label_template.csv")
                # The subject file a user would hand `mocap markers --subject` (MJCF + marker placement).
                if subject_model(bench) is not None:
                    subject_model(bench).save_toml(tmp / "exports" / "subject.toml")
            _contact_sheet(bench, gt, kept_frames, tmp / "contact_sheet.png")
            (tmp / "metrics.json").write_text(json.dumps({k: _jsonable(v) for k, v in sorted(metrics.items())}, indent=2))
            from simbench.report import write_run_report

            write_run_report(tmp, scenario, gt, capture, metrics, timings, extra_sections=calib_report + shirt_report,
                             calibration=calibration)
    except BaseException:
        if ctx is not None:
            ctx.__exit__(RuntimeError, None, None)
        raise
    if ctx is not None:
        ctx.__exit__(None, None, None)
    return RunResult(metrics, Path(out) if out else None, seq, capture, timings)


def _jsonable(v):
    if isinstance(v, (np.floating, float)):
        return None if not np.isfinite(v) else float(v)
    if isinstance(v, (np.integer,)):
        return int(v)
    return v


def _contact_sheet(bench: Bench, gt, kept: dict[int, np.ndarray], path: Path) -> None:
    from simbench.render.contact_sheet import contact_sheet

    rows = sorted(kept)
    frames = {(k, c.name): kept[k][ci] for k in rows for ci, c in enumerate(bench.cameras)}
    overlays = {(k, c.name): gt.markers_2d[k, ci][gt.marker_visible[k, ci]] for k in rows for ci, c in enumerate(bench.cameras)}
    contact_sheet(frames, {k: float(gt.times[k]) for k in rows}, path, overlays=overlays)
