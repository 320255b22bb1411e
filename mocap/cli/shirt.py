"""``mocap shirt``: the colour-shirt pipeline of seed 001 on video files from real webcams.

Inputs are what a user with webcams has: one video per camera (synchronised), their
calibration, the pose database (``simbench shirt build-db``, or one made for the
user's body), the colour model and IK covariances trained ahead of time, and one
labelled frame per camera (scribbles).

Scribble files are 8-bit PNGs of the video's frame size: 0 unlabelled, ``k + 1`` for
shirt colour ``k`` (the database's colour order), 255 for *not shirt* (trousers,
skin, background next to the subject).  Optional empty-scene videos prime the
background model.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Optional

import cv2
import numpy as np
import typer

from mocap.calibration import Calibration
from mocap.cli.common import console, order_videos_by_camera
from mocap.errors import InputFileError

__all__ = ["shirt", "load_scribbles"]


def load_scribbles(path: Path, size: tuple[int, int], n_colours: int) -> np.ndarray:
    """Labels ``(H, W)`` int16 from a scribble PNG: colour ids, -1 unlabelled, ``NOT_SHIRT`` for 255."""
    from mocap.shirt.colour_model import NOT_SHIRT  # the shirt pipeline (faiss, Pinocchio) loads on use

    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise InputFileError(path, "cannot read the scribble image", "give an 8-bit PNG (0 unlabelled, k+1 colour k, 255 not shirt)")
    if img.ndim == 3:
        img = img[..., 0]
    if (img.shape[1], img.shape[0]) != tuple(size):
        raise InputFileError(path, f"size {img.shape[1]}x{img.shape[0]} differs from the video's {size[0]}x{size[1]}",
                             "draw the scribbles on the video's frame")
    bad = (img > n_colours) & (img != 255)
    if bad.any():
        raise InputFileError(path, f"values {sorted(set(np.unique(img[bad]).tolist()))[:5]} are not labels",
                             f"use 0 (unlabelled), 1..{n_colours} (shirt colours) or 255 (not shirt)")
    out = img.astype(np.int16) - 1
    out[img == 255] = NOT_SHIRT
    return out


def _read_frames(path: Path, start: int, count: int | None) -> list[np.ndarray]:
    """RGB frames ``(H, W, 3)`` uint8 of a video from frame ``start`` (at most ``count``)."""
    if not path.is_file():
        raise InputFileError(path, "file not found", "pass the path of a video file (e.g. an MP4 written by `simbench render`)")
    cap = cv2.VideoCapture(str(path))
    if not cap.isOpened():
        raise InputFileError(path, "cannot be opened as a video", "check that it is a video OpenCV/FFmpeg can decode (e.g. MP4 H.264)")
    frames: list[np.ndarray] = []
    i = 0
    try:
        while count is None or len(frames) < count:
            ok, frame = cap.read()
            if not ok:
                break
            if i >= start:
                if frame.ndim != 3:
                    raise InputFileError(path, "frames are not colour images", "the shirt pipeline needs colour video")
                frames.append(np.ascontiguousarray(frame[..., ::-1]))
            i += 1
    finally:
        cap.release()
    return frames


def shirt(
    videos: list[Path] = typer.Argument(..., help="one video per camera (synchronised)"),
    calibration: Path = typer.Option(..., "--calibration", help="OpenCV YAML or anipose TOML"),
    database: Path = typer.Option(..., "--database", help="pose database (.npz from `simbench shirt build-db`)"),
    colour_model: Path = typer.Option(..., "--colour-model", help="colour model (.npz, ColourModel.save)"),
    priors: Path = typer.Option(..., "--priors", help="IK covariances (.npz, IKPriors.save)"),
    scribbles: list[Path] = typer.Option(..., "--scribbles", help="one label PNG per camera for the init frame"),
    out: Path = typer.Option(..., "--out", help="output directory"),
    init_frame: int = typer.Option(0, "--init-frame", help="frame the scribbles label; tracking starts there"),
    frames: Optional[int] = typer.Option(None, "--frames", help="number of frames to track (default: all)"),
    empty: list[Path] = typer.Option([], "--empty", help="videos of the empty scene, one per camera (background model)"),
    baseline: bool = typer.Option(False, "--baseline", help="run the baseline (no pose prior, fixed white balance)"),
    fps: Optional[float] = typer.Option(None, "--fps", help="frame rate (default: read from the first video)"),
    seed: int = typer.Option(0, "--seed", help="seed of the not-shirt colour clustering"),
) -> None:
    """Track the upper body of a subject wearing the colour shirt; write poses and joint centres."""
    # the shirt pipeline (faiss, Pinocchio) loads when the command runs: `mocap --help` stays quick
    from mocap.shirt.colour_model import ColourModel, train_other_colours
    from mocap.shirt.ik import IKPriors
    from mocap.shirt.pipeline import STAGES, ShirtPipelineParams, ShirtTracker, initial_white_balance
    from mocap.shirt.pose_database import PoseDatabase
    from mocap.shirt.kinematics import UPPER_BODY_JOINTS

    cal = Calibration.load(calibration)
    paths = order_videos_by_camera(list(videos), cal.names)
    if len(scribbles) != len(paths):
        raise InputFileError(scribbles[0] if scribbles else Path("--scribbles"), f"{len(scribbles)} scribble files for {len(paths)} cameras",
                             "give one --scribbles PNG per camera, in calibration order")
    if empty and len(empty) != len(paths):
        raise InputFileError(empty[0], f"{len(empty)} empty-scene videos for {len(paths)} cameras", "give one --empty video per camera or none")
    db = PoseDatabase.load(database)
    cm = ColourModel.load(colour_model)
    pr = IKPriors.load(priors)
    if fps is None:
        cap = cv2.VideoCapture(str(paths[0]))
        fps = cap.get(cv2.CAP_PROP_FPS) or 30.0
        cap.release()
    seqs = [_read_frames(p, init_frame, frames) for p in paths]
    n = min(len(s) for s in seqs)
    if n == 0:
        raise InputFileError(paths[0], f"no frames from --init-frame {init_frame}", "check the videos and --init-frame")
    labels = [load_scribbles(sp, cal[ci].size, db.n_colours) for ci, sp in enumerate(scribbles)]
    W0 = [initial_white_balance(seqs[ci][0], labels[ci], cm) for ci in range(len(paths))]
    other = train_other_colours([s[0] for s in seqs], labels, W0, np.random.default_rng(seed))
    empty_frames = [_read_frames(p, 0, 5) for p in empty] if empty else None
    # without frames of the empty scene a background model would learn the subject: none then
    params = ShirtPipelineParams() if empty_frames is not None else ShirtPipelineParams(background=None)
    tracker = ShirtTracker(db, cm, pr, cal, W0, params.baseline() if baseline else params, empty_frames, other)
    q = np.full((n, tracker.kin.nq), np.nan)
    timings = np.zeros((n, len(STAGES)))
    for k in range(n):
        est = tracker.process([s[k] for s in seqs])
        q[k] = est.q
        timings[k] = [est.timings_ms[s] for s in STAGES]
    out.mkdir(parents=True, exist_ok=True)
    times = (init_frame + np.arange(n)) / fps
    jc = tracker.kin.joint_centres(q)
    np.savez(out / "poses.npz", times=times, q=q, qpos=tracker.kin.to_full_qpos(q), joint_centres_m=jc,
             joint_names=np.array(UPPER_BODY_JOINTS))
    header = "time_s," + ",".join(f"{j}_{a}" for j in UPPER_BODY_JOINTS for a in "xyz")
    np.savetxt(out / "joint_centres.csv", np.column_stack([times, jc.reshape(n, -1)]), delimiter=",", header=header, comments="", fmt="%.6f")
    summary = {"frames": n, "tracked_fraction": float(np.mean(np.all(np.isfinite(q), axis=1))),
               "method": "baseline" if baseline else "full", "ms_per_frame": {s: round(float(v), 2) for s, v in zip(STAGES, timings.mean(axis=0))},
               "files": ["poses.npz", "joint_centres.csv"]}
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    console.print(f"{n} frames, tracked {summary['tracked_fraction']:.3f}, {timings.sum(axis=1).mean():.1f} ms per frame; wrote {out}/")
