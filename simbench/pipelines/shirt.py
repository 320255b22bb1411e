"""The colour-shirt pipeline (seed 001) on one take of the bench: the session, the scored run and its report.

``simbench run`` feeds a :class:`ShirtCapture` each frame as it renders, for scenarios whose
subject wears the shirt (the frames are not kept: memory does not grow with the take).  The
pipeline (:mod:`mocap.shirt`) gets only what a user would have:

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

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable

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
from simbench.pipelines.shirt_inputs import colour_labels, first_frame_inputs, render_empty_frames, scribble_labels
from simbench.pipelines.shirt_training import ShirtTraining, ensure_training
from simbench.render.video import Mp4Writer
from simbench.scenario.model import Scenario
from simbench.stage.build import build_stage
from simbench.stage.ground_truth import GroundTruth
from simbench.stage.stage import Stage

__all__ = ["ShirtSession", "start_session", "ShirtRun", "track_sequence", "tracker_params", "ShirtCapture", "ROC_THRESHOLDS",
           "prepare_shirt_caches"]

ROC_THRESHOLDS = np.concatenate([np.linspace(0.0, 12.0, 61), [3.0, 5.0]])
"""The classifiers' thresholds a run's ROC is counted at: the plot's 0-12 and the operating points (3 and 5)."""
_OPERATING = (("g", 3.0, "gaussian"), ("a", 5.0, "assisted"))  # classifier, threshold, metric name
_CURVE = slice(0, 61)  # ROC_THRESHOLDS of the plotted curve


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
    db, training = _database_and_training(stage, progress_factory)
    ids0 = np.stack([gt.id_maps[n][0] for n in gt.camera_names])
    return _session(stage, db, training, frames[0], ids0, render_empty_frames(stage))


def prepare_shirt_caches(scenarios: Iterable[Scenario], progress_factory: ProgressFactory | None = None) -> int:
    """Build, or find, the pose database and training of each distinct colour-shirt scenario of ``scenarios`` (seeds
    apart); how many distinct ones there were.

    Why: the workers of a sweep, of ``--seeds`` or of a check that find them missing build them inside a worker, where
    the user sees log lines but no progress bar (an 80k-pose database takes minutes). The command line calls this
    before it starts local workers, so the build shows ``progress_factory``'s bar and the workers load the files.
    """
    seen: set[str] = set()
    for sc in scenarios:
        if not sc.subject.shirt:
            continue
        key = json.dumps({k: v for k, v in sc.model_dump(mode="json").items() if k not in ("seed", "name", "description")},
                         sort_keys=True, default=str)
        if key not in seen:
            seen.add(key)
            _database_and_training(build_stage(sc), progress_factory)
    return len(seen)


def _database_and_training(stage: Stage, progress_factory: ProgressFactory | None) -> tuple[PoseDatabase, ShirtTraining]:
    """The pose database and the training of a stage's scenario (built, or loaded from the caches)."""
    cfg = stage.scenario.shirt_pipeline
    sampling = PoseSampling(n_poses=cfg.database_size)
    db = ensure_database(stage.params, sampling, cfg.database, progress_factory=progress_factory)
    db.meta.setdefault("key", database_key(stage.params, sampling))
    return db, ensure_training(stage.scenario, db, cfg.training_frames)


def _session(stage: Stage, db: PoseDatabase, training: ShirtTraining, images0: np.ndarray, ids0: np.ndarray,
             empty: list[list[np.ndarray]]) -> ShirtSession:
    """The session of a take from its first frame's images ``(C, H, W, 3)`` and id maps ``(C, H, W)`` and the
    empty scene's frames; the exact calibration."""
    W0, other = first_frame_inputs(stage.scenario.seed, images0, ids0, training.colour_model, np.asarray(db.geometry.patch_colour))
    calibration = Calibration(tuple(c.calibration_camera() for c in stage.cameras))
    return ShirtSession(db, training, calibration, W0, other, empty)


# --------------------------------------------------------------------------- tracking
@dataclass
class ShirtRun:
    """One method's results over a sequence.

    q : (F, 18) upper-body configurations (NaN where the frame failed)
    q_blend : (F, 18) blended database poses after the 6-DoF fit
    classified_fraction : (F, C)
    timings_ms : (F, S) per stage (:data:`mocap.shirt.pipeline.STAGES`)
    roc : the classifiers' ROC counts at :data:`ROC_THRESHOLDS` (``"g"``: step 1's Gaussian classifier,
        ``"a"``: step 3's pose-assisted one) over sampled frames, full method only
    """

    q: np.ndarray
    q_blend: np.ndarray
    classified_fraction: np.ndarray
    timings_ms: np.ndarray
    roc: dict[str, shirt_metrics.RocCounts] | None = None


