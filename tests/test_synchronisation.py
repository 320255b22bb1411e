"""Synchronising cameras on their own clocks from the markers' motion (mocap.synchronisation),
on synthetic cameras and unlabelled markers whose true clocks are known."""

from __future__ import annotations

import numpy as np
import pytest

from mocap.calibration import calibration_from_arrays
from mocap.errors import MocapInputError
from mocap.synchronisation import ClockSync, LinkedDetections, SyncParams, estimate_sync, resample_detections
from mocap.types import Detections

FPS = 30.0


def _look_at(centre: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    z = target - centre
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])
    return R, -R @ centre


def _rig(n: int = 4):
    Rs, ts = [], []
    for i in range(n):
        az = 2 * np.pi * i / n + 0.5
        R, t = _look_at(np.array([3 * np.cos(az), 3 * np.sin(az), 2.0]), np.array([0.0, 0.0, 1.0]))
        Rs.append(R)
        ts.append(t)
    K = np.array([[600.0, 0, 320], [0, 600.0, 240], [0, 0, 1]])
    return calibration_from_arrays([f"cam{i}" for i in range(n)], (640, 480), [K] * n, [np.zeros(5)] * n, Rs, ts)


def _markers(rng: np.random.Generator, n: int = 25):
    """``xyz(t)`` of ``n`` markers: each a sum of three sinusoids of unrelated frequencies (not periodic)."""
    base = rng.uniform([-0.4, -0.4, 0.3], [0.4, 0.4, 1.7], (n, 3))
    amp = rng.uniform(0.03, 0.2, (n, 3, 3))
    freq = rng.uniform(0.2, 1.3, (n, 3, 3))
    phase = rng.uniform(0, 2 * np.pi, (n, 3, 3))

    def xyz(t: np.ndarray) -> np.ndarray:  # (T,) -> (T, n, 3)
        t = np.asarray(t, float)[:, None, None, None]
        return base + (amp * np.sin(2 * np.pi * freq * t + phase)).sum(axis=3)
    return xyz


def _take(seed: int, duration_s: float, offsets_s: np.ndarray, rates: np.ndarray, noise_px: float = 0.1):
    """Unlabelled detections (shuffled every frame) and each camera's own timestamps."""
    rng = np.random.default_rng(seed)
    cal, xyz = _rig(len(offsets_s)), _markers(rng)
    n = int(duration_s * FPS)
    stamps = np.arange(n) / FPS + 0.002
    dets, times = [], []
    for c, cam in enumerate(cal):
        true = offsets_s[c] + rates[c] * stamps
        frames = []
        for p in xyz(true):
            uv = cam.project(p) + rng.normal(0, noise_px, (len(p), 2))
            uv = uv[cam.in_image(uv)]
            frames.append(Detections.from_points(uv[rng.permutation(len(uv))]))
        dets.append(frames)
        times.append(stamps.copy())
    return cal, xyz, dets, times


def _truth(offsets_s: np.ndarray, rates: np.ndarray):
    return (offsets_s - offsets_s[0]) / rates[0], rates / rates[0] - 1.0


def test_offsets_recovered_within_a_millisecond():
    offsets = np.array([0.3, 0.0, 0.75, 0.52])       # relative offsets of up to 750 ms
    rates = 1.0 + np.array([40.0, -90.0, 100.0, 10.0]) * 1e-6
    cal, _, dets, times = _take(1, 8.0, offsets, rates)
    sync = estimate_sync(dets, times, cal)
    true_off, true_drift = _truth(offsets, rates)
    err_ms = (sync.offset_s - true_off)[1:] * 1e3
    assert np.sqrt(np.mean(err_ms**2)) < 1.0, err_ms
    assert sync.offset_s[0] == 0.0 and sync.drift[0] == 0.0
    assert np.all(np.abs(sync.drift) <= SyncParams().max_drift_ppm * 1e-6 + 1e-12)
    # A wrong offset by a frame or more would show: the search really distinguishes them.
    assert np.all(np.abs(err_ms) < 3.0)


def test_resampled_detections_are_the_markers_at_the_reference_instants():
    offsets = np.array([0.0, 0.41, -0.2])
    rates = 1.0 + np.array([0.0, 60.0, -60.0]) * 1e-6
    cal, xyz, dets, times = _take(2, 4.0, offsets, rates, noise_px=0.0)
    true_off, true_drift = _truth(offsets, rates)
    out = resample_detections(dets, times, ClockSync(0, true_off, true_drift))
    assert [len(o) for o in out] == [len(times[0])] * 3
    ref_true = offsets[0] + rates[0] * times[0]
    errs, n_expected, n_got = [], 0, 0
    for c in (1, 2):
        s_c = (times[0] - true_off[c]) / (1 + true_drift[c])
        inside = (s_c >= times[c][0]) & (s_c <= times[c][-1])
        for k in np.flatnonzero(inside):
            uv = cal[c].project(xyz(ref_true[k : k + 1])[0])
            uv = uv[cal[c].in_image(uv)]
            got = out[c][k].xy
            if len(got):
                errs.append(np.linalg.norm(got[:, None] - uv[None], axis=2).min(axis=1))
            n_expected += len(uv)
            n_got += len(got)
        outside = np.flatnonzero(~inside)
        assert all(len(out[c][k]) == 0 for k in outside)  # no camera frame there: no detection
    e = np.concatenate(errs)
    assert np.median(e) < 0.05 and np.percentile(e, 99) < 0.5, (np.median(e), np.percentile(e, 99))
    assert n_got > 0.95 * n_expected


