"""Rendered body surface and colour shirt: closed pieces, budget, joints, patches, colours."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
import trimesh

from simbench.scenes.anthropometry import body_dimensions
from simbench.scenes.humanoid import BODY_NAMES, BodyParams, humanoid_mjcf, joint_qpos_index, tpose_qpos
from simbench.scenes.shirt import N_PATCHES, PATCH_COLOUR, PATCH_NAMES, SHIRT_BODIES, SHIRT_COLOURS_RGB
from simbench.scenes.surface import DEFAULT_CLOTHES_RGB, DEFAULT_SKIN_RGB, body_surface


def _inside(piece: trimesh.Trimesh, points: np.ndarray) -> np.ndarray:
    """Points strictly inside a closed mesh, by the generalised winding number
    (sum of solid angles, van Oosterom & Strackee 1983); trimesh's own
    ``contains`` needs rtree/embree, which are not dependencies."""
    tri = piece.triangles[None] - np.asarray(points, dtype=np.float64).reshape(-1, 1, 1, 3)
    a, b, c = tri[..., 0, :], tri[..., 1, :], tri[..., 2, :]
    la, lb, lc = (np.linalg.norm(v, axis=-1) for v in (a, b, c))
    num = np.einsum("...i,...i", a, np.cross(b, c))
    den = la * lb * lc + np.einsum("...i,...i", a, b) * lc + np.einsum("...i,...i", a, c) * lb + np.einsum("...i,...i", b, c) * la
    winding = 2.0 * np.arctan2(num, den).sum(axis=-1) / (4.0 * np.pi)
    return winding > 0.5


def _posed(params, setter):
    model = mujoco.MjModel.from_xml_string(humanoid_mjcf(params))
    data = mujoco.MjData(model)
    data.qpos[:] = tpose_qpos(params)
    idx = joint_qpos_index(model)
    for name, value in setter.items():
        data.qpos[idx[name]] = value
    mujoco.mj_kinematics(model, data)
    return model, data


POSES = {
    "tpose": {},
    "arms_down": {"shoulder_l_x": -np.pi / 2, "shoulder_r_x": np.pi / 2},
    "elbows_90": {"shoulder_l_x": -1.3, "shoulder_r_x": 1.3, "elbow_l": -np.pi / 2, "elbow_r": np.pi / 2},
    "knees_bent": {"hip_l_y": -0.6, "knee_l": 1.2, "hip_r_y": -0.3, "knee_r": 0.6, "ankle_l_y": -0.3},
    "squat": {"hip_l_y": -1.9, "hip_r_y": -1.9, "knee_l": 2.4, "knee_r": 2.4, "ankle_l_y": -0.5, "ankle_r_y": -0.5,
              "lumbar_y": 0.5, "wrist_l_x": 0.8, "neck_y": 0.5},
}


def test_pieces_closed_outward_and_within_budget():
    parts = body_surface(BodyParams(), shirt=True)
    assert [p.body for p in parts] == list(BODY_NAMES)
    n_faces = sum(len(p.mesh.faces) for p in parts)
    print(f"whole body: {n_faces} faces, {sum(len(p.pieces) for p in parts)} closed pieces")
    assert n_faces < 15000
    for p in parts:
        assert len(p.face_patch) == len(p.mesh.faces) == len(p.albedo)
        assert p.face_patch.dtype == np.int16 and p.albedo.shape == (len(p.mesh.faces), 3)
        assert sum(len(q.faces) for q in p.pieces) == len(p.mesh.faces)
        for q in p.pieces:
            assert q.is_watertight and q.is_winding_consistent
            assert q.volume > 0  # outward normals
            # everything is convex except the torso lofts, which follow the waist
            assert q.is_convex or p.body in ("pelvis", "abdomen", "thorax")


def test_body_volume_matches_mass():
    """Volume of the union is close to that of a human of that mass (density ~1010 kg/m^3)."""
    for height, mass in ((1.55, 50.0), (1.95, 90.0)):
        # Monte-Carlo volume of the union of convex pieces in the T-pose
        params = BodyParams(height_m=height, mass_kg=mass)
        model, data = _posed(params, {})
        rng = np.random.default_rng(0)
        lo, hi = np.array([-0.35, -height / 1.8, 0.0]), np.array([0.35, height / 1.8, height])
        pts = rng.uniform(lo, hi, size=(40_000, 3))
        inside = np.zeros(len(pts), dtype=bool)
        for part in body_surface(params):
            b = model.body(part.body).id
            local = (pts - data.xpos[b]) @ data.xmat[b].reshape(3, 3)
            for q in part.pieces:
                box = np.flatnonzero(((local >= q.bounds[0]) & (local <= q.bounds[1])).all(axis=1) & ~inside)
                for chunk in np.array_split(box, max(1, len(box) // 200)):
                    inside[chunk[_inside(q, local[chunk])]] = True
        volume = inside.mean() * np.prod(hi - lo)
        expected = mass / 1010.0
        print(f"{height} m, {mass} kg (default girth): volume {volume * 1000:.1f} l, a {mass} kg body {expected * 1000:.1f} l")
        # radii follow the ponderal index, so the volume follows the mass
        assert 0.8 * expected < volume < 1.2 * expected


@pytest.mark.parametrize("pose", sorted(POSES))
def test_surface_closed_at_joints(pose):
    """Neighbouring segments overlap across every joint in common poses (no gap opens)."""
    params = BodyParams()
    model, data = _posed(params, POSES[pose])
    parts = {p.body: p for p in body_surface(params)}

    def dist_inside(body: str, point: np.ndarray) -> float:
        """Depth of a world point inside a body's surface (negative if outside all pieces)."""
        b = model.body(body).id
        local = data.xmat[b].reshape(3, 3).T @ (point - data.xpos[b])
        best = -np.inf
        for q in parts[body].pieces:
            if _inside(q, local)[0]:
                c = trimesh.triangles.closest_point(q.triangles, np.repeat(local[None], len(q.faces), axis=0))
                best = max(best, float(np.linalg.norm(c - local, axis=1).min()))
        return best

    for child in BODY_NAMES[1:]:
        parent = model.body(model.body_parentid[model.body(child).id]).name
        centre = data.xpos[model.body(child).id]
        if child in ("abdomen", "thorax", "head"):
            # trunk: the two neighbours overlap across the joint (a point 1.5 cm into
            # the parent is at least 8 mm deep inside both)
            down = data.xmat[model.body(parent).id].reshape(3, 3)[:, 2]
            p = centre - 0.015 * down
            assert dist_inside(parent, p) > 0.008 and dist_inside(child, p) > 0.008, (pose, child)
        else:
            # limbs: the child contains a ball about the joint centre, which no joint
            # rotation moves, and that ball reaches deep into the parent
            depth_child = dist_inside(child, centre)
            assert depth_child > 0.015
            assert dist_inside(parent, centre) >= 0.75 * depth_child, (pose, child)


