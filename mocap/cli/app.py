"""``mocap`` command line: the capture pipeline on real video files.

Nothing here knows about the simulator: inputs are videos (or images), a calibration
file and a label template, exactly what a user with real webcams has.

Commands import the pipeline when they run, so ``mocap --help`` stays quick.
"""

from __future__ import annotations

import contextlib
import json
import re
from pathlib import Path
from typing import Optional

import numpy as np
import typer

from mocap.calibration import Calibration
from mocap.cli import shirt as shirt_commands
from mocap.cli.common import atomic_output_dir, check_videos_against_calibration, console, order_videos_by_camera, probe_video, user_errors
from mocap.errors import InputFileError, MocapInputError

app = typer.Typer(add_completion=False, no_args_is_help=True, help="Optical motion capture from webcam videos.")


@app.command()
@user_errors
def markers(
    videos: list[Path] = typer.Argument(..., help="one video per camera (synchronised)"),
    calibration: Path = typer.Option(..., "--calibration", help="OpenCV YAML or anipose TOML"),
    template: Optional[Path] = typer.Option(None, "--template", help="label template CSV: name,x,y,z of the T-pose (m); "
                                            "with --labelled-trial it may be left out: the trial's fullest frame is the template"),
    out: Path = typer.Option(..., "--out", help="output directory"),
    subject: Optional[Path] = typer.Option(None, "--subject", help="subject model (MJCF with marker sites, or its TOML) to solve the skeleton"),
    labelled_trial: Optional[Path] = typer.Option(None, "--labelled-trial", help="without a subject model: a labelled trial of "
                                                  "the same subject and markers (C3D, TRC or CSV; a range of motion, an earlier "
                                                  "capture); each marker is labelled from its most rigid neighbours in it"),
    tracker: str = typer.Option("kalman", "--tracker", help="2D tracker (registry name or module:Class)"),
    mode: str = typer.Option("ir", "--mode", help="'ir' (bright markers, dark scene) or 'visible'"),
    fps: Optional[float] = typer.Option(None, "--fps", help="frame rate (default: read from the first video)"),
    seed: int = typer.Option(0, "--seed", help="seed of stochastic trackers"),
    timestamps: bool = typer.Option(False, "--timestamps", help="cameras not synchronised: read each video's "
                                    "<name>.timestamps.csv (its own clock) and synchronise them from the markers' motion"),
    readout_ms: float = typer.Option(0.0, "--readout-ms", help="rolling shutter: the cameras read their rows out over "
                                     "this long (ms; row y of H at the frame's time + y / H * readout); each blob is "
                                     "moved to its frame's timestamp before triangulation. 0: global shutter"),
    marker_diameter_mm: float = typer.Option(0.0, "--marker-diameter-mm", help="the markers' diameter (mm). With "
                                             "--mode visible, blobs of markers lit from one side are re-centred on "
                                             "their lit limb at the image radius this gives. 0: unknown"),
) -> None:
    """Detect, label, track and triangulate markers; write C3D, TRC, CSV (and BVH with --subject).

    With --timestamps the cameras may run on their own clocks: each camera's offset and drift
    relative to the first are estimated from the markers' motion (mocap.synchronisation), the
    blobs are interpolated to the first camera's frame instants, and summary.json gives the
    estimated clocks. With --readout-ms the rows' times are corrected (mocap.rolling_shutter).

    Labels come from a model of the subject found in any frame: its skeleton (--subject) or the
    rigid marker clusters of a labelled trial (--labelled-trial). Without either, or with two
    cameras, they start from a T-pose in the first frame and 2D trackers keep them (seed 000),
    which loses them when the subject does not start in a T-pose."""
    from mocap.detection import DetectionParams, iter_video_frames
    from mocap.marker_pipeline import DetectionStream, MarkerPipelineParams, export_capture
    from rich.progress import track

    cal = Calibration.load(calibration)
    if len(cal) < 2:
        raise InputFileError(calibration, f"describes {len(cal)} camera ({', '.join(cal.names)})",
                             "markers are triangulated: give the calibration of two cameras or more")
    tmpl, subj, trial = _labelling_inputs(template, subject, labelled_trial)
    paths = order_videos_by_camera(list(videos), cal.names)
    _check_mode_and_tracker(mode, tracker)
    probes = [probe_video(p) for p in paths]
    check_videos_against_calibration(paths, probes, cal)
    fps = _capture_fps(paths, probes, fps)
    stamps = _read_camera_timestamps(paths, probes) if timestamps else None
    if not (np.isfinite(readout_ms) and 0.0 <= readout_ms <= 1000.0 / fps):
        raise InputFileError(Path("--readout-ms"), f"value {readout_ms!r}",
                             f"give the rows' readout time in ms, 0 (global shutter) to the frame interval {1000.0 / fps:.2f}")
    if not (np.isfinite(marker_diameter_mm) and 0.0 <= marker_diameter_mm <= 1000.0):
        raise InputFileError(Path("--marker-diameter-mm"), f"value {marker_diameter_mm!r}",
                             "give the markers' diameter in mm (e.g. 14), or 0 if unknown")
    out_dir = Path(out)
    params = MarkerPipelineParams(detection=DetectionParams(mode=mode), tracker=tracker, solve_skeleton=subj is not None,
                                  marker_radius_m=marker_diameter_mm * 0.5e-3)
    with _output_errors(out_dir), atomic_output_dir(out_dir) as tmp:
        stream = DetectionStream(len(cal), params.detection)
        frames = zip(*(iter_video_frames(p) for p in paths))
        for images in track(frames, total=probes[0].frames, description="detecting", console=console, transient=True):
            stream.add(images)
        if sum(len(d) for per_cam in stream.detections for d in per_cam) == 0:
            raise InputFileError(paths[0], "no marker blob was found in any frame of any video",
                                 f"check --mode ({mode}: 'ir' finds bright markers on a dark scene, 'visible' white markers on a lit subject) and the exposure")
        capture, sync_summary = _capture(stream, cal, tmpl, params, seed, subj, stamps, fps, readout_ms * 1e-3,
                                         trial.model if trial is not None else None)
        files = export_capture(capture, tmp, cal, subj)
        summary = _markers_summary(capture, files, out_dir, sync_summary)
        (tmp / "summary.json").write_text(json.dumps(summary, indent=2))
    _note_labelling(capture, subj, trial, labelled_trial, len(cal))
    console.print(f"{summary['frames']} frames, {summary['markers']} labels, reconstructed {summary['reconstructed_fraction']:.3f}; wrote {out_dir}/",
                  markup=False)


