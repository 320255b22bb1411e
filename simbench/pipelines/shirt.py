"""The colour-shirt pipeline (seed 001) on the bench: training, the scored run and the report.

``simbench run`` calls :func:`run_shirt_capture` for scenarios whose subject wears the
shirt.  The pipeline (:mod:`mocap.shirt`) gets only what a user would have:

* the calibration (exact, from the bench);
* one labelled frame per camera: the bench's id map of frame 0 stands in for the
  user's scribbles on the first frame (it gives the initial white balance);
* a few frames of the empty scene per camera (for the background model), rendered
  with the subject out of view under the lighting at the start of the take;
* the pose database (:mod:`simbench.pipelines.shirt_database`, cached);
* a colour model and IK covariances trained *ahead of time* on different takes:
  three short renders with the same cameras and camera settings, of other motions
  and seeds, under office, tungsten and daylight presets with the cameras
  white-balanced for each (:data:`TRAINING_TAKES`, :func:`train_shirt_pipeline`, cached).

It runs the full method and the baseline (no pose prior, no adaptive white balance)
on the same frames and scores both against the ground truth with :mod:`eval.shirt_metrics`.
"""

from __future__ import annotations

import hashlib
import json
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import pinocchio as pin

from eval import shirt_metrics
from mocap.shirt.classify import crop_image
from mocap.shirt.colour_model import NOT_SHIRT, ColourModel, train_colour_model, train_other_colours
from mocap.shirt.ik import IKPriors, train_priors
from mocap.shirt.pipeline import STAGES, ShirtPipelineParams, ShirtTracker, initial_white_balance
from mocap.shirt.pose_database import PoseDatabase
from mocap.shirt.shirt_model import UPPER_BODY_JOINTS, UPPER_NV, ShirtModel
from simbench.stage.build import build_stage
from simbench.stage.stage import Stage
from simbench.render import ids as idc
from simbench.render.frames import Pose, frame_rng
from simbench.scenario import Scenario
from simbench.pipelines.shirt_database import (PoseSampling, ProgressFactory, cache_dir, database_key, default_database_path,
                                               ensure_database)

__all__ = [
    "TRAINING_TAKES",
    "ShirtTraining",
    "colour_labels",
    "scribble_labels",
    "session_inputs",
    "render_empty_frames",
    "training_scenarios",
    "render_training_takes",
    "train_shirt_pipeline",
    "ensure_training",
    "ShirtRun",
    "track_sequence",
    "run_shirt_capture",
]

TRAINING_TAKES: tuple[tuple[str, float, int, str, float], ...] = (
    ("zigzag_fast", 1.2, 101, "office_fluorescent", 4100.0),
    ("swing_accelerating", 1.5, 102, "tungsten_lamp", 2800.0),
    ("walk_in_place", 1.2, 103, "daylight_outdoor", 6000.0),
)
"""Training takes: (procedural clip, start time in the clip (s), seed, lighting preset, the cameras'
white balance (K) for it).  Each take is white-balanced for its light, as the paper's five
labelled white-balanced images; three lights give the colour model the spread of a real shirt."""

_TRAINING_VERSION = 10


def colour_labels(id_map: np.ndarray, patch_colour: np.ndarray) -> np.ndarray:
    """Colour id per pixel ``(H, W)`` int16 from a bench id map (shirt patch ids), -1 elsewhere."""
    ids = np.asarray(id_map)
    patch = idc.shirt_patch(ids)
    pc = np.asarray(patch_colour)
    return np.where(patch >= 0, pc[np.clip(patch, 0, len(pc) - 1)], -1).astype(np.int16)


