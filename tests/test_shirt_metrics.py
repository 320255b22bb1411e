"""eval.shirt_metrics against hand-computed values."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from eval.shirt_metrics import RocCounts, classification_roc, fill_forward, frames_within_cm, per_frame_rms_cm, rmse_cm, shoulder_angle_deg

NAMES = ("abdomen", "thorax", "head", "upperarm_l", "forearm_l", "hand_l", "upperarm_r", "forearm_r", "hand_r")


def test_rmse_in_centimetres_skips_missing_points():
    true = np.zeros((2, 3, 3))
    est = true.copy()
    est[0, 0] = [0.03, 0.0, 0.04]  # 5 cm
    est[1, 2] = np.nan
    assert rmse_cm(est, true) == pytest.approx(np.sqrt(25.0 / 5.0))
    np.testing.assert_allclose(per_frame_rms_cm(est, true), [np.sqrt(25.0 / 3.0), np.nan])


def test_fill_forward_holds_the_last_complete_row():
    v = np.array([[np.nan, 1.0], [1.0, 2.0], [np.nan, 3.0], [4.0, 5.0]])
    out = fill_forward(v)
    assert np.isnan(out[0, 0]) and out[0, 1] == 1.0  # nothing to hold yet
    assert out[2].tolist() == [1.0, 2.0] and out[3].tolist() == [4.0, 5.0]


def test_shoulder_angle_between_upper_arm_and_trunk_axis():
    j = np.zeros((3, len(NAMES), 3))
    j[:, NAMES.index("abdomen")] = [0.0, 0.0, 1.0]
    j[:, NAMES.index("head")] = [0.0, 0.0, 1.5]
    j[:, NAMES.index("upperarm_r")] = [0.0, -0.2, 1.45]
    j[0, NAMES.index("forearm_r")] = [0.0, -0.2, 1.15]  # hanging: 0 deg
    j[1, NAMES.index("forearm_r")] = [0.0, -0.5, 1.45]  # sideways: 90 deg
    j[2, NAMES.index("forearm_r")] = [0.3, -0.2, 1.45 + 0.3]  # forward and up: 135 deg
    np.testing.assert_allclose(shoulder_angle_deg(j, NAMES, "r"), [0.0, 90.0, 135.0], atol=1e-9)


def test_roc_counts_correct_shirt_pixels_and_all_wrong_classifications():
    score = np.array([0.5, 1.0, 2.0, 3.0, 4.0, np.inf])
    pred = np.array([0, 1, 1, 2, 0, 1])
    truth = np.array([0, 1, 0, -1, 0, 1])  # pixel 3 is not shirt
    cor, inc = classification_roc(score, pred, truth, np.array([0.0, 1.5, 3.5, 10.0]))
    np.testing.assert_allclose(cor, [0.0, 2 / 5, 2 / 5, 3 / 5])  # 5 shirt pixels
    np.testing.assert_allclose(inc, [0.0, 0.0, 2 / 6, 2 / 6])


def test_frames_within_counts_frames_whose_elbows_and_wrists_are_all_close():
    true = np.zeros((4, len(NAMES), 3))
    est = true.copy()
    est[1, NAMES.index("hand_r")] = [0.0, 0.049, 0.0]     # 4.9 cm: still within
    est[2, NAMES.index("forearm_l")] = [0.0, 0.0, 0.051]  # an elbow 5.1 cm off: not
    est[3, NAMES.index("head")] = [1.0, 0.0, 0.0]         # the head does not count
    assert frames_within_cm(est, true, NAMES) == pytest.approx(3 / 4)
    est[0] = np.nan                                       # a lost frame is not within
    assert frames_within_cm(est, true, NAMES) == pytest.approx(2 / 4)
    assert frames_within_cm(est, true, NAMES, joints=("head",), threshold_cm=200.0) == pytest.approx(3 / 4)


def _roc_by_sorting(score, predicted, truth, thresholds):
    """The ROC by one sort of all pixels and cumulative sums: an independent formulation to check against."""
    s, p, t = np.asarray(score, float), np.asarray(predicted), np.asarray(truth)
    right = (p == t) & (t >= 0)
    order = np.argsort(s, kind="stable")
    cum_right = np.concatenate([[0], np.cumsum(right[order])])
    cum_wrong = np.concatenate([[0], np.cumsum(~right[order])])
    k = np.searchsorted(s[order], thresholds, side="left")
    return cum_right[k] / max(int((t >= 0).sum()), 1), cum_wrong[k] / max(len(s), 1)


@settings(max_examples=200, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(0, 60), st.integers(1, 4))
def test_roc_counts_summed_over_frames_equal_the_roc_of_all_samples(seed, n, chunks):
    """Counts added chunk by chunk (frames of a take) give the ROC of all the samples at once, to the bit; ties and
    scores at the thresholds (quarter steps) and infinite scores (outside the foreground) included."""
    rng = np.random.default_rng(seed)
    score = rng.integers(0, 20, n) / 4.0
    score[rng.random(n) < 0.2] = np.inf
    pred = rng.integers(0, 3, n)
    truth = rng.integers(-1, 3, n)
    th = np.concatenate([np.linspace(0.0, 5.0, 21), [np.inf]])
    counts = RocCounts(th)
    for part in np.array_split(np.arange(n), chunks):
        counts.add(score[part], pred[part], truth[part])
    cor, inc = counts.rates()
    ref_cor, ref_inc = _roc_by_sorting(score, pred, truth, th)
    np.testing.assert_array_equal(cor, ref_cor)
    np.testing.assert_array_equal(inc, ref_inc)
    one_cor, one_inc = classification_roc(score, pred, truth, th)
    np.testing.assert_array_equal(one_cor, ref_cor)
    assert counts.rates_at(2.5) == (float(ref_cor[10]), float(ref_inc[10]))
    with pytest.raises(ValueError, match="not one of its thresholds"):
        counts.rates_at(2.6)
