"""The virtual webcam: distortion as OpenCV models it, shutter blur, sensor noise, light colour."""

from __future__ import annotations

import numpy as np
import pytest

from mocap.detection import DetectionParams, detect_markers
from simbench.stage.build import build_stage
from simbench.render.camera import VirtualCamera, look_at_rotation
from simbench.render.color import cct_to_rgb
from simbench.render.lighting import Lighting
from simbench.render.sensor import Sensor, WhiteBalance
from simbench.stage.rendering import render_frames
from simbench.scenario import CameraConfig, LightingConfig, SensorConfig, load_scenario


def test_look_at_points_the_optical_axis_at_the_target():
    cam = VirtualCamera.from_config(CameraConfig(name="c", position=(3.0, 1.0, 2.0), look_at=(0.0, 0.0, 1.0), hfov_deg=60))
    uv = cam.project(np.array([[0.0, 0.0, 1.0]]))[0]
    np.testing.assert_allclose(uv, [(640 - 1) / 2, (480 - 1) / 2], atol=1e-9)
    R = look_at_rotation(np.array([3.0, 1.0, 2.0]), np.zeros(3))
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    # Image "up" is world +Z: a point above the target projects above the centre (smaller v).
    assert cam.project(np.array([[0.0, 0.0, 1.5]]))[0, 1] < uv[1]


def test_distorted_render_puts_markers_where_opencv_projects_them():
    """Strong barrel distortion (k1 = -0.28): detected blobs sit at cv2.projectPoints of the
    true marker centres, including near the image border."""
    sc = load_scenario("scenarios/wide_angle_distorted.toml", overrides={
        "duration_s": 0.1, "rig.count": 2, "sensor.shot_noise": False, "sensor.read_noise_e": 0.0})
    seq = render_frames(build_stage(sc), keep_frames=True)
    gt = seq.ground_truth
    d_all, r_all = [], []
    for f in range(gt.n_frames):
        for c in range(2):
            det = detect_markers(seq.frames[f, c], DetectionParams(mode="ir"))
            uv = gt.markers_2d[f, c][gt.marker_visible[f, c]]
            d_all.append(np.linalg.norm(uv[:, None] - det.xy[None], axis=2).min(axis=1))
            r_all.append(np.linalg.norm(uv - gt.K[c, :2, 2], axis=1))
    d, r = np.concatenate(d_all), np.concatenate(r_all)
    assert np.median(d[d < 2]) < 0.2
    assert np.mean(d < 1.0) > 0.97
    # The claim is about distortion: markers far from the centre (where it displaces
    # points by many pixels) are as accurate as the rest.
    far = r > 0.6 * r.max()
    assert far.sum() > 20 and np.median(d[far]) < 0.3


def test_shutter_blur_streak_grows_with_exposure():
    """The same fast motion with a 4x longer shutter smears each marker into a longer blob."""
    areas = {}
    for exposure in (4.0, 16.0):
        sc = load_scenario("scenarios/blur_zigzag.toml", overrides={
            "duration_s": 0.1, "rig.count": 1, "sensor.exposure_ms": exposure, "sensor.shot_noise": False,
            "sensor.read_noise_e": 0.0, "motion.start_s": 1.4})
        seq = render_frames(build_stage(sc), keep_frames=True)
        det = detect_markers(seq.frames[1, 0], DetectionParams(mode="ir"))
        areas[exposure] = (np.percentile(det.area, 90), seq.ground_truth.n_subframes[1])
    assert areas[16.0][1] > areas[4.0][1] >= 1
    assert areas[16.0][0] > 1.5 * areas[4.0][0]


def test_sensor_noise_follows_the_shot_noise_model():
    """Flat grey input: the variance in electrons equals mean + read_noise^2."""
    cfg = SensorConfig(mode="visible", read_noise_e=5.0, gain=1.0, full_well_e=20000.0, gamma="linear")
    s = Sensor(cfg, 30.0)
    rad = np.full((200, 200, 3), 1.5, np.float32)
    e = s.electrons(rad, np.random.default_rng(0))
    mean = 1.5 * cfg.electrons_per_unit * cfg.exposure_ms * 1e-3
    assert abs(e.mean() - mean) / mean < 0.01
    np.testing.assert_allclose(e.var(), mean + 25.0, rtol=0.03)
    frame = s.to_frame(e, None)
    assert frame.dtype == np.uint8 and frame.shape == (200, 200, 3)
    np.testing.assert_allclose(frame.mean(), mean / cfg.full_well_e * 255, rtol=0.02)


def test_tungsten_is_redder_than_daylight_and_fixed_white_balance_neutralises_its_own_light():
    warm, cool = cct_to_rgb(2800.0), cct_to_rgb(6500.0)
    assert warm[0] / warm[2] > 2.0 > 1.0 > cool[0] / cool[2] * 0.9
    # D65 (sRGB white) lies 0.003 Duv above the Planckian locus, so a 6504 K blackbody is
    # within a few percent of neutral but not exactly.
    np.testing.assert_allclose(cct_to_rgb(6504.0), [1.0, 1.0, 1.0], atol=0.05)
    wb = WhiteBalance(SensorConfig(white_balance="fixed", wb_cct_k=2800.0), 30.0)
    balanced = warm * wb.update(np.zeros((2, 2, 3), np.float32))
    np.testing.assert_allclose(balanced / balanced[1], [1, 1, 1], atol=1e-6)


def test_light_event_switches_the_lamp_off_at_its_time():
    light = Lighting(LightingConfig(preset="mixed", events=({"t_s": 1.5, "light": "tungsten", "intensity": 0.0},)))
    i = light.names.index("tungsten")
    assert light.intensities_at(1.49)[i] > 0
    assert light.intensities_at(1.5)[i] == 0
    assert len(light.lights_at(2.0)) == len(light.lights_at(0.0)) - 1


def test_tungsten_off_scenario_frames_get_bluer_after_the_event():
    sc = load_scenario("scenarios/shirt_tungsten_off.toml", overrides={"duration_s": 3.0, "fps": 2.0})
    seq = render_frames(build_stage(sc), keep_frames=True)
    before, after = seq.frames[1, 0].reshape(-1, 3).mean(0), seq.frames[4, 0].reshape(-1, 3).mean(0)
    assert seq.ground_truth.light_intensity[1, sc_index(seq, "tungsten")] > 0
    assert seq.ground_truth.light_intensity[4, sc_index(seq, "tungsten")] == 0
    assert before[0] / before[2] > 1.05 * after[0] / after[2]
    assert before.sum() > after.sum()


def sc_index(seq, name: str) -> int:
    return seq.ground_truth.light_names.index(name)