def scribble_labels(id_map: np.ndarray, patch_colour: np.ndarray, margin_px: int = 15) -> np.ndarray:
    """A user's labelling of the first frame, from the bench's id map.

    Shirt pixels get their colour id; the subject's other pixels (trousers, skin) and
    the set within ``margin_px`` of the subject get :data:`mocap.shirt.colour_model.NOT_SHIRT`;
    the rest stays unlabelled (-1).
    """
    ids = np.asarray(id_map)
    out = colour_labels(ids, patch_colour)
    subject = (ids == idc.BODY) | (out >= 0)
    near = cv2.dilate(subject.astype(np.uint8), cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * margin_px + 1,) * 2)) > 0
    out[(out < 0) & near] = NOT_SHIRT
    return out


def render_empty_frames(bench: Stage, n: int = 3) -> list[list[np.ndarray]]:
    """``n`` frames per camera of the empty scene (the subject moved far below the floor), lights as at the start."""
    fr = bench.frame_renderer()
    times = bench.scenario.frame_times()[:n]
    out: list[list[np.ndarray]] = [[] for _ in bench.cameras]
    for k, (t, pose) in enumerate(zip(times, bench.pose_at(times))):
        gone = Pose(pose.body_pos + np.array([0.0, 0.0, -100.0]), pose.body_rot, pose.marker_pos - np.array([0.0, 0.0, 100.0]),
                    pose.prop_T, pose.probe_points)
        fo = fr.render_frame(k, float(t), [gone], gone, frame_rng(bench.scenario.seed + 7919, k))
        for ci in range(len(bench.cameras)):
            out[ci].append(fo.images[ci])
    return out


def session_inputs(bench: Stage, frames: np.ndarray, gt, colours: ColourModel, patch_colour: np.ndarray):
    """What the user provides at the start of a session: ``W`` per camera and the not-shirt colours
    (from frame 0's labels), and frames of the empty scene."""
    labels = [scribble_labels(gt.id_maps[n][0], patch_colour) for n in gt.camera_names]
    W0 = [initial_white_balance(frames[0, ci], labels[ci], colours) for ci in range(len(labels))]
    rng = np.random.default_rng(np.random.SeedSequence([bench.scenario.seed, 0x07E]))
    other = train_other_colours([frames[0, ci] for ci in range(len(labels))], labels, W0, rng)
    return W0, other, render_empty_frames(bench)



@dataclass(frozen=True)
class ShirtSession:
    """Everything a shirt capture of one take starts from: the pose database, the trained
    colour model and IK priors, the exact calibration and the user's session inputs
    (see :func:`session_inputs`)."""

    db: PoseDatabase
    training: "ShirtTraining"
    calibration: object
    W0: list
    other: object
    empty: list

    def tracker(self, params: ShirtPipelineParams) -> ShirtTracker:
        """A fresh tracker of this session with ``params``."""
        t = self.training
        return ShirtTracker(self.db, t.colour_model, t.priors, self.calibration, self.W0, params, self.empty, self.other)


def start_session(bench: Stage, frames: np.ndarray, gt, echo=print,
                  progress_factory: ProgressFactory | None = None) -> ShirtSession:
    """Database and training (built or loaded from the cache) and the session inputs of a take;
    ``progress_factory`` shows a database build's progress."""
    cfg = bench.scenario.shirt_pipeline
    sampling = PoseSampling(n_poses=cfg.database_size)
    db = ensure_database(bench.params, sampling, cfg.database, echo=echo, progress_factory=progress_factory)
    db.meta.setdefault("key", database_key(bench.params, sampling))
    training = ensure_training(bench.scenario, db, cfg.training_frames, echo=echo)
    W0, other, empty = session_inputs(bench, frames, gt, training.colour_model, np.asarray(db.geometry.patch_colour))
    return ShirtSession(db, training, gt.calibration(), W0, other, empty)

# --------------------------------------------------------------------------- training
@dataclass(frozen=True)
class ShirtTraining:
    """What is trained ahead of time: the colour model and the IK covariances."""

    colour_model: ColourModel
    priors: IKPriors
    info: dict


