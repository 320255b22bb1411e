"""Each camera on its own clock (simbench.stage.clocks, [sensor.clock]): the timing model, the
render of every camera at its own instants, and the run that synchronises them from the markers."""

from __future__ import annotations

import numpy as np
import pytest

from mocap.detection import DetectionParams, detect_markers
from simbench.errors import ScenarioError
from simbench.pipelines.run import run_scenario
from simbench.scenario import ClockConfig, load_scenario
from simbench.stage.build import build_stage
from simbench.stage.clocks import camera_clocks
from simbench.stage.renderer import mid_exposure_times
from simbench.stage.rendering import read_timestamps, render_frames, write_timestamps


def test_without_a_clock_every_camera_exposes_at_the_frame_times():
    for cfg in (None, ClockConfig()):
        clocks = camera_clocks(cfg, 3, 50, 30.0, 4.0, seed=7)
        assert clocks.synchronised
        assert np.array_equal(clocks.true_times_s[:, 2], mid_exposure_times(50, 30.0, 4.0))
        assert np.array_equal(clocks.timestamps_s, clocks.true_times_s)


def test_the_clock_model_offsets_drift_jitter_drops_and_duplicates():
    cfg = ClockConfig(offset_ms_max=500.0, drift_ppm_max=100.0, jitter_ms=1.0, drop_probability=0.1,
                      duplicate_probability=0.05)
    clocks = camera_clocks(cfg, 4, 3000, 30.0, 4.0, seed=3)
    again = camera_clocks(cfg, 4, 3000, 30.0, 4.0, seed=3)
    assert np.array_equal(clocks.true_times_s, again.true_times_s)  # seeded
    assert not np.array_equal(clocks.true_times_s, camera_clocks(cfg, 4, 3000, 30.0, 4.0, seed=4).true_times_s)
    assert np.ptp(clocks.offset_s) <= 1.0 and np.ptp(clocks.offset_s) > 0.1
    assert np.all(np.abs(clocks.rate - 1.0) <= 100e-6)
    assert clocks.true_times_s.min() >= 0.0  # the simulation starts at 0
    fresh = ~clocks.duplicated
    expected = clocks.offset_s + clocks.rate * clocks.timestamps_s
    assert np.allclose(clocks.true_times_s[fresh], expected[fresh], rtol=0, atol=1e-12)
    # a duplicated frame shows the previous frame's instant under its own, later, timestamp
    f, c = np.nonzero(clocks.duplicated)
    assert len(f) > 0.03 * clocks.duplicated.size
    assert np.array_equal(clocks.true_times_s[f, c], clocks.true_times_s[f - 1, c])
    assert (np.diff(clocks.timestamps_s, axis=0) > 0).all()
    # dropped ticks leave gaps of about two frame intervals; jitter is ~1 ms RMS
    steps = np.diff(clocks.timestamps_s, axis=0) * 30.0
    assert np.array_equal((np.round(steps) - 1).sum(axis=0), clocks.dropped)  # consecutive drops: one longer gap
    assert 0.07 < clocks.dropped.mean() / 3000 < 0.13
    jitter = (clocks.timestamps_s - 0.002) * 30.0
    residual_ms = (jitter - np.round(jitter)) / 30.0 * 1e3
    assert 0.8 < residual_ms.std() < 1.2
    off, drift = clocks.relative_to(0)
    assert off[0] == 0.0 and drift[0] == 0.0
    s = np.array([0.0, 10.0])  # camera 2's clock onto camera 0's, through true time
    t_true = clocks.offset_s[2] + clocks.rate[2] * s
    assert np.allclose(off[2] + (1 + drift[2]) * s, (t_true - clocks.offset_s[0]) / clocks.rate[0], atol=1e-12)


@pytest.mark.parametrize("field, value", [("sensor.clock.drift_ppm_max", float("nan")), ("sensor.clock.offset_ms_max", -1.0),
                                          ("sensor.clock.drop_probability", 0.9), ("sensor.clock.jitter_ms", float("inf"))])
def test_bad_clock_fields_name_the_file_and_field(field, value):
    with pytest.raises(ScenarioError) as err:
        load_scenario("scenarios/webcams_unsynced.toml", overrides={field: value})
    assert field in str(err.value) and "webcams_unsynced.toml" in str(err.value)


def test_a_zero_clock_renders_exactly_the_synchronised_frames():
    base = {"duration_s": 0.1}
    plain = render_frames(build_stage(load_scenario("scenarios/quickstart.toml", overrides=base)), keep_ids=False)
    zero = render_frames(build_stage(load_scenario("scenarios/quickstart.toml", overrides={
        **base, "sensor.clock.offset_ms_max": 0.0})), keep_ids=False)
    assert np.array_equal(plain.frames, zero.frames)
    assert zero.ground_truth.camera_times is None


