"""The colour-shirt pipeline (seed 001) on one take of the bench: the session, the scored run and its report.

``simbench run`` calls :func:`run_shirt_capture` for scenarios whose subject wears the
shirt.  The pipeline (:mod:`mocap.shirt`) gets only what a user would have:

* the calibration (exact, from the bench);
* one labelled frame per camera: the bench's id map of frame 0 stands in for the
  user's scribbles on the first frame (it gives the initial white balance), and a few
  frames of the empty scene per camera (for the background model), rendered with the
  subject out of view under the lighting at the start of the take
  (:mod:`simbench.pipelines.shirt_inputs`);
* the pose database (:mod:`simbench.pipelines.shirt_database`, cached);
* a colour model and IK covariances trained *ahead of time* on different takes
  (:mod:`simbench.pipelines.shirt_training`, cached).

It runs the full method and the baseline (no pose prior, no adaptive white balance)
on the same frames and scores both against the ground truth with :mod:`eval.shirt_metrics`.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from eval import shirt_metrics
from mocap.calibration import Calibration
from mocap.shirt.classify import crop_image
from mocap.shirt.colour_model import NOT_SHIRT, ColourModel
from mocap.shirt.pipeline import STAGES, ShirtPipelineParams, ShirtTracker
from mocap.shirt.pose_database import PoseDatabase
from mocap.shirt.kinematics import UPPER_BODY_JOINTS
from mocap.shirt.shirt_model import ShirtModel
from simbench.pipelines.shirt_database import PoseSampling, ProgressFactory, database_key, default_database_path, ensure_database
from simbench.pipelines.shirt_inputs import colour_labels, scribble_labels, session_inputs
from simbench.pipelines.shirt_training import ShirtTraining, ensure_training
from simbench.render.video import Mp4Writer
from simbench.scenario.model import Scenario
from simbench.stage.ground_truth import GroundTruth
from simbench.stage.stage import Stage

__all__ = ["ShirtSession", "start_session", "ShirtRun", "track_sequence", "tracker_params", "run_shirt_capture"]

@dataclass(frozen=True)
class ShirtSession:
    """Everything a shirt capture of one take starts from: the pose database, the trained
    colour model and IK priors, the exact calibration and the user's session inputs
    (see :func:`session_inputs`)."""

    db: PoseDatabase
    training: ShirtTraining
    calibration: Calibration
    W0: list[np.ndarray]            # (3, 3) white balance per camera, from the first frame's scribbles
    other: ColourModel | None       # the not-shirt colours of the first frames
    empty: list[list[np.ndarray]]   # per camera, frames of the empty scene

    def tracker(self, params: ShirtPipelineParams) -> ShirtTracker:
        """A fresh tracker of this session with ``params``."""
        t = self.training
        return ShirtTracker(self.db, t.colour_model, t.priors, self.calibration, self.W0, params, self.empty, self.other)


def start_session(stage: Stage, frames: np.ndarray, gt: GroundTruth,
                  progress_factory: ProgressFactory | None = None) -> ShirtSession:
    """Database and training (built or loaded from the cache) and the session inputs of a take;
    ``progress_factory`` shows a database build's progress."""
    cfg = stage.scenario.shirt_pipeline
    sampling = PoseSampling(n_poses=cfg.database_size)
    db = ensure_database(stage.params, sampling, cfg.database, progress_factory=progress_factory)
    db.meta.setdefault("key", database_key(stage.params, sampling))
    training = ensure_training(stage.scenario, db, cfg.training_frames)
    W0, other, empty = session_inputs(stage, frames, gt, training.colour_model, np.asarray(db.geometry.patch_colour))
    return ShirtSession(db, training, gt.calibration(), W0, other, empty)


