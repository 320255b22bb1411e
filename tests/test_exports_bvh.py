"""BVH export of the solved skeleton: hierarchy, channels, frame count and forward kinematics.

The file is re-parsed by the small independent reader below (BVH semantics: a joint's
local transform is ``T(offset) R``, ``R`` the product of its rotation channels in the listed
order, position channels replacing the offset) and its FK is compared with the solver's.
"""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from mocap.errors import MocapInputError
from mocap.exports import write_bvh
from mocap.skeleton import SkeletonSolver
from mocap.subject import SubjectModel
from mocap.types import Trajectories
from simbench.scenes.humanoid import BODY_NAMES, BodyParams, humanoid_mjcf

Y_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])  # (x, y, z) -> (x, z, -y)


def _read_bvh(text: str) -> dict:
    tokens = text.split()
    i = 0
    names, parents, offsets, channels, ends = [], [], [], [], []
    stack: list[int] = []
    assert tokens[0] == "HIERARCHY"
    i = 1
    while tokens[i] != "MOTION":
        tok = tokens[i]
        if tok in ("ROOT", "JOINT"):
            names.append(tokens[i + 1])
            parents.append(stack[-1] if stack else -1)
            offsets.append(None)
            channels.append([])
            i += 2
        elif tok == "End":  # End Site { OFFSET x y z }
            assert tokens[i + 1] == "Site" and tokens[i + 2] == "{" and tokens[i + 3] == "OFFSET"
            ends.append((stack[-1], np.array([float(v) for v in tokens[i + 4 : i + 7]])))
            assert tokens[i + 7] == "}"
            i += 8
        elif tok == "{":
            stack.append(len(names) - 1)
            i += 1
        elif tok == "}":
            stack.pop()
            i += 1
        elif tok == "OFFSET":
            offsets[stack[-1]] = np.array([float(v) for v in tokens[i + 1 : i + 4]])
            i += 4
        elif tok == "CHANNELS":
            n = int(tokens[i + 1])
            channels[stack[-1]] = tokens[i + 2 : i + 2 + n]
            i += 2 + n
        else:
            raise AssertionError(f"unexpected token {tok!r}")
    assert tokens[i + 1] == "Frames:" and tokens[i + 3] == "Frame" and tokens[i + 4] == "Time:"
    n_frames, frame_time = int(tokens[i + 2]), float(tokens[i + 5])
    values = np.array([float(v) for v in tokens[i + 6 :]]).reshape(n_frames, -1)
    return dict(names=names, parents=parents, offsets=np.array(offsets), channels=channels, ends=ends,
                n_frames=n_frames, frame_time=frame_time, values=values)


def _bvh_fk(bvh: dict) -> tuple[np.ndarray, np.ndarray]:
    """World joint positions ``(F, J, 3)`` and End Site positions ``(F, E, 3)``, file units/axes."""
    F, J = bvh["n_frames"], len(bvh["names"])
    pos = np.zeros((F, J, 3))
    rot = np.zeros((F, J, 3, 3))
    col = 0
    for j in range(J):
        local_t = np.tile(bvh["offsets"][j], (F, 1))
        local_R = np.tile(np.eye(3), (F, 1, 1))
        for ch in bvh["channels"][j]:
            v = bvh["values"][:, col]
            col += 1
            axis = "XYZ".index(ch[0])
            if ch.endswith("position"):
                local_t[:, axis] = v
            else:
                local_R = local_R @ Rotation.from_euler("XYZ"[axis], v[:, None], degrees=True).as_matrix()
        p = bvh["parents"][j]
        if p < 0:
            pos[:, j], rot[:, j] = local_t, local_R
        else:
            pos[:, j] = pos[:, p] + np.einsum("fij,fj->fi", rot[:, p], local_t)
            rot[:, j] = rot[:, p] @ local_R
    ends = np.stack([pos[:, j] + np.einsum("fij,j->fi", rot[:, j], off) for j, off in bvh["ends"]], axis=1)
    return pos, ends


