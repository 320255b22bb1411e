"""``simbench bench pipeline``: the marker pipeline's cost per stage per 4-camera frame, one core.

Frames of a scenario (default the quickstart: 4 cameras, 640x480, 39 markers) are rendered
once and kept; then, on one core (OpenCV limited to one thread, BLAS to one thread where the
environment allows it), each stage is timed over the same frames:

* detection (:func:`mocap.detection.detect_markers` on every image), beside a reference measured
  in the same run: a fixed threshold and ``cv2.connectedComponentsWithStats`` on the same images,
  the least any blob detector must do;
* correspondence, labelling, reconstruction and skeleton, from the pipeline's own stage timers
  (:func:`mocap.marker_pipeline.capture_from_detections`);
* apart, the labeller's start search (its global fit, once per take): over the benchmark's 30
  frames it would add ~80 ms to every frame, over a minute's take ~1 ms.

Each figure is the fastest of ``passes`` passes (a shared machine disturbs single passes).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from mocap.detection import DetectionParams, detect_markers
from mocap.marker_pipeline import capture_from_detections
from simbench.benchmarks.timing import best_ms, one_core
from simbench.pipelines.markers import label_template, pipeline_params, subject_model
from simbench.scenario import load_scenario
from simbench.stage.build import build_stage
from simbench.stage.rendering import render_frames

STAGES = ("detection", "correspondence", "labelling", "tracking", "reconstruction", "skeleton")
TARGET_MS = 33.0  # real time at 30 Hz


@dataclass
class PipelineBenchmark:
    """Milliseconds per multi-camera frame for every stage, and the reference."""

    n_frames: int
    n_cameras: int
    image_size: tuple[int, int]
    n_markers: int
    stage_ms: dict[str, float]
    reference_ms: float
    start_search_ms: float = 0.0  # the labeller's start search, once per take (not per frame)

    @property
    def total_ms(self) -> float:
        return float(sum(self.stage_ms.values()))

    def table(self) -> str:
        w, h = self.image_size
        lines = [f"marker pipeline, {self.n_cameras} cameras {w}x{h}, {self.n_markers} markers, {self.n_frames} frames, one core "
                 f"(ms per {self.n_cameras}-camera frame, fastest of the passes)",
                 f"{'stage':<16}{'ms/frame':>10}"]
        for k, v in self.stage_ms.items():
            lines.append(f"{k:<16}{v:>10.2f}")
        lines.append(f"{'total':<16}{self.total_ms:>10.2f}   target {TARGET_MS:.0f} ms (30 Hz): "
                     f"{'met' if self.total_ms <= TARGET_MS else 'NOT met'}")
        amortised = self.total_ms + self.start_search_ms / max(self.n_frames, 1)
        lines.append(f"{'start search':<16}{self.start_search_ms:>10.2f}   ms once per take (the labeller's global fit); "
                     f"spread over these {self.n_frames} frames the total is {amortised:.2f} ms/frame")
        lines.append(f"{'reference':<16}{self.reference_ms:>10.2f}   threshold + cv2.connectedComponentsWithStats on the same images")
        lines.append(f"detection / reference: {self.stage_ms['detection'] / max(self.reference_ms, 1e-9):.2f}x")
        return "\n".join(lines)


def run_pipeline_benchmark(n_frames: int = 30, scenario_path: str = "scenarios/quickstart.toml", passes: int = 3,
                           progress=None) -> PipelineBenchmark:
    """Render ``n_frames`` of the scenario, then time every stage on them (see the module doc)."""
    one_core()
    sc = load_scenario(scenario_path, overrides={"duration_s": n_frames / 30.0 + 1e-6, "fps": 30.0})
    bench = build_stage(sc)
    images: list[list[np.ndarray]] = []

    def keep(fo) -> None:
        images.append([np.ascontiguousarray(im) for im in fo.images])
        if progress is not None:
            progress(1)

    seq = render_frames(bench, on_frame=keep, keep_frames=False, keep_ids=False)
    gt = seq.ground_truth
    F, C = len(images), len(images[0])
    params = pipeline_params(sc)
    det_params = DetectionParams(mode=sc.sensor.mode)
    detections: list[list] = [[] for _ in range(C)]

    def detect_all() -> None:
        for c in range(C):
            detections[c] = [detect_markers(images[f][c], det_params) for f in range(F)]

    detection_ms = best_ms(detect_all, passes) / F
    grays = [[cv2.cvtColor(im, cv2.COLOR_RGB2GRAY) if im.ndim == 3 else im for im in fr] for fr in images]

    def reference() -> None:
        for fr, gfr in zip(images, grays):
            for im, g in zip(fr, gfr):
                if im.ndim == 3:
                    g = cv2.cvtColor(im, cv2.COLOR_RGB2GRAY)
                _, mask = cv2.threshold(g, 100, 255, cv2.THRESH_BINARY)
                cv2.connectedComponentsWithStats(mask, connectivity=8)

    reference_ms = best_ms(reference, passes) / F
    template, subject = label_template(bench), subject_model(bench)
    stage = {k: np.inf for k in STAGES if k != "detection"}
    start_search = np.inf
    for _ in range(passes):
        cap = capture_from_detections(detections, gt.calibration(), template, gt.times, params,
                                      np.random.default_rng(0), subject)
        for k in stage:
            stage[k] = min(stage[k], cap.timings_ms.get(k, 0.0) / F)
        start_search = min(start_search, cap.timings_ms.get("label_start", 0.0))
    out = {"detection": detection_ms, **{k: float(v) for k, v in stage.items()}}
    w, h = bench.cameras[0].width, bench.cameras[0].height
    return PipelineBenchmark(F, C, (w, h), len(template), out, reference_ms, float(start_search))
