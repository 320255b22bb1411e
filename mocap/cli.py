"""``mocap`` command line: the capture pipeline on real video files.

Nothing here knows about the simulator: inputs are videos (or images), a calibration
file and a label template, exactly what a user with real webcams has.
"""

from __future__ import annotations

import functools
import json
from pathlib import Path
from typing import Optional

import numpy as np
import typer
from rich.console import Console

from mocap.errors import InputFileError, MocapInputError

app = typer.Typer(add_completion=False, no_args_is_help=True, help="Optical motion capture from webcam videos.")
console = Console(stderr=True)


def user_errors(fn):
    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        try:
            return fn(*args, **kwargs)
        except MocapInputError as exc:
            console.print(f"[bold red]error:[/] {exc}", highlight=False, soft_wrap=True)
            raise typer.Exit(2)

    return wrapper


def order_videos_by_camera(videos: list[Path], camera_names: list[str]) -> list[Path]:
    """Match video files to calibration cameras by file stem (``cam0.mp4`` -> ``cam0``), else by order."""
    stems = {v.stem: v for v in videos}
    if all(n in stems for n in camera_names):
        return [stems[n] for n in camera_names]
    if len(videos) != len(camera_names):
        raise InputFileError(videos[0] if videos else Path("."), f"{len(videos)} videos for {len(camera_names)} calibrated cameras {camera_names}",
                             "pass one video per camera, named after the camera (e.g. cam0.mp4) or in calibration order")
    return list(videos)


@app.command()
@user_errors
def markers(
    videos: list[Path] = typer.Argument(..., help="one video per camera (synchronised)"),
    calibration: Path = typer.Option(..., "--calibration", help="OpenCV YAML or anipose TOML"),
    template: Path = typer.Option(..., "--template", help="label template CSV: name,x,y,z of the T-pose (m)"),
    out: Path = typer.Option(..., "--out", help="output directory"),
    subject: Optional[Path] = typer.Option(None, "--subject", help="subject model (MJCF with marker sites, or its TOML) to solve the skeleton"),
    tracker: str = typer.Option("kalman", "--tracker", help="2D tracker (registry name or module:Class)"),
    mode: str = typer.Option("ir", "--mode", help="'ir' (bright markers, dark scene) or 'visible'"),
    fps: Optional[float] = typer.Option(None, "--fps", help="frame rate (default: read from the first video)"),
    seed: int = typer.Option(0, "--seed", help="seed of stochastic trackers"),
) -> None:
    """Detect, label, track and triangulate markers; write C3D, TRC, CSV (and BVH with --subject)."""
    import cv2

    from mocap.calibration import Calibration
    from mocap.detection import DetectionParams, iter_video_frames
    from mocap.labelling import load_template
    from mocap.marker_pipeline import MarkerPipelineParams, capture_markers, export_capture

    cal = Calibration.load(calibration)
    tmpl = load_template(template)
    paths = order_videos_by_camera(list(videos), cal.names)
    if fps is None:
        cap = cv2.VideoCapture(str(paths[0]))
        fps = cap.get(cv2.CAP_PROP_FPS) or 30.0
        cap.release()
    subj = None
    if subject is not None:
        from mocap.subject import SubjectModel

        subj = SubjectModel.load(subject)
    if mode not in ("ir", "visible"):
        raise InputFileError(Path("--mode"), f"value {mode!r}", "use 'ir' or 'visible'")
    params = MarkerPipelineParams(detection=DetectionParams(mode=mode), tracker=tracker, solve_skeleton=subj is not None)
    frames = [iter_video_frames(p) for p in paths]
    n = min(int(cv2.VideoCapture(str(p)).get(cv2.CAP_PROP_FRAME_COUNT)) for p in paths)
    times = np.arange(max(n, 1)) / fps
    capture = capture_markers(frames, cal, tmpl, times, params, np.random.default_rng(seed), subj)
    files = export_capture(capture, out, cal, subj)
    traj = capture.trajectories
    have = np.isfinite(traj.xyz).all(-1)
    summary = {"frames": int(traj.xyz.shape[0]), "markers": len(traj.labels),
               "reconstructed_fraction": float(have.mean()),
               "timings_ms": {k: round(v, 1) for k, v in capture.timings_ms.items()},
               "files": {k: str(v) for k, v in files.items()}}
    (Path(out) / "summary.json").write_text(json.dumps(summary, indent=2))
    console.print(f"{summary['frames']} frames, {summary['markers']} labels, reconstructed {summary['reconstructed_fraction']:.3f}; wrote {out}/")


from mocap import shirt_cli  # noqa: E402  (colour-shirt pipeline, issue 6)
app.command("shirt")(user_errors(shirt_cli.shirt))


def main() -> None:
    app()


if __name__ == "__main__":
    main()
