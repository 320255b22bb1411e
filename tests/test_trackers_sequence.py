"""Trackers over whole sequences: crossings, occlusion, several cameras, the benchmarks."""

from __future__ import annotations

import numpy as np
import pytest

from mocap.tracker_trials import CATEGORIES, format_robustness_table, run_robustness_check, synthetic_trial
from simbench.benchmarks.trackers import REFERENCE_NAME, format_benchmark_table, run_tracker_benchmark
from mocap.trackers import COASTING, LOST, TRACKED
from mocap.tracking import track_camera, track_cameras
from mocap.types import Detections, Tracks2D

DT = 1.0 / 30.0
BUILT_IN = ("alpha_beta", "kalman_openmocap", "condensation", "alpha_beta_adaptive", "kalman", "condensation_drift", "imm")
PAPER = ("alpha_beta", "kalman_openmocap", "condensation")  # seed 000's, as OpenMoCap had them
BENCH = ("alpha_beta_adaptive", "kalman", "condensation_drift", "imm")


def crossing(angle_deg: float, lag_frames: float, merge_px: float, rng: np.random.Generator, n_frames: int = 70,
             speed: float = 4.0, noise_px: float = 0.2):
    """Two markers (4 px/frame) whose straight paths cross at the image centre at an angle
    ``angle_deg``, the second passing the crossing point ``lag_frames`` later (closest
    approach ~ ``speed * lag_frames`` px). Blobs closer than ``merge_px`` give one
    detection at their midpoint. Returns true (F, 2, 2) px, the detections per frame and,
    per frame, the marker index of each detection (-1: merged blob)."""
    t = np.arange(n_frames)[:, None] - n_frames / 2
    half = np.radians(angle_deg) / 2
    true = np.empty((n_frames, 2, 2))
    for k, (sign, lag) in enumerate(zip((1, -1), (0.0, lag_frames))):
        heading = np.array([np.cos(sign * half), np.sin(sign * half)])
        true[:, k] = np.array([320.0, 240.0]) + (t - lag) * speed * heading
    noisy = true + rng.normal(0, noise_px, true.shape)
    dets, owners = [], []
    for f in range(n_frames):
        if np.linalg.norm(true[f, 0] - true[f, 1]) < merge_px:
            d, o = noisy[f].mean(axis=0, keepdims=True), np.array([-1])
        else:
            order = rng.permutation(2)
            d, o = noisy[f, order], order
        dets.append(d)
        owners.append(o)
    return true, dets, owners


def kept_labels(res, owners, n_labels: int) -> bool:
    """Every label holds its own marker's detection whenever that marker is seen alone."""
    for f, own in enumerate(owners):
        for m in range(n_labels):
            if m in own and (res.index[f, m] < 0 or own[res.index[f, m]] != m):
                return False
            if m not in own and res.index[f, m] >= 0 and own[res.index[f, m]] >= 0:
                return False  # took the other marker's own detection
    return True


@pytest.mark.parametrize("name", ["kalman", "imm"])
def test_shallow_crossing_keeps_labels(name):
    for seed in range(5):
        true, dets, owners = crossing(angle_deg=12.0, lag_frames=0.8, merge_px=0.0, rng=np.random.default_rng(seed))
        assert np.linalg.norm(true[:, 0] - true[:, 1], axis=1).min() < 3.5  # they cross closely
        res = track_camera(dets, true[0], ["a", "b"], name, DT, np.random.default_rng(0))
        assert kept_labels(res, owners, 2), f"labels swapped in crossing {seed}"
        assert (res.status[1:] == TRACKED).all()


@pytest.mark.parametrize("labelled", [2, 1])
def test_imm_keeps_labels_through_merged_blobs(labelled):
    # The blobs merge for several frames; with labelled=1 the second marker is unlabelled,
    # as seed 000's "NULL" marker.
    for seed in range(5):
        true, dets, owners = crossing(angle_deg=8.0, lag_frames=0.3, merge_px=6.0, rng=np.random.default_rng(seed))
        assert sum(len(o) == 1 for o in owners) >= 8  # frames with one merged blob
        res = track_camera(dets, true[0, :labelled], ["a", "b"][:labelled], "imm", DT, np.random.default_rng(0))
        assert kept_labels(res, owners, labelled), f"labels swapped in crossing {seed}"
        assert not (res.status == LOST).any()


def _barrier_video():
    """A marker passing 10 frames behind a 50 px barrier at 5 px/frame, a neighbour 35 px
    away always seen; returns true (F, 2, 2), noisy positions, per-frame detections and
    the hidden frames of marker 0."""
    F = 50
    t = np.arange(F)[:, None]
    true = np.empty((F, 2, 2))
    true[:, 0] = np.array([150.0, 200.0]) + t * np.array([5.0, 0.5])  # passes behind the barrier
    true[:, 1] = np.array([150.0, 235.0]) + t * np.array([5.0, 0.3])  # a neighbour, always seen
    hidden = (true[:, 0, 0] > 248.0) & (true[:, 0, 0] < 298.0)  # barrier 50 px wide
    assert hidden.sum() == 10
    noisy = true + np.random.default_rng(3).normal(0, 0.2, true.shape)
    dets = [Detections.from_points(noisy[f, 1:] if hidden[f] else noisy[f, ::-1]) for f in range(F)]
    return true, noisy, dets, hidden


