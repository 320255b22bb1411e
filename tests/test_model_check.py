"""The model check (mocap.model_check): wrong labelled points are dropped, correct ones beside
them are kept.

Ground truth: MuJoCo forward kinematics of the bench's humanoid with the Plug-in Gait marker
sites, 0.5 mm of noise; wrong points are put where a labelling error puts them (a wrist label on
a detection 40 mm off, a toe label on the heel's detection).
"""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from mocap.model_check import error_limit_mm, model_error_mm, robust_skeleton_fit, without_points
from mocap.skeleton import SkeletonSolver
from mocap.subject import SubjectModel
from mocap.types import Trajectories
from simbench.scenes.humanoid import BodyParams, humanoid_mjcf

from helpers import site_positions

NOISE_M = 0.0005
LIMIT_MM = 10.0


@pytest.fixture(scope="module")
def walk():
    """A solver and 12 frames of a smooth motion's exact markers ``(F, M, 3)`` m."""
    xml = humanoid_mjcf(BodyParams(), marker_set="plugin_gait_full")
    model = mujoco.MjModel.from_xml_string(xml)
    rng = np.random.default_rng(4)
    lo, hi = model.jnt_range[1:, 0], model.jnt_range[1:, 1]
    t = np.arange(12) / 30.0
    qpos = np.zeros((len(t), model.nq))
    qpos[:, 7:] = (lo + hi) / 2 + 0.5 * (hi - lo) / 2 * np.sin(2 * np.pi * rng.uniform(0.5, 1.5, len(lo)) * t[:, None]
                                                                  + rng.uniform(0, 2 * np.pi, len(lo)))
    qpos[:, 3] = 1.0
    qpos[:, 0] = 0.8 * t
    qpos[:, 2] = 0.95
    sites = site_positions(model, qpos)
    names = [model.site(i).name for i in range(model.nsite)]
    solver = SkeletonSolver(SubjectModel.from_mjcf_text(xml, name="pig"))
    return solver, names, sites, t


def _trajectories(names, sites, t, rng) -> Trajectories:
    F, M = sites.shape[:2]
    xyz = sites + rng.normal(0.0, NOISE_M, sites.shape)
    return Trajectories(list(names), xyz, t, np.zeros((F, M), bool), np.zeros((F, M)), np.full((F, M), 4))


def _drop_all_at_once(traj, solver):
    """The check before: one fit, every point over the limit dropped."""
    fit = solver.solve(traj)
    return np.nan_to_num(model_error_mm(solver, fit, traj), nan=0.0) > error_limit_mm(traj, LIMIT_MM)


def test_wrong_wrist_point_is_dropped_and_its_neighbours_kept(walk):
    solver, names, sites, t = walk
    traj = _trajectories(names, sites, t, np.random.default_rng(0))
    wrong = np.zeros(traj.xyz.shape[:2], bool)
    lwra = names.index("LWRA")
    frames = np.arange(3, 8)
    traj.xyz[frames, lwra] += np.array([0.0, 0.04, -0.02])   # a detection 45 mm off under the wrist label
    wrong[frames, lwra] = True

    fit, kept = robust_skeleton_fit(traj, solver, LIMIT_MM)
    dropped = np.isnan(kept.xyz[..., 0])
    np.testing.assert_array_equal(dropped, wrong)                     # exactly the wrong points
    err = np.linalg.norm(kept.xyz - sites, axis=2)[~dropped] * 1e3
    assert err.max() < 3.0
    assert np.nanmax(fit.marker_errors_mm) < 3.0                      # the fit is off the wrong point
    # The case is one the single-pass rule gets wrong: it drops correct forearm points too.
    assert (_drop_all_at_once(traj, solver) & ~wrong).any()


def test_frame_with_many_wrong_points_keeps_none_of_them(walk):
    """Four wrong points on one leg: whatever the rounds leave, no wrong point may stay."""
    solver, names, sites, t = walk
    traj = _trajectories(names, sites, t, np.random.default_rng(1))
    f = 6
    wrong = [names.index(n) for n in ("LTOE", "LHEE", "LANK", "LTIB")]
    traj.xyz[f, names.index("LTOE")] = sites[f, names.index("LHEE")]  # the toe label on the heel's detection
    traj.xyz[f, names.index("LHEE")] += np.array([0.03, -0.03, 0.02])
    traj.xyz[f, names.index("LANK")] += np.array([-0.04, 0.0, 0.03])
    traj.xyz[f, names.index("LTIB")] += np.array([0.0, 0.05, -0.02])

    _, kept = robust_skeleton_fit(traj, solver, LIMIT_MM)
    assert np.isnan(kept.xyz[f, wrong, 0]).all()
    assert np.isfinite(kept.xyz[np.arange(len(t)) != f]).all()       # other frames untouched


