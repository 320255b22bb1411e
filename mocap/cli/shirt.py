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
from contextlib import ExitStack, closing
from pathlib import Path
from typing import Iterator, Optional

import cv2
import numpy as np
import typer

from mocap.calibration import Calibration
from mocap.cli.common import (atomic_output_dir, check_videos_against_calibration, console, order_by_camera_name,
                              order_videos_by_camera, probe_video)
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


def _iter_rgb_frames(path: Path, start: int = 0, count: int | None = None) -> Iterator[np.ndarray]:
    """RGB frames ``(H, W, 3)`` uint8 of a video from frame ``start`` (at most ``count``), one at a time:
    a take of any length is tracked in the memory of a few frames."""
    if not path.is_file():
        raise InputFileError(path, "file not found", "pass the path of a video file (e.g. an MP4 written by `simbench render`)")
    cap = cv2.VideoCapture(str(path))
    if not cap.isOpened():
        raise InputFileError(path, "cannot be opened as a video", "check that it is a video OpenCV/FFmpeg can decode (e.g. MP4 H.264)")
    i = n = 0
    try:
        while count is None or n < count:
            ok, frame = cap.read()
            if not ok:
                break
            if i >= start:
                if frame.ndim != 3:
                    raise InputFileError(path, "frames are not colour images", "the shirt pipeline needs colour video")
                yield np.ascontiguousarray(frame[..., ::-1])
                n += 1
            i += 1
    finally:
        cap.release()