def test_feet_on_floor_and_height():
    for height in (1.55, 1.95):
        params = BodyParams(height_m=height)
        model, data = _posed(params, {})
        lowest, highest = np.inf, -np.inf
        for part in body_surface(params):
            b = model.body(part.body).id
            v = part.world_vertices(data.xpos[b], data.xmat[b])
            lowest, highest = min(lowest, v[:, 2].min()), max(highest, v[:, 2].max())
        assert abs(lowest) < 3e-3  # soles on the floor
        assert highest == pytest.approx(height, abs=3e-3)  # vertex at the stated height


def test_world_vertices_batched():
    params = BodyParams()
    part = body_surface(params)[5]
    model, data = _posed(params, POSES["elbows_90"])
    b = model.body(part.body).id
    xpos = np.stack([data.xpos[b], data.xpos[b] + 1.0])
    xmat = np.stack([data.xmat[b], data.xmat[b]])
    v = part.world_vertices(xpos, xmat)
    assert v.shape == (2, len(part.mesh.vertices), 3)
    np.testing.assert_allclose(v[1] - v[0], 1.0)
    np.testing.assert_allclose(v[0], part.mesh.vertices @ data.xmat[b].reshape(3, 3).T + data.xpos[b], atol=1e-12)


def test_colours_without_shirt():
    parts = body_surface(BodyParams(), shirt=False, skin_rgb=(0.5, 0.4, 0.3), clothes_rgb=(0.2, 0.2, 0.6))
    for p in parts:
        assert (p.face_patch == -1).all()
        expected = (0.5, 0.4, 0.3) if p.body in ("head", "hand_l", "hand_r") else (0.2, 0.2, 0.6)
        np.testing.assert_array_equal(p.albedo, np.broadcast_to(expected, p.albedo.shape))
    with pytest.raises(ValueError, match="skin_rgb"):
        body_surface(BodyParams(), skin_rgb=(128, 100, 90))


