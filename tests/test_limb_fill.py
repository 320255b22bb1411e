"""A limb the model check emptied, found again by fitting it to the blobs no label uses
(mocap.limb_fill), and the model fill's test of which markers the measured ones determine.

Ground truth: MuJoCo forward kinematics of the bench's humanoid with the Plug-in Gait marker
sites, seen exactly by four cameras; the right leg's labels are dropped for some frames (as the
model check drops a limb it cannot explain) while its blobs stay detected.
"""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from mocap.free_blob_fill import fill_from_free_blobs
from mocap.limb_fill import fill_limbs_from_free_blobs
from mocap.marker_pipeline import _constrained
from mocap.model_check import model_markers
from mocap.skeleton import SkeletonSolver
from mocap.subject import SubjectModel
from mocap.types import Detections, Trajectories
from simbench.scenes.humanoid import BodyParams, humanoid_mjcf

from helpers import ring_calibration, site_positions

LIMITS_MM = (5.0, 10.0)
LEG = ["RTHI", "RKNE", "RTIB", "RANK", "RHEE", "RTOE"]
LOST = slice(4, 9)


@pytest.fixture(scope="module")
def scene():
    """Solver, marker names, 12 frames of exact markers with the right leg swinging fast, the
    rig and every camera's blobs."""
    xml = humanoid_mjcf(BodyParams(), marker_set="plugin_gait_full")
    model = mujoco.MjModel.from_xml_string(xml)
    t = np.arange(12) / 30.0
    qpos = np.zeros((len(t), model.nq))
    qpos[:, 3], qpos[:, 0], qpos[:, 2] = 1.0, 0.5 * t, 0.95
    names = [model.joint(j).name for j in range(model.njnt)]
    swing = np.sin(2 * np.pi * 1.5 * t)                                      # a stride a 0.67 s
    for name, q in (("hip_r_y", -0.3 - 0.4 * swing), ("knee_r", 0.4 + 0.4 * swing), ("ankle_r_y", 0.2 + 0.2 * swing),
                    ("hip_l_y", -0.15 + 0.15 * swing), ("knee_l", 0.2 - 0.15 * swing)):
        qpos[:, model.jnt_qposadr[names.index(name)]] = q
    sites = site_positions(model, qpos)
    labels = [model.site(i).name for i in range(model.nsite)]
    cal = ring_calibration(4, 4.0, (0.2, 0.0, 0.9), 900.0, (1280, 960), 0.4)
    uv = np.stack([cal.project(sites[f]) for f in range(len(t))])         # (F, C, M, 2)
    dets = [[Detections(uv[f, c].copy(), np.full(len(labels), 20.0), np.full(len(labels), 200.0))
             for f in range(len(t))] for c in range(len(cal))]
    solver = SkeletonSolver(SubjectModel.from_mjcf_text(xml, name="pig"))
    return solver, labels, sites, t, cal, uv, dets


def _leg_lost(labels, sites, t, uv, lost):
    """Trajectories and labelled blobs with ``lost`` markers' labels dropped in frames ``LOST``."""
    F, M = sites.shape[:2]
    traj = Trajectories(list(labels), sites.copy(), t, np.zeros((F, M), bool), np.zeros((F, M)), np.full((F, M), 4))
    measured = uv.copy()
    cols = [labels.index(n) for n in lost]
    for j in cols:
        traj.xyz[LOST, j] = np.nan
        measured[LOST, :, j] = np.nan
    return traj, measured, cols


def test_an_emptied_leg_is_fitted_to_its_free_blobs(scene):
    solver, labels, sites, t, cal, uv, dets = scene
    traj, measured, cols = _leg_lost(labels, sites, t, uv, LEG)
    fit = solver.solve(traj, bridge=False)
    predicted = model_markers(solver, fit, labels)
    # The fit holds the leg near its last measured pose: the swinging foot is centimetres off and
    # the fill near the prediction finds none of it.
    assert np.linalg.norm(predicted[LOST, cols] - sites[LOST, cols], axis=-1).max() > 0.03
    _, _, near = fill_from_free_blobs(traj, measured, dets, cal, predicted, LIMITS_MM)
    out, xy, added = fill_limbs_from_free_blobs(traj, measured, dets, cal, solver, fit, LIMITS_MM)
    assert added > near
    got = out.xyz[LOST][:, cols]
    found = np.isfinite(got[..., 0])
    assert found.all()                                                    # the whole leg comes back
    np.testing.assert_allclose(got[found], sites[LOST][:, cols][found], atol=1e-4)   # each on its own point
    np.testing.assert_allclose(xy[LOST][:, :, cols][found.nonzero()[0], :, found.nonzero()[1]],
                               uv[LOST][:, :, cols][found.nonzero()[0], :, found.nonzero()[1]])
    keep = np.ones(len(labels), bool)
    keep[cols] = False
    np.testing.assert_array_equal(out.xyz[:, keep], traj.xyz[:, keep])   # nothing else moves


def test_a_foot_alone_on_an_emptied_leg_is_not_taken(scene):
    """With only the foot's blobs left of the leg, the heel and toe points fit a leg bent to them
    whatever they are; nothing else on the leg vouches for them, so neither is added."""
    solver, labels, sites, t, cal, uv, dets = scene
    traj, measured, cols = _leg_lost(labels, sites, t, uv, LEG)
    gone = [labels.index(n) for n in ("RTHI", "RKNE", "RTIB", "RANK")]
    dets = [[Detections(np.delete(d.xy, gone if LOST.start <= f < LOST.stop else [], axis=0),
                        np.full(len(d.xy) - (len(gone) if LOST.start <= f < LOST.stop else 0), 20.0),
                        np.full(len(d.xy) - (len(gone) if LOST.start <= f < LOST.stop else 0), 200.0))
             for f, d in enumerate(cam)] for cam in dets]
    fit = solver.solve(traj, bridge=False)
    out, _, added = fill_limbs_from_free_blobs(traj, measured, dets, cal, solver, fit, LIMITS_MM)
    assert added == 0 and np.isnan(out.xyz[LOST][:, cols]).all()


def test_the_model_fill_judges_a_marker_by_its_position_not_each_hinge(scene):
    """The lumbar and thorax hinges turn about the same axes: the markers fix their sum, not each,
    so a test of every hinge on the way never let an arm or head marker be filled."""
    solver, labels, sites, t, cal, uv, dets = scene
    traj, _, cols = _leg_lost(labels, sites, t, uv, ["RELB"])
    fit = solver.solve(traj)
    ok = _constrained(solver, fit, labels, 3.0)
    assert ok[LOST, cols[0]].all()                                        # the arm's others place it
    traj, _, cols = _leg_lost(labels, sites, t, uv, ["RFIN"])
    fit = solver.solve(traj)
    assert not _constrained(solver, fit, labels, 3.0)[LOST, cols[0]].any()   # nothing else on the hand
