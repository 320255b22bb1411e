"""What the ``mocap`` commands share: the error policy (one line, exit code 2), matching
video files to calibrated cameras and checking them against each other, and atomic output
folders that never replace what the command did not write."""

from __future__ import annotations

import contextlib
import functools
import json
import os
import re
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path

import cv2
import typer
from rich.console import Console

from mocap.errors import InputFileError, MocapInputError

console = Console(stderr=True)


def exit_on_user_errors(*errors: type[Exception], console: Console = console):
    """A decorator turning the user-caused ``errors`` of a command into one line on
    ``console`` and exit code 2 (no traceback: the message names the file, field and fix)."""

    def decorate(fn):
        @functools.wraps(fn)
        def wrapper(*args, **kwargs):
            try:
                return fn(*args, **kwargs)
            except errors as exc:
                # The message is printed as text, not rich markup: "[[lighting.lights]]" or a
                # path with brackets must reach the user intact.
                console.print("[bold red]error:[/] ", end="", highlight=False)
                console.print(str(exc), markup=False, highlight=False, soft_wrap=True)
                raise typer.Exit(2)

        return wrapper

    return decorate


user_errors = exit_on_user_errors(MocapInputError)


def order_videos_by_camera(videos: list[Path], camera_names: list[str], per_camera_options: tuple[str, ...] = ()) -> list[Path]:
    """Match video files to calibration cameras by file stem (``cam0.mp4`` -> ``cam0``), else by order.

    ``per_camera_options``: the command's options that take a file per camera; with more videos than
    cameras the error says to repeat them (a second file after ``--scribbles A.png`` is read as a video)."""
    repeat = ""
    if per_camera_options and len(videos) > len(camera_names):
        repeat = (f"; give {' and '.join(per_camera_options)} once per file ({per_camera_options[0]} A --{per_camera_options[0].lstrip('-')}"
                  " B): a file after the first is read as a video")
    stems = {v.stem: v for v in videos}
    if all(n in stems for n in camera_names):
        extra = [v for v in videos if v.stem not in camera_names]
        if extra or len(videos) != len(camera_names):
            raise InputFileError(extra[0] if extra else videos[0], f"{len(videos)} videos for {len(camera_names)} calibrated cameras "
                                 f"{camera_names}" + (f"; {extra[0].name} is none of them" if extra else ", some twice"),
                                 "pass one video per calibrated camera" + repeat)
        return [stems[n] for n in camera_names]
    if len(videos) != len(camera_names):
        raise InputFileError(videos[0] if videos else Path("."), f"{len(videos)} videos for {len(camera_names)} calibrated cameras {camera_names}",
                             "pass one video per camera, named after the camera (e.g. cam0.mp4) or in calibration order" + repeat)
    return list(videos)


def order_by_camera_name(files: list[Path], camera_names: list[str]) -> list[Path]:
    """``files`` (one per camera) in calibration order where each camera's name is a word of exactly one file's
    stem (``scribbles_left.png`` -> camera ``left``; words split at anything but letters and digits), else as
    given: the calibration's order. Why: a per-camera input given in another order than the calibration's
    would be used for the wrong camera without a word said."""
    def words(path: Path) -> set[str]:
        return set(re.split(r"[^A-Za-z0-9]+", path.stem))

    owners = {n: [f for f in files if n in words(f)] for n in camera_names}
    if len(files) == len(camera_names) and all(len(v) == 1 for v in owners.values()) \
            and len({v[0] for v in owners.values()}) == len(files):
        return [owners[n][0] for n in camera_names]
    return list(files)


@dataclass(frozen=True)
class VideoProbe:
    """What a video file says of itself: frame count, frame size (pixels) and rate (Hz)."""

    frames: int
    width: int
    height: int
    fps: float


def probe_video(path: Path) -> VideoProbe:
    """Open ``path`` and read its frame count, size and rate; one clear error if it cannot be read."""
    if not Path(path).is_file():
        raise InputFileError(path, "file not found", "give one video per camera")
    cap = cv2.VideoCapture(str(path))
    try:
        if not cap.isOpened():
            raise InputFileError(path, "cannot be opened as a video", "give a video file OpenCV reads (MP4, AVI, MKV)")
        probe = VideoProbe(int(cap.get(cv2.CAP_PROP_FRAME_COUNT)), int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)),
                           int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT)), float(cap.get(cv2.CAP_PROP_FPS)))
    finally:
        cap.release()
    if probe.frames <= 0 or probe.width <= 0 or probe.height <= 0:
        raise InputFileError(path, f"holds no readable frame ({probe.frames} frames, {probe.width}x{probe.height})",
                             "give a video with at least one frame")
    return probe


def check_videos_against_calibration(paths: list[Path], probes: list[VideoProbe], calibration) -> None:
    """Every video has its camera's calibrated size, and all have the same number of frames and rate.

    A video at another size than its calibration would be measured with the wrong camera
    model; videos of unequal length are not one synchronised take. Both are refused rather
    than silently cut or rescaled."""
    for path, probe, cam in zip(paths, probes, calibration):
        if (probe.width, probe.height) != tuple(cam.size):
            raise InputFileError(path, f"frames are {probe.width}x{probe.height} but camera {cam.name!r} was calibrated at "
                                 f"{cam.size[0]}x{cam.size[1]}", "give the videos of the cameras this calibration describes, at their full size")
    counts = {p.name: pr.frames for p, pr in zip(paths, probes)}
    if len(set(counts.values())) > 1:
        listed = ", ".join(f"{k} {v}" for k, v in counts.items())
        raise InputFileError(paths[0], f"the videos differ in length ({listed} frames)",
                             "trim them to the same synchronised span before capture")
    rates = {p.name: pr.fps for p, pr in zip(paths, probes) if pr.fps > 0}  # 0: the file states none (--fps then)
    if rates and max(rates.values()) > min(rates.values()) * 1.001:
        listed = ", ".join(f"{k} {v:g}" for k, v in rates.items())
        raise InputFileError(paths[0], f"the videos state different frame rates ({listed} Hz)",
                             "give videos of one synchronised take, recorded at one rate")


OUTPUT_MARKER = ".mocap-output.json"


@contextlib.contextmanager
def atomic_output_dir(out: Path):
    """Yield a temporary folder next to ``out``; move it to ``out`` when the block succeeds.

    ``out`` may be new, an empty folder, or a folder this command wrote before (it carries
    :data:`OUTPUT_MARKER`); anything else is refused before any work, and nothing of the user's
    is deleted. A failure leaves nothing behind."""
    out = Path(out)
    if out.exists() or out.is_symlink():
        ours = out.is_dir() and not out.is_symlink() and (out / OUTPUT_MARKER).is_file()
        empty = out.is_dir() and not out.is_symlink() and not any(out.iterdir())
        if not (ours or empty):
            what = "is a file" if out.is_file() else "exists and was not written by mocap"
            raise InputFileError(out, f"--out {what}", "choose another --out, or move or remove it yourself")
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.partial-", dir=out.parent))
    try:
        (tmp / OUTPUT_MARKER).write_text(json.dumps({"tool": "mocap markers", "pid": os.getpid()}))
        yield tmp
        if out.exists():
            old = Path(tempfile.mkdtemp(prefix=f".{out.name}.old-", dir=out.parent))
            os.replace(out, old / out.name)
            os.replace(tmp, out)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