# --------------------------------------------------------------------------- tracking
@dataclass
class ShirtRun:
    """One method's results over a sequence.

    q : (F, 18) upper-body configurations (NaN where the frame failed)
    q_blend : (F, 18) blended database poses after the 6-DoF fit
    classified_fraction : (F, C)
    timings_ms : (F, S) per stage (:data:`mocap.shirt.pipeline.STAGES`)
    roc : dict of arrays (score/best of both classifiers and the truth of sampled pixels), full method only
    """

    q: np.ndarray
    q_blend: np.ndarray
    classified_fraction: np.ndarray
    timings_ms: np.ndarray
    roc: dict | None = None


def track_sequence(tracker: ShirtTracker, frames: np.ndarray, truth_labels: list[np.ndarray] | None = None,
                   roc_every: int = 5, progress=None) -> ShirtRun:
    """Run a tracker over frames ``(F, C, H, W, 3)``; sample classification ROC data when truth labels ``[(F, H, W)] per camera`` are given."""
    F, C = frames.shape[:2]
    q = np.full((F, tracker.kin.nq), np.nan)
    qb = np.full((F, tracker.kin.nq), np.nan)
    frac = np.zeros((F, C))
    T = np.zeros((F, len(STAGES)))
    roc = {"g_score": [], "g_best": [], "a_score": [], "a_best": [], "truth": []} if truth_labels is not None else None
    for k in range(F):
        est = tracker.process([frames[k, ci] for ci in range(C)])
        q[k], qb[k], frac[k] = est.q, est.q_blend, est.classified_fraction
        T[k] = [est.timings_ms[s] for s in STAGES]
        if roc is not None and k % roc_every == 0:
            for ci, o in enumerate(est.cameras):
                if o.step1 is None or o.final is None:
                    continue
                truth = crop_image(truth_labels[ci][k], o.view, cv2.INTER_NEAREST).ravel()
                fg = np.ones(truth.size, bool) if o.foreground is None else o.foreground.ravel()
                for key, cls in (("g", o.step1), ("a", o.final)):
                    roc[f"{key}_score"].append(np.where(fg, cls.score.ravel(), np.inf))
                    roc[f"{key}_best"].append(cls.best.ravel())
                roc["truth"].append(truth)
        if progress is not None:
            progress(1)
    if roc is not None:
        roc = {k: np.concatenate(v) if v else np.zeros(0) for k, v in roc.items()}
    return ShirtRun(q, qb, frac, T, roc)


def tracker_params(scenario: Scenario) -> ShirtPipelineParams:
    """The full method's settings for a scenario's run: classification maps kept (for the ROC data), the hands
    as ``[shirt_pipeline] hands`` says."""
    return ShirtPipelineParams(keep_classification=True, hand_constraints=scenario.shirt_pipeline.hands)


def run_shirt_capture(stage: Stage, frames: np.ndarray, gt: GroundTruth, out_dir: Path | None,
                      progress_factory: ProgressFactory | None = None) -> tuple[dict[str, float], list[str]]:
    """The hook of ``simbench run``: full method and baseline on the same frames, scored.

    Parameters
    ----------
    stage : Stage
    frames : (F, C, H, W, 3) uint8 RGB
    gt : GroundTruth
        With id maps (only frame 0's are given to the pipeline, as the user's scribbles).
    out_dir : Path or None
        Where plots (``plots/``) and the estimated poses (``shirt/``) go.
    progress_factory : optional
        Shows the progress of a pose-database build (the command line's progress bar).

    Returns
    -------
    metrics : dict
        ``shirt.*`` numbers.
    report_lines : list[str]
        A Markdown section for the run report.
    """
    session = start_session(stage, frames, gt, progress_factory=progress_factory)
    model = ShirtModel(session.db.mjcf_text, session.db.geometry)
    truth_labels = [colour_labels(gt.id_maps[n], model.patch_colour) for n in gt.camera_names]
    params = tracker_params(stage.scenario)
    runs = {"full": track_sequence(session.tracker(params), frames, truth_labels)}
    if stage.scenario.shirt_pipeline.baseline:
        runs["baseline"] = track_sequence(session.tracker(params.baseline()), frames)
    scores = score_runs(runs, model, gt)
    metrics = {"shirt.database_poses": len(session.db), "shirt.training_frames": session.training.info.get("frames", 0),
               **scores.metrics}
    lines = report_lines(metrics, session)
    if out_dir is not None:
        lines += write_shirt_outputs(Path(out_dir), stage, gt, frames, session, model, runs, scores)
    return metrics, lines