def shirt(
    videos: list[Path] = typer.Argument(..., help="one video per camera (synchronised)"),
    calibration: Path = typer.Option(..., "--calibration", help="OpenCV YAML or anipose TOML"),
    database: Path = typer.Option(..., "--database", help="pose database (.npz from `simbench shirt build-db`)"),
    colour_model: Path = typer.Option(..., "--colour-model", help="colour model (.npz, ColourModel.save)"),
    priors: Path = typer.Option(..., "--priors", help="IK covariances (.npz, IKPriors.save)"),
    scribbles: list[Path] = typer.Option(..., "--scribbles", help="one label PNG per camera for the init frame, "
                                         "matched to the cameras by a word of its name (scribbles_left.png: camera left), "
                                         "else in calibration order; repeat the option: --scribbles A.png --scribbles B.png"),
    out: Path = typer.Option(..., "--out", help="output directory"),
    init_frame: int = typer.Option(0, "--init-frame", help="frame the scribbles label; tracking starts there"),
    frames: Optional[int] = typer.Option(None, "--frames", help="number of frames to track (default: all)"),
    empty: list[Path] = typer.Option([], "--empty", help="videos of the empty scene, one per camera (background model), "
                                     "matched as --scribbles; repeat the option: --empty A.mp4 --empty B.mp4"),
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

    from rich.progress import track

    cal = Calibration.load(calibration)
    paths = order_videos_by_camera(list(videos), cal.names, ("--scribbles", "--empty"))
    n_todo, fps = _check_inputs(paths, cal, scribbles, empty, init_frame, frames, fps)
    scribbles, empty = order_by_camera_name(scribbles, cal.names), order_by_camera_name(empty, cal.names) if empty else empty
    db = PoseDatabase.load(database)
    cm = ColourModel.load(colour_model)
    pr = IKPriors.load(priors)
    labels = [load_scribbles(sp, cal[ci].size, db.n_colours) for ci, sp in enumerate(scribbles)]
    empty_frames = [list(_iter_rgb_frames(p, 0, 5)) for p in empty] if empty else None
    # without frames of the empty scene a background model would learn the subject: none then
    params = ShirtPipelineParams() if empty_frames is not None else ShirtPipelineParams(background=None)
    q_rows, timing_rows = [], []
    tracker = None
    with atomic_output_dir(out) as tmp, ExitStack() as videos_open:
        # the cameras' frames in step, one frame at a time (a take of any length: the memory of a few frames)
        streams = [videos_open.enter_context(closing(_iter_rgb_frames(p, init_frame, frames))) for p in paths]
        for images in track(zip(*streams), total=n_todo, description="tracking", console=console, transient=True):
            if tracker is None:  # the scribbled frame: white balance and the not-shirt colours
                W0 = [initial_white_balance(images[ci], labels[ci], cm) for ci in range(len(paths))]
                other = train_other_colours(list(images), labels, W0, np.random.default_rng(seed))
                tracker = ShirtTracker(db, cm, pr, cal, W0, params.baseline() if baseline else params, empty_frames, other)
            est = tracker.process(list(images))
            q_rows.append(est.q)
            timing_rows.append([est.timings_ms[s] for s in STAGES])
        if tracker is None:
            raise InputFileError(paths[0], f"no frames from --init-frame {init_frame}", "check the videos and --init-frame")
        n = len(q_rows)
        q, timings = np.array(q_rows), np.array(timing_rows)
        times = (init_frame + np.arange(n)) / fps
        jc = tracker.kin.joint_centres(q)
        np.savez(tmp / "poses.npz", times=times, q=q, qpos=tracker.kin.to_full_qpos(q), joint_centres_m=jc,
                 joint_names=np.array(UPPER_BODY_JOINTS))
        header = "time_s," + ",".join(f"{j}_{a}" for j in UPPER_BODY_JOINTS for a in "xyz")
        np.savetxt(tmp / "joint_centres.csv", np.column_stack([times, jc.reshape(n, -1)]), delimiter=",", header=header, comments="",
                   fmt="%.6f")
        summary = {"frames": n, "tracked_fraction": float(np.mean(np.all(np.isfinite(q), axis=1))),
                   "method": "baseline" if baseline else "full",
                   "ms_per_frame": {s: round(float(v), 2) for s, v in zip(STAGES, timings.mean(axis=0))},
                   "files": ["poses.npz", "joint_centres.csv"]}
        (tmp / "summary.json").write_text(json.dumps(summary, indent=2))
    console.print(f"{n} frames, tracked {summary['tracked_fraction']:.3f}, {timings.sum(axis=1).mean():.1f} ms per frame; wrote {out}/",
                  markup=False)


def _check_inputs(paths: list[Path], cal: Calibration, scribbles: list[Path], empty: list[Path], init_frame: int,
                  frames: int | None, fps: float | None) -> tuple[int, float]:
    """Refuse, before any work, inputs that do not fit together (one line naming the file or option); the number
    of frames to track and the frame rate (Hz)."""
    if len(scribbles) != len(paths):
        raise InputFileError(scribbles[0] if scribbles else Path("--scribbles"), f"{len(scribbles)} scribble files for {len(paths)} cameras",
                             "give one --scribbles PNG per camera (named after it, or in calibration order)")
    if empty and len(empty) != len(paths):
        raise InputFileError(empty[0], f"{len(empty)} empty-scene videos for {len(paths)} cameras", "give one --empty video per camera or none")
    probes = [probe_video(p) for p in paths]
    check_videos_against_calibration(paths, probes, cal)
    if not 0 <= init_frame < probes[0].frames:
        raise InputFileError(Path("--init-frame"), f"value {init_frame} (the videos hold {probes[0].frames} frames)",
                             "give the index of the frame the scribbles label, 0 to the last frame")
    if frames is not None and frames < 1:
        raise InputFileError(Path("--frames"), f"value {frames}", "give the number of frames to track, 1 or more (or leave it out: all)")
    n_todo = probes[0].frames - init_frame if frames is None else min(frames, probes[0].frames - init_frame)
    if fps is None:
        fps = probes[0].fps if probes[0].fps > 0 else 30.0
    elif not (np.isfinite(fps) and fps > 0):
        raise InputFileError(Path("--fps"), f"value {fps!r}", "give the frame rate in Hz, a number > 0")
    return n_todo, float(fps)
