"""Markers the model check left out, measured again from blobs no kept label uses."""

from __future__ import annotations

import numpy as np

from mocap.free_blob_fill import fill_from_free_blobs
from mocap.types import Detections, Trajectories

from helpers import ring_calibration

LIMITS_MM = (5.0, 10.0)


def _scene(rng: np.random.Generator):
    """Three frames of 12 markers 6-30 cm apart, every blob detected; every label kept but
    marker 0 (its point dropped by the check) in frame 1."""
    cal = ring_calibration(3, 3.0, (0.0, 0.0, 1.0), 600.0, (640, 480), 0.5)
    F, M = 3, 12
    xyz = rng.uniform([-0.3, -0.3, 0.6], [0.3, 0.3, 1.4], (M, 3))[None] + np.linspace(0, 0.02, F)[:, None, None]
    uv = np.stack([cal.project(xyz[f]) for f in range(F)])                # (F, C, M, 2)
    dets = [[Detections(uv[f, c].copy(), np.full(M, 20.0), np.full(M, 200.0)) for f in range(F)]
            for c in range(len(cal))]
    traj = Trajectories([f"m{j}" for j in range(M)], xyz.copy(), np.arange(F) / 30.0,
                        np.zeros((F, M), bool), np.zeros((F, M)), np.full((F, M), 3))
    traj.xyz[1, 0] = np.nan
    measured = uv.copy()
    measured[1, :, 0] = np.nan
    return cal, xyz, uv, dets, traj, measured


def test_a_dropped_marker_is_measured_again_from_its_free_blobs():
    cal, xyz, uv, dets, traj, measured = _scene(np.random.default_rng(0))
    predicted = xyz + np.array([0.002, -0.001, 0.0])                     # the checked model, 2 mm off
    out, xy, added = fill_from_free_blobs(traj, measured, dets, cal, predicted, LIMITS_MM)
    assert added == 1
    np.testing.assert_allclose(out.xyz[1, 0], xyz[1, 0], atol=1e-6)      # measured, not the prediction
    assert out.n_views[1, 0] == 3 and not out.filled[1, 0]
    np.testing.assert_allclose(xy[1, :, 0], uv[1, :, 0])
    np.testing.assert_array_equal(out.xyz[[0, 2]], traj.xyz[[0, 2]])       # nothing else moves


def test_nothing_is_added_beyond_the_checks_limit_or_from_blobs_a_kept_label_uses():
    cal, xyz, uv, dets, traj, measured = _scene(np.random.default_rng(1))
    far = xyz.copy()
    far[1, 0] += np.array([0.0, 0.0, 0.012])                               # the model 12 mm off: its blobs
    out, _, added = fill_from_free_blobs(traj, measured, dets, cal, far, LIMITS_MM, gate_px=6.0)
    assert added == 0 and np.isnan(out.xyz[1, 0]).all()                   # are within the gate, not the limit
    # marker 0's blobs are another label's measurements: they are not free
    taken = measured.copy()
    taken[1, :, 5] = uv[1, :, 0]
    traj.xyz[1, 5] = xyz[1, 0]
    out, _, added = fill_from_free_blobs(traj, taken, dets, cal, xyz, LIMITS_MM)
    assert np.isnan(out.xyz[1, 0]).all()