@dataclass(frozen=True)
class ShirtScores:
    """The ``shirt.*`` metrics of every method, and the per-frame series the plots show."""

    metrics: dict[str, float]
    true_angle_deg: np.ndarray          # (F,) right shoulder angle of the ground truth
    angle_deg: dict[str, np.ndarray]    # method -> (F,) its shoulder angle
    joint_error_cm: dict[str, np.ndarray]  # method -> (F,) RMS error of the upper-body joint centres


def score_runs(runs: dict[str, ShirtRun], model: ShirtModel, gt: GroundTruth) -> ShirtScores:
    """Every method's joint, vertex, blend, classification, tracking, angle and timing figures against ``gt``."""
    jidx = [gt.joint_names.index(b) for b in UPPER_BODY_JOINTS]
    true_j = gt.joint_centres[:, jidx]
    true_v = model.shirt_vertices(model.kin.from_full_qpos(gt.qpos))
    true_angle = shirt_metrics.shoulder_angle_deg(true_j, UPPER_BODY_JOINTS)
    metrics: dict[str, float] = {}
    angles, errors = {}, {}
    for name, r in runs.items():
        q = shirt_metrics.fill_forward(r.q)
        est_j = model.kin.joint_centres(q)
        blend_j = model.kin.joint_centres(shirt_metrics.fill_forward(r.q_blend))
        prefix = "shirt." if name == "full" else "shirt.baseline_"
        angles[name] = shirt_metrics.shoulder_angle_deg(est_j, UPPER_BODY_JOINTS)
        errors[name] = shirt_metrics.per_frame_rms_cm(est_j, true_j)
        metrics[prefix + "joint_rmse_cm"] = shirt_metrics.rmse_cm(est_j, true_j)
        metrics[prefix + "arms_within_5cm_fraction"] = shirt_metrics.frames_within_cm(est_j, true_j, UPPER_BODY_JOINTS)
        metrics[prefix + "vertex_rmse_cm"] = shirt_metrics.rmse_cm(model.shirt_vertices(q), true_v)
        metrics[prefix + "blend_joint_rmse_cm"] = shirt_metrics.rmse_cm(blend_j, true_j)
        metrics[prefix + "classified_fraction"] = float(np.mean(r.classified_fraction))
        metrics[prefix + "tracked_fraction"] = float(np.mean(np.all(np.isfinite(r.q), axis=1)))
        metrics[prefix + "shoulder_angle_rmse_deg"] = float(np.sqrt(np.nanmean((angles[name] - true_angle) ** 2)))
        metrics[prefix + "ms_per_frame"] = float(np.mean(r.timings_ms.sum(axis=1)))
    full = runs["full"]
    for s, v in zip(STAGES, full.timings_ms.mean(axis=0)):
        metrics[f"shirt.ms.{s}"] = float(v)
    if "baseline" in runs:
        metrics["shirt.improvement_vs_baseline"] = 1.0 - metrics["shirt.joint_rmse_cm"] / metrics["shirt.baseline_joint_rmse_cm"]
    if full.roc is not None and full.roc["truth"].size:
        for key, T_op, label in (("g", 3.0, "gaussian"), ("a", 5.0, "assisted")):
            cor, inc = shirt_metrics.classification_roc(full.roc[f"{key}_score"], full.roc[f"{key}_best"], full.roc["truth"], np.array([T_op]))
            metrics[f"shirt.{label}_correct_rate"] = float(cor[0])
            metrics[f"shirt.{label}_incorrect_rate"] = float(inc[0])
    return ShirtScores(metrics, true_angle, angles, errors)


