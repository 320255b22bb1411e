"""The sensor's fast path and GL passes against the reference numpy sensor model."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from simbench.render.sensor import Sensor, WhiteBalance
from simbench.scenario import SensorConfig


def _scene_radiance(h: int = 120, w: int = 160) -> np.ndarray:
    """RGBA float32 test radiance: smooth colour ramps, hard-edged discs, a saturated patch,
    black areas (alpha 1, as the rasteriser's read-back)."""
    y, x = np.mgrid[0:h, 0:w].astype(np.float32)
    rad = np.zeros((h, w, 4), np.float32)
    rad[..., 0] = 0.6 * x / w
    rad[..., 1] = 0.5 * y / h
    rad[..., 2] = 0.3 * (1 + np.sin(x / 7.0) * np.cos(y / 5.0)) / 2
    for cx, cy, r, v in ((40, 30, 9.5, 0.9), (110, 80, 4.3, 1.5), (70, 95, 12.0, 0.05)):
        rad[(x - cx) ** 2 + (y - cy) ** 2 <= r * r, :3] = v
    rad[5:20, 120:150, :3] = 20.0  # far above full well
    rad[100:118, 5:30, :3] = 0.0
    rad[..., 3] = 1.0
    return rad


def _reference_frame(sensor: Sensor, rad: np.ndarray, wb, psf: float, rng=None) -> np.ndarray:
    img = rad[..., :3]
    if psf > 0:
        img = cv2.GaussianBlur(img, (0, 0), psf)
    return sensor.to_frame(sensor.electrons(img, rng), wb)


CONFIGS = {
    "srgb_fixed_wb": dict(mode="visible", white_balance="fixed", wb_cct_k=3200.0),
    "auto_wb": dict(mode="visible", white_balance="auto"),
    "gain_below_one": dict(mode="visible", gain=0.6),
    "linear_gamma_high_gain": dict(mode="visible", gamma="linear", gain=8.0),
    "ir": dict(mode="ir", gain=2.0),
}


@pytest.mark.parametrize("psf", [0.0, 0.4, 1.3])
@pytest.mark.parametrize("name", sorted(CONFIGS))
def test_fast_sensor_equals_the_reference_without_noise(name, psf):
    """Noise off: Sensor.frame (the renderer's path) gives the reference's frame within one
    grey level, and exactly on nearly every pixel."""
    cfg = SensorConfig(**CONFIGS[name], shot_noise=False, read_noise_e=0.0, psf_sigma_px=psf)
    rad = _scene_radiance()
    fast_sensor, ref_sensor = Sensor(cfg, 30.0), Sensor(cfg, 30.0)
    wb_fast, wb_ref = WhiteBalance(cfg, 30.0), WhiteBalance(cfg, 30.0)
    for n_sub in (1, 3):  # the fast path takes the shutter's sum and divides by the sub-frame count
        fast = fast_sensor.frame(rad * np.float32(n_sub), None, wb_fast, psf, n_sub)
        ref = _reference_frame(ref_sensor, rad, wb_ref, psf)
        d = np.abs(fast.astype(int) - ref)
        assert fast.shape == ref.shape == (120, 160, 3) and fast.dtype == np.uint8
        assert d.max() <= 1, (name, psf, n_sub, d.max())
        assert np.mean(d == 0) > 0.995, (name, psf, n_sub, np.mean(d == 0))
    if cfg.mode == "ir":
        assert np.array_equal(fast[..., 0], fast[..., 1]) and np.array_equal(fast[..., 0], fast[..., 2])


def _flat_patch_stats(frame_fn, levels_e, cfg, size=200):
    """Mean and variance of the output level of flat patches at the given electron counts."""
    scale = cfg.electrons_per_unit * cfg.exposure_ms * 1e-3
    out = []
    for e in levels_e:
        rad = np.full((size, size, 4), e / scale, np.float32)
        rad[..., 3] = 1.0
        f = frame_fn(rad).astype(np.float64)
        out.append((f.reshape(-1, 3).mean(0), f.reshape(-1, 3).var(0)))
    return out


# Linear gamma and a high gain make one electron worth 0.2 output level, so the noise
# spans several levels and its variance can be read off the 8-bit frame.
NOISE_CFG = SensorConfig(mode="visible", gamma="linear", gain=16.0, full_well_e=20000.0, read_noise_e=5.0,
                         shot_noise=True, psf_sigma_px=0.0)
NOISE_LEVELS_E = (60.0, 400.0, 900.0)


def _check_noise_model(stats, cfg):
    c = cfg.gain * 255.0 / cfg.full_well_e  # output levels per electron
    for e, (mean, var) in zip(NOISE_LEVELS_E, stats):
        expected_var = (e + cfg.read_noise_e**2) * c * c + 1.0 / 12.0  # shot + read noise, + 8-bit quantisation
        np.testing.assert_allclose(mean, e * c, rtol=0.01, atol=0.05, err_msg=f"mean at {e} e-")
        np.testing.assert_allclose(var, expected_var, rtol=0.05, err_msg=f"variance at {e} e-")


def test_fast_sensor_noise_has_the_shot_and_read_noise_of_the_model():
    """Flat patches: per-level mean and variance of the fast path's frames follow the model
    (variance = electrons + read noise^2), as the reference's do."""
    fast, ref = Sensor(NOISE_CFG, 30.0), Sensor(NOISE_CFG, 30.0)
    rng_fast, rng_ref = np.random.default_rng(1), np.random.default_rng(2)
    _check_noise_model(_flat_patch_stats(lambda r: fast.frame(r, rng_fast, None, 0.0), NOISE_LEVELS_E, NOISE_CFG),
                       NOISE_CFG)
    _check_noise_model(_flat_patch_stats(lambda r: _reference_frame(ref, r, None, 0.0, rng_ref), NOISE_LEVELS_E,
                                         NOISE_CFG), NOISE_CFG)
    # Deterministic given the generator's state; a different state, different noise.
    rad = np.full((50, 50, 4), 400.0 / (NOISE_CFG.electrons_per_unit * NOISE_CFG.exposure_ms * 1e-3), np.float32)
    a = fast.frame(rad, np.random.default_rng(7), None, 0.0)
    assert np.array_equal(a, fast.frame(rad, np.random.default_rng(7), None, 0.0))
    assert not np.array_equal(a, fast.frame(rad, np.random.default_rng(8), None, 0.0))


def test_fast_sensor_noise_is_independent_over_time_and_between_neighbours():
    """The fast path's noise is a window of a pre-drawn table at a per-frame offset: over
    many frames of a flat patch each pixel's temporal variance is the model's, and
    neighbouring pixels, channels and consecutive frames are uncorrelated."""
    cfg = NOISE_CFG
    e = 400.0
    c = cfg.gain * 255.0 / cfg.full_well_e
    sensor = Sensor(cfg, 30.0, noise_rng=np.random.default_rng(11))
    rad = np.full((48, 64, 4), e / (cfg.electrons_per_unit * cfg.exposure_ms * 1e-3), np.float32)
    frames = np.stack([sensor.frame(rad, np.random.default_rng([12, k]), None, 0.0) for k in range(64)]).astype(float)
    temporal_var = frames.var(axis=0, ddof=1)  # (H, W, 3): per pixel and channel over the 64 frames
    expected = (e + cfg.read_noise_e**2) * c * c + 1.0 / 12.0
    np.testing.assert_allclose(temporal_var.mean(), expected, rtol=0.03)
    assert np.all(np.abs(np.log(temporal_var / expected)) < 1.2)  # no pixel frozen or doubled
    d = frames - frames.mean(axis=0)
    pairs = {"right": (d[:, :, 1:], d[:, :, :-1]), "down": (d[:, 1:], d[:, :-1]),
             "channel": (d[..., 0], d[..., 1]), "next frame": (d[1:], d[:-1])}
    for name, (a, b) in pairs.items():
        r = np.corrcoef(a.ravel(), b.ravel())[0, 1]
        assert abs(r) < 0.02, (name, r)
    # Same generators, same frames (the table comes from noise_rng, the offset from the frame's rng).
    again = Sensor(cfg, 30.0, noise_rng=np.random.default_rng(11))
    assert np.array_equal(again.frame(rad, np.random.default_rng([12, 5]), None, 0.0), frames[5])


@pytest.mark.parametrize("overrides", [dict(mode="visible"), dict(mode="ir"), dict(mode="visible", jpeg_quality=80)],
                         ids=["visible", "ir", "jpeg"])
def test_fast_sensor_writes_into_a_given_frame(overrides):
    cfg = SensorConfig(**overrides)
    rad = _scene_radiance()
    s = Sensor(cfg, 30.0)
    expected = s.frame(rad, np.random.default_rng(3), WhiteBalance(cfg, 30.0), 0.4)
    frames = np.zeros((2,) + expected.shape, np.uint8)
    got = s.frame(rad, np.random.default_rng(3), WhiteBalance(cfg, 30.0), 0.4, out=frames[1])
    assert np.shares_memory(got, frames[1]) and np.array_equal(frames[1], expected) and not frames[0].any()
    with pytest.raises(ValueError):
        s.frame(rad, None, None, 0.4, out=frames[1, :, :10])


# ---------------------------------------------------------------- GL passes
@pytest.fixture(scope="module")
def gl_pipeline():
    from simbench.errors import GLUnavailableError

    try:
        from simbench.render.gl_sensor import GLSensorPipeline
        from simbench.render.rasterizer import Rasterizer

        return GLSensorPipeline(Rasterizer())
    except GLUnavailableError as exc:  # pragma: no cover - machines without EGL/OSMesa
        pytest.skip(str(exc))


def _gl_frame(pipe, rad, sensor, wb, psf, rng=None, n_sub=1):
    tex = pipe.upload(rad)
    h, w = rad.shape[:2]
    return pipe.finish(tex, n_sub, (w, h), 1, None, (w, h), sensor, wb, psf, rng)


@pytest.mark.parametrize("name", sorted(CONFIGS))
def test_gl_sensor_equals_the_reference_without_noise(gl_pipeline, name):
    psf = 0.4
    cfg = SensorConfig(**CONFIGS[name], shot_noise=False, read_noise_e=0.0, psf_sigma_px=psf)
    rad = _scene_radiance()
    gl_sensor, ref_sensor = Sensor(cfg, 30.0), Sensor(cfg, 30.0)
    wb_gl, wb_ref = WhiteBalance(cfg, 30.0), WhiteBalance(cfg, 30.0)
    glf = _gl_frame(gl_pipeline, rad * np.float32(2), gl_sensor, wb_gl, psf, n_sub=2)
    ref = _reference_frame(ref_sensor, rad, wb_ref, psf)
    d = np.abs(glf.astype(int) - ref)
    assert d.max() <= 1, (name, d.max())
    # Grey world on the GL side averages every pixel, the reference every 7th: gains
    # agree to a fraction of a percent, which moves some levels by one.
    np.testing.assert_allclose(wb_gl.gains, wb_ref.gains, rtol=0.01)
    assert np.mean(d == 0) > (0.85 if cfg.white_balance == "auto" else 0.99), (name, np.mean(d == 0))


def test_gl_sensor_noise_has_the_shot_and_read_noise_of_the_model(gl_pipeline):
    s = Sensor(NOISE_CFG, 30.0)
    rng = np.random.default_rng(3)
    _check_noise_model(_flat_patch_stats(lambda r: _gl_frame(gl_pipeline, r, s, None, 0.0, rng), NOISE_LEVELS_E,
                                         NOISE_CFG), NOISE_CFG)
    # Neighbouring pixels and channels are uncorrelated (the hash has no visible structure).
    rad = np.full((200, 200, 4), 400.0 / (NOISE_CFG.electrons_per_unit * NOISE_CFG.exposure_ms * 1e-3), np.float32)
    f = _gl_frame(gl_pipeline, rad, s, None, 0.0, np.random.default_rng(4)).astype(float)
    f -= f.mean()
    for a, b in ((f[:, 1:, 0], f[:, :-1, 0]), (f[1:, :, 0], f[:-1, :, 0]), (f[..., 0], f[..., 1]), (f[..., 1], f[..., 2])):
        assert abs(np.corrcoef(a.ravel(), b.ravel())[0, 1]) < 0.02
    g = _gl_frame(gl_pipeline, rad, s, None, 0.0, np.random.default_rng(5)).astype(float)
    assert abs(np.corrcoef(f.ravel(), g.ravel() - g.mean())[0, 1]) < 0.02  # frame to frame


# ---------------------------------------------------------------- whole frames
def _frames(sc, backend: str) -> np.ndarray:
    from simbench.stage.build import build_stage
    from simbench.render.frames import iterate_frames

    bench = build_stage(sc)
    fr = bench.frame_renderer()
    fr.set_sensor_backend(backend)
    return np.stack([o.images for o in iterate_frames(fr, bench.frame_times(), bench.pose_at, sc.seed)])


@pytest.mark.parametrize("path,overrides", [
    ("scenarios/quickstart.toml", {"sensor.mode": "visible", "sensor.antialias": 2, "sensor.motion_blur": True}),
    ("scenarios/quickstart.toml", {"sensor.antialias": 1, "sensor.motion_blur": True, "sensor.exposure_ms": 16.0}),
    ("scenarios/wide_angle_distorted.toml", {}),
], ids=["visible_ss2_blur", "ir_blur", "ir_distorted"])
def test_rendered_frames_agree_across_sensor_backends(path, overrides):
    """Noise off, whole rendered frames (supersampling, shutter sub-frames, distortion,
    optics blur): the fast path and the GL passes give the reference's frames within one
    grey level, exactly on nearly every pixel."""
    from simbench.scenario import load_scenario

    sc = load_scenario(path, overrides={"duration_s": 0.07, "rig.count": 2, "motion.start_s": 1.0,
                                        "sensor.shot_noise": False, "sensor.read_noise_e": 0.0, **overrides})
    ref = _frames(sc, "reference").astype(int)
    assert ref.max() > 50 and ref.std() > 3  # not a blank frame
    for backend in ("numpy", "gl"):
        d = np.abs(_frames(sc, backend) - ref)
        assert d.max() <= 1, (backend, d.max())
        assert np.mean(d == 0) > 0.999, (backend, np.mean(d == 0))
