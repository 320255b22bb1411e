"""Webcams as they are (issue 15): rolling shutter (the row-time render and the pipeline's row-time
correction), auto exposure, vignetting, and their scenario fields."""

from __future__ import annotations

import numpy as np
import pytest

from eval.exposure_metrics import detection_rate, recovery_time_s
from mocap.calibration import Calibration, Camera
from mocap.detection import DetectionParams, detect_markers
from mocap.rolling_shutter import correct_rolling_shutter, detection_times, refine_with_trajectories
from mocap.types import Detections
from simbench.errors import ScenarioError
from simbench.render.frames import rolling_weights, row_times
from simbench.render.sensor import AutoExposure, Sensor, vignetting_map
from simbench.scenario import SensorConfig, load_scenario
from simbench.stage.build import build_stage
from simbench.stage.rendering import render_frames


# ---------------------------------------------------------------- rolling shutter: the render
def test_rolling_weights_follow_each_rows_exposure():
    H, R, e = 480, 0.025, 0.004
    t = 1.0
    sub = t - e / 2 + (R + e) * (np.arange(30) + 0.5) / 30
    w = rolling_weights(sub, t, R, e, H)
    assert w.shape == (30, H) and np.allclose(w.sum(axis=0), 1.0)
    # each row's weighted sub-frame time is its row time, within half a sub-frame step
    step = (R + e) / 30
    assert np.all(np.abs(w.T @ sub - row_times(t, np.arange(H), H, R)) <= step / 2)
    assert np.abs(w.T @ sub - row_times(t, np.arange(H), H, R)).mean() < step / 8
    # without exposure: the nearest sub-frame only
    w0 = rolling_weights(sub, t, R, 0.0, H)
    assert set(np.unique(w0)) <= {0.0, 1.0} and np.allclose(w0.sum(axis=0), 1.0)
    assert np.all(np.abs(w0.T @ sub - row_times(t, np.arange(H), H, R)) <= (R + e) / 30 / 2 + 1e-12)


def _fast_take(readout_ms: float, duration_s: float = 0.2):
    return load_scenario("scenarios/quickstart.toml", overrides={
        "duration_s": duration_s, "motion.start_s": 0.9, "motion.clip": "zigzag_fast", "sensor.exposure_ms": 4.0,
        "sensor.motion_blur": True, "rig.count": 2, "sensor.readout_ms": readout_ms})


def test_a_rolling_shutter_render_shows_moving_markers_where_the_row_time_model_says():
    seq = render_frames(build_stage(_fast_take(25.0)), keep_ids=False)
    gt = seq.ground_truth
    assert gt.readout_s == pytest.approx(0.025) and gt.markers_2d_rolling.shape == gt.markers_2d.shape
    assert gt.n_subframes.min() > 5  # the span (readout + exposure) is rendered in many sub-frames
    model, frame_time = [], []
    for k in range(gt.n_frames):
        for c in range(2):
            d = detect_markers(seq.frames[k, c], DetectionParams(mode="ir"))
            for m in np.flatnonzero(gt.marker_visible[k, c]):
                model.append(np.linalg.norm(d.xy - gt.markers_2d_rolling[k, c, m], axis=1).min())
                frame_time.append(np.linalg.norm(d.xy - gt.markers_2d[k, c, m], axis=1).min())
    model, frame_time = np.array(model), np.array(frame_time)
    assert np.median(model) < 0.15 and np.percentile(model, 95) < 0.4
    assert np.percentile(frame_time, 95) > 1.5  # the fast markers are pixels away from the frame time's projection
    # determinism: the same scenario and seed render the same frames
    again = render_frames(build_stage(_fast_take(25.0, duration_s=0.1)), keep_ids=False)
    assert np.array_equal(again.frames, seq.frames[: again.ground_truth.n_frames])


def test_without_a_readout_the_render_is_the_global_shutter_one():
    a = render_frames(build_stage(load_scenario("scenarios/quickstart.toml", overrides={"duration_s": 0.1})), keep_ids=False)
    b = render_frames(build_stage(load_scenario("scenarios/quickstart.toml", overrides={"duration_s": 0.1, "sensor.readout_ms": 0.0})),
                      keep_ids=False)
    assert np.array_equal(a.frames, b.frames) and b.ground_truth.markers_2d_rolling is None


# ---------------------------------------------------------------- rolling shutter: the correction
def _rig() -> Calibration:
    K = np.array([[700.0, 0, 320], [0, 700.0, 240], [0, 0, 1]])
    cams = []
    for i, ang in enumerate((0.0, np.pi / 2)):
        c = np.array([3 * np.cos(ang), 3 * np.sin(ang), 1.0])
        z = -c / np.linalg.norm(c)
        x = np.cross(z, [0, 0, 1.0])
        x /= np.linalg.norm(x)
        y = np.cross(z, x)
        R = np.stack([x, y, z])
        cams.append(Camera(f"c{i}", (640, 480), K, np.zeros(5), R, -R @ c))
    return Calibration(tuple(cams))