def report_lines(metrics: dict[str, float], session: ShirtSession) -> list[str]:
    """The run report's colour-shirt section: what the pipeline was given, both methods side by side, stage timings."""
    info = session.training.info
    lines = ["## Colour shirt (seed 001)", "",
             f"Pose database: {len(session.db)} poses; colour model and IK covariances trained on {info.get('frames', 0)} frames of "
             f"other takes ({', '.join(info.get('takes', []))}: same cameras, other motions, office/tungsten/daylight light with "
             "white-balanced cameras). "
             "The pipeline was given the calibration, frame 0's id map as the user's scribbles (shirt colours, and not-shirt for the subject's other pixels and the set next to them), and 3 frames of the empty scene.", "",
             "| | full method | baseline (no pose prior, fixed white balance) |", "|---|---|---|"]
    for key, label in (("joint_rmse_cm", "upper-body joint RMS (cm)"), ("vertex_rmse_cm", "shirt vertex RMS (cm)"),
                       ("blend_joint_rmse_cm", "database blend alone, joint RMS (cm)"),
                       ("shoulder_angle_rmse_deg", "shoulder angle RMS (deg)"),
                       ("arms_within_5cm_fraction", "frames with both elbows and wrists within 5 cm"), ("classified_fraction", "classified fraction of foreground"),
                       ("tracked_fraction", "frames tracked"), ("ms_per_frame", "ms per frame (all cameras)")):
        b = metrics.get("shirt.baseline_" + key, float("nan"))
        lines.append(f"| {label} | {metrics['shirt.' + key]:.3g} | {b:.3g} |")
    lines += ["", "| stage | ms per frame |", "|---|---|"] + [f"| {s} | {metrics[f'shirt.ms.{s}']:.1f} |" for s in STAGES] + [""]
    return lines


def write_shirt_outputs(out: Path, stage: Stage, gt: GroundTruth, frames: np.ndarray, session: ShirtSession,
                        model: ShirtModel, runs: dict[str, ShirtRun], scores: ShirtScores) -> list[str]:
    """Plots, the estimated poses and what ``mocap shirt`` needs to run on this take's videos; the report lines naming them."""
    nan = np.full(len(gt.times), np.nan)
    pics = _plots(out, gt.times, scores.true_angle_deg, scores.angle_deg["full"], scores.angle_deg.get("baseline", nan),
                  runs["full"].roc, scores.joint_error_cm["full"], scores.joint_error_cm.get("baseline", nan), stage.scenario.name)
    lines = [f"![{Path(p).stem}]({p})" for p in pics] + [""]
    folder = out / "shirt"
    folder.mkdir(parents=True, exist_ok=True)
    np.savez(folder / "poses.npz", times=gt.times, joint_names=np.array(UPPER_BODY_JOINTS),
             **{f"{n}_q": r.q for n, r in runs.items()}, **{f"{n}_qpos": model.kin.to_full_qpos(r.q) for n, r in runs.items()},
             **{f"{n}_joint_centres_m": model.kin.joint_centres(r.q) for n, r in runs.items()})
    # what `mocap shirt` needs to run on this take's videos: colour model, covariances, scribbles
    session.training.colour_model.save(folder / "colour_model.npz")
    session.training.priors.save(folder / "ik_priors.npz")
    for name in gt.camera_names:
        lab = scribble_labels(gt.id_maps[name][0], model.patch_colour)
        png = np.where(lab >= 0, lab + 1, np.where(lab == NOT_SHIRT, 255, 0)).astype(np.uint8)
        cv2.imwrite(str(folder / f"scribbles_{name}.png"), png)
    for ci, name in enumerate(gt.camera_names):
        with Mp4Writer(folder / f"empty_{name}.mp4", frames.shape[3], frames.shape[2], stage.scenario.fps) as w:
            for f in session.empty[ci]:
                w.write(f)
    cfg = stage.scenario.shirt_pipeline
    database = cfg.database or default_database_path(stage.params, PoseSampling(n_poses=cfg.database_size))
    (folder / "database.txt").write_text(f"{database}\n")
    lines += ["Estimated poses: `shirt/poses.npz` (upper-body q, MuJoCo qpos with the other hinges at zero, joint centres). "
              "For `mocap shirt` on `videos/*.mp4`: `shirt/colour_model.npz`, `shirt/ik_priors.npz`, "
              "`shirt/scribbles_<camera>.png` (frame 0), `shirt/empty_<camera>.mp4` (the empty scene) and the database named "
              "in `shirt/database.txt`.", ""]
    return lines


