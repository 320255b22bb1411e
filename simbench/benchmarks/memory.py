"""``simbench bench memory``: resident memory (RSS) against frames rendered over a long take.

The take goes through :func:`simbench.pipelines.run.run_scenario`, the code of ``simbench
run``: render with MP4 writing and streamed marker detection, the marker pipeline
(labelling, tracking, reconstruction, skeleton solve), scoring, ground truth, exports,
contact sheet and report, into a temporary output folder (removed afterwards unless
``out`` is given). RSS is read after every rendered frame and, from a sampling thread,
every ``interval_s`` during the stages after the render; the whole run's peak is the
kernel's high-water mark of the process (``getrusage``: it also catches a spike between
two samples), or the highest sample if that is higher (the mark lags by a few pages).

Beside it, measured in the same run: the RSS before the run starts (imports, nothing
rendered) and the size of one camera-frame of this scenario, i.e. what RSS would grow
by per camera-frame if the render kept its images.
"""

from __future__ import annotations

import resource
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import psutil

from simbench.pipelines.run import run_scenario
from simbench.scenario import Scenario

MIB = 1024 ** 2
#: The acceptance limits of issue 17 for a 60 s take with 4 cameras.
PEAK_LIMIT_BYTES = int(1.5 * 1024 ** 3)
GROWTH_LIMIT_BYTES = 50 * 10 ** 6
GROWTH_FROM_FRAME = 300
CHILDREN_EVERY = 30  # frames between two readings of the child processes' RSS


@dataclass(frozen=True)
class MemorySample:
    """RSS of the process at one moment: ``frames`` rendered so far (the take's length once the render ended)."""

    elapsed_s: float
    frames: int
    rss_bytes: int
    rendering: bool


@dataclass
class MemoryBenchmark:
    scenario_name: str
    n_frames: int
    n_cameras: int
    image_size: tuple[int, int]       # (width, height) px
    baseline_rss_bytes: int           # before the run: imports done, nothing built or rendered
    peak_rss_bytes: int               # the process's high-water mark over the whole run
    samples: list[MemorySample] = field(default_factory=list)
    children_peak_rss_bytes: int = 0  # the most the child processes (the MP4 encoders) held at once, sampled
    failed_stages: list[str] = field(default_factory=list)
    wall_s: float = 0.0

    @property
    def camera_frame_bytes(self) -> int:
        """One RGB uint8 camera image: what keeping every image would add per camera-frame."""
        w, h = self.image_size
        return w * h * 3

    @property
    def render_samples(self) -> list[MemorySample]:
        return [s for s in self.samples if s.rendering]

    def rss_at_frame(self, frame: int) -> int:
        """RSS right after frame ``frame`` (1-based count of frames rendered) was rendered."""
        for s in self.render_samples:
            if s.frames >= frame:
                return s.rss_bytes
        return self.render_samples[-1].rss_bytes

    def growth_bytes(self, from_frame: int = GROWTH_FROM_FRAME) -> int | None:
        """RSS after the last frame minus RSS after frame ``from_frame``; None if the take is shorter."""
        rs = self.render_samples
        if not rs or rs[-1].frames <= from_frame:
            return None
        return rs[-1].rss_bytes - self.rss_at_frame(from_frame)

    def after_render_peak(self) -> MemorySample | None:
        """The highest sample of the stages after the render (pipeline, scoring, exports, report)."""
        after = [s for s in self.samples if not s.rendering]
        return max(after, key=lambda s: s.rss_bytes) if after else None

    def table(self, every: int = 100) -> str:
        w, h = self.image_size
        cf = self.camera_frame_bytes
        lines = [f"memory soak: {self.scenario_name}, {self.n_frames} frames, {self.n_cameras} cameras {w}x{h}, "
                 f"through simbench run's code (render + MP4 + detection, marker pipeline, exports, report)",
                 f"reference: RSS before the run {self.baseline_rss_bytes / MIB:.0f} MiB; one camera-frame "
                 f"{cf / MIB:.2f} MiB, so keeping the images would add {self.n_cameras * cf / MIB:.2f} MiB per frame",
                 "",
                 f"{'frame':>6} {'elapsed s':>10} {'RSS MiB':>9} {'over start':>11} {'images kept would add':>22}"]
        rs = self.render_samples
        shown = [s for s in rs if s.frames % every == 0 or s.frames == 1]
        if rs and rs[-1] not in shown:
            shown.append(rs[-1])
        for s in shown:
            lines.append(f"{s.frames:>6} {s.elapsed_s:>10.1f} {s.rss_bytes / MIB:>9.1f} "
                         f"{(s.rss_bytes - self.baseline_rss_bytes) / MIB:>+11.1f} {s.frames * self.n_cameras * cf / MIB:>+22.1f}")
        after = self.after_render_peak()
        if after is not None:
            lines.append(f"{'after':>6} {after.elapsed_s:>10.1f} {after.rss_bytes / MIB:>9.1f} "
                         f"{(after.rss_bytes - self.baseline_rss_bytes) / MIB:>+11.1f}   highest sample of the stages after "
                         f"the render (pipeline, exports, report)")
        lines.append("")
        peak_ok = self.peak_rss_bytes <= PEAK_LIMIT_BYTES
        lines.append(f"peak RSS (whole run, kernel high-water mark): {self.peak_rss_bytes / MIB:.0f} MiB "
                     f"(limit {PEAK_LIMIT_BYTES / MIB:.0f} MiB for 60 s, 4 cameras: {'met' if peak_ok else 'NOT met'})")
        g = self.growth_bytes()
        if g is None:
            lines.append(f"growth from frame {GROWTH_FROM_FRAME} to the end: take too short to tell")
        else:
            n = self.render_samples[-1].frames - GROWTH_FROM_FRAME
            lines.append(f"growth from frame {GROWTH_FROM_FRAME} to the end ({n} frames): {g / 1e6:+.1f} MB "
                         f"(limit {GROWTH_LIMIT_BYTES / 1e6:.0f} MB: {'met' if g < GROWTH_LIMIT_BYTES else 'NOT met'}); "
                         f"keeping the images would add {n * self.n_cameras * cf / 1e6:.0f} MB")
        lines.append(f"child processes (ffmpeg MP4 encoders, one per camera; not in the figures above): at most "
                     f"{self.children_peak_rss_bytes / MIB:.0f} MiB together (sampled every {CHILDREN_EVERY} frames)")
        lines.append(f"wall time {self.wall_s:.0f} s")
        if self.failed_stages:
            lines.append("failed stages (the run went on without them): " + "; ".join(self.failed_stages))
        return "\n".join(lines)