def _moving_points(t: np.ndarray) -> np.ndarray:
    """(T, 3, 3): three markers on fast, curved paths (~3 m/s)."""
    base = np.array([[0.0, 0.0, 1.0], [0.2, 0.1, 1.3], [-0.2, -0.1, 0.7]])
    w = 2 * np.pi * 1.5
    off = np.stack([0.3 * np.sin(w * t), 0.25 * np.cos(0.7 * w * t), 0.15 * np.sin(1.3 * w * t + 1)], axis=1)
    return base[None] + off[:, None]


def _rolling_observations(cal: Calibration, times: np.ndarray, readout: float, points=_moving_points):
    """Each camera's blobs where a rolling shutter shows the markers ``points(t)`` (fixed point of
    the row-time model)."""
    out = []
    for cam in cal:
        frames = []
        for t in times:
            uv = cam.project(points(np.array([t]))[0])
            for _ in range(6):
                tt = t + uv[:, 1] / cam.size[1] * readout
                uv = np.array([cam.project(points(np.array([ti]))[0][m:m + 1])[0] for m, ti in enumerate(tt)])
            frames.append(Detections(uv, np.full(3, 20.0), np.full(3, 200.0)))
        out.append(frames)
    return out


def test_the_row_time_correction_moves_blobs_to_the_frame_timestamps():
    cal, readout = _rig(), 0.025
    times = np.arange(30) / 30.0
    raw = _rolling_observations(cal, times, readout)
    truth = [np.stack([cam.project(p) for p in _moving_points(times)]) for cam in cal]  # (F, 3, 2)
    d = raw[0][5]
    assert np.allclose(detection_times(d, times[5], readout, 480), times[5] + d.xy[:, 1] / 480 * readout)
    first = correct_rolling_shutter(raw, [times, times], readout, 480)
    for c in range(2):
        before = np.array([np.linalg.norm(raw[c][k].xy - truth[c][k], axis=1) for k in range(1, 29)])
        after = np.array([np.linalg.norm(first[c][k].xy - truth[c][k], axis=1) for k in range(1, 29)])
        assert before.mean() > 1.0 and before.max() > 2.0 and after.max() < 0.5 and after.mean() < 0.1 * before.mean()
    # the refinement by the markers' own 3D motion: exact trajectories give the frame-time projections
    traj = type("T", (), {"xyz": _moving_points(times)})()
    refined = refine_with_trajectories(raw, first, times, readout, cal, traj)
    err = np.array([np.linalg.norm(refined[c][k].xy - truth[c][k], axis=1) for c in range(2) for k in range(1, 29)])
    assert err.max() < 0.1
    # readout 0 leaves the blobs as they are
    same = correct_rolling_shutter(raw, [times, times], 0.0, 480)
    assert all(a is b for a, b in zip(same[0], raw[0]))


def test_the_refinement_follows_a_fast_reversal_with_a_cubic():
    """Markers reversing at ~6 m/s (3 Hz sweeps of 0.3 m) on jittered frame times, refined with
    exact trajectories: the cubic through the four frames around each row's instant lands within
    a quarter pixel of the frame-time projection; a parabola through three frames does not."""
    def fast(t):
        base = np.array([[0.0, 0.0, 1.0], [0.2, 0.1, 1.3], [-0.2, -0.1, 0.7]])
        w = 2 * np.pi * 3.0
        off = np.stack([0.3 * np.sin(w * t), 0.2 * np.cos(0.8 * w * t), 0.15 * np.sin(1.1 * w * t + 1)], axis=1)
        return base[None] + off[:, None]

    cal, readout = _rig(), 0.025
    times = np.arange(30) / 30.0 + np.random.default_rng(0).normal(0.0, 5e-4, 30)
    raw = _rolling_observations(cal, times, readout, fast)
    truth = [np.stack([cam.project(p) for p in fast(times)]) for cam in cal]
    first = correct_rolling_shutter(raw, [times, times], readout, 480)
    traj = type("T", (), {"xyz": fast(times)})()

    def errors(degree):
        refined = refine_with_trajectories(raw, first, times, readout, cal, traj, degree=degree)
        return np.array([np.linalg.norm(refined[c][k].xy - truth[c][k], axis=1) for c in range(2) for k in range(1, 28)])

    before = np.array([np.linalg.norm(raw[c][k].xy - truth[c][k], axis=1) for c in range(2) for k in range(1, 28)])
    cubic, parabola = errors(3), errors(2)
    assert before.max() > 8.0  # the readout really moves the markers
    assert cubic.max() < 0.35 and np.median(cubic) < 0.06
    assert np.median(cubic) < 0.4 * np.median(parabola) and parabola.max() > 0.5