def training_scenarios(scenario: Scenario, n_frames: int) -> list[Scenario]:
    """The training takes for a scored scenario: its cameras and camera settings, other lights, other motions."""
    per = max(2, int(np.ceil(n_frames / len(TRAINING_TAKES))))
    out = []
    for clip, start, seed, preset, wb_k in TRAINING_TAKES:
        data = scenario.model_dump(mode="python")
        data.update(name=f"shirt_training_{clip}", description="colour-shirt training take", seed=seed,
                    duration_s=per / scenario.fps, props=())
        data["motion"] = {"clip": clip, "start_s": start, "speed": 1.0}
        data["lighting"] = {"preset": preset, "scale": 1.0, "lights": (), "events": ()}
        data["sensor"] = dict(data["sensor"], white_balance="fixed", wb_cct_k=wb_k)
        data["source_dir"] = scenario.source_dir
        out.append(Scenario.model_validate(data))
    return out


def _motion_floor(fps: float) -> np.ndarray:
    """Least per-frame standard deviation of each tangent component of the motion prior.

    The training takes do not move every joint as fast as a person can (their root stays
    put, their arms swing in one plane), so the trained spread is floored at ordinary
    fast human motion: the root 1 m/s and 2 rad/s, the thorax 2 rad/s, shoulders and
    elbows 5 rad/s (a brisk arm swing).  Below these the prior towards the previous
    pose makes the estimate lag behind a fast stroke.
    """
    per_s = np.full(UPPER_NV, 5.0)
    per_s[:3] = 1.0
    per_s[3:9] = 2.0
    return per_s / fps


def _training_key(scenario: Scenario, db: PoseDatabase, n_frames: int) -> str:
    takes = [s.model_dump(mode="json") for s in training_scenarios(scenario, n_frames)]
    for t in takes:
        t.pop("name", None)
        t.pop("description", None)
        t.pop("shirt_pipeline", None)
    blob = json.dumps({"takes": takes, "db": db.meta.get("key", ""), "n_db": len(db), "v": _TRAINING_VERSION},
                      sort_keys=True, default=str).encode()
    return hashlib.sha256(blob).hexdigest()[:12]


def render_training_takes(scenario: Scenario, n_frames: int, echo=print) -> list:
    """Render the training takes: ``[(Stage, RenderedSequence)]``."""
    from simbench.stage.rendering import render_frames

    takes = []
    for sc in training_scenarios(scenario, n_frames):
        bench = build_stage(sc)
        t0 = time.perf_counter()
        seq = render_frames(bench, keep_frames=True, keep_ids=True)
        echo(f"shirt training: rendered {sc.name} ({seq.ground_truth.n_frames} frames) in {time.perf_counter() - t0:.0f} s")
        takes.append((bench, seq))
    return takes