class _RunRecorder:
    """A :class:`ShirtRun` filled frame by frame: per-frame results, and the ROC counts of every
    ``roc_every``-th frame when given its truth labels (the frames themselves are not kept)."""

    def __init__(self, n_frames: int, n_cameras: int, nq: int, roc: bool, roc_every: int = 5) -> None:
        self.run = ShirtRun(np.full((n_frames, nq), np.nan), np.full((n_frames, nq), np.nan), np.zeros((n_frames, n_cameras)),
                            np.zeros((n_frames, len(STAGES))),
                            {key: shirt_metrics.RocCounts(ROC_THRESHOLDS) for key in ("g", "a")} if roc else None)
        self.roc_every = roc_every

    def wants_truth(self, k: int) -> bool:
        """Whether frame ``k``'s truth labels are sampled for the ROC."""
        return self.run.roc is not None and k % self.roc_every == 0

    def add(self, k: int, est, truth_labels: list[np.ndarray] | None = None) -> None:
        """Frame ``k``'s estimate; ``truth_labels``: its colour labels ``(H, W)`` per camera when :meth:`wants_truth`."""
        r = self.run
        r.q[k], r.q_blend[k], r.classified_fraction[k] = est.q, est.q_blend, est.classified_fraction
        r.timings_ms[k] = [est.timings_ms[s] for s in STAGES]
        if truth_labels is None or not self.wants_truth(k):
            return
        for ci, o in enumerate(est.cameras):
            if o.step1 is None or o.final is None:
                continue
            truth = crop_image(truth_labels[ci], o.view, cv2.INTER_NEAREST).ravel()
            fg = np.ones(truth.size, bool) if o.foreground is None else o.foreground.ravel()
            for key, cls in (("g", o.step1), ("a", o.final)):
                r.roc[key].add(np.where(fg, cls.score.ravel(), np.inf), cls.best.ravel(), truth)


def track_sequence(tracker: ShirtTracker, frames: np.ndarray, truth_labels: list[np.ndarray] | None = None,
                   roc_every: int = 5, progress=None) -> ShirtRun:
    """Run a tracker over frames ``(F, C, H, W, 3)``; count the classifiers' ROC when truth labels ``[(F, H, W)] per camera`` are given."""
    F, C = frames.shape[:2]
    rec = _RunRecorder(F, C, tracker.kin.nq, truth_labels is not None, roc_every)
    for k in range(F):
        est = tracker.process([frames[k, ci] for ci in range(C)])
        rec.add(k, est, [t[k] for t in truth_labels] if rec.wants_truth(k) else None)
        if progress is not None:
            progress(1)
    return rec.run


def tracker_params(scenario: Scenario) -> ShirtPipelineParams:
    """The full method's settings for a scenario's run: classification maps kept (for the ROC data), the hands
    as ``[shirt_pipeline] hands`` says, and ``[shirt_pipeline.settings]`` (the baseline is derived from these)."""
    params = ShirtPipelineParams(keep_classification=True, hand_constraints=scenario.shirt_pipeline.hands)
    return params.with_settings(scenario.shirt_pipeline.settings, where="shirt_pipeline.settings")