@pytest.mark.parametrize("name", BENCH)
def test_marker_behind_barrier_is_coasted_and_reacquired(name):
    true, noisy, dets, hidden = _barrier_video()
    F = len(true)
    res = track_camera(dets, true[0], ["hidden", "seen"], name, DT, np.random.default_rng(0))
    assert (res.status[hidden, 0] == COASTING).all()
    assert (res.status[~hidden, 0] == TRACKED).all() and (res.status[:, 1] == TRACKED).all()
    after = np.flatnonzero(~hidden & (np.arange(F) > np.flatnonzero(hidden)[-1]))
    np.testing.assert_allclose(res.xy[after, 0], noisy[after, 0])  # right marker, right label
    np.testing.assert_allclose(res.xy[:, 1], noisy[:, 1])
    # While coasting, the estimate is the prediction and the search area grows.
    h = np.flatnonzero(hidden)
    assert np.isnan(res.xy[h, 0]).all()
    assert res.search_radius[h[-1], 0] > res.search_radius[h[0], 0]


@pytest.mark.parametrize("name", PAPER)
def test_openmocap_trackers_behind_a_barrier(name):
    """Seed 000's trackers as OpenMoCap had them: a lone marker is coasted (never given
    up) and re-acquired; alpha-beta's circle stays 40 px, CONDENSATION's estimate stays
    at the last detection."""
    true, noisy, dets, hidden = _barrier_video()
    lone = [Detections.from_points(noisy[f, :1]) if not hidden[f] else Detections.from_points(np.zeros((0, 2)))
            for f in range(len(true))]
    res = track_camera(lone, true[0, :1], ["hidden"], name, DT, np.random.default_rng(0))
    h = np.flatnonzero(hidden)
    assert (res.status[h, 0] == COASTING).all() and (res.status[~hidden, 0] == TRACKED).all()
    np.testing.assert_allclose(res.xy[~hidden, 0], noisy[~hidden, 0])
    if name == "alpha_beta":
        np.testing.assert_allclose(res.search_radius[1:, 0], 40.0)
        # inertia: on at the last velocity (5, 0.5) px/frame, within noise
        np.testing.assert_allclose(res.estimate[h, 0], true[h, 0], atol=2.0)
    if name == "condensation":
        np.testing.assert_allclose(res.estimate[h, 0], np.broadcast_to(noisy[h[0] - 1, 0], (len(h), 2)))


def test_track_cameras_returns_tracks2d():
    rng = np.random.default_rng(4)
    F, M = 20, 3
    x0 = np.array([[[100.0, 100.0], [200.0, 150.0], [300.0, 100.0]], [[400.0, 300.0], [np.nan, np.nan], [450.0, 350.0]]])
    v = np.array([2.0, 1.0])  # px per frame
    dets = [[Detections.from_points(x0[c][np.isfinite(x0[c, :, 0])] + f * v) for f in range(F)] for c in range(2)]
    out = track_cameras(dets, x0, ["a", "b", "c"], ["cam0", "cam1"], "kalman", DT, rng)
    assert isinstance(out, Tracks2D)
    assert out.xy.shape == (F, 2, M, 2) and out.status.shape == (F, 2, M) and out.camera_names == ["cam0", "cam1"]
    assert (out.status[:, 1, 1] == LOST).all() and np.isnan(out.predicted_xy[:, 1, 1]).all()
    np.testing.assert_allclose(out.xy[-1, 0], x0[0] + (F - 1) * v)
    np.testing.assert_allclose(out.predicted_xy[-1, 0], x0[0] + (F - 1) * v, atol=0.05)
    xy, predicted, status = track_camera(dets[0], x0[0], ["a", "b", "c"], "kalman", DT, rng)  # unpacks
    assert xy.shape == predicted.shape == (F, M, 2) and status.shape == (F, M)
    with pytest.raises(ValueError, match=r"\(C, M, 2\)"):
        track_cameras(dets, x0[:1], ["a", "b", "c"], ["cam0", "cam1"], "kalman", DT, rng)


def test_synthetic_trials_have_their_difficulties():
    rng = np.random.default_rng(0)
    occ = synthetic_trial("occlusion", rng)
    assert (~occ.visible).any() and all(len(d) == int(v.sum()) for d, v in zip(occ.detections, occ.visible))
    swap = synthetic_trial("swap", rng)
    assert swap.true_xy.shape[1] == 2 and any((o == -1).any() for o in swap.owner)
    rapid = synthetic_trial("rapid", rng)
    step = np.diff(rapid.true_xy[:, 0], axis=0)
    turn = np.degrees(np.arccos(np.clip((step[1:] * step[:-1]).sum(1) / np.linalg.norm(step[1:], axis=1) / np.linalg.norm(step[:-1], axis=1), -1, 1)))
    assert turn.max() > 60  # sharp zigzag corners
    with pytest.raises(ValueError, match="unknown category"):
        synthetic_trial("sideways", rng)


def test_imm_loses_fewer_markers_than_the_seed_trackers():
    table = run_robustness_check(videos_per_category=4, seed=0)
    totals = {n: sum(table.losses[c][n] for c in CATEGORIES) for n in BUILT_IN}
    print(format_robustness_table(table))
    assert totals["imm"] == 0
    assert all(totals["imm"] < totals[n] for n in PAPER)


def test_benchmark_table_layout():
    table = run_tracker_benchmark(marker_counts=(1, 4), n_frames=12, seed=1)
    names = set(BUILT_IN) | {REFERENCE_NAME}
    assert {r.tracker for r in table.rows} >= names
    for r in table.rows:
        assert 0 < r.p5_ms <= r.median_ms <= r.p95_ms <= r.max_ms
    assert set(table.speedup) == {1, 4} and all(s > 0 for s in table.speedup.values())
    text = format_benchmark_table(table)
    assert text.count("Markers") == len({r.tracker for r in table.rows})
    assert f"{table.row('kalman', 4).median_ms:.4f}" in text