def test_timestamps_csv_round_trip(tmp_path):
    clocks = camera_clocks(ClockConfig(offset_ms_max=100.0, jitter_ms=0.5), 2, 40, 30.0, 4.0, seed=1)
    write_timestamps(clocks, ["a", "b"], tmp_path)
    assert np.allclose(read_timestamps(tmp_path / "b.timestamps.csv"), clocks.timestamps_s[:, 1], atol=1e-9)


def test_each_camera_is_rendered_at_its_own_instants():
    sc = load_scenario("scenarios/webcams_unsynced.toml", overrides={"duration_s": 0.2, "motion.start_s": 12.0})
    seq = render_frames(build_stage(sc), keep_ids=False)
    gt = seq.ground_truth
    assert np.array_equal(gt.camera_times[:, 0], gt.times)
    assert np.ptp(gt.camera_times[0]) > 0.2  # the cameras' frames 0 are hundreds of ms apart
    k = 3
    for c in range(1, 4):
        blobs = detect_markers(seq.frames[k, c], DetectionParams(mode="ir")).xy
        vis = gt.marker_visible[k, c]
        own = np.linalg.norm(gt.markers_2d[k, c][vis][:, None] - blobs[None], axis=2).min(axis=1)
        at_cam0 = build_stage(sc).cameras[c].project(gt.markers_3d[k][vis])  # where they were at camera 0's instant
        moved = np.linalg.norm(at_cam0 - gt.markers_2d[k, c][vis], axis=1) > 5.0
        assert moved.any()
        assert np.median(own) < 0.3 and own[moved].max() < 1.0


@pytest.mark.slow  # a rendered take end to end: seconds
def test_unsynchronised_take_is_synchronised_from_the_markers():
    """A short webcams_unsynced take (offsets up to +-500 ms, drift up to +-100 ppm): the run
    recovers the offsets within 1 ms RMS of the truth, and its markers are far better than
    with frames paired by index."""
    sc = load_scenario("scenarios/webcams_unsynced.toml", overrides={"duration_s": 2.5})
    m = run_scenario(sc, write_outputs=False).metrics
    assert m["sync.true_offset_max_ms"] > 300.0
    assert m["sync.offset_error_ms"] < 1.0, m["sync.offset_error_ms"]
    # (the 95th percentile: in the first second one camera has not started yet, and the model
    # labelling swaps a toe marker there on this take)
    assert m["markers.p95_error_mm"] < 3.0
    assert m["markers.rmse_naive_mm"] > 20 * m["markers.p95_error_mm"]


def test_a_duplicated_frame_of_camera_0_is_scored_at_its_timestamps_instant():
    """The pipeline's frames are at camera 0's timestamps; where camera 0 repeats a frame, the
    truth it is scored against is the markers at the instant that timestamp stands for, not at
    the repeated image's (the previous frame's) instant. No render: the ground truth of the
    frames' instants alone."""
    from simbench.pipelines.run import _Run
    from simbench.stage.rendering import FrameRecord, _ground_truth

    sc = load_scenario("scenarios/webcams_unsynced.toml", overrides={
        "duration_s": 2.0, "sensor.clock.duplicate_probability": 0.1})
    stage = build_stage(sc)
    clocks = stage.clocks()
    F, C, M = clocks.true_times_s.shape[0], len(stage.cameras), len(stage.marker_names)
    records = [FrameRecord(float(clocks.true_times_s[k, 0]), np.ones((C, M)), 1) for k in range(F)]
    gt = _ground_truth(stage, records, None, clocks)
    run = _Run.__new__(_Run)
    run.gt, run.stage = gt, stage
    scored = run._gt_at_reference_instants()
    dup = np.flatnonzero(clocks.duplicated[:, 0])
    assert len(dup) >= 3
    at_stamps = stage.states(clocks.offset_s[0] + clocks.rate[0] * clocks.timestamps_s[:, 0]).marker_xpos
    assert np.allclose(scored.markers_3d, at_stamps, atol=1e-9)
    # the repeated image's instant is a frame earlier: the markers there are elsewhere
    assert np.abs(gt.markers_3d[dup] - at_stamps[dup]).max() > 0.01
    assert np.array_equal(scored.markers_3d[~clocks.duplicated[:, 0]], gt.markers_3d[~clocks.duplicated[:, 0]])
    proj = gt.calibration()[2].project(at_stamps[dup[0]])
    assert np.allclose(scored.markers_2d[dup[0], 2], proj, atol=1e-6)
