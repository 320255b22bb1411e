"""The colour-shirt pipeline's training, done ahead of time on other takes (seed 001's
labelled white-balanced images): the colour model and the IK covariances, cached.

Three short renders with the scored scenario's cameras and camera settings, of other
motions and seeds, under office, tungsten and daylight presets with the cameras
white-balanced for each (:data:`TRAINING_TAKES`); :func:`ensure_training` trains them
when the cache has no training for this rig.
"""

from __future__ import annotations

import hashlib
import json
import logging
import time
import zipfile
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pinocchio as pin

from mocap.atomic_files import atomic_target
from mocap.shirt.colour_model import ColourModel, train_colour_model
from mocap.shirt.ik import IKPriors, train_priors
from mocap.shirt.pipeline import ShirtPipelineParams, ShirtTracker
from mocap.shirt.pose_database import PoseDatabase
from mocap.shirt.kinematics import UPPER_NV
from mocap.shirt.shirt_model import ShirtModel
from simbench.errors import SimbenchInputError
from simbench.pipelines.shirt_database import cache_dir, read_or_build
from simbench.pipelines.shirt_inputs import colour_labels, session_inputs
from simbench.scenario import Scenario
from simbench.stage.build import build_stage
from simbench.stage.rendering import RenderedSequence, render_frames
from simbench.stage.stage import Stage

__all__ = ["TRAINING_TAKES", "ShirtTraining", "training_scenarios", "render_training_takes", "train_shirt_pipeline",
           "ensure_training"]

log = logging.getLogger(__name__)

TRAINING_TAKES: tuple[tuple[str, float, int, str, float], ...] = (
    ("zigzag_fast", 1.2, 101, "office_fluorescent", 4100.0),
    ("swing_accelerating", 1.5, 102, "tungsten_lamp", 2800.0),
    ("walk_in_place", 1.2, 103, "daylight_outdoor", 6000.0),
)
"""Training takes: (procedural clip, start time in the clip (s), seed, lighting preset, the cameras'
white balance (K) for it).  Each take is white-balanced for its light, as the paper's five
labelled white-balanced images; three lights give the colour model the spread of a real shirt."""

_TRAINING_VERSION = 10


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


def render_training_takes(scenario: Scenario, n_frames: int) -> list[tuple[Stage, RenderedSequence]]:
    """Render the training takes: ``[(Stage, RenderedSequence)]``."""
    takes = []
    for sc in training_scenarios(scenario, n_frames):
        bench = build_stage(sc)
        t0 = time.perf_counter()
        seq = render_frames(bench, keep_frames=True, keep_ids=True)
        log.info("shirt training: rendered %s (%d frames) in %.0f s", sc.name, seq.ground_truth.n_frames, time.perf_counter() - t0)
        takes.append((bench, seq))
    return takes


def train_shirt_pipeline(scenario: Scenario, db: PoseDatabase, n_frames: int,
                         takes: list[tuple[Stage, RenderedSequence]] | None = None) -> ShirtTraining:
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
        takes = render_training_takes(scenario, n_frames)
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
        raise SimbenchInputError("shirt training: the pipeline found the shirt in no training frame; check the cameras see the subject")
    priors = train_priors(np.concatenate(patches), np.concatenate(residuals), np.array(blend), np.array(motion), P, n_used,
                          floor_std=_motion_floor(scenario.fps))
    info = {"takes": [s.name for s in training_scenarios(scenario, n_frames)], "frames": int(sum(s.ground_truth.n_frames for _, s in takes)),
            "frames_with_blend": n_used, "centroid_residuals": int(sum(len(p) for p in patches))}
    return ShirtTraining(colours, priors, info)


def ensure_training(scenario: Scenario, db: PoseDatabase, n_frames: int) -> ShirtTraining:
    """The cached training for this scenario's rig (trained and cached when missing or unreadable; processes that
    want it at once train once, :func:`~simbench.pipelines.shirt_database.cache_lock`)."""
    path = cache_dir() / f"shirt_training_{_training_key(scenario, db, n_frames)}.npz"

    def train() -> ShirtTraining:
        log.info("shirt training %s missing: training on %d frames of other takes", path.name, n_frames)
        tr = train_shirt_pipeline(scenario, db, n_frames)
        path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_target(path, ".npz") as tmp:
            np.savez(tmp, means=tr.colour_model.means, covariances=tr.colour_model.covariances, names=np.array(tr.colour_model.names),
                     centroid_cov=tr.priors.centroid_cov, blend_std=tr.priors.blend_std, motion_std=tr.priors.motion_std,
                     n_frames=np.array(tr.priors.n_frames), info=np.array(json.dumps(tr.info)))
        return tr

    return read_or_build(path, _read_training, train)


def _read_training(path: Path) -> ShirtTraining | None:
    """The cached training at ``path``; None, said once, when it cannot be read."""
    try:
        with np.load(path, allow_pickle=False) as z:
            cm = ColourModel(z["means"], z["covariances"], tuple(str(s) for s in z["names"]))
            pr = IKPriors(z["centroid_cov"], z["blend_std"], z["motion_std"], int(z["n_frames"]))
            return ShirtTraining(cm, pr, json.loads(str(z["info"])))
    except (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile, zlib.error) as exc:
        log.warning("the cached shirt training %s cannot be read (%s: %s): training again", path, type(exc).__name__, exc)
        return None