def test_shirt_patches():
    params = BodyParams()
    parts = body_surface(params, shirt=True)
    model, data = _posed(params, {})
    centres = {k: [] for k in range(N_PATCHES)}
    for p in parts:
        on = p.face_patch >= 0
        if p.body in SHIRT_BODIES:
            assert on.all(), p.body  # every shirt face has exactly one id
            assert (p.face_patch < N_PATCHES).all()
            np.testing.assert_array_equal(p.albedo, SHIRT_COLOURS_RGB[PATCH_COLOUR[p.face_patch]])
        else:
            assert not on.any(), p.body
            expected = DEFAULT_SKIN_RGB if p.body in ("head", "hand_l", "hand_r") else DEFAULT_CLOTHES_RGB
            np.testing.assert_array_equal(p.albedo[0], expected)
        b = model.body(p.body).id
        world = p.mesh.triangles_center @ data.xmat[b].reshape(3, 3).T + data.xpos[b]
        area = p.mesh.area_faces
        for k in np.unique(p.face_patch[on]):
            sel = p.face_patch == k
            centres[int(k)].append((world[sel], area[sel]))
    assert all(len(v) > 0 for v in centres.values()), "all 20 patches present"
    assert len(PATCH_NAMES) == 20 and len(set(PATCH_NAMES)) == 20
    counts = np.bincount(PATCH_COLOUR, minlength=10)
    np.testing.assert_array_equal(counts, 2)  # 10 colours, each used twice
    centroid = np.zeros((N_PATCHES, 3))
    extent = np.zeros(N_PATCHES)
    for k, chunks in centres.items():
        pts = np.concatenate([c for c, _ in chunks])
        w = np.concatenate([a for _, a in chunks])
        centroid[k] = (pts * w[:, None]).sum(0) / w.sum()
        extent[k] = np.linalg.norm(pts - centroid[k], axis=1).max()
    # compact patches; the two patches of a colour far apart
    print(f"patch extent (max distance from centroid): max {extent.max():.3f} m")
    assert extent.max() < 0.25
    for colour in range(10):
        a, b = np.flatnonzero(PATCH_COLOUR == colour)
        sep = np.linalg.norm(centroid[a] - centroid[b])
        assert sep > 0.25, (PATCH_NAMES[a], PATCH_NAMES[b], sep)


def test_shirt_colours_separable_under_white_balance_errors():
    """Chromaticities of the 10 colours stay nearest to their own reference under a
    per-channel white-balance error of up to +-25 % (roughly 2500 K of colour
    temperature error), and the two achromatic colours differ strongly in brightness."""
    c = SHIRT_COLOURS_RGB
    assert c.shape == (10, 3) and (c >= 0).all() and (c <= 1).all()
    chroma = c[:, :2] / c.sum(axis=1, keepdims=True)
    rng = np.random.default_rng(1)
    for gains in rng.uniform(0.75, 1.25, size=(200, 3)):
        shifted = c * gains
        ch = shifted[:, :2] / shifted.sum(axis=1, keepdims=True)
        d = np.linalg.norm(ch[:, None] - chroma[None], axis=-1)
        chromatic = np.arange(8)
        assert (d[chromatic][:, chromatic].argmin(axis=1) == chromatic).all()
    # light grey vs black: an order of magnitude of albedo apart
    assert c[8].mean() > 10 * c[9].mean()
