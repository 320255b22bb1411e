"""``simbench run``: render a scenario, run the real pipeline on the frames, score it.

This is the only place that holds both the ground truth and the pipeline's output.
The pipeline gets what a user's session would have: the frames, a calibration (the
exact one, or one estimated by ``mocap calibrate`` on rendered calibration views), a
T-pose label template and the subject model; never the ground truth.

A run never loses its metrics to a late failure: once the frames are rendered, a stage
that raises is recorded (``RunResult.failures``, ``metrics.json``'s ``failed_stages``,
the top of ``report.md``) and the run's outputs are still moved into place;
``simbench run`` then exits with code 3 (``simbench.cli.common.EXIT_STAGE_FAILED``).
"""

from __future__ import annotations

import dataclasses
import json
import time
import traceback
from contextlib import contextmanager, nullcontext
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterator

import mujoco
import numpy as np

from eval import marker_metrics, skeleton_metrics
from mocap.detection import DetectionParams
from mocap.errors import MocapInputError
from mocap.labelling import LabelTemplate, save_template
from mocap.marker_pipeline import DetectionStream, MarkerCapture, MarkerPipelineParams, capture_from_detections, export_capture
from mocap.reconstruction import ReconstructionParams
from mocap.subject import SubjectModel
from mocap.trackers import get_tracker
from simbench import interrupts
from simbench.errors import SimbenchInputError
from simbench.pipelines.calibration import run_calibration
from simbench.pipelines.report import write_run_report
from simbench.pipelines.shirt import run_shirt_capture
from simbench.pipelines.shirt_database import ProgressFactory
from simbench.scenario import Scenario
from simbench.scenes.humanoid import humanoid_mjcf, tpose_qpos
from simbench.stage.build import build_stage
from simbench.stage.rendering import AtomicOutputDir, RenderedSequence, render_frames, save_scenario_copy, write_render_outputs
from simbench.stage.stage import Stage


@dataclass(frozen=True)
class StageFailure:
    """A stage of a run that raised; the run went on without that stage's output."""

    stage: str  # e.g. "skeleton solve", "exports", "contact sheet", "report"
    cause: str  # one line; paths name the final output folder, never the partial one
    detail: str = ""  # the traceback (for sweep records and debugging), same path rule

    def line(self) -> str:
        return f"{self.stage} failed: {self.cause}"


@dataclass
class RunResult:
    metrics: dict[str, float]
    out_dir: Path | None
    sequence: RenderedSequence
    capture: MarkerCapture | None = None
    timings_s: dict[str, float] = field(default_factory=dict)
    failures: list[StageFailure] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not self.failures


def one_line_cause(exc: BaseException | str) -> str:
    """First line of an exception's message; our own input errors without their class name
    (their messages name the file and the fix), other exceptions with it."""
    if isinstance(exc, str):
        return exc
    msg = (str(exc).strip().splitlines() or [""])[0]
    if isinstance(exc, (SimbenchInputError, MocapInputError)) and msg:
        return msg
    return f"{type(exc).__name__}: {msg}" if msg else type(exc).__name__


class _Stages:
    """Runs the stages after rendering, each in ``with stages.run(name)``; an ``Exception``
    in one is recorded (stage and cause) instead of propagated. ``BaseException`` that is
    not an ``Exception`` (KeyboardInterrupt, the CLI's signal exception) propagates."""

    def __init__(self, public: Callable[[str], str]) -> None:
        self._public = public
        self.failures: list[StageFailure] = []

    @contextmanager
    def run(self, stage: str) -> Iterator[None]:
        interrupts.raise_if_pending()
        try:
            yield
        except Exception as exc:  # a late failure must not lose the run (module doc)
            interrupts.raise_if_pending(exc)  # unless it is a signal in disguise: stop
            self.record(stage, exc)
        interrupts.raise_if_pending()

    def record(self, stage: str, cause: BaseException | str) -> None:
        detail = "" if isinstance(cause, str) else "".join(traceback.format_exception(cause, limit=-8))
        self.failures.append(StageFailure(stage, self._public(one_line_cause(cause)), self._public(detail)))

    def failed(self, stage: str) -> bool:
        return any(f.stage == stage for f in self.failures)