def _plots(out: Path, times: np.ndarray, gt_angle: np.ndarray, full_angle: np.ndarray, base_angle: np.ndarray,
           roc: dict | None, err_full: np.ndarray, err_base: np.ndarray, title: str) -> list[str]:
    """The shoulder angle of both methods against the truth (seed 001 Fig. 10) and the classifiers' ROC (Fig. 6)."""
    figs = out / "plots"
    figs.mkdir(parents=True, exist_ok=True)
    names = []
    from matplotlib.figure import Figure  # here, not at the top: see simbench/pipelines/calibration.py

    fig = Figure(figsize=(9, 6))
    ax0, ax1 = fig.subplots(2, 1, sharex=True)
    ax0.plot(times, gt_angle, "k-", lw=2, label="ground truth")
    ax0.plot(times, full_angle, "C1-", lw=1.2, label="full method")
    ax0.plot(times, base_angle, "C2-", lw=1.0, alpha=0.8, label="baseline (no pose prior, fixed WB)")
    ax0.set_ylabel("right shoulder angle (deg)")
    ax0.set_title(f"{title}: shoulder angle (arm vs trunk axis), cf. seed 001 Fig. 10")
    ax0.legend(fontsize=8)
    ax0.grid(alpha=0.3)
    ax1.plot(times, err_full, "C1-", label="full method")
    ax1.plot(times, err_base, "C2-", alpha=0.8, label="baseline")
    ax1.set_ylabel("joint RMS error (cm)")
    ax1.set_xlabel("time (s)")
    ax1.legend(fontsize=8)
    ax1.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(figs / "shirt_shoulder_angle.png", dpi=100)
    names.append("plots/shirt_shoulder_angle.png")
    if roc is not None and roc["truth"].size:
        th = np.linspace(0.0, 12.0, 61)
        fig = Figure(figsize=(6, 5))
        ax = fig.subplots()
        for key, label, T_op, c in (("g", "Gaussian classifier (step 1)", 3.0, "C0"), ("a", "pose-assisted (step 3)", 5.0, "C3")):
            cor, inc = shirt_metrics.classification_roc(roc[f"{key}_score"], roc[f"{key}_best"], roc["truth"], th)
            ax.plot(inc * 100, cor * 100, "-", color=c, label=label)
            c0, i0 = shirt_metrics.classification_roc(roc[f"{key}_score"], roc[f"{key}_best"], roc["truth"], np.array([T_op]))
            ax.plot(i0 * 100, c0 * 100, "o", color=c, label=f"T = {T_op:g}")
        ax.set_xlabel("incorrectly classified pixels (% of crop pixels)")
        ax.set_ylabel("correctly classified shirt pixels (%)")
        ax.set_title(f"{title}: classification ROC (threshold 0-12), cf. seed 001 Fig. 6", fontsize=9)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
        fig.tight_layout()
        fig.savefig(figs / "shirt_roc.png", dpi=100)
        names.append("plots/shirt_roc.png")
    return names