_TRACKER_LABELS = ("labels start from a T-pose in the first frame and 2D trackers keep them; a subject who does not "
                   "start in a T-pose loses them")


def _labelling_inputs(template: Path | None, subject: Path | None, labelled_trial: Path | None):
    """``(label template, subject model or None, labelled trial or None)`` from ``--template``, ``--subject`` and
    ``--labelled-trial`` (one of the last two at most; without ``--template`` the trial's), read before any work so
    that a bad file stops the command at once."""
    from mocap.labelling import load_template

    if subject is not None and labelled_trial is not None:
        raise InputFileError(Path("--labelled-trial"), "given with --subject",
                             "give one: --subject labels with the skeleton, --labelled-trial without one")
    if template is None and labelled_trial is None:
        raise InputFileError(Path("--template"), "not given", "give the label template CSV (or --labelled-trial, whose fullest "
                             "frame is then the template)")
    tmpl = load_template(template) if template is not None else None
    if subject is not None:
        from mocap.subject import SubjectModel

        return tmpl, SubjectModel.load(subject), None
    if labelled_trial is not None:
        from mocap.labelled_trial import load_labelled_trial

        trial = load_labelled_trial(labelled_trial, list(tmpl.names) if tmpl is not None else None)
        return (tmpl if tmpl is not None else trial.template), None, trial
    return tmpl, None, None