def label_template(bench: Stage) -> LabelTemplate:
    """The subject's markers in its T-pose, subject-local frame (what a user's template holds);
    for a real capture (no humanoid), its markers in the capture's reference frame."""
    reference = bench.capture_reference()
    if reference is not None:
        return reference.label_template()
    xml = humanoid_mjcf(bench.params, marker_set=bench.scenario.subject.markers)
    m = mujoco.MjModel.from_xml_string(xml)
    d = mujoco.MjData(m)
    d.qpos[:] = tpose_qpos(bench.params)
    d.qpos[0:2] = 0.0
    mujoco.mj_kinematics(m, d)
    pos = np.array([d.site_xpos[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, n)] for n in bench.marker_names])
    return LabelTemplate(tuple(bench.marker_names), pos)


def subject_model(bench: Stage) -> SubjectModel | None:
    """The humanoid's subject model; None for a real capture (no body: markers only)."""
    if bench.capture_reference() is not None:
        return None
    return SubjectModel.from_mjcf_text(humanoid_mjcf(bench.params, marker_set=bench.scenario.subject.markers),
                                       name=bench.scenario.name)


def pipeline_params(sc: Scenario) -> MarkerPipelineParams:
    cfg = sc.markers_pipeline
    return MarkerPipelineParams(
        detection=DetectionParams(mode=sc.sensor.mode),
        labelling=cfg.labelling,
        tracker=cfg.tracker,
        reconstruction=ReconstructionParams(smoothing=cfg.smoothing, max_gap_frames=cfg.max_gap_frames),
        solve_skeleton=cfg.solve_skeleton,
    )


def score_markers(gt, capture: MarkerCapture) -> dict[str, float]:
    traj = capture.trajectories
    idx = [traj.labels.index(n) for n in gt.marker_names]
    est = traj.xyz[:, idx]
    tracked = capture.tracks.predicted_xy[:, :, idx]
    metrics = marker_metrics.summarize_markers(est, gt.markers_3d, gt.marker_visible, tracked_xy=tracked,
                                               true_xy=gt.markers_2d, filled=traj.filled[:, idx])
    fit = capture.skeleton
    if fit is not None:
        mask = fit.well_constrained() if hasattr(fit, "well_constrained") else None
        hinge_idx = [fit.hinge_names.index(h) for h in gt.hinge_names]
        est_ang = fit.joint_angles_rad[:, hinge_idx]
        true_ang = gt.qpos[:, 7:]
        m = None if mask is None else np.asarray(mask)[..., hinge_idx]
        metrics["skeleton.joint_angle_rmse_deg"] = skeleton_metrics.joint_angle_rmse_deg(est_ang, true_ang, m)
        metrics["skeleton.joint_angle_rmse_all_deg"] = skeleton_metrics.joint_angle_rmse_deg(est_ang, true_ang)
        body_idx = [fit.body_names.index(b) for b in gt.joint_names]
        metrics["skeleton.joint_position_rmse_mm"] = skeleton_metrics.joint_position_rmse_mm(
            fit.joint_centres_m[:, body_idx], gt.joint_centres)
    return metrics


def preflight(scenario: Scenario) -> None:
    """Settings only the pipeline reads, checked before anything renders (a user error
    found after rendering would be a failed stage, exit 3, rather than exit 2)."""
    if scenario.subject.markers != "none":
        get_tracker(scenario.markers_pipeline.tracker)  # TrackerNotFoundError names the known ones


