"""Memory of a render does not grow with the take: no frame's images or id maps outlive it
(issue 17), unless the caller asks to keep them; ``simbench bench memory``'s figures."""

from __future__ import annotations

import gc
import weakref

import numpy as np
import pytest

from simbench.benchmarks.memory import run_memory_benchmark
from simbench.pipelines import run
from simbench.scenario import load_scenario
from simbench.stage.build import build_stage
from simbench.stage.rendering import render_frames

SMALL = {"rig.count": 2, "rig.width": 320, "rig.height": 240, "sensor.antialias": 1, "markers_pipeline.solve_skeleton": False}


def _scenario(duration_s: float):
    return load_scenario("scenarios/quickstart.toml", overrides={**SMALL, "duration_s": duration_s})


class _LiveFrames:
    """Wraps an ``on_frame``: weak references to every frame's images and id maps, and how
    many earlier frames' arrays are still alive when each new frame arrives."""

    def __init__(self, inner=None) -> None:
        self.inner = inner
        self.refs: list[weakref.ref] = []
        self.alive_before: list[int] = []

    def __call__(self, fo) -> None:
        gc.collect()
        self.alive_before.append(sum(r() is not None for r in self.refs))
        self.refs += [weakref.ref(fo.images), weakref.ref(fo.ids)]
        if self.inner is not None:
            self.inner(fo)


def test_render_frames_keeps_no_images_or_id_maps_of_earlier_frames():
    sc = _scenario(0.4)
    live = _LiveFrames()
    seq = render_frames(build_stage(sc), on_frame=live, keep_frames=False, keep_ids=False)
    assert seq.frames is None and seq.ground_truth.id_maps == {}
    assert len(live.alive_before) == sc.n_frames == 12
    # Keeping them (the code before issue 17) gives 2, 4, 6, ... live arrays: 2 per earlier frame.
    assert max(live.alive_before) == 0, live.alive_before


def test_kept_frames_and_id_maps_are_the_frames_rendered_and_the_ground_truth_does_not_depend_on_keeping():
    sc = _scenario(0.2)
    seen_images, seen_ids = [], []

    def copy(fo):
        seen_images.append(fo.images.copy())
        seen_ids.append(fo.ids.copy())

    kept = render_frames(build_stage(sc), on_frame=copy, keep_frames=True, keep_ids=True)
    lean = render_frames(build_stage(sc), keep_frames=False, keep_ids=False)
    np.testing.assert_array_equal(kept.frames, np.stack(seen_images))
    for ci, name in enumerate(kept.ground_truth.camera_names):
        np.testing.assert_array_equal(kept.ground_truth.id_maps[name], np.stack([i[ci] for i in seen_ids]))
    for key in kept.ground_truth._ARRAYS:
        np.testing.assert_array_equal(getattr(kept.ground_truth, key), getattr(lean.ground_truth, key), err_msg=key)


def test_a_run_keeps_no_frames_while_it_renders(monkeypatch, tmp_path):
    """Through ``run_scenario`` (videos, streamed detection, the contact sheet's copies): at
    every frame, no earlier frame's arrays are alive."""
    sc = _scenario(0.4)
    lives: list[_LiveFrames] = []
    real = run.render_frames

    def watched(stage, on_frame=None, **kw):
        lives.append(_LiveFrames(on_frame))
        return real(stage, on_frame=lives[-1], **kw)

    monkeypatch.setattr(run, "render_frames", watched)
    result = run.run_scenario(sc, tmp_path / "result")
    assert result.ok and (tmp_path / "result" / "contact_sheet.png").is_file()
    assert len(lives) == 1 and len(lives[0].alive_before) == sc.n_frames
    # The previous frame's images live until the MP4 writers get the next one (imageio-ffmpeg's
    # writer holds the last frame it was sent): one frame at most, whatever the take's length.
    assert max(lives[0].alive_before) <= 1, lives[0].alive_before


@pytest.mark.slow
def test_memory_benchmark_samples_every_frame():
    sc = _scenario(0.5)
    res = run_memory_benchmark(sc, interval_s=0.05)
    rendering = res.render_samples
    assert [s.frames for s in rendering] == list(range(1, sc.n_frames + 1))
    assert res.n_frames == sc.n_frames and res.n_cameras == 2 and res.camera_frame_bytes == 320 * 240 * 3
    assert res.peak_rss_bytes >= max(s.rss_bytes for s in res.samples) > res.baseline_rss_bytes > 0
    assert res.growth_bytes() is None  # 15 frames: shorter than frame 300
    table = res.table(every=5)
    assert "peak RSS" in table and "take too short" in table