# ---------------------------------------------------------------- auto exposure, vignetting
def test_auto_exposure_brightness_recovers_with_its_time_constant():
    fps, tau = 30.0, 0.1
    cfg = SensorConfig(mode="ir", gamma="linear", auto_exposure=True, ae_target=0.2, ae_adapt_s=tau, ae_max_gain=64.0,
                       psf_sigma_px=0.0, shot_noise=False, read_noise_e=0.0)
    sensor, ae = Sensor(cfg, fps), AutoExposure(cfg, fps)
    bright = np.full((40, 50, 1), 0.5, np.float32)  # gain 1 reaches the target: room for 8x more
    levels = []
    for k in range(60):
        rad = bright if k < 20 else bright / 8.0  # the light drops eightfold at frame 20
        frame = sensor.frame(rad, None, None, out=np.empty((40, 50, 3), np.uint8), ae=ae)
        levels.append(frame[..., 0].mean() / 255.0)
    levels = np.array(levels)
    assert abs(levels[19] - 0.2) < 0.01  # converged before
    assert levels[20] < 0.04  # the step: the gain has not moved yet
    # then the log error decays as exp(-t / tau), one frame late
    err = np.log(0.2 / levels[20:40])
    expected = np.log(8.0) * np.exp(-np.arange(20) / (fps * tau))
    assert np.allclose(err[1:12], expected[1:12], atol=0.05)  # (8-bit levels; the first is 6/255)
    t_back = (np.argmax(levels[20:] > 0.9 * 0.2)) / fps
    assert t_back == pytest.approx(tau * np.log(np.log(8.0) / -np.log(0.9)), abs=1.5 / fps)


def test_vignetting_darkens_the_corners_by_its_strength():
    v = vignetting_map(48, 64, 0.4)
    assert v[24, 32] == pytest.approx(1.0, abs=0.01) and v[0, 0] == pytest.approx(0.6, abs=1e-5)
    cfg = SensorConfig(mode="ir", gamma="linear", vignetting=0.4, psf_sigma_px=0.0, shot_noise=False, read_noise_e=0.0)
    img = Sensor(cfg, 30.0).frame(np.full((48, 64, 1), 0.05, np.float32), None, None)
    assert img[0, 0, 0] / img[24, 31, 0] == pytest.approx(0.6, abs=0.02)


def test_recovery_time_and_detection_rate():
    t = np.arange(60) / 30.0
    rate = np.where(t < 1.0, 0.9, np.where(t < 1.3, 0.3, 0.88))
    assert recovery_time_s(t, rate, 1.0) == pytest.approx(t[t >= 1.3][0] - 1.0)
    assert recovery_time_s(t, np.full(60, 0.9), 1.0) == 0.0
    assert recovery_time_s(t, np.where(t < 1.0, 0.9, 0.1), 1.0) == float("inf")
    true_xy = np.zeros((1, 1, 2, 2))
    true_xy[0, 0, 1] = [10, 10]
    assert detection_rate([[np.array([[0.5, 0.5]])]], true_xy, np.ones((1, 1, 2), bool))[0] == 0.5


# ---------------------------------------------------------------- scenario fields
@pytest.mark.parametrize("field, value", [("sensor.readout_ms", 40.0), ("sensor.readout_ms", -1.0),
                                          ("sensor.ae_target", 1.5), ("sensor.ae_adapt_s", 0.0),
                                          ("sensor.vignetting", 1.0), ("sensor.auto_exposure", "yes"),
                                          ("markers_pipeline.rolling_shutter_correction", 2)])
def test_bad_webcam_fields_name_the_file_and_field(field, value):
    with pytest.raises(ScenarioError) as err:
        load_scenario("scenarios/webcams_rolling_shutter.toml", overrides={field: value})
    assert field in str(err.value) and "webcams_rolling_shutter.toml" in str(err.value)


def test_the_new_fields_at_their_defaults_keep_the_content_hash():
    sc = load_scenario("scenarios/quickstart.toml")
    same = sc.with_overrides({"sensor.readout_ms": 0.0, "sensor.auto_exposure": False, "sensor.vignetting": 0.0,
                              "markers_pipeline.rolling_shutter_correction": True})
    assert same.content_hash() == sc.content_hash()
    assert sc.with_overrides({"sensor.readout_ms": 10.0}).content_hash() != sc.content_hash()
