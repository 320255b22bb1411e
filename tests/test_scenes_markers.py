"""Marker sets: counts, names, placement on the skin, separation, MuJoCo sites."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
import trimesh

from simbench.scenes.humanoid import BodyParams, humanoid_mjcf, joint_qpos_index, tpose_qpos
from simbench.scenes.markers import MARKER_RADIUS_M, MARKER_SETS, marker_set
from simbench.scenes.surface import body_surface

PIG = (
    "LFHD RFHD LBHD RBHD C7 T10 CLAV STRN RBAK LSHO LUPA LELB LFRM LWRA LWRB LFIN RSHO RUPA RELB RFRM "
    "RWRA RWRB RFIN LASI RASI LPSI RPSI LTHI LKNE LTIB LANK LHEE LTOE RTHI RKNE RTIB RANK RHEE RTOE"
).split()


def _distance_to_mesh(tris: np.ndarray, p: np.ndarray) -> float:
    c = trimesh.triangles.closest_point(tris, np.repeat(p[None, :], len(tris), axis=0))
    return float(np.linalg.norm(c - p, axis=1).min())


def _inside(piece: trimesh.Trimesh, p: np.ndarray) -> bool:
    """True if p is inside a closed mesh: generalised winding number (sum of solid
    angles); trimesh's ``contains`` needs rtree/embree, which are not dependencies."""
    tri = piece.triangles - p
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    la, lb, lc = (np.linalg.norm(v, axis=1) for v in (a, b, c))
    num = np.einsum("ij,ij->i", a, np.cross(b, c))
    den = la * lb * lc + np.einsum("ij,ij->i", a, b) * lc + np.einsum("ij,ij->i", a, c) * lb + np.einsum("ij,ij->i", b, c) * la
    return bool(2.0 * np.arctan2(num, den).sum() / (4.0 * np.pi) > 0.5)


def test_marker_counts_and_names():
    params = BodyParams()
    pig = marker_set("plugin_gait_full", params)
    assert [m.name for m in pig] == PIG
    assert len(marker_set("sparse_joints", params)) == 15
    upper = marker_set("upper_body", params)
    assert set(m.name for m in upper) < set(PIG)
    assert {m.body for m in upper} <= {"head", "thorax", "upperarm_l", "forearm_l", "hand_l", "upperarm_r", "forearm_r", "hand_r"}
    # the upper body set is every Plug-in Gait marker of the head, torso and arms
    upper_bodies = {"head", "thorax", "upperarm_l", "forearm_l", "hand_l", "upperarm_r", "forearm_r", "hand_r"}
    assert {m.name for m in upper} == {m.name for m in pig if m.body in upper_bodies}
    with pytest.raises(ValueError, match="plugin_gait_full"):
        marker_set("vicon_full", params)


@pytest.mark.parametrize("height", [1.55, 1.95])
@pytest.mark.parametrize("set_name", sorted(MARKER_SETS))
def test_markers_sit_on_the_skin_and_apart(set_name, height):
    """Each marker centre is one radius from its body's surface, outside every other body,
    and no two markers are closer than 4 cm (their image blobs would merge)."""
    params = BodyParams(height_m=height)
    model = mujoco.MjModel.from_xml_string(humanoid_mjcf(params, set_name))
    data = mujoco.MjData(model)
    data.qpos[:] = tpose_qpos(params)
    mujoco.mj_kinematics(model, data)
    parts = {p.body: p for p in body_surface(params)}
    markers = marker_set(set_name, params)
    world = np.array([data.site_xpos[model.site(m.name).id] for m in markers])
    # sites are where the specs say (body frame -> world)
    for m, w in zip(markers, world):
        b = model.body(m.body).id
        np.testing.assert_allclose(w, data.xmat[b].reshape(3, 3) @ m.offset_m + data.xpos[b], atol=1e-9)
        assert model.site_size[model.site(m.name).id][0] == MARKER_RADIUS_M
    worst = 0.0
    for m, w in zip(markers, world):
        for body, part in parts.items():
            b = model.body(body).id
            tris = part.world_vertices(data.xpos[b], data.xmat[b])[part.mesh.faces]
            dist = _distance_to_mesh(tris, w)
            if body == m.body:
                worst = max(worst, abs(dist - MARKER_RADIUS_M))
                assert abs(dist - MARKER_RADIUS_M) < 3e-3, (m.name, dist)
            else:
                assert dist > MARKER_RADIUS_M - 3e-3, (m.name, body, dist)
            local = data.xmat[b].reshape(3, 3).T @ (w - data.xpos[b])
            assert not any(_inside(piece, local) for piece in part.pieces), (m.name, body)
    sep = np.linalg.norm(world[:, None] - world[None], axis=-1)
    np.fill_diagonal(sep, np.inf)
    print(f"{set_name} {height} m: |distance to skin - radius| <= {worst * 1e3:.3f} mm, min separation {sep.min() * 100:.1f} cm")
    assert sep.min() > 0.04


def test_markers_follow_their_segments_and_body_size():
    small, tall = BodyParams(height_m=1.55), BodyParams(height_m=1.95)
    ms = {m.name: m for m in marker_set("plugin_gait_full", small)}
    mt = {m.name: m for m in marker_set("plugin_gait_full", tall)}
    # knee and ankle markers sit at the lower joint of their segment; distances scale with height
    for name in ("LKNE", "RKNE"):
        assert ms[name].body.startswith("thigh")
    ratio = np.linalg.norm(mt["LKNE"].offset_m) / np.linalg.norm(ms["LKNE"].offset_m)
    assert ratio == pytest.approx(1.95 / 1.55, rel=0.02)
    # left/right mirror symmetry of the symmetric markers (to 1 mm: the torso mesh's
    # diagonals are not mirror images)
    for name in ("FHD", "SHO", "ELB", "WRA", "ASI", "KNE", "ANK", "HEE", "TOE"):
        np.testing.assert_allclose(ms["L" + name].offset_m * [1, -1, 1], ms["R" + name].offset_m, atol=1e-3)
    # Plug-in Gait's deliberate asymmetry: thigh markers at different heights
    assert abs(ms["LTHI"].offset_m[2] - ms["RTHI"].offset_m[2]) > 0.03


def test_wrist_markers_move_with_the_forearm():
    params = BodyParams()
    model = mujoco.MjModel.from_xml_string(humanoid_mjcf(params, "plugin_gait_full"))
    data = mujoco.MjData(model)
    idx = joint_qpos_index(model)
    data.qpos[:] = tpose_qpos(params)
    data.qpos[idx["elbow_l"]] = -np.pi / 2
    mujoco.mj_kinematics(model, data)
    elbow = data.xpos[model.body("forearm_l").id]
    wrist = data.site_xpos[[model.site("LWRA").id, model.site("LWRB").id]].mean(axis=0)
    # forearm flexed 90 deg: the wrist is straight in front of the elbow
    d = wrist - elbow
    assert d[0] > 0.2 and abs(d[1]) < 0.01 and abs(d[2]) < 0.01