def train_shirt_pipeline(scenario: Scenario, db: PoseDatabase, n_frames: int, echo=print, takes: list | None = None) -> ShirtTraining:
    """Render the training takes and train the colour model and the IK covariances on their ground truth.

    Colour model: Gaussians of the labelled (id-map) pixels of every training frame.
    Covariances (after Wang & Popovic): steps 1-3 of the pipeline run on each frame
    (white balance from the take's labelled first frame, then re-estimated under the
    *true* pose), and with ``q`` the true pose:
    ``Sigma_c`` from ``c*(q) - c``, ``Sigma_b`` from ``difference(q_b, q)``,
    ``Sigma_p`` from ``difference(q_prev, q)``.
    """
    model = ShirtModel(db.mjcf_text, db.geometry)
    pc = model.patch_colour
    if takes is None:
        takes = render_training_takes(scenario, n_frames, echo)
    images, labels = [], []
    for bench, seq in takes:
        gt = seq.ground_truth
        for k in range(gt.n_frames):
            for ci, name in enumerate(gt.camera_names):
                images.append(seq.frames[k, ci])
                labels.append(colour_labels(gt.id_maps[name][k], pc))
    colours = train_colour_model(images, labels, db.geometry.colour_names)
    P = model.n_patches
    provisional = IKPriors(np.repeat((np.eye(2) * 0.02**2)[None], P, 0), np.full(UPPER_NV, 1.0), np.full(UPPER_NV, 1.0))
    patches, residuals, blend, motion = [], [], [], []
    n_used = 0
    for bench, seq in takes:
        gt = seq.ground_truth
        cal = gt.calibration()
        W0, other, empty = session_inputs(bench, seq.frames, gt, colours, pc)
        tracker = ShirtTracker(db, colours, provisional, cal, W0, ShirtPipelineParams(), empty, other)
        q_true = tracker.kin.from_full_qpos(gt.qpos)
        for k in range(gt.n_frames):
            est, cons, lin = tracker.observe([seq.frames[k, ci] for ci in range(len(cal))])
            if k > 0:
                motion.append(pin.difference(tracker.kin.model, q_true[k - 1], q_true[k]))
            if np.all(np.isfinite(est.q_blend)):
                blend.append(pin.difference(tracker.kin.model, est.q_blend, q_true[k]))
                n_used += 1
                if len(cons):
                    c, _ = tracker.ik.centroids(q_true[k], cons)
                    residuals.append((c - cons.target_px) / cons.size_px[:, None])
                    patches.append(cons.patch)
            tracker.finish(q_true[k], est.cameras, lin)
    if not residuals:
        from simbench.errors import SimbenchInputError

        raise SimbenchInputError("shirt training: the pipeline found the shirt in no training frame; check the cameras see the subject")
    priors = train_priors(np.concatenate(patches), np.concatenate(residuals), np.array(blend), np.array(motion), P, n_used,
                          floor_std=_motion_floor(scenario.fps))
    info = {"takes": [s.name for s in training_scenarios(scenario, n_frames)], "frames": int(sum(s.ground_truth.n_frames for _, s in takes)),
            "frames_with_blend": n_used, "centroid_residuals": int(sum(len(p) for p in patches))}
    return ShirtTraining(colours, priors, info)


def ensure_training(scenario: Scenario, db: PoseDatabase, n_frames: int, echo=print) -> ShirtTraining:
    """The cached training for this scenario's rig (trained and cached when missing)."""
    path = cache_dir() / f"shirt_training_{_training_key(scenario, db, n_frames)}.npz"
    if path.is_file():
        with np.load(path, allow_pickle=False) as z:
            cm = ColourModel(z["means"], z["covariances"], tuple(str(s) for s in z["names"]))
            pr = IKPriors(z["centroid_cov"], z["blend_std"], z["motion_std"], int(z["n_frames"]))
            return ShirtTraining(cm, pr, json.loads(str(z["info"])))
    echo(f"shirt training {path.name} missing: training on {n_frames} frames of other takes")
    tr = train_shirt_pipeline(scenario, db, n_frames, echo)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".partial.npz")
    np.savez(tmp, means=tr.colour_model.means, covariances=tr.colour_model.covariances, names=np.array(tr.colour_model.names),
             centroid_cov=tr.priors.centroid_cov, blend_std=tr.priors.blend_std, motion_std=tr.priors.motion_std,
             n_frames=np.array(tr.priors.n_frames), info=np.array(json.dumps(tr.info)))
    tmp.replace(path)
    return tr


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


def _plots(out: Path, times: np.ndarray, gt_angle: np.ndarray, full_angle: np.ndarray, base_angle: np.ndarray,
           roc: dict | None, err_full: np.ndarray, err_base: np.ndarray, title: str) -> list[str]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figs = out / "plots"
    figs.mkdir(parents=True, exist_ok=True)
    names = []
    fig, (ax0, ax1) = plt.subplots(2, 1, figsize=(9, 6), sharex=True)
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
    plt.close(fig)
    names.append("plots/shirt_shoulder_angle.png")
    if roc is not None and roc["truth"].size:
        th = np.linspace(0.0, 12.0, 61)
        fig, ax = plt.subplots(figsize=(6, 5))
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
        plt.close(fig)
        names.append("plots/shirt_roc.png")
    return names