def run_scenario(scenario: Scenario, out: str | Path | None = None, progress=None, write_outputs: bool = True,
                 progress_factory: ProgressFactory | None = None) -> RunResult:
    """Render, capture and score one scenario; write metrics.json, report and exports to ``out``.

    ``out`` is replaced only if it is an earlier bench output or an empty folder
    (:mod:`simbench.output_dir`; else :class:`~simbench.output_dir.OutputPathError`
    before anything renders). Once the frames are rendered, a stage that raises (the
    calibration session, the marker pipeline or its skeleton solve, scoring, the shirt
    pipeline, the exports, the contact sheet, the report) does not lose the run: it is
    listed in ``RunResult.failures`` (stage and one-line cause naming final paths), in
    ``metrics.json`` (``failed_stages``) and at the top of ``report.md``, and the output
    is moved into place as usual. An interruption (KeyboardInterrupt, or a signal the CLI
    turns into an exception) or a failure before the frames exist discards everything.
    """
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    preflight(scenario)
    output = AtomicOutputDir(out, scenario=scenario.name, kind="run") if (out is not None and write_outputs) else None
    with output if output is not None else nullcontext() as tmp:
        stages = _Stages(output.public if output is not None else str)
        bench = build_stage(scenario)
        C = len(bench.cameras)
        has_markers = len(bench.marker_names) > 0
        stream = DetectionStream(C, DetectionParams(mode=scenario.sensor.mode)) if has_markers else None
        keep = {0, scenario.n_frames // 2, scenario.n_frames - 1}
        kept_frames: dict[int, np.ndarray] = {}
        writer = write_render_outputs(bench, tmp, png=False) if tmp is not None else None

        def on_frame(fo):
            interrupts.raise_if_pending()  # a signal swallowed by a C callback stops the run here
            if writer is not None:
                writer[0](fo)
            if stream is not None:
                stream.add(list(fo.images))
            if fo.index in keep:
                kept_frames[fo.index] = fo.images.copy()

        shirt = scenario.subject.shirt
        try:
            seq = render_frames(bench, on_frame=on_frame, keep_frames=shirt, keep_ids=shirt, progress=progress)
        finally:
            if writer is not None:
                writer[1]()
        timings["render_s"] = time.perf_counter() - t0
        gt = seq.ground_truth
        metrics: dict[str, float] = {}
        capture = None
        calibration = gt.calibration()
        calib_report: list[str] = []
        if scenario.calibration_scene is not None:
            # Calibration session (simbench/pipelines/calibration.py): render the board and wand
            # pictures, run the calibration tool, score it. Its estimate is in the true
            # world frame without alignment when the scene has a floor view (the floor
            # board defines the world), else rigidly aligned to the true camera centres.
            t1 = time.perf_counter()
            with stages.run("calibration session"):
                calib_metrics, calib_report, estimated = run_calibration(bench, tmp)
                metrics.update(calib_metrics)
                if scenario.markers_pipeline.calibration == "estimated":
                    calibration = estimated
            timings["calibration_s"] = time.perf_counter() - t1
        no_calibration = scenario.markers_pipeline.calibration == "estimated" and stages.failed("calibration session")
        if has_markers and no_calibration:
            stages.record("marker pipeline", "not run: it needs the estimated calibration, and the calibration session failed")
        if has_markers and not no_calibration:
            t1 = time.perf_counter()
            with stages.run("marker pipeline"):
                template = label_template(bench)
                subject = subject_model(bench)
                reference = bench.capture_reference()  # a real capture: rigid clusters instead of a skeleton
                marker_model = reference.marker_model() if reference is not None else None

                def capture_with(params: MarkerPipelineParams) -> MarkerCapture:
                    rng = np.random.default_rng(np.random.SeedSequence([scenario.seed, 0x7AC]))
                    return capture_from_detections(stream.detections, calibration, template, gt.times,
                                                   params, rng, subject, stream.ms, marker_model=marker_model)

                try:
                    capture = capture_with(pipeline_params(scenario))
                except Exception as exc:
                    interrupts.raise_if_pending(exc)
                    if not scenario.markers_pipeline.solve_skeleton:
                        raise
                    # Keep the markers when only the skeleton solve fails: run again without
                    # it; if that raises too, the marker pipeline itself failed (its cause).
                    capture = capture_with(dataclasses.replace(pipeline_params(scenario), solve_skeleton=False))
                    stages.record("skeleton solve", exc)
            timings["pipeline_s"] = time.perf_counter() - t1
            if capture is not None:
                with stages.run("scoring"):
                    metrics.update(score_markers(gt, capture))
        shirt_report: list[str] = []
        if shirt:
            # The colour-shirt pipeline of seed 001 (simbench/pipelines/shirt.py).
            t1 = time.perf_counter()
            with stages.run("shirt pipeline"):
                shirt_metrics, shirt_report = run_shirt_capture(bench, seq.frames, gt, tmp, progress_factory=progress_factory)
                metrics.update(shirt_metrics)
            timings["shirt_pipeline_s"] = time.perf_counter() - t1
        metrics["run.frames"] = gt.n_frames
        metrics["run.cameras"] = C
        metrics["run.mean_subframes"] = float(gt.n_subframes.mean())
        timings["total_s"] = time.perf_counter() - t0
        if tmp is not None:
            with stages.run("ground truth"):
                gt.save(tmp / "ground_truth")
                gt.calibration().save_opencv_yaml(tmp / "calibration_ground_truth.yml")
            save_scenario_copy(scenario, tmp)
            if capture is not None:
                with stages.run("exports"):
                    export_capture(capture, tmp / "exports", calibration, subject_model(bench))
                with stages.run("exports (label template, subject file)"):
                    (tmp / "exports").mkdir(exist_ok=True)
                    save_template(label_template(bench), tmp / "exports" / "label_template.csv")
                    # The subject file a user would hand `mocap markers --subject` (MJCF + marker placement).
                    if subject_model(bench) is not None:
                        subject_model(bench).save_toml(tmp / "exports" / "subject.toml")
            with stages.run("contact sheet"):
                _contact_sheet(bench, gt, kept_frames, tmp / "contact_sheet.png")
            with stages.run("report"):
                write_run_report(tmp, scenario, gt, capture, metrics, timings, extra_sections=calib_report + shirt_report,
                                 calibration=calibration)
            _note_failures_in_report(tmp / "report.md", scenario, metrics, stages.failures)
            write_metrics_json(tmp / "metrics.json", metrics, stages.failures)
    return RunResult(metrics, Path(out) if out else None, seq, capture, timings, list(stages.failures))


def write_metrics_json(path: Path, metrics: dict[str, float], failures: list[StageFailure]) -> None:
    """``metrics.json``: every metric (NaN as null) and ``failed_stages`` (a list, empty when
    every stage ran: ``[{"stage": ..., "cause": ...}]``)."""
    data: dict[str, object] = {k: _jsonable(v) for k, v in sorted(metrics.items())}
    data["failed_stages"] = [{"stage": f.stage, "cause": f.cause} for f in failures]
    path.write_text(json.dumps(data, indent=2) + "\n")


def _note_failures_in_report(path: Path, scenario: Scenario, metrics: dict[str, float],
                             failures: list[StageFailure]) -> None:
    """Put the failed stages at the top of ``report.md`` (a minimal report if it could not be written)."""
    if not failures:
        return
    section = ["## Failed stages", "", "The run finished without the output of these stages:", ""]
    section += [f"- **{f.stage}**: {f.cause}" for f in failures] + [""]
    if path.is_file():
        lines = path.read_text().splitlines()
        lines[1:1] = [""] + section[:-1]  # after the title; the report's own blank line follows
    else:
        lines = [f"# simbench run: {scenario.name}", ""] + section + ["## Metrics", "", "| metric | value |", "|---|---|"]
        lines += [f"| `{k}` | {_jsonable(v)} |" for k, v in sorted(metrics.items())] + [""]
    path.write_text("\n".join(lines) + "\n")


def _jsonable(v):
    if isinstance(v, (np.floating, float)):
        return None if not np.isfinite(v) else float(v)
    if isinstance(v, (np.integer,)):
        return int(v)
    return v


def _contact_sheet(bench: Stage, gt, kept: dict[int, np.ndarray], path: Path) -> None:
    from simbench.render.contact_sheet import contact_sheet

    rows = sorted(kept)
    frames = {(k, c.name): kept[k][ci] for k in rows for ci, c in enumerate(bench.cameras)}
    overlays = {(k, c.name): gt.markers_2d[k, ci][gt.marker_visible[k, ci]] for k in rows for ci, c in enumerate(bench.cameras)}
    contact_sheet(frames, {k: float(gt.times[k]) for k in rows}, path, overlays=overlays)
