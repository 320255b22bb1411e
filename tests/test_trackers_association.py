"""Gated assignment of detections to labels, loss handling and the tracker registry."""

from __future__ import annotations

import numpy as np
import pytest

from mocap.errors import MocapInputError
from mocap.trackers import (
    COASTING,
    LOST,
    TRACKED,
    TRACKERS,
    KalmanTracker,
    Tracker2D,
    TrackerNotFoundError,
    available_trackers,
    get_tracker,
    make_tracker,
    register_tracker,
    tracker_params,
    unregister_tracker,
)
from mocap.trackers.gating import gated_assignment
from scipy.spatial.distance import cdist
from mocap.tracking import track_camera

DT = 1.0 / 30.0
BUILT_IN = ("alpha_beta", "kalman_openmocap", "condensation", "alpha_beta_adaptive", "kalman", "condensation_drift", "imm")
PAPER = ("alpha_beta", "kalman_openmocap", "condensation")  # seed 000's, as OpenMoCap had them
BENCH = ("alpha_beta_adaptive", "kalman", "condensation_drift", "imm")


def test_hungarian_beats_greedy_nearest():
    # Greedy nearest-first would give detection 0 to label 1 (distance 1) and leave
    # label 0 with detection 1 at distance 9; the global optimum pairs 0-0 (3) and 1-1 (3).
    centres = np.array([[0.0, 0.0], [4.0, 0.0]])
    dets = np.array([[3.0, 0.0], [7.0, 0.0]])
    var = np.full((2, 2), 10.0)  # gates of radius sqrt(10 * 13.8) ~ 11.7 px
    idx = gated_assignment(centres, var, dets, threshold=13.8)
    np.testing.assert_array_equal(idx, [0, 1])


def test_pairs_outside_gates_are_forbidden():
    centres = np.array([[0.0, 0.0], [100.0, 0.0]])
    var = np.full((2, 1), 1.0)  # radius sqrt(13.8) ~ 3.7 px
    dets = np.array([[0.0, 3.5], [104.0, 0.0]])  # inside label 0's gate, outside label 1's
    np.testing.assert_array_equal(gated_assignment(centres, var, dets, 13.8), [0, -1])
    # Even when the optimum would like it, a pair outside the gate is never made.
    dets = np.array([[1.0, 0.0], [2.0, 0.0], [50.0, 0.0]])
    idx = gated_assignment(centres, var, dets, 13.8)
    assert idx[1] == -1 and idx[0] in (0, 1)


def test_tracker_gate_and_association_match_standalone_function():
    rng = np.random.default_rng(0)
    x0 = rng.uniform(0, 200, (8, 2))
    trk = KalmanTracker(x0, DT, np.random.default_rng(0), initial_velocity_std=600.0)
    trk.predict()
    area = trk.gate()
    dets = x0[rng.permutation(8)] + rng.normal(0, 3, (8, 2))
    var = np.stack([area.covariance[:, 0, 0], area.covariance[:, 1, 1]], axis=1)
    np.testing.assert_array_equal(trk.associate(dets), gated_assignment(area.centre, var, dets, area.threshold))
    inside = area.contains(dets)
    idx = trk.associate(dets)
    assert all(inside[m, idx[m]] for m in range(8) if idx[m] >= 0)


@pytest.mark.parametrize("name", BUILT_IN)
def test_shuffled_detection_order_gives_the_same_tracks(name):
    rng = np.random.default_rng(7)
    F, M = 40, 12
    t = np.arange(F)[:, None, None] * DT
    x0 = np.stack(np.meshgrid(np.linspace(80, 560, 4), np.linspace(80, 400, 3)), -1).reshape(M, 2)
    v = rng.uniform(-60, 60, (M, 2))
    true = x0 + v * t  # (F, M, 2)
    noisy = true + rng.normal(0, 0.2, true.shape)
    dets_a = [noisy[f] for f in range(F)]
    dets_b = [noisy[f][rng.permutation(M)] for f in range(F)]
    a = track_camera(dets_a, x0, [str(m) for m in range(M)], name, DT, np.random.default_rng(1))
    b = track_camera(dets_b, x0, [str(m) for m in range(M)], name, DT, np.random.default_rng(1))
    np.testing.assert_array_equal(a.xy, b.xy)
    np.testing.assert_array_equal(a.estimate, b.estimate)
    np.testing.assert_array_equal(a.status, b.status)
    np.testing.assert_allclose(a.xy, noisy)  # and every label kept its own marker


