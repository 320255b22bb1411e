"""eval.shirt_metrics against hand-computed values."""

from __future__ import annotations

import numpy as np
import pytest

from eval.shirt_metrics import classification_roc, fill_forward, frames_within_cm, per_frame_rms_cm, rmse_cm, shoulder_angle_deg

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