def _note(text: str) -> None:
    console.print(f"note: {text}", markup=False, highlight=False, soft_wrap=True)


def _note_labelling(capture, subj, trial, labelled_trial: Path | None, n_cameras: int) -> None:
    """After a capture (notes, not errors: they follow the work): what the labelled trial lacks, and
    where labels came from the first frame's T-pose, why and how much of the template that fit found."""
    if trial is not None and trial.missing:
        _note(f"{labelled_trial} does not hold {len(trial.missing)} of the template's markers ({', '.join(trial.missing)}): "
              "they are left unlabelled")
    if trial is not None and trial.is_static:
        _note(f"the markers of {labelled_trial} barely move ({trial.travel_m * 1e3:.0f} mm at most): its clusters follow "
              "nearness alone; a range-of-motion trial tells the body's segments apart")
    if capture.labelling != "tracker":
        return
    if n_cameras < 3:
        why = "two cameras cannot confirm a model's labels"
    elif subj is None and trial is None:
        why = "no --subject or --labelled-trial"
    else:
        why = f"the {'skeleton' if subj is not None else 'labelled trial'} fitted no frame with confidence"
    _note(f"{why}: {_TRACKER_LABELS}")
    # (the bench's quickstart, 4 cameras: 75 % from its T-pose start, 44 % started mid-wave)
    _note(f"the T-pose fit of the first frame found {_first_frame_found(capture):.0%} of the template's markers in the "
          "cameras' images (a T-pose start on 4 cameras: about 75 %)")


def _check_mode_and_tracker(mode: str, tracker: str) -> None:
    """Refuse a ``--mode`` other than ir/visible and a ``--tracker`` the registry does not know."""
    from mocap.trackers import get_tracker

    if mode not in ("ir", "visible"):
        raise InputFileError(Path("--mode"), f"value {mode!r}", "use 'ir' or 'visible'")
    try:
        get_tracker(tracker)
    except MocapInputError as exc:
        raise InputFileError(Path("--tracker"), f"value {tracker!r}", str(exc)) from None


def _capture_fps(paths: list[Path], probes: list, fps: float | None) -> float:
    """The capture's frame rate (Hz): ``--fps`` if given (checked), else the first video's; 2 frames or more required."""
    if probes[0].frames < 2:
        raise InputFileError(paths[0], f"holds {probes[0].frames} frame", "a capture needs 2 frames or more (its markers "
                             "are tracked from frame to frame)")
    if fps is None:
        fps = probes[0].fps
        if not (np.isfinite(fps) and fps > 0):
            raise InputFileError(paths[0], f"the file states no frame rate ({fps})", "pass --fps with the capture's frame rate")
    elif not (np.isfinite(fps) and 0 < fps <= 10000):
        raise InputFileError(Path("--fps"), f"value {fps!r}", "give the frame rate in Hz, a number > 0")
    return fps


def _read_camera_timestamps(paths: list[Path], probes: list) -> list[np.ndarray]:
    """Each video's ``<name>.timestamps.csv``: ``(frames,)`` seconds on its camera's own clock, one per frame."""
    from mocap.synchronisation import read_timestamps_csv

    stamps = [read_timestamps_csv(p.with_name(p.stem + ".timestamps.csv")) for p in paths]
    for p, t, pr in zip(paths, stamps, probes):
        if len(t) != pr.frames:
            raise InputFileError(p.with_name(p.stem + ".timestamps.csv"), f"holds {len(t)} timestamps for the "
                                 f"{pr.frames} frames of {p.name}", "give one timestamp per frame")
    return stamps