def test_lost_label_is_reacquired_only_by_an_unclaimed_detection():
    x0 = np.array([[100.0, 100.0], [130.0, 100.0]])
    trk = make_tracker("kalman", x0, DT, np.random.default_rng(0), max_coast_frames=3, max_gate_px=60.0)
    for _ in range(5):  # label 1 sees nothing: coasting, then lost
        trk.step(x0[:1])
    assert trk.status[0] == TRACKED and trk.status[1] == LOST
    # One detection in both gates: the tracked label keeps it.
    idx = trk.step(np.array([[101.0, 100.0]]))
    np.testing.assert_array_equal(idx, [0, -1])
    # A second, unclaimed detection inside label 1's grown gate re-acquires it.
    idx = trk.step(np.array([[125.0, 101.0], [101.0, 100.0]]))
    np.testing.assert_array_equal(idx, [1, 0])
    assert list(trk.status) == [TRACKED, TRACKED]
    np.testing.assert_allclose(trk.x_est[1], [125.0, 101.0])


def test_coasting_then_lost_after_max_coast_frames():
    x0 = np.array([[100.0, 100.0], [300.0, 100.0]])
    trk = make_tracker("alpha_beta", x0, DT, np.random.default_rng(0), max_coast_frames=4)
    seen = []
    for _ in range(6):
        trk.step(x0[:1])
        seen.append(int(trk.status[1]))
    assert seen == [COASTING] * 4 + [LOST] * 2


@pytest.mark.parametrize("name", PAPER)
def test_openmocap_labels_without_initial_position_stay_lost_until_reset(name):
    x0 = np.array([[100.0, 100.0], [np.nan, np.nan]])
    trk = make_tracker(name, x0, DT, np.random.default_rng(0))
    for _ in range(3):
        idx = trk.step(np.array([[100.0, 100.0], [300.0, 300.0]]))
        np.testing.assert_array_equal(idx, [0, -1])
        assert list(trk.status) == [TRACKED, LOST] and np.isnan(trk.x_pred[1]).all()
    trk.reset_labels(np.array([False, True]), np.array([[0.0, 0.0], [300.0, 300.0]]))
    for _ in range(3):
        idx = trk.step(np.array([[300.5, 300.0], [100.0, 100.0]]))
        np.testing.assert_array_equal(idx, [1, 0])
    np.testing.assert_allclose(trk.x_est[1], [300.5, 300.0], atol=1.0)


def test_labels_without_initial_position_stay_lost_until_reset():
    x0 = np.array([[100.0, 100.0], [np.nan, np.nan]])
    trk = make_tracker("kalman", x0, DT, np.random.default_rng(0))
    assert list(trk.status) == [TRACKED, LOST]
    for _ in range(3):  # a spare detection is never given to a label of unknown position
        idx = trk.step(np.array([[100.0, 100.0], [300.0, 300.0]]))
        np.testing.assert_array_equal(idx, [0, -1])
    trk.reset_labels(np.array([False, True]), np.array([[0.0, 0.0], [300.0, 300.0]]))
    idx = trk.step(np.array([[300.5, 300.0], [100.0, 100.0]]))
    np.testing.assert_array_equal(idx, [1, 0])
    assert list(trk.status) == [TRACKED, TRACKED]


# ------------------------------------------------------------------ registry
class StillTracker(Tracker2D):
    """A test tracker: constant position, fixed 5 px gate."""

    def __init__(self, initial_xy, dt, rng, *, radius_px: float = 5.0, **base_params):
        super().__init__(initial_xy, dt, rng, **base_params)
        self.pos = np.array(initial_xy, dtype=np.float64)
        self.radius_px = radius_px
        self._svar = np.full((self.n_markers, 1), radius_px**2 / self.gate_threshold)
        self._set_info()

    def _predict(self):
        self._centre = self.pos.copy()

    def _correct(self, z, has):
        self.pos = z.copy() if has is None else np.where(has[:, None], z, self.pos)

    def _restart(self, mask, xy):
        self.pos[mask] = xy[mask]

    @property
    def x_est(self):
        return self.pos


