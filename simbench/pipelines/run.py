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
import os
import tempfile
import time
import traceback
from contextlib import contextmanager, nullcontext
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterator

import numpy as np

from mocap.detection import DetectionParams
from mocap.types import Detections
from mocap.errors import MocapInputError
from mocap.labelling import save_template
from mocap.marker_pipeline import (DetectionStream, MarkerCapture, MarkerPipelineParams, capture_from_detections,
                                   capture_unsynchronised, export_capture)
from mocap.rolling_shutter import capture_rolling_shutter, correct_rolling_shutter
from mocap.synchronisation import ClockSync
from simbench import interrupts
from simbench.errors import SimbenchInputError
from simbench.pipelines.exchange.command import run_command
from simbench.pipelines.exchange.inputs import write_inputs
from simbench.pipelines.exchange.results import read_results, score_results
from simbench.output_dir import AtomicOutputDir
from simbench.pipelines.calibration import run_calibration
from simbench.pipelines.exposure import score_light_events
from simbench.pipelines.markers import label_template, pipeline_params, score_markers, score_sync, subject_model, sync_report
from simbench.pipelines.report import write_run_report
from simbench.pipelines.shirt import ShirtCapture
from simbench.pipelines.shirt_database import ProgressFactory
from simbench.scenario import Scenario
from simbench.stage.build import build_stage
from simbench.stage.ground_truth import GroundTruth
from simbench.stage.rendering import (RenderedSequence, contact_sheet_rows, render_frames, render_writer, save_scenario_copy,
                                      write_contact_sheet)


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


