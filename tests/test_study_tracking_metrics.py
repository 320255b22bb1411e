"""eval.tracking_metrics: the loss definition, prediction errors, CI and Shapiro-Wilk."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from eval import tracking_metrics as tm


def _one_label(F: int = 12):
    true = np.stack([np.linspace(100, 200, F), np.full(F, 240.0)], axis=1)[:, None, :]  # (F, 1, 2)
    visible = np.ones((F, 1), bool)
    status = np.ones((F, 1), np.int8)
    return true, visible, true.copy(), status, true.copy()


def test_label_that_follows_its_marker_is_not_lost():
    true, vis, est, status, meas = _one_label()
    est = est + 3.0  # within the 10 px radius
    res = tm.label_losses(true, vis, est, status, meas, radius_px=10.0)
    assert not res.lost[0] and res.first_frame[0] == -1 and res.reason_names() == [""]
    assert not tm.video_lost(res)


def test_estimate_beyond_radius_is_a_loss_at_its_first_frame():
    true, vis, est, status, meas = _one_label()
    est[5:, 0, 0] += 10.5
    res = tm.label_losses(true, vis, est, status, meas, radius_px=10.0)
    assert res.lost[0] and res.first_frame[0] == 5 and res.reason_names() == ["far"]
    assert (res.flags[5:, 0] == tm.REASON_FAR).all() and (res.flags[:5, 0] == 0).all()


def test_frames_where_the_marker_is_hidden_do_not_count():
    true, vis, est, status, meas = _one_label()
    vis[4:8] = False
    est[4:8, 0, 0] += 50.0  # coasting far off while hidden, back on the marker after
    status[4:8] = 2
    assert not tm.label_losses(true, vis, est, status, meas, radius_px=10.0).lost[0]
    vis[7] = True  # visible again while still off: a loss
    res = tm.label_losses(true, vis, est, status, meas, radius_px=10.0)
    assert res.lost[0] and res.first_frame[0] == 7


def test_declared_lost_while_visible_is_a_loss_and_frame_zero_is_not_scored():
    true, vis, est, status, meas = _one_label()
    status[0] = 0  # frame 0 is the initialisation
    assert not tm.label_losses(true, vis, est, status, meas, radius_px=10.0).lost[0]
    status[3] = 0
    est[3] = np.nan
    res = tm.label_losses(true, vis, est, status, meas, radius_px=10.0)
    assert res.first_frame[0] == 3 and res.reason_names() == ["lost"]


def test_taking_the_other_markers_blob_is_a_swap_only_when_markers_are_apart():
    F = 6
    true = np.zeros((F, 2, 2))
    true[:, 0] = [100.0, 100.0]
    true[:, 1] = [130.0, 100.0]  # 30 px apart
    vis = np.ones((F, 2), bool)
    status = np.ones((F, 2), np.int8)
    est = true.copy()
    meas = true.copy()
    meas[2, 0] = [122.0, 100.0]  # label 0 took a blob nearer marker 1 (estimate still within radius)
    est[2, 0] = [108.0, 100.0]
    res = tm.label_losses(true, vis, est, status, meas, radius_px=10.0)
    assert res.lost.tolist() == [True, False] and res.first_frame[0] == 2 and res.reason_names()[0] == "other"
    # Markers 4 px apart (one merged blob): taking the blob nearer the other marker is no swap.
    true[:, 1] = [104.0, 100.0]
    meas = true.copy()
    meas[2, 0] = [103.5, 100.0]
    est = true.copy()
    assert not tm.label_losses(true, vis, est, status, meas, radius_px=10.0).lost.any()


def test_label_losses_rejects_mismatched_shapes_and_radius():
    true, vis, est, status, meas = _one_label()
    with pytest.raises(ValueError, match="estimate"):
        tm.label_losses(true, vis, est[:-1], status, meas, radius_px=10.0)
    with pytest.raises(ValueError, match="radius"):
        tm.label_losses(true, vis, est, status, meas, radius_px=0.0)


def test_count_and_total_losses():
    recs = [("slow", "a", True), ("slow", "a", False), ("slow", "b", False), ("swap", "a", True), ("swap", "b", True)]
    table = tm.count_losses(recs)
    assert table == {"slow": {"a": 1, "b": 0}, "swap": {"a": 1, "b": 1}}
    assert tm.total_losses(table) == {"a": 2, "b": 1}


def test_prediction_errors_skip_frame_zero_and_missing_detections():
    pred = np.zeros((4, 2, 2))
    meas = np.zeros((4, 2, 2))
    meas[:, 0, 0] = [9.0, 3.0, 4.0, 5.0]
    meas[2, 1] = np.nan
    e = tm.prediction_errors(pred, meas)
    np.testing.assert_allclose(e, [3.0, 0.0, 4.0, 5.0, 0.0])


def test_confidence_interval_matches_the_t_formula():
    rng = np.random.default_rng(3)
    v = rng.exponential(2.0, 400)
    ci = tm.mean_confidence_interval(v, 0.99)
    half = stats.t.ppf(0.995, len(v) - 1) * v.std(ddof=1) / np.sqrt(len(v))
    assert ci.n == 400
    assert ci.mean == pytest.approx(v.mean())
    assert ci.lower == pytest.approx(v.mean() - half) and ci.upper == pytest.approx(v.mean() + half)
    assert np.isnan(tm.mean_confidence_interval(np.zeros(0)).mean)
    assert np.isnan(tm.mean_confidence_interval(np.array([1.0])).lower)


def test_shapiro_wilk_accepts_normal_and_rejects_skewed_errors():
    rng = np.random.default_rng(7)
    normal = tm.shapiro_wilk(rng.normal(5.0, 1.0, 1000))
    skewed = tm.shapiro_wilk(rng.exponential(1.0, 1000))
    assert normal.normal and normal.p_value > 0.01
    assert not skewed.normal and skewed.p_value < 1e-6 and skewed.statistic < normal.statistic
    assert np.isnan(tm.shapiro_wilk(np.ones(5)).p_value)
    summary = tm.summarise_errors(rng.exponential(1.0, 200))
    assert summary.n == 200 and summary.interval.lower < summary.interval.mean < summary.interval.upper


def test_unrecovered_losses_and_merged_markers():
    true, vis, est, status, meas = _one_label()
    est[4:6, 0, 0] += 20.0  # off for two frames, then back on its marker
    res = tm.label_losses(true, vis, est, status, meas, radius_px=10.0)
    assert res.lost[0] and res.bad_frames[0] == 2 and not res.at_end[0]
    vis[-2:] = False
    est[-3:, 0, 0] += 20.0  # off at the last visible frame
    res = tm.label_losses(true, vis, est, status, meas, radius_px=10.0)
    assert res.at_end[0] and res.bad_frames[0] == 3
    xy = np.array([[[0.0, 0.0], [5.0, 0.0], [50.0, 0.0]], [[0.0, 0.0], [9.0, 0.0], [50.0, 0.0]]])
    assert tm.merged_markers(xy, 7.0).tolist() == [[True, True, False], [False, False, False]]