def run_shirt_capture(bench: Stage, frames: np.ndarray, gt, out_dir: Path | None, echo=print,
                      progress_factory: ProgressFactory | None = None) -> tuple[dict, list[str]]:
    """The hook of ``simbench run``: full method and baseline on the same frames, scored.

    Parameters
    ----------
    bench : Stage
    frames : (F, C, H, W, 3) uint8 RGB
    gt : simbench.stage.ground_truth.GroundTruth
        With id maps (only frame 0's are given to the pipeline, as the user's scribbles).
    out_dir : Path or None
        Where plots (``plots/``) and the estimated poses (``shirt/``) go.

    Returns
    -------
    metrics : dict
        ``shirt.*`` numbers.
    report_lines : list[str]
        A Markdown section for the run report.
    """
    sc = bench.scenario
    cfg = sc.shirt_pipeline
    session = start_session(bench, frames, gt, echo=echo, progress_factory=progress_factory)
    db, training = session.db, session.training
    model = ShirtModel(db.mjcf_text, db.geometry)
    pc = model.patch_colour
    truth_labels = [colour_labels(gt.id_maps[n], pc) for n in gt.camera_names]
    params = ShirtPipelineParams(keep_classification=True)
    runs: dict[str, ShirtRun] = {}
    for name, p in (("full", params), ("baseline", params.baseline())):
        if name == "baseline" and not cfg.baseline:
            continue
        tracker = session.tracker(p)
        runs[name] = track_sequence(tracker, frames, truth_labels if name == "full" else None)

    # ------------------------------------------------------------------ scoring
    jidx = [gt.joint_names.index(b) for b in UPPER_BODY_JOINTS]
    true_j = gt.joint_centres[:, jidx]
    q_true = model.kin.from_full_qpos(gt.qpos)
    true_v = model.shirt_vertices(q_true)
    true_angle = shirt_metrics.shoulder_angle_deg(true_j, UPPER_BODY_JOINTS)
    metrics: dict[str, float] = {"shirt.database_poses": len(db), "shirt.training_frames": training.info.get("frames", 0)}
    per: dict[str, dict] = {}
    for name, r in runs.items():
        q = shirt_metrics.fill_forward(r.q)
        est_j = model.kin.joint_centres(q)
        est_v = model.shirt_vertices(q)
        blend_j = model.kin.joint_centres(shirt_metrics.fill_forward(r.q_blend))
        prefix = "shirt." if name == "full" else "shirt.baseline_"
        angle = shirt_metrics.shoulder_angle_deg(est_j, UPPER_BODY_JOINTS)
        d_ang = angle - true_angle
        per[name] = {"angle": angle, "err": shirt_metrics.per_frame_rms_cm(est_j, true_j)}
        metrics[prefix + "joint_rmse_cm"] = shirt_metrics.rmse_cm(est_j, true_j)
        metrics[prefix + "vertex_rmse_cm"] = shirt_metrics.rmse_cm(est_v, true_v)
        metrics[prefix + "blend_joint_rmse_cm"] = shirt_metrics.rmse_cm(blend_j, true_j)
        metrics[prefix + "classified_fraction"] = float(np.mean(r.classified_fraction))
        metrics[prefix + "tracked_fraction"] = float(np.mean(np.all(np.isfinite(r.q), axis=1)))
        metrics[prefix + "shoulder_angle_rmse_deg"] = float(np.sqrt(np.nanmean(d_ang**2)))
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

    # ------------------------------------------------------------------ outputs and report
    lines = ["## Colour shirt (seed 001)", "",
             f"Pose database: {len(db)} poses; colour model and IK covariances trained on {training.info.get('frames', 0)} frames of "
             f"other takes ({', '.join(training.info.get('takes', []))}: same cameras, other motions, office/tungsten/daylight light with "
             "white-balanced cameras). "
             "The pipeline was given the calibration, frame 0's id map as the user's scribbles (shirt colours, and not-shirt for the subject's other pixels and the set next to them), and 3 frames of the empty scene.", "",
             "| | full method | baseline (no pose prior, fixed white balance) |", "|---|---|---|"]
    for key, label in (("joint_rmse_cm", "upper-body joint RMS (cm)"), ("vertex_rmse_cm", "shirt vertex RMS (cm)"),
                       ("blend_joint_rmse_cm", "database blend alone, joint RMS (cm)"),
                       ("shoulder_angle_rmse_deg", "shoulder angle RMS (deg)"), ("classified_fraction", "classified fraction of foreground"),
                       ("tracked_fraction", "frames tracked"), ("ms_per_frame", "ms per frame (all cameras)")):
        b = metrics.get("shirt.baseline_" + key, float("nan"))
        lines.append(f"| {label} | {metrics['shirt.' + key]:.3g} | {b:.3g} |")
    lines += ["", "| stage | ms per frame |", "|---|---|"] + [f"| {s} | {metrics[f'shirt.ms.{s}']:.1f} |" for s in STAGES] + [""]
    if out_dir is not None:
        out = Path(out_dir)
        base = runs.get("baseline")
        pics = _plots(out, gt.times, true_angle, per["full"]["angle"],
                      per["baseline"]["angle"] if base is not None else np.full_like(true_angle, np.nan), full.roc,
                      per["full"]["err"], per["baseline"]["err"] if base is not None else np.full(len(true_angle), np.nan), sc.name)
        lines += [f"![{Path(p).stem}]({p})" for p in pics] + [""]
        (out / "shirt").mkdir(parents=True, exist_ok=True)
        np.savez(out / "shirt" / "poses.npz", times=gt.times, joint_names=np.array(UPPER_BODY_JOINTS),
                 **{f"{n}_q": r.q for n, r in runs.items()}, **{f"{n}_qpos": model.kin.to_full_qpos(r.q) for n, r in runs.items()},
                 **{f"{n}_joint_centres_m": model.kin.joint_centres(r.q) for n, r in runs.items()})
        # what `mocap shirt` needs to run on this take's videos: colour model, covariances, scribbles
        training.colour_model.save(out / "shirt" / "colour_model.npz")
        training.priors.save(out / "shirt" / "ik_priors.npz")
        for ci, name in enumerate(gt.camera_names):
            lab = scribble_labels(gt.id_maps[name][0], pc)
            png = np.where(lab >= 0, lab + 1, np.where(lab == NOT_SHIRT, 255, 0)).astype(np.uint8)
            cv2.imwrite(str(out / "shirt" / f"scribbles_{name}.png"), png)
        from simbench.render.video import Mp4Writer

        for ci, name in enumerate(gt.camera_names):
            w = Mp4Writer(out / "shirt" / f"empty_{name}.mp4", frames.shape[3], frames.shape[2], sc.fps)
            for f in session.empty[ci]:
                w.write(f)
            w.close()
        (out / "shirt" / "database.txt").write_text(str(cfg.database or default_database_path(bench.params, PoseSampling(n_poses=cfg.database_size))) + "\n")
        lines += ["Estimated poses: `shirt/poses.npz` (upper-body q, MuJoCo qpos with the other hinges at zero, joint centres). "
                  "For `mocap shirt` on `videos/*.mp4`: `shirt/colour_model.npz`, `shirt/ik_priors.npz`, "
                  "`shirt/scribbles_<camera>.png` (frame 0), `shirt/empty_<camera>.mp4` (the empty scene) and the database named "
                  "in `shirt/database.txt`.", ""]
    return metrics, lines