def _peak_rss_bytes() -> int:
    """The process's RSS high-water mark (``ru_maxrss``: KiB on Linux, bytes on macOS)."""
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return int(peak) if sys.platform == "darwin" else int(peak) * 1024


def _children_rss_bytes(proc: psutil.Process) -> int:
    total = 0
    for c in proc.children(recursive=True):
        try:
            total += c.memory_info().rss
        except psutil.NoSuchProcess:  # ended between the listing and the reading
            pass
    return total


def run_memory_benchmark(scenario: Scenario, out: Path | None = None, interval_s: float = 0.2,
                         on_sample: Callable[[MemorySample], None] | None = None) -> MemoryBenchmark:
    """Run ``scenario`` as ``simbench run`` does, sampling RSS (see the module doc).

    ``out``: where the run's outputs go (default a temporary folder, removed afterwards).
    ``on_sample`` is called with every sample taken after a rendered frame (e.g. to print rows as they come).
    """
    proc = psutil.Process()
    t0 = time.perf_counter()
    baseline = proc.memory_info().rss
    samples: list[MemorySample] = []
    state = {"frames": 0, "rendering": True, "children": 0}
    done = threading.Event()

    def on_frame(n: int = 1) -> None:
        state["frames"] += n
        s = MemorySample(time.perf_counter() - t0, state["frames"], proc.memory_info().rss, True)
        samples.append(s)
        if state["frames"] % CHILDREN_EVERY == 0:
            state["children"] = max(state["children"], _children_rss_bytes(proc))
        if state["frames"] >= scenario.n_frames:
            state["rendering"] = False
        if on_sample is not None:
            on_sample(s)

    def sample_after_render() -> None:
        while not done.wait(interval_s):
            if not state["rendering"]:
                samples.append(MemorySample(time.perf_counter() - t0, state["frames"], proc.memory_info().rss, False))

    sampler = threading.Thread(target=sample_after_render, name="rss-sampler", daemon=True)
    sampler.start()
    with tempfile.TemporaryDirectory(prefix="simbench-memory-") as tmp:
        try:
            result = run_scenario(scenario, out if out is not None else Path(tmp) / "run", progress=on_frame)
        finally:
            done.set()
            sampler.join()
    cam = result.sequence.ground_truth
    # The kernel updates the high-water mark from per-thread counters it syncs now and then:
    # it can lag a reading of the current RSS by a few pages.
    peak = max(_peak_rss_bytes(), *(s.rss_bytes for s in samples))
    return MemoryBenchmark(scenario.name, cam.n_frames, len(cam.camera_names), cam.image_size, baseline, peak,
                           sorted(samples, key=lambda s: s.elapsed_s), state["children"], [f.line() for f in result.failures],
                           time.perf_counter() - t0)
