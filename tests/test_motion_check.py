"""The motion check (mocap.motion_check): a lone marker's point that no limb could have moved to
is vetoed, fast but physical motion is kept.

Ground truth: a wrist swinging as in jumping jacks at 30 fps (0.7 m arc, up to 4.8 m/s, the
fastest true wrist speed of dim_gym_noisy) and a toe kicked at up to 10.7 m/s (the fastest true
marker speed of the CMU kick); wrong points are put where dim_gym_noisy's wrong wrist labels put
them, 0.85 m away (on the head marker).
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from mocap.marker_pipeline import MarkerPipelineParams
from mocap.motion_check import MAX_MARKER_SPEED_MPS, lone_markers, motion_outliers, too_fast, without_motion_outliers
from mocap.types import Trajectories

FPS = 30.0
T = np.arange(60) / FPS
#: Where a wrong wrist label puts the point: on the head marker, 0.85 m from the wrist.
OFF = np.array([-0.6, 0.0, 0.6])


def swing(peak_mps: float, radius_m: float = 0.35) -> np.ndarray:
    """``(60, 3)`` m: a point on an arc of ``radius_m`` swinging with peak speed ``peak_mps``."""
    w = 2 * np.pi * 0.8
    amp = peak_mps / (radius_m * w)
    ang = amp * np.sin(w * T)
    return np.stack([0.4 + radius_m * np.sin(ang), np.zeros_like(T), 1.0 + radius_m * np.cos(ang)], axis=1)


def peak_speed(x: np.ndarray) -> float:
    return float(np.max(np.linalg.norm(np.diff(x, axis=0), axis=1)) * FPS)


def test_physical_motion_is_kept():
    wrist, toe = swing(4.8), swing(10.7, radius_m=0.9)
    assert 4.5 < peak_speed(wrist) < 4.9 and 10.0 < peak_speed(toe) < 10.8
    ok = np.ones(len(T), bool)
    assert not too_fast(wrist, T, ok, MAX_MARKER_SPEED_MPS).any()
    assert not too_fast(toe, T, ok, MAX_MARKER_SPEED_MPS).any()


def test_a_teleported_sample_is_vetoed():
    x = swing(4.8)
    x[20] += OFF  # 0.85 m off in one frame: about 25 m/s each way
    assert np.linalg.norm(x[20] - x[19]) * FPS > 20 and np.linalg.norm(x[21] - x[20]) * FPS > 20
    veto = too_fast(x, T, np.ones(len(T), bool), MAX_MARKER_SPEED_MPS)
    assert np.flatnonzero(veto).tolist() == [20]


def test_a_run_that_jumped_away_and_back_is_vetoed():
    x = swing(4.8)
    x[20:26] = x[20] + OFF + 0.003 * np.arange(6)[:, None]  # then follows the head, slowly
    veto = too_fast(x, T, np.ones(len(T), bool), MAX_MARKER_SPEED_MPS)
    assert np.flatnonzero(veto).tolist() == list(range(20, 26))


def test_a_run_at_the_end_is_vetoed_when_shorter_than_the_one_it_left():
    x = swing(4.8)
    x[50:] = x[50] + OFF
    veto = too_fast(x, T, np.ones(len(T), bool), MAX_MARKER_SPEED_MPS)
    assert np.flatnonzero(veto).tolist() == list(range(50, 60))
    y = swing(4.8)
    y[:5] = y[4] + OFF  # the same at the start
    assert np.flatnonzero(too_fast(y, T, np.ones(len(T), bool), MAX_MARKER_SPEED_MPS)).tolist() == list(range(5))


def test_a_gap_allows_the_distance_a_limb_covers_in_it():
    x = swing(4.8)
    ok = np.ones(len(T), bool)
    ok[25:35] = False
    x[35:] += np.array([0.8, 0.0, 0.0])  # 0.8 m over 11 frames (0.37 s): 2.2 m/s
    assert not too_fast(x, T, ok, MAX_MARKER_SPEED_MPS).any()
    ok[:] = True  # the same 0.8 m in one frame (24 m/s): the shorter run goes
    assert np.flatnonzero(too_fast(x, T, ok, MAX_MARKER_SPEED_MPS)).tolist() == list(range(35, 60))


def test_only_lone_measured_markers_are_judged_and_fills_are_made_again():
    wrist, elbow = swing(4.8), swing(3.0, radius_m=0.2)
    xyz = np.stack([wrist, elbow, elbow + 0.05], axis=1)
    xyz[20, 0] += OFF
    xyz[20, 2] += OFF  # the forearm's second marker: the model check judges it, not this one
    filled = np.zeros((len(T), 3), bool)
    filled[22:24, 0] = True  # fills made by a spline through the wrong point
    xyz[22:24, 0] = (wrist[24] + xyz[20, 0]) / 2
    subject = SimpleNamespace(markers=[SimpleNamespace(name="LWRI", body="hand_l"),
                                       SimpleNamespace(name="LELB", body="forearm_l"),
                                       SimpleNamespace(name="LFRM", body="forearm_l")])
    lone = lone_markers(subject, ["LWRI", "LELB", "LFRM"])
    assert lone.tolist() == [True, False, False]
    assert lone_markers(subject, ["LWRI", "XTRA"]).tolist() == [True, False]
    traj = Trajectories(["LWRI", "LELB", "LFRM"], xyz, T, filled, np.zeros((len(T), 3)), np.where(filled, 0, 3))
    veto = motion_outliers(traj, lone)
    assert np.argwhere(veto).tolist() == [[20, 0]]
    out = without_motion_outliers(traj, veto, max_gap_frames=10, method="lsq", context_frames=10)
    assert out.filled[:, 0].tolist() == [f in (20, 22, 23) for f in range(len(T))]
    assert out.n_views[[20, 22, 23], 0].tolist() == [0, 0, 0] and np.isnan(out.residual_px[20, 0])
    # the new fills follow the wrist (a cubic across a 4.8 m/s swing: 16-34 mm), the old ones did not
    assert np.linalg.norm(out.xyz[[20, 22, 23], 0] - wrist[[20, 22, 23]], axis=1).max() < 0.04
    assert np.linalg.norm(traj.xyz[[22, 23], 0] - wrist[[22, 23]], axis=1).min() > 0.3
    assert np.array_equal(out.xyz[:, 1:], traj.xyz[:, 1:])
    assert without_motion_outliers(traj, np.zeros_like(veto), 10, "lsq", 10) is traj


def test_the_limit_is_a_pipeline_setting():
    assert MarkerPipelineParams().max_marker_speed_mps == MAX_MARKER_SPEED_MPS == 15.0
    with pytest.raises(Exception, match="max_marker_speed_mps"):
        MarkerPipelineParams(max_marker_speed_mps=-1.0)