def _capture(stream, cal: Calibration, tmpl, params, seed: int, subj, stamps: list[np.ndarray] | None, fps: float,
             readout_s: float = 0.0, marker_model=None):
    """The marker pipeline on the detected blobs of ``stream``.

    Synchronised cameras: frame ``i`` at ``i / fps`` seconds. With ``stamps`` (per camera
    ``(frames,)`` seconds, own clocks): the clocks are estimated first. With ``readout_s`` > 0
    (rolling shutters) the blobs are moved to their frames' timestamps first
    (:mod:`mocap.rolling_shutter`). Returns the capture and, with ``stamps``, the summary of
    the estimated clocks (offsets ms, drifts ppm), else None.
    """
    from mocap.marker_pipeline import capture_from_detections, capture_unsynchronised
    from mocap.rolling_shutter import capture_rolling_shutter, correct_rolling_shutter

    if stamps is None:
        times = np.arange(len(stream.detections[0])) / fps
        if readout_s > 0:
            return capture_rolling_shutter(stream.detections, times, readout_s, cal, tmpl, params, np.random.default_rng(seed),
                                           subj, stream.ms, marker_model), None
        return capture_from_detections(stream.detections, cal, tmpl, times, params, np.random.default_rng(seed), subj,
                                       stream.ms, marker_model), None
    n = len(stream.detections[0])
    stamps = [t[:n] for t in stamps]
    detections = stream.detections
    if readout_s > 0:
        detections = correct_rolling_shutter(detections, stamps, readout_s, [c.size[1] for c in cal])
    capture, sync = capture_unsynchronised(detections, stamps, cal, tmpl, params,
                                           np.random.default_rng(seed), subj, stream.ms, marker_model)
    sync_summary = {"reference": cal.names[sync.reference], "model": "s_reference = offset + (1 + drift) * s_camera",
                    "offset_ms": {c: round(float(o) * 1e3, 4) for c, o in zip(cal.names, sync.offset_s)},
                    "drift_ppm": {c: round(float(d) * 1e6, 2) for c, d in zip(cal.names, sync.drift)}}
    return capture, sync_summary


def _first_frame_found(capture) -> float:
    """The fraction of (camera, template marker) pairs that the T-pose fit of the first frame found a blob for."""
    index = np.asarray(capture.label_init.detection_index)
    return float((index >= 0).mean()) if index.size else 0.0


def _markers_summary(capture, files: dict, out_dir: Path, sync_summary: dict | None) -> dict:
    """``summary.json``'s content: frames, labels, reconstructed fraction, stage timings (ms), files written, clocks."""
    traj = capture.trajectories
    have = np.isfinite(traj.xyz).all(-1)
    summary = {"frames": int(traj.xyz.shape[0]), "markers": len(traj.labels),
               "reconstructed_fraction": float(have.mean()),
               "labelling": capture.labelling,
               **({"first_frame_found": round(_first_frame_found(capture), 4)} if capture.labelling == "tracker" else {}),
               "timings_ms": {k: round(v, 1) for k, v in capture.timings_ms.items()},
               "files": {k: str(out_dir / Path(v).name) for k, v in files.items()}}
    if sync_summary is not None:
        summary["synchronisation"] = sync_summary
    return summary


@contextlib.contextmanager
def _output_errors(out_dir: Path):
    """Errors while the output is being made, as one line naming ``--out`` and never the
    temporary folder the user does not see (``.NAME.partial-*``, already removed by
    :func:`atomic_output_dir`): a write that fails (a full disk, a permission), or an input
    error raised by an export."""
    partial = re.compile(rf"\.{re.escape(out_dir.name)}\.partial-[A-Za-z0-9_]+")

    def public(text: str) -> str:
        return partial.sub(out_dir.name, text)

    try:
        yield
    except OSError as exc:
        raise InputFileError(out_dir, f"--out could not be written ({exc.strerror or exc}: {public(str(exc.filename or ''))})",
                             "free some space or choose another --out; nothing was written there") from None
    except MocapInputError as exc:
        raise MocapInputError(public(str(exc))) from None


