"""The marker pipeline's part of a run: what a user's session gives it (label template,
subject model, the scenario's pipeline settings) and its scores against the ground truth."""

from __future__ import annotations

import mujoco
import numpy as np

from eval import marker_metrics, skeleton_metrics
from mocap.detection import DetectionParams
from mocap.labelling import LabelTemplate
from mocap.marker_pipeline import MarkerCapture, MarkerPipelineParams
from mocap.reassociation import ReassociationParams
from mocap.reconstruction import ReconstructionParams
from mocap.subject import SubjectModel
from simbench.scenario import Scenario
from simbench.scenes.humanoid import humanoid_mjcf, tpose_qpos
from simbench.scenes.markers import MARKER_RADIUS_M
from simbench.stage.ground_truth import GroundTruth
from simbench.stage.stage import Stage

__all__ = ["label_template", "subject_model", "pipeline_params", "score_markers"]


def label_template(stage: Stage) -> LabelTemplate:
    """The subject's markers in its T-pose, subject-local frame (what a user's template holds);
    for a real capture (no humanoid), its markers in the capture's reference frame."""
    reference = stage.capture_reference()
    if reference is not None:
        return reference.label_template()
    xml = humanoid_mjcf(stage.params, marker_set=stage.scenario.subject.markers)
    m = mujoco.MjModel.from_xml_string(xml)
    d = mujoco.MjData(m)
    d.qpos[:] = tpose_qpos(stage.params)
    d.qpos[0:2] = 0.0
    mujoco.mj_kinematics(m, d)
    pos = np.array([d.site_xpos[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, n)] for n in stage.marker_names])
    return LabelTemplate(tuple(stage.marker_names), pos)


def subject_model(stage: Stage) -> SubjectModel | None:
    """The humanoid's subject model; None for a real capture (no body: markers only)."""
    if stage.capture_reference() is not None:
        return None
    return SubjectModel.from_mjcf_text(humanoid_mjcf(stage.params, marker_set=stage.scenario.subject.markers),
                                       name=stage.scenario.name)


def pipeline_params(sc: Scenario) -> MarkerPipelineParams:
    """The marker pipeline's settings from the scenario's ``[markers_pipeline]`` and sensor mode."""
    cfg = sc.markers_pipeline
    # The rendered markers' size, as a user gives their markers' size: a capture's own
    # (`motion.marker_diameter_mm`), else the bench's 14 mm spheres.
    d = sc.motion.marker_diameter_mm
    radius = MARKER_RADIUS_M if d is None else 0.5e-3 * float(d)
    return MarkerPipelineParams(
        detection=DetectionParams(mode=sc.sensor.mode),
        labelling=cfg.labelling,
        tracker=cfg.tracker,
        reconstruction=ReconstructionParams(smoothing=cfg.smoothing, max_gap_frames=cfg.max_gap_frames),
        solve_skeleton=cfg.solve_skeleton,
        marker_radius_m=radius,
        reassociation=ReassociationParams(marker_radius_m=radius),
    )


def score_markers(gt: GroundTruth, capture: MarkerCapture) -> dict[str, float]:
    """``markers.*`` (3D error, reconstruction, swaps, 2D tracking) and, with a skeleton fit, ``skeleton.*`` metrics."""
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


def score_sync(sync, gt: GroundTruth) -> dict[str, float]:
    """``sync.*``: the estimated clocks of unsynchronised cameras against the true ones.

    ``sync.offset_error_ms`` and ``sync.drift_error_ppm`` are RMS over the cameras other than
    the reference (whose offset and drift are zero by definition); the offset is that of each
    camera clock's zero on the reference clock (:meth:`simbench.stage.clocks.CameraClocks.relative_to`).
    """
    rate = np.asarray(gt.clock_rate, float)
    ref = sync.reference
    true_offset = (np.asarray(gt.clock_offset_s, float) - gt.clock_offset_s[ref]) / rate[ref]
    true_drift = rate / rate[ref] - 1.0
    others = np.arange(len(rate)) != ref
    off_err = (np.asarray(sync.offset_s) - true_offset)[others]
    drift_err = (np.asarray(sync.drift) - true_drift)[others]
    return {
        "sync.offset_error_ms": float(np.sqrt(np.mean(off_err**2)) * 1e3),
        "sync.offset_error_max_ms": float(np.max(np.abs(off_err)) * 1e3),
        "sync.drift_error_ppm": float(np.sqrt(np.mean(drift_err**2)) * 1e6),
        "sync.true_offset_max_ms": float(np.max(np.abs(true_offset)) * 1e3),
        "sync.true_drift_max_ppm": float(np.max(np.abs(true_drift)) * 1e6),
    }


def sync_report(sync, gt: GroundTruth) -> list[str]:
    """The report's section on the cameras' clocks: each camera's true and estimated offset and drift."""
    rate = np.asarray(gt.clock_rate, float)
    ref = sync.reference
    true_offset = (np.asarray(gt.clock_offset_s, float) - gt.clock_offset_s[ref]) / rate[ref]
    true_drift = rate / rate[ref] - 1.0
    lines = ["## Camera clocks (estimated from the markers' motion)", "",
             f"Each camera's clock on {gt.camera_names[ref]}'s: `s_ref = offset + (1 + drift) * s_cam`.", "",
             "| camera | true offset (ms) | estimated (ms) | error (ms) | true drift (ppm) | estimated (ppm) |",
             "|---|---|---|---|---|---|"]
    for c, name in enumerate(gt.camera_names):
        lines.append(f"| {name} | {true_offset[c] * 1e3:.3f} | {sync.offset_s[c] * 1e3:.3f} | "
                     f"{(sync.offset_s[c] - true_offset[c]) * 1e3:+.3f} | {true_drift[c] * 1e6:.1f} | {sync.drift[c] * 1e6:.1f} |")
    return lines + [""]