def test_duplicated_frames_are_not_interpolated_through():
    xy = [np.array([[10.0, 10.0]]), np.array([[20.0, 10.0]]), np.array([[20.0, 10.0]]), np.array([[40.0, 10.0]])]
    linked = LinkedDetections([Detections.from_points(p) for p in xy], np.array([0.0, 1.0, 2.0, 3.0]), gate_px=40.0)
    assert len(linked.times) == 3  # the repeat is dropped
    at, _, _ = linked.at(np.array([2.0]))
    assert at[0, 0, 0] == pytest.approx(30.0, abs=3.0)  # between frames 1 and 3, not stuck at 20


def test_bad_inputs_are_refused_with_one_line():
    cal, _, dets, times = _take(3, 1.0, np.zeros(3), np.ones(3))
    with pytest.raises(MocapInputError, match="timestamps of 2 cameras"):
        estimate_sync(dets, times[:2], cal)
    bad = [t.copy() for t in times]
    bad[1][5] = bad[1][4]
    with pytest.raises(MocapInputError, match="strictly increasing"):
        estimate_sync(dets, bad, cal)
    with pytest.raises(MocapInputError, match="camera 2: 3 timestamps"):
        estimate_sync(dets, times[:2] + [times[2][:3]], cal)
    with pytest.raises(MocapInputError, match="max_offset_s"):
        SyncParams(max_offset_s=float("nan"))


def test_clocks_known_to_share_one_rate_get_the_offset_alone():
    offsets = np.array([0.0, -0.33, 0.6])
    cal, _, dets, times = _take(4, 5.0, offsets, np.ones(3))
    sync = estimate_sync(dets, times, cal, params=SyncParams(max_drift_ppm=0.0))
    assert np.array_equal(sync.drift, np.zeros(3))
    assert np.abs(sync.offset_s - offsets).max() < 1e-3


def test_timestamps_files_are_read_or_refused_naming_the_file(tmp_path):
    from mocap.errors import InputFileError
    from mocap.synchronisation import read_timestamps_csv

    good = tmp_path / "cam0.timestamps.csv"
    good.write_text("frame,timestamp_s\n0,0.002\n1,0.0353\n2,0.0687\n")
    assert np.allclose(read_timestamps_csv(good), [0.002, 0.0353, 0.0687])
    cases = {"missing.timestamps.csv": None, "back.csv": "frame,timestamp_s\n0,0.1\n1,0.05\n",
             "nan.csv": "frame,timestamp_s\n0,0.1\n1,nan\n", "words.csv": "frame,timestamp_s\n0,zero\n",
             "three.csv": "frame,timestamp_s\n0,0.1,7\n"}
    for name, text in cases.items():
        p = tmp_path / name
        if text is not None:
            p.write_text(text)
        with pytest.raises(InputFileError) as err:
            read_timestamps_csv(p)
        assert str(p) in str(err.value) and "\n" not in str(err.value)


def test_a_duplicated_reference_frame_is_resampled_to_its_timestamp():
    """Camera 0 repeats frames 30 and 61-62 (the previous image under later timestamps): the
    output at those timestamps has camera 0's blobs where the markers were then, not where
    the repeated image shows them (a frame earlier, a few pixels away)."""
    offsets = np.array([0.0, 0.2, -0.15])
    rates = np.ones(3)
    cal, xyz, dets, times = _take(5, 3.0, offsets, rates, noise_px=0.0)
    dup = [30, 61, 62]
    for k in dup:
        dets[0][k] = dets[0][k - 1]
    out = resample_detections(dets, times, ClockSync(0, offsets, np.zeros(3)))
    moved = []
    for k in range(len(times[0])):
        uv = cal[0].project(xyz(times[0][k : k + 1])[0])
        uv = uv[cal[0].in_image(uv)]
        got = out[0][k].xy
        if k in dup:
            stale = np.linalg.norm(dets[0][k].xy[:, None] - uv[None], axis=2).min(axis=1)
            moved.append(np.median(stale))
            assert len(got) > 0.9 * len(uv)
            err = np.linalg.norm(got[:, None] - uv[None], axis=2).min(axis=1)
            assert np.median(err) < 0.1 * np.median(stale), (k, np.median(err), np.median(stale))
            assert np.percentile(err, 90) < 0.5
        else:
            assert got is dets[0][k].xy or np.array_equal(got, dets[0][k].xy)  # other frames as they were
    assert min(moved) > 1.0  # the markers really moved between the frames: the test can fail