class ShirtCapture:
    """The colour-shirt capture of one take, fed frame by frame as the take renders (``simbench run``).

    Inputs: the stage, then each frame's images ``(C, H, W, 3)`` uint8 and id maps ``(C, H, W)``
    (:meth:`add_frame`, in order from frame 0); outputs: the ``shirt.*`` metrics, the report's
    section and the files of :func:`write_shirt_outputs` (:meth:`finish`). The full method and the
    baseline track each frame as it comes, so neither the frames nor the id maps are kept: of
    frame 0 its id maps (the user's scribbles), of the others the ROC counts of every 5th.

    The pose database and training are built or loaded, and the empty scene rendered, when it is made
    (before the take's render: they render on their own).
    """

    def __init__(self, stage: Stage, progress_factory: ProgressFactory | None = None) -> None:
        self.stage = stage
        self._db, self._training = _database_and_training(stage, progress_factory)
        self._empty = render_empty_frames(stage)
        self.model = ShirtModel(self._db.mjcf_text, self._db.geometry)
        self.session: ShirtSession | None = None
        self._scribble_ids: np.ndarray | None = None  # (C, H, W) frame 0's id maps
        self._trackers: dict[str, ShirtTracker] = {}
        self._records: dict[str, _RunRecorder] = {}
        self._next = 0

    def add_frame(self, index: int, images: np.ndarray, ids: np.ndarray) -> None:
        """Track frame ``index`` (``images (C, H, W, 3)`` uint8, ``ids (C, H, W)``) with both methods."""
        if index != self._next:
            raise ValueError(f"ShirtCapture.add_frame: frame {index} given where frame {self._next} was expected")
        if self.session is None:
            self.session = _session(self.stage, self._db, self._training, images, ids, self._empty)
            self._scribble_ids = np.array(ids, copy=True)
            params = tracker_params(self.stage.scenario)
            methods = {"full": params, "baseline": params.baseline()} if self.stage.scenario.shirt_pipeline.baseline else {"full": params}
            F, C = len(self.stage.frame_times()), len(self.stage.cameras)
            for name, p in methods.items():
                self._trackers[name] = self.session.tracker(p)
                self._records[name] = _RunRecorder(F, C, self._trackers[name].kin.nq, roc=name == "full")
        truth = None
        if self._records["full"].wants_truth(index):
            truth = [colour_labels(ids[ci], self.model.patch_colour) for ci in range(len(ids))]
        for name, tracker in self._trackers.items():
            self._records[name].add(index, tracker.process([images[ci] for ci in range(len(images))]), truth)
        self._next += 1

    def finish(self, gt: GroundTruth, out_dir: Path | None) -> tuple[dict[str, float], list[str]]:
        """Score both methods against ``gt`` once every frame was added; the ``shirt.*`` metrics and the
        report's section, and with ``out_dir`` the plots (``plots/``) and estimated poses (``shirt/``)."""
        if self.session is None or self._next != gt.n_frames:
            raise ValueError(f"ShirtCapture.finish: {self._next} frames tracked of the take's {gt.n_frames}")
        runs = {name: rec.run for name, rec in self._records.items()}
        scores = score_runs(runs, self.model, gt)
        metrics = {"shirt.database_poses": len(self.session.db), "shirt.training_frames": self.session.training.info.get("frames", 0),
                   **scores.metrics}
        lines = report_lines(metrics, self.session)
        if out_dir is not None:
            lines += write_shirt_outputs(Path(out_dir), self.stage, gt, self._scribble_ids, self.session, self.model, runs, scores)
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
    if full.roc is not None and full.roc["g"].n:
        for key, T_op, label in _OPERATING:
            metrics[f"shirt.{label}_correct_rate"], metrics[f"shirt.{label}_incorrect_rate"] = full.roc[key].rates_at(T_op)
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


def write_shirt_outputs(out: Path, stage: Stage, gt: GroundTruth, scribble_ids: np.ndarray, session: ShirtSession,
                        model: ShirtModel, runs: dict[str, ShirtRun], scores: ShirtScores) -> list[str]:
    """Plots, the estimated poses and what ``mocap shirt`` needs to run on this take's videos; the report lines naming them.
    ``scribble_ids``: frame 0's id maps ``(C, H, W)``, the user's scribbles."""
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
    for ci, name in enumerate(gt.camera_names):
        lab = scribble_labels(scribble_ids[ci], model.patch_colour)
        png = np.where(lab >= 0, lab + 1, np.where(lab == NOT_SHIRT, 255, 0)).astype(np.uint8)
        cv2.imwrite(str(folder / f"scribbles_{name}.png"), png)
    for ci, name in enumerate(gt.camera_names):
        with Mp4Writer(folder / f"empty_{name}.mp4", scribble_ids.shape[2], scribble_ids.shape[1], stage.scenario.fps) as w:
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
    if roc is not None and roc["g"].n:
        fig = Figure(figsize=(6, 5))
        ax = fig.subplots()
        for key, label, T_op, c in (("g", "Gaussian classifier (step 1)", 3.0, "C0"), ("a", "pose-assisted (step 3)", 5.0, "C3")):
            cor, inc = roc[key].rates()
            ax.plot(inc[_CURVE] * 100, cor[_CURVE] * 100, "-", color=c, label=label)
            c0, i0 = roc[key].rates_at(T_op)
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