@pytest.fixture(scope="module")
def solved():
    xml = humanoid_mjcf(BodyParams(), marker_set="plugin_gait_full")
    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)
    subject = SubjectModel.from_mjcf_text(xml)
    rng = np.random.default_rng(11)
    F, rate = 40, 60.0
    t = np.arange(F) / rate
    lo, hi = model.jnt_range[1:, 0], model.jnt_range[1:, 1]
    qpos = np.zeros((F, 40))
    qpos[:, 7:] = (lo + hi) / 2 + 0.4 * (hi - lo) / 2 * np.sin(2 * np.pi * rng.uniform(0.5, 1.5, 33) * t[:, None] + rng.uniform(0, 6, 33))
    qpos[:, 3:7] = Rotation.from_euler("zyx", np.c_[1.5 * t, 0.1 * np.sin(3 * t), 0.05 + 0 * t]).as_quat(scalar_first=True)
    qpos[:, :3] = np.c_[0.8 * t, 0.2 * t, 0.93 + 0 * t]
    sites = np.zeros((F, model.nsite, 3))
    for f in range(F):
        data.qpos[:] = qpos[f]
        mujoco.mj_kinematics(model, data)
        sites[f] = data.site_xpos
    xyz = sites + rng.normal(0, 0.001, sites.shape)
    xyz[20, :] = np.nan  # one frame without markers: not solved
    traj = Trajectories([model.site(i).name for i in range(model.nsite)], xyz, t)
    solver = SkeletonSolver(subject)
    return subject, solver, solver.solve(traj)


@pytest.mark.parametrize("up_axis", ["y", "z"])
def test_bvh_hierarchy_frames_and_fk(solved, tmp_path, up_axis):
    subject, solver, fit = solved
    path = write_bvh(tmp_path / "take.bvh", fit, subject, up_axis=up_axis)
    bvh = _read_bvh(path.read_text())
    assert bvh["names"] == list(BODY_NAMES)
    assert [bvh["names"][p] if p >= 0 else None for p in bvh["parents"]] == [b.parent for b in subject.bodies]
    assert bvh["n_frames"] == len(fit.times) == 40
    assert bvh["frame_time"] == pytest.approx(1 / 60.0, rel=1e-6)
    assert bvh["channels"][0] == ["Xposition", "Yposition", "Zposition", "Zrotation", "Yrotation", "Xrotation"]
    assert all(len(c) == 3 and all(ch.endswith("rotation") for ch in c) for c in bvh["channels"][1:])
    P = Y_UP if up_axis == "y" else np.eye(3)
    # Offsets in cm from the MJCF body positions; channels follow the hinge order.
    np.testing.assert_allclose(bvh["offsets"][1:], 100 * np.array([b.pos_m for b in subject.bodies[1:]]) @ P.T, atol=1e-6)
    upper = bvh["names"].index("upperarm_l")
    ankle = bvh["names"].index("foot_l")
    if up_axis == "y":
        assert bvh["channels"][upper] == ["Xrotation", "Zrotation", "Yrotation"]  # body x, y, z -> X, -Z, Y
        assert bvh["channels"][ankle] == ["Zrotation", "Xrotation", "Yrotation"]  # ankle_y, ankle_x
    else:
        assert bvh["channels"][upper] == ["Xrotation", "Yrotation", "Zrotation"]
        assert bvh["channels"][ankle] == ["Yrotation", "Xrotation", "Zrotation"]
    assert sorted(bvh["names"][j] for j, _ in bvh["ends"]) == sorted(["head", "hand_l", "hand_r", "foot_l", "foot_r"])

    pos, ends = _bvh_fk(bvh)
    world = pos @ P / 100.0  # back to Z-up metres
    ok = fit.valid
    assert not ok[20] and ok.sum() == 39
    err_mm = 1000 * np.linalg.norm(world[ok] - fit.joint_centres_m[ok], axis=2)
    print(f"\nBVH ({up_axis}-up) FK vs solved joint centres: max {err_mm.max():.4f} mm")
    assert err_mm.max() < 1.0
    # End Sites sit on each leaf's farthest marker: checks the leaves' rotations too.
    model_markers = solver.marker_positions(fit.q[ok])
    leaf_marker = {"head": None, "hand_l": "LFIN", "hand_r": "RFIN", "foot_l": "LTOE", "foot_r": "RTOE"}
    for e, (j, _) in enumerate(bvh["ends"]):
        name = leaf_marker[bvh["names"][j]]
        if name is not None:
            m = subject.marker_names.index(name)
            np.testing.assert_allclose(ends[ok, e] @ P / 100.0, model_markers[:, m], atol=1e-3)
    # The unsolved frame repeats a solved neighbour.
    np.testing.assert_allclose(bvh["values"][20], bvh["values"][19])


def test_bvh_errors(solved, tmp_path):
    subject, _, fit = solved
    with pytest.raises(MocapInputError, match="up_axis"):
        write_bvh(tmp_path / "x.bvh", fit, subject, up_axis="x")
    other = subject.with_markers(subject.marker_names[:5])
    other.bodies = other.bodies[:-1]
    with pytest.raises(MocapInputError, match="bodies"):
        write_bvh(tmp_path / "x.bvh", fit, other)
    assert not (tmp_path / "x.bvh").exists()
