"""Issue 15 end to end: `simbench run` of the rolling-shutter and lamp-switch-off webcam scenarios,
short, scored against their ground truth."""

from __future__ import annotations

import numpy as np

from simbench.pipelines.run import run_scenario
from simbench.scenario import load_scenario


def test_the_row_time_correction_beats_triangulating_rows_as_simultaneous(tmp_path):
    # 0.5 s (15 frames; 2026-11-27: corrected 0.85 mm against 7.19 mm uncorrected, 28.6 CPU-s for the
    # run); 0.6 s gave 0.84 / 7.44 in 33.7 CPU-s
    sc = load_scenario("scenarios/webcams_rolling_shutter.toml",
                       overrides={"duration_s": 0.5, "motion.start_s": 0.5, "sensor.antialias": 1})
    res = run_scenario(sc, out=tmp_path / "run")
    m = res.metrics
    assert m["rolling_shutter.readout_ms"] == 25.0
    assert m["markers.rmse_mm"] == m["rolling_shutter.rmse_corrected_mm"]  # the correction is on by default
    assert m["rolling_shutter.rmse_corrected_mm"] < 0.35 * m["rolling_shutter.rmse_uncorrected_mm"]
    assert m["rolling_shutter.rmse_corrected_mm"] < 2.5
    assert "## Rolling shutter" in (tmp_path / "run" / "report.md").read_text()
    gt = res.sequence.ground_truth
    assert gt.readout_s == 0.025 and np.isfinite(gt.markers_2d_rolling).any()


def test_auto_exposure_through_a_lamp_switch_off_is_scored_and_reported(tmp_path):
    sc = load_scenario("scenarios/webcams_lamp_off.toml", overrides={
        "duration_s": 1.2, "rig.count": 2, "sensor.antialias": 1, "markers_pipeline.solve_skeleton": False,
        "lighting.events": [{"t_s": 0.6, "light": "lamp", "intensity": 0.0}]})
    res = run_scenario(sc, out=tmp_path / "run")
    m = res.metrics
    assert 0.0 <= m["detections.recovery_s"] <= 0.5
    assert 0.1 < m["exposure.brightness_recovery_s"] < 0.5  # a 0.1 s time constant from a 60x step: ~0.3 s
    report = (tmp_path / "run" / "report.md").read_text()
    assert "## Light events" in report and "| t - event (s) | mean grey level | detection rate | precision |" in report
