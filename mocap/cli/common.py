"""What the ``mocap`` commands share: the error policy (one line, exit code 2) and matching
video files to calibrated cameras."""

from __future__ import annotations

import functools
from pathlib import Path

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
                console.print(f"[bold red]error:[/] {exc}", highlight=False, soft_wrap=True)
                raise typer.Exit(2)

        return wrapper

    return decorate


user_errors = exit_on_user_errors(MocapInputError)


def order_videos_by_camera(videos: list[Path], camera_names: list[str]) -> list[Path]:
    """Match video files to calibration cameras by file stem (``cam0.mp4`` -> ``cam0``), else by order."""
    stems = {v.stem: v for v in videos}
    if all(n in stems for n in camera_names):
        return [stems[n] for n in camera_names]
    if len(videos) != len(camera_names):
        raise InputFileError(videos[0] if videos else Path("."), f"{len(videos)} videos for {len(camera_names)} calibrated cameras {camera_names}",
                             "pass one video per camera, named after the camera (e.g. cam0.mp4) or in calibration order")
    return list(videos)