def run_scenario(scenario: Scenario, out: str | Path | None = None, progress=None, write_outputs: bool = True,
                 progress_factory: ProgressFactory | None = None, detection_noise_px: float = 0.0) -> RunResult:
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

    ``detection_noise_px`` adds Gaussian noise of that SD (px, per axis; drawn from the
    scenario's seed) to every 2D detection before the marker pipeline: a regression injected
    by ``simbench check --calibrate``, 0 for a normal run.
    """
    t0 = time.perf_counter()
    output = AtomicOutputDir(out, scenario=scenario.name, kind="run") if (out is not None and write_outputs) else None
    with output if output is not None else nullcontext() as tmp:
        run = _Run(scenario, _Stages(output.public if output is not None else str), tmp, t0)
        run.detection_noise_px = float(detection_noise_px)
        run.start_shirt(progress_factory)
        run.render(progress)
        run.calibration_session()
        run.marker_capture()
        run.command_pipeline()
        run.shirt_capture()
        run.finish()
        if tmp is not None:
            run.write_outputs(tmp)
    return RunResult(run.metrics, Path(out) if out else None, run.seq, run.capture, run.timings, list(run.stages.failures))


class _Run:
    """One run's state as its steps fill it in (:func:`run_scenario` calls them in order)."""

    def __init__(self, scenario: Scenario, stages: _Stages, tmp: Path | None, t0: float) -> None:
        self.scenario, self.stages, self.t0 = scenario, stages, t0
        self.stage = build_stage(scenario)
        self.has_markers = len(self.stage.marker_names) > 0
        self.stream = DetectionStream(len(self.stage.cameras), DetectionParams(mode=scenario.sensor.mode)) if self.has_markers else None
        self.kept_frames: dict[int, np.ndarray] = {}  # the contact sheet's frames
        self.tmp = tmp
        self.timings: dict[str, float] = {}
        self.metrics: dict[str, float] = {}
        self.report_sections: list[str] = []
        self.capture: MarkerCapture | None = None
        self.sync: ClockSync | None = None  # the estimated clocks of unsynchronised cameras
        self.detection_noise_px = 0.0  # injected 2D detection noise (run_scenario's argument)
        self.brightness: list[np.ndarray] | None = [] if scenario.lighting.events and self.has_markers else None
        self.shirt: ShirtCapture | None = None  # the colour-shirt capture, fed each frame as it renders
        self._shirt_failure: Exception | None = None  # what stopped it, raised again in its stage
        self._shirt_s = 0.0  # seconds spent in it

    def start_shirt(self, progress_factory: ProgressFactory | None) -> None:
        """When the subject wears the shirt: its pose database and training (built or loaded) and the empty
        scene, before the take renders (:class:`~simbench.pipelines.shirt.ShirtCapture`)."""
        if not self.scenario.subject.shirt:
            return
        t1 = time.perf_counter()
        try:
            self.shirt = ShirtCapture(self.stage, progress_factory=progress_factory)
        except Exception as exc:  # recorded in the shirt pipeline's stage, after the render (module doc)
            interrupts.raise_if_pending(exc)
            self._shirt_failure = exc
        self._shirt_s += time.perf_counter() - t1

    def _track_shirt(self, fo) -> None:
        """The shirt capture on one rendered frame; a failure stops it (and is recorded in its stage)."""
        if self.shirt is None or self._shirt_failure is not None:
            return
        t1 = time.perf_counter()
        try:
            self.shirt.add_frame(fo.index, fo.images, fo.ids)
        except Exception as exc:
            interrupts.raise_if_pending(exc)
            self._shirt_failure = exc
        self._shirt_s += time.perf_counter() - t1

    def render(self, progress) -> None:
        """Render every frame: videos written, detections streamed, the shirt tracked, the contact sheet's
        frames kept; no other frame is kept."""
        keep = set(contact_sheet_rows(self.scenario.n_frames))
        with render_writer(self.stage, self.tmp, png=False) if self.tmp is not None else nullcontext() as write:

            def on_frame(fo):
                interrupts.raise_if_pending()  # a signal swallowed by a C callback stops the run here
                # the shirt first: the encoders then compress this frame while the next one renders, not while
                # the shirt's trackers time themselves (that read 37 -> 45 ms per frame on shirt_office)
                self._track_shirt(fo)
                if write is not None:
                    write(fo)
                if self.stream is not None:
                    self.stream.add(list(fo.images))
                if self.brightness is not None:  # light events: each frame's mean grey level (subsampled)
                    self.brightness.append(fo.images[:, ::8, ::8].mean(axis=(1, 2, 3)))
                if fo.index in keep:
                    self.kept_frames[fo.index] = fo.images.copy()

            self.seq = render_frames(self.stage, on_frame=on_frame, keep_frames=False, keep_ids=False, progress=progress)
        self.timings["render_s"] = time.perf_counter() - self.t0 - self._shirt_s  # (the shirt's tracking is its own)
        self.gt = self.seq.ground_truth
        self.calibration = self.gt.calibration()

    def calibration_session(self) -> None:
        """With a ``[calibration_scene]``: render the board and wand pictures, run the calibration
        tool, score it (:mod:`simbench.pipelines.calibration`). Its estimate is in the true world
        frame without alignment when the scene has a floor view (the floor board defines the
        world), else rigidly aligned to the true camera centres."""
        if self.scenario.calibration_scene is None:
            return
        t1 = time.perf_counter()
        with self.stages.run("calibration session"):
            calib_metrics, calib_report, estimated = run_calibration(self.stage, self.tmp)
            self.metrics.update(calib_metrics)
            self.report_sections += calib_report
            if self.scenario.markers_pipeline.calibration == "estimated":
                self.calibration = estimated
        self.timings["calibration_s"] = time.perf_counter() - t1

    def marker_capture(self) -> None:
        """The marker pipeline on the streamed detections, then its scores. When only the
        skeleton solve fails, the markers are kept (the pipeline runs again without it)."""
        if not self.has_markers or self.scenario.command_pipeline is not None:
            return
        if self.scenario.markers_pipeline.calibration == "estimated" and self.stages.failed("calibration session"):
            self.stages.record("marker pipeline", "not run: it needs the estimated calibration, and the calibration session failed")
            return
        t1 = time.perf_counter()
        with self.stages.run("marker pipeline"):
            params = pipeline_params(self.scenario)
            try:
                self.capture = self._capture_with(params)
            except Exception as exc:
                interrupts.raise_if_pending(exc)
                if not self.scenario.markers_pipeline.solve_skeleton:
                    raise
                # if this raises too, the marker pipeline itself failed (its cause)
                self.capture = self._capture_with(dataclasses.replace(params, solve_skeleton=False))
                self.stages.record("skeleton solve", exc)
        self.timings["pipeline_s"] = time.perf_counter() - t1
        if self.capture is not None:
            with self.stages.run("scoring"):
                self.metrics.update(score_markers(self._gt_at_reference_instants(), self.capture))
        clip = getattr(self.stage, "clip", None)
        if clip is not None and clip.label_repairs:  # a real capture's truth, as it was scored
            self.report_sections += ["## Capture truth", "", clip.label_repairs + ".", ""]
        if self.capture is not None and self.gt.readout_s > 0:
            with self.stages.run("rolling-shutter comparison"):
                self._rolling_shutter_comparison(params)
        if self.brightness:
            with self.stages.run("light events"):
                metrics, section = score_light_events(self.scenario, self.gt, self.stream.detections, np.stack(self.brightness))
                self.metrics.update(metrics)
                self.report_sections += section
        if self.sync is not None:
            with self.stages.run("synchronisation scoring"):
                self.metrics.update(score_sync(self.sync, self.gt))
                self.report_sections += sync_report(self.sync, self.gt)
            with self.stages.run("naive frame pairing"):
                self._naive_pairing(params)

    def _unsynchronised(self) -> bool:
        """The cameras run on their own clocks (a ``[sensor.clock]`` that is not all zero)."""
        return self.gt.camera_timestamps is not None

    def _gt_at_reference_instants(self) -> GroundTruth:
        """The ground truth the synchronised capture is scored against: with unsynchronised
        cameras the pipeline's 2D tracks are at camera 0's instants (it resampled every camera
        there), so their truth is the markers projected at those instants. A duplicated frame of
        camera 0 shows the previous instant under a later timestamp; the pipeline puts its output
        at the timestamp (:func:`mocap.synchronisation.resample_detections`), so its truth is the
        instant the timestamp stands for on camera 0's clock, not the repeated image's."""
        if not self._unsynchronised():
            return self.gt
        gt = self.gt
        F, M = gt.markers_3d.shape[:2]
        dup = np.zeros(F, bool)
        dup[1:] = gt.camera_times[1:, 0] == gt.camera_times[:-1, 0]
        fix = {}
        if dup.any():
            st = self.stage.states(gt.clock_offset_s[0] + gt.clock_rate[0] * gt.camera_timestamps[dup, 0])
            for name, value in (("markers_3d", st.marker_xpos), ("joint_centres", st.joint_centres),
                                ("qpos", st.qpos[:, : gt.qpos.shape[1]])):
                fix[name] = getattr(gt, name).copy()
                fix[name][dup] = value
        m3d = fix.get("markers_3d", gt.markers_3d)
        m2d = gt.calibration().project(m3d.reshape(-1, 3)).reshape(-1, F, M, 2).transpose(1, 0, 2, 3)
        return dataclasses.replace(gt, markers_2d=m2d, **fix)

    def _naive_pairing(self, params: MarkerPipelineParams) -> None:
        """The pipeline as if the cameras were synchronised (frame ``k`` of every camera together,
        camera 0's timestamps): ``markers.rmse_naive_mm``, what synchronisation is worth."""
        rng = np.random.default_rng(np.random.SeedSequence([self.scenario.seed, 0x7AC]))
        naive = capture_from_detections(self._detections(), self.calibration, label_template(self.stage),
                                        self.gt.camera_timestamps[:, 0], dataclasses.replace(params, solve_skeleton=False),
                                        rng, subject_model(self.stage), self.stream.ms)
        scored = score_markers(self.gt, naive)
        self.metrics["markers.rmse_naive_mm"] = scored["markers.rmse_mm"]
        self.metrics["markers.reconstructed_fraction_naive"] = scored["markers.reconstructed_fraction"]

    def command_pipeline(self) -> None:
        """``[pipeline] kind = "command"``: the inputs folder (``inputs/``, in the pipeline's format,
        with the calibration the run hands a pipeline), the user's command on it
        (:mod:`simbench.pipelines.exchange.command`; ``command.log``), its 3D result scored like the project's
        (``markers.*``). Without a run folder the inputs go to a temporary folder."""
        cfg = self.scenario.command_pipeline
        if cfg is None or not self.has_markers:
            return
        t1 = time.perf_counter()
        with self.stages.run("command pipeline"), (nullcontext(self.tmp) if self.tmp is not None
                                                    else tempfile.TemporaryDirectory(prefix="simbench-command-")) as base:
            base = Path(base)
            inputs = base / "inputs"
            write_inputs(inputs, cfg.format, self.scenario, self.stage, self.gt, self.calibration, self.stream.detections,
                         board=False)
            if (base / "videos").is_dir():  # the take's videos, shared rather than copied
                (inputs / "videos").mkdir(exist_ok=True)
                for v in (base / "videos").iterdir():
                    os.link(v, inputs / "videos" / v.name)
            done = run_command(cfg, inputs.resolve(), (base / "command_output").resolve(), (base / "command.log").resolve(),
                               Path(self.scenario.source_dir or "."))
            traj = read_results(done.result, trc_axes=cfg.trc_axes)
            self.metrics.update(score_results(traj, self.gt.markers_3d, self.gt.marker_visible, self.gt.marker_names,
                                              self.gt.times, done.result))
            self.timings["command_s"] = done.seconds
            self.timings["command_ms_per_frame"] = 1e3 * done.seconds / max(self.gt.n_frames, 1)
        self.timings["pipeline_s"] = time.perf_counter() - t1

    def _rolling_shutter_comparison(self, params: MarkerPipelineParams) -> None:
        """With a rolling shutter: the pipeline again with the row-time correction switched the
        other way, so that ``rolling_shutter.rmse_corrected_mm`` and ``rolling_shutter.rmse_uncorrected_mm``
        are both in every run (``markers.rmse_mm`` is the one ``[markers_pipeline]`` asks for)."""
        on = self.scenario.markers_pipeline.rolling_shutter_correction
        other = score_markers(self._gt_at_reference_instants(), self._capture_with(params, correct_rows=not on, keep_sync=False))
        mine = {k: self.metrics[k] for k in ("markers.rmse_mm", "markers.reconstructed_fraction", "markers.label_swaps")}
        theirs = {k: other[k] for k in mine}
        corrected, uncorrected = (mine, theirs) if on else (theirs, mine)
        self.metrics["rolling_shutter.readout_ms"] = self.gt.readout_s * 1e3
        for name, vals in (("corrected", corrected), ("uncorrected", uncorrected)):
            self.metrics[f"rolling_shutter.rmse_{name}_mm"] = vals["markers.rmse_mm"]
            self.metrics[f"rolling_shutter.reconstructed_fraction_{name}"] = vals["markers.reconstructed_fraction"]
            self.metrics[f"rolling_shutter.label_swaps_{name}"] = vals["markers.label_swaps"]
        self.report_sections += [
            "## Rolling shutter", "",
            f"Readout {self.gt.readout_s * 1e3:.1f} ms: row `y` of a frame is exposed `y / H * readout` after its "
            f"timestamp. The pipeline ran with the row-time correction {'on' if on else 'off'} (`markers.rmse_mm`) "
            f"and again with it {'off' if on else 'on'}.", "",
            "| row-time correction | marker RMSE (mm) | reconstructed | label swaps |", "|---|---|---|---|",
            f"| on | {corrected['markers.rmse_mm']:.3f} | {corrected['markers.reconstructed_fraction']:.4f} | "
            f"{corrected['markers.label_swaps']:.0f} |",
            f"| off | {uncorrected['markers.rmse_mm']:.3f} | {uncorrected['markers.reconstructed_fraction']:.4f} | "
            f"{uncorrected['markers.label_swaps']:.0f} |", ""]

    def _capture_with(self, params: MarkerPipelineParams, correct_rows: bool | None = None,
                      keep_sync: bool = True) -> MarkerCapture:
        """The marker pipeline on the streamed detections; with a rolling shutter, their rows' times
        corrected (:mod:`mocap.rolling_shutter`) when ``correct_rows`` (default: the scenario's
        ``markers_pipeline.rolling_shutter_correction``)."""
        reference = self.stage.capture_reference()  # a real capture: rigid clusters instead of a skeleton
        rng = np.random.default_rng(np.random.SeedSequence([self.scenario.seed, 0x7AC]))
        detections = self._detections()
        unsynced = self._unsynchronised()
        stamps = list(self.gt.camera_timestamps.T) if unsynced else [self.gt.times] * len(detections)
        if correct_rows is None:
            correct_rows = self.scenario.markers_pipeline.rolling_shutter_correction
        marker_model = reference.marker_model() if reference is not None else None
        if self.gt.readout_s > 0 and correct_rows:
            if not unsynced:  # two passes: links, then the reconstructed markers' own motion
                return capture_rolling_shutter(detections, self.gt.times, self.gt.readout_s, self.calibration,
                                               label_template(self.stage), params, rng, subject_model(self.stage),
                                               self.stream.ms, marker_model)
            detections = correct_rolling_shutter(detections, stamps, self.gt.readout_s, self.gt.image_size[1])
        if unsynced:  # each camera's own timestamps: synchronise from the markers' motion
            capture, sync = capture_unsynchronised(
                detections, stamps, self.calibration, label_template(self.stage),
                params, rng, subject_model(self.stage), self.stream.ms,
                marker_model=reference.marker_model() if reference is not None else None)
            if keep_sync:
                self.sync = sync
            return capture
        return capture_from_detections(detections, self.calibration, label_template(self.stage), self.gt.times,
                                       params, rng, subject_model(self.stage), self.stream.ms,
                                       marker_model=reference.marker_model() if reference is not None else None)

    def _detections(self) -> list[list[Detections]]:
        """The streamed detections, with the injected noise (``detection_noise_px``) if any."""
        if self.detection_noise_px <= 0:
            return self.stream.detections
        rng = np.random.default_rng(np.random.SeedSequence([self.scenario.seed, 0xD7E]))
        return [[dataclasses.replace(d, xy=d.xy + rng.normal(0.0, self.detection_noise_px, d.xy.shape)) for d in cam]
                for cam in self.stream.detections]

    def shirt_capture(self) -> None:
        """The colour-shirt pipeline of seed 001 (:mod:`simbench.pipelines.shirt`) when the subject wears the shirt:
        both methods scored once the take has rendered (they tracked each frame as it came)."""
        if not self.scenario.subject.shirt:
            return
        t1 = time.perf_counter()
        with self.stages.run("shirt pipeline"):
            if self._shirt_failure is not None:
                raise self._shirt_failure
            shirt_metrics, shirt_report = self.shirt.finish(self.gt, self.tmp)
            self.metrics.update(shirt_metrics)
            self.report_sections += shirt_report
        self.timings["shirt_pipeline_s"] = self._shirt_s + time.perf_counter() - t1

    def finish(self) -> None:
        self.metrics["run.frames"] = self.gt.n_frames
        self.metrics["run.cameras"] = len(self.stage.cameras)
        self.metrics["run.mean_subframes"] = float(self.gt.n_subframes.mean())
        self.timings["total_s"] = time.perf_counter() - self.t0

    def write_outputs(self, tmp: Path) -> None:
        """Ground truth, exports, contact sheet, report and ``metrics.json`` into the run's folder."""
        stages, stage = self.stages, self.stage
        with stages.run("ground truth"):
            self.gt.save(tmp / "ground_truth")
            self.gt.calibration().save_opencv_yaml(tmp / "calibration_ground_truth.yml")
        save_scenario_copy(self.scenario, tmp)
        if self.capture is not None:
            with stages.run("exports"):
                export_capture(self.capture, tmp / "exports", self.calibration, subject_model(stage))
            with stages.run("exports (label template, subject file)"):
                (tmp / "exports").mkdir(exist_ok=True)
                save_template(label_template(stage), tmp / "exports" / "label_template.csv")
                # The subject file a user would hand `mocap markers --subject` (MJCF + marker placement).
                subject = subject_model(stage)
                if subject is not None:
                    subject.save_toml(tmp / "exports" / "subject.toml")
        with stages.run("contact sheet"):
            write_contact_sheet(stage, self.gt, self.kept_frames, tmp / "contact_sheet.png")
        with stages.run("report"):
            write_run_report(tmp, self.scenario, self.gt, self.capture, self.metrics, self.timings,
                             extra_sections=self.report_sections, calibration=self.calibration)
        _note_failures_in_report(tmp / "report.md", self.scenario, self.metrics, stages.failures)
        write_metrics_json(tmp / "metrics.json", self.metrics, stages.failures)


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