def test_registry_picks_up_a_tracker_defined_here():
    register_tracker("still_test")(StillTracker)
    try:
        assert "still_test" in available_trackers() and TRACKERS["still_test"] is StillTracker
        assert tracker_params("still_test")["radius_px"] == 5.0
        x0 = np.array([[10.0, 10.0], [50.0, 50.0]])
        dets = [x0 + f for f in range(4)]  # moves 1 px per frame per axis
        res = track_camera(dets, x0, ["a", "b"], "still_test", DT, np.random.default_rng(0))
        np.testing.assert_array_equal(res.xy, np.stack(dets))
        # The same class through an entry point "module:Class".
        assert get_tracker(f"{__name__}:StillTracker") is StillTracker
        res2 = track_camera(dets, x0, ["a", "b"], f"{__name__}:StillTracker", DT, np.random.default_rng(0), radius_px=0.5, min_gate_px=0.1)
        assert np.isnan(res2.xy[1:]).all()  # 1.4 px steps fall outside a 0.5 px gate
    finally:
        unregister_tracker("still_test")
    assert "still_test" not in available_trackers()


def test_registry_errors_name_the_fix():
    assert set(BUILT_IN) <= set(available_trackers())
    with pytest.raises(TrackerNotFoundError, match="known trackers: .*kalman"):
        get_tracker("kalmann")
    with pytest.raises(TrackerNotFoundError, match="no attribute"):
        get_tracker("mocap.trackers.kalman:NoSuchClass")
    with pytest.raises(TrackerNotFoundError, match="not a subclass"):
        get_tracker("numpy:ndarray")
    with pytest.raises(MocapInputError, match="no parameter.*alfa.*alpha=1.0"):
        make_tracker("alpha_beta", np.zeros((1, 2)), DT, np.random.default_rng(0), alfa=0.5)
    with pytest.raises(ValueError, match="already used"):
        register_tracker("kalman")(StillTracker)
    with pytest.raises(TypeError, match="Generator"):
        make_tracker("kalman", np.zeros((1, 2)), DT, 0)
    with pytest.raises(ValueError, match=r"\(M, 2\)"):
        make_tracker("kalman", np.zeros((3, 3)), DT, np.random.default_rng(0))


def _numpy_unique_pairs(centre, gate_var, threshold, det):
    """Reference of the compiled check: the (M, n) gate matrix, then the uniqueness test."""
    if gate_var.shape[1] == 1:
        inside = cdist(centre, det, "sqeuclidean") <= gate_var * threshold
    else:
        d2 = ((det[None, :, :] - centre[:, None, :]) ** 2 / gate_var[:, None, :]).sum(axis=2)
        inside = d2 <= threshold
    if (inside.sum(axis=1) > 1).any() or (inside.sum(axis=0) > 1).any():
        return -1, None
    idx = np.full(len(centre), -1)
    rows, cols = inside.nonzero()
    idx[rows] = cols
    return int(inside.sum()), idx


@pytest.mark.parametrize("axes", [1, 2])
def test_compiled_gate_check_matches_numpy(axes):
    from mocap.trackers.gating import unique_gated_pairs

    rng = np.random.default_rng(7)
    seen = {"unique": 0, "ambiguous": 0}
    for trial in range(400):
        M, n = rng.integers(0, 12, size=2)
        centre = rng.uniform(0, 100, (M, 2))
        centre[rng.random(M) < 0.1] = np.nan  # labels without a gate
        det = rng.uniform(0, 100, (n, 2))
        gate_var = rng.uniform(1, 60, (M, axes))
        threshold = 13.8
        idx = np.empty(M, dtype=np.intp)
        K = unique_gated_pairs(centre, gate_var, gate_var[:, :1] * threshold, threshold, det, idx)
        K_ref, idx_ref = _numpy_unique_pairs(centre, gate_var, threshold, det)
        assert K == K_ref, trial
        if K >= 0:
            np.testing.assert_array_equal(idx, idx_ref)
        seen["unique" if K >= 0 else "ambiguous"] += 1
    assert min(seen.values()) > 50  # both outcomes exercised