@app.command()
@user_errors
def calibrate(
    cameras: list[str] = typer.Argument(..., help="one name=path per camera: a folder of images, a video or an image; "
                                                  "view i of every camera is the same moment"),
    out: str = typer.Option(..., "--out", help="output stem: writes STEM.toml (anipose), STEM.yml (OpenCV), STEM.report.json"),
    board: str = typer.Option("checkerboard", "--board", help="'checkerboard' or 'charuco'"),
    board_size: str = typer.Option("9x6", "--board-size", help="checkerboard: inner corners; ChArUco: squares (cols x rows)"),
    square_mm: float = typer.Option(25.0, "--square-mm", help="side of one printed square (measure it)"),
    marker_mm: Optional[float] = typer.Option(None, "--marker-mm", help="ChArUco marker side"),
    dictionary: str = typer.Option("DICT_4X4_50", "--board-dictionary", help="ChArUco ArUco dictionary"),
    legacy_charuco: bool = typer.Option(False, "--legacy-charuco", help="ChArUco board made by OpenCV < 4.6"),
    wand_file: Optional[str] = typer.Option(None, "--wand-file", help=".npz with markers_px or blobs_px (C, F, 3, 2)"),
    wand_distances_mm: Optional[str] = typer.Option(None, "--wand-distances-mm", help="'d01,d12' (collinear) or 'd01,d12,d02'"),
    intrinsics: Optional[str] = typer.Option(None, "--intrinsics", help="calibration file whose intrinsics are known"),
    reference: Optional[str] = typer.Option(None, "--reference", help="camera fixed in the bundle adjustment"),
    floor_view: Optional[str] = typer.Option(None, "--floor-view", help="index or file name of the view with the board on the floor (world frame)"),
    world_camera: Optional[str] = typer.Option(None, "--world-camera", help="without --floor-view: camera whose frame is the world"),
    fix_aspect_ratio: bool = typer.Option(False, "--fix-aspect-ratio"),
    fix_principal_point: bool = typer.Option(False, "--fix-principal-point"),
    zero_tangent: bool = typer.Option(False, "--zero-tangent"),
    k3: str = typer.Option("auto", "--k3", help="'auto' (kept if it pays off), 'free' or 'fixed'"),
    min_views: int = typer.Option(5, "--min-views", help="fewest usable views per camera"),
    refine_intrinsics: bool = typer.Option(True, "--refine-intrinsics/--no-refine-intrinsics"),
    loss: str = typer.Option("soft_l1", "--loss", help="bundle adjustment loss"),
    ba_max_evaluations: int = typer.Option(300, "--ba-max-evaluations"),
    frame_step: int = typer.Option(1, "--frame-step", help="videos: use every n-th frame"),
    blur_threshold: float = typer.Option(20.0, "--blur-threshold", help="variance of Laplacian under which a failed view is called blurred"),
) -> None:
    """Calibrate cameras from pictures or videos of a board (and optionally a wand)."""
    from mocap.calibrate import run_calibrate_cli

    try:
        result = run_calibrate_cli(cameras, out, board=board, board_size=board_size, square_mm=square_mm,
                                   marker_mm=marker_mm, dictionary=dictionary, legacy_charuco=legacy_charuco,
                                   wand_file=wand_file, wand_distances_mm=wand_distances_mm, intrinsics=intrinsics,
                                   reference=reference, floor_view=floor_view, world_camera=world_camera,
                                   fix_aspect_ratio=fix_aspect_ratio, fix_principal_point=fix_principal_point,
                                   zero_tangent=zero_tangent, k3=k3, min_views=min_views,
                                   refine_intrinsics=refine_intrinsics, loss=loss,
                                   ba_max_evaluations=ba_max_evaluations, frame_step=frame_step,
                                   blur_threshold=blur_threshold)
    except ValueError as exc:  # BoardSpec / WandSpec field values (calibration errors: user_errors)
        console.print(f"[bold red]error:[/] {exc}", highlight=False, soft_wrap=True)
        raise typer.Exit(2)
    console.print(result.summary(), highlight=False)
    console.print("wrote " + ", ".join(str(p) for p in result.written), highlight=False)


app.command("shirt")(user_errors(shirt_commands.shirt))


def main() -> None:
    app()


if __name__ == "__main__":
    main()