def test_without_points_marks_gaps():
    traj = Trajectories(["a", "b"], np.ones((3, 2, 3)), np.arange(3.0), np.ones((3, 2), bool), np.zeros((3, 2)),
                        np.full((3, 2), 3))
    drop = np.array([[True, False], [False, False], [False, True]])
    out = without_points(traj, drop)
    assert np.isnan(out.xyz[drop]).all() and np.isfinite(out.xyz[~drop]).all()
    np.testing.assert_array_equal(out.filled, ~drop)
    np.testing.assert_array_equal(out.n_views, np.where(drop, 0, 3))


def test_correct_points_the_fallback_dropped_are_taken_back(walk):
    """Three wrong points on a foot in a frame seen by two cameras (so the limit is 5 mm): the
    first fit, pulled by them, misses correct pelvis points, and the fallback drops every point
    the first fit missed. The fit without any suspect point explains the pelvis points again, so
    they are taken back; no wrong point is. The leg's correct points stay out: without its other
    markers the fit cannot judge them."""
    solver, names, sites, t = walk
    traj = _trajectories(names, sites, t, np.random.default_rng(0))
    f = 6
    traj.n_views[f] = 2
    wrong = [names.index(n) for n in ("LTOE", "LHEE", "LANK")]
    traj.xyz[f, names.index("LTOE")] = sites[f, names.index("LHEE")]    # the toe label on the heel's detection
    traj.xyz[f, names.index("LHEE")] += np.array([0.09, -0.09, 0.06])
    traj.xyz[f, names.index("LANK")] += np.array([-0.12, 0.0, 0.09])
    first = solver.solve(traj, bridge=False)
    missed = np.nan_to_num(model_error_mm(solver, first, traj)[f], nan=0.0) > error_limit_mm(traj, LIMIT_MM)[f]
    pelvis = [names.index(n) for n in ("LASI", "RASI", "LPSI")]
    assert missed[pelvis].all()                                       # the fallback drops them

    _, kept = robust_skeleton_fit(traj, solver, LIMIT_MM)
    assert np.isnan(kept.xyz[f, wrong, 0]).all()
    leg = [names.index(n) for n in ("LTHI", "LKNE", "LTIB", "LANK", "LHEE", "LTOE")]
    rest = np.setdiff1d(np.arange(len(names)), leg)
    assert np.isfinite(kept.xyz[f, rest, 0]).all()                   # the pelvis points among them
    assert np.isfinite(kept.xyz[np.arange(len(t)) != f]).all()


def test_a_limb_the_fallback_emptied_is_rebuilt_from_its_correct_points(walk):
    """The frame of the test above: after the fallback the leg's correct thigh and knee points
    are out with the three wrong foot points (the rounds dropped the tibia point), and the fit
    without them cannot judge them (50 and 81 mm off). Taken back one at a time from the hip
    down, the thigh vouched for by the knee, they come back exactly; no wrong point does.
    Without the growth rounds they stay out."""
    solver, names, sites, t = walk
    traj = _trajectories(names, sites, t, np.random.default_rng(0))
    f = 6
    traj.n_views[f] = 2
    wrong = [names.index(n) for n in ("LTOE", "LHEE", "LANK")]
    traj.xyz[f, names.index("LTOE")] = sites[f, names.index("LHEE")]
    traj.xyz[f, names.index("LHEE")] += np.array([0.09, -0.09, 0.06])
    traj.xyz[f, names.index("LANK")] += np.array([-0.12, 0.0, 0.09])
    correct_leg = [names.index(n) for n in ("LTHI", "LKNE")]

    _, kept = robust_skeleton_fit(traj, solver, LIMIT_MM)
    assert np.isnan(kept.xyz[f, wrong, 0]).all()
    assert np.isfinite(kept.xyz[f, correct_leg, 0]).all()
    np.testing.assert_allclose(kept.xyz[f, correct_leg], traj.xyz[f, correct_leg])

    _, without = robust_skeleton_fit(traj, solver, LIMIT_MM, grow_rounds=0)
    assert np.isnan(without.xyz[f, correct_leg, 0]).any()
