"""The shirt model of the colour-shirt pipeline: CPU z-buffer, reduced kinematics, agreement with the bench's renderer."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
import trimesh

from mocap.calib.synthetic import look_at
from mocap.calibration import Camera
from mocap.shirt.hypotheses import ARMS
from mocap.shirt.kinematics import UPPER_BODY_JOINTS
from mocap.shirt.shirt_model import CropView, look_at_view
from mocap.shirt.zbuffer import rasterise_faces
from simbench.stage.build import build_stage
from simbench.render import ids as idc
from simbench.stage.rendering import render_frames
from simbench.scenario import load_scenario
from simbench.scenes.anthropometry import BodyParams
from simbench.scenes.humanoid import humanoid_mjcf, joint_ranges
from simbench.pipelines.shirt_database import shirt_model


@pytest.fixture(scope="module")
def model():
    return shirt_model(BodyParams())


def _pinhole(points: np.ndarray, f: float = 200.0, c: float = 49.5) -> tuple[np.ndarray, np.ndarray]:
    return points[:, :2] / points[:, 2:3] * f + c, points[:, 2]


def test_rasteriser_covers_exactly_the_pixel_centres_of_a_projected_square():
    box = trimesh.creation.box((0.4, 0.4, 0.4))
    box.apply_translation((0.013, -0.021, 3.0))  # front face at z = 2.8, seen from the origin looking +z
    uv, z = _pinhole(np.asarray(box.vertices))
    face = rasterise_faces(uv, z, np.asarray(box.faces), 100, 100)
    # front face x, y in [-0.2, 0.2] + offset at depth 2.8: its projected square
    lo = (np.array([0.013, -0.021]) - 0.2) / 2.8 * 200 + 49.5
    hi = (np.array([0.013, -0.021]) + 0.2) / 2.8 * 200 + 49.5
    xs, ys = np.arange(100), np.arange(100)
    inside = ((xs[None, :] >= lo[0]) & (xs[None, :] <= hi[0])) & ((ys[:, None] >= lo[1]) & (ys[:, None] <= hi[1]))
    assert np.array_equal(face >= 0, inside)
    # only the two triangles of the face towards the camera (normal -z) are drawn
    normals = np.asarray(box.face_normals)
    assert set(np.unique(face[face >= 0])) == set(np.flatnonzero(normals[:, 2] < -0.9))


def test_rasteriser_keeps_the_nearer_surface_and_culls_back_faces():
    near = trimesh.creation.box((0.2, 0.2, 0.2))
    near.apply_translation((0.0, 0.0, 2.0))
    far = trimesh.creation.box((0.6, 0.6, 0.2))
    far.apply_translation((0.0, 0.0, 3.0))
    mesh = trimesh.util.concatenate([near, far])
    uv, z = _pinhole(np.asarray(mesh.vertices))
    face = rasterise_faces(uv, z, np.asarray(mesh.faces), 100, 100)
    n_near = len(near.faces)
    assert (face[49:51, 49:51] < n_near).all() and (face[49:51, 49:51] >= 0).all()  # centre: the near box
    assert (face[49, 31:38] >= n_near).all()  # beside it (the near box spans x 39..60, the far one 29..70): the far box
    assert (face[49, :28] < 0).all()
    # the near box's face towards the camera, with its winding flipped, faces away: culled
    front = np.asarray(mesh.faces)[np.flatnonzero(np.asarray(mesh.face_normals)[:, 2] < -0.9)]
    assert (rasterise_faces(uv, z, front, 100, 100) >= 0).sum() > 400
    assert (rasterise_faces(uv, z, front[:, ::-1], 100, 100) < 0).all()
    assert np.array_equal(rasterise_faces(uv, z, front[:, ::-1], 100, 100, cull_back=False) >= 0,
                          rasterise_faces(uv, z, front, 100, 100) >= 0)


def test_batched_renders_equal_single_renders(model):
    rng = np.random.default_rng(3)
    hinges = model.kin.lower + (model.kin.upper - model.kin.lower) * rng.random((3, len(model.kin.lower)))
    views = np.stack([look_at_view(np.array([0.1 * i, 0.0, 1.0])) @ np.array([[0, 1, 0], [0, 0, -1], [-1, 0, 0]]) for i in range(3)])
    vv = model.view_vertices_batch(hinges, views)
    c, s = model.shirt_extent_batch(vv)
    maps = model.render_orthographic_batch(vv, c, s * 1.1, 48)
    for i in range(3):
        single = model.render_orthographic(model.view_vertices(hinges[i], views[i]), c[i], s[i] * 1.1, 48)
        assert np.array_equal(single.colour, maps[i])
        assert (maps[i] >= 0).sum() > 100


def test_upper_body_configuration_reproduces_mujoco_joint_centres(model):
    """from_full_qpos folds the lumbar joint into the root: every upper-body joint centre stays exact."""
    m = mujoco.MjModel.from_xml_string(humanoid_mjcf(BodyParams()))
    d = mujoco.MjData(m)
    rng = np.random.default_rng(0)
    ranges = joint_ranges()
    for _ in range(5):
        q = np.zeros(m.nq)
        q[:3] = rng.normal(0, 0.5, 3) + [0, 0, 1]
        quat = rng.normal(size=4)
        q[3:7] = quat / np.linalg.norm(quat)
        q[7:] = [rng.uniform(*ranges[n]) for n in ranges]
        d.qpos[:] = q
        mujoco.mj_kinematics(m, d)
        want = np.array([d.xpos[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, b)] for b in UPPER_BODY_JOINTS])
        got = model.kin.joint_centres(model.kin.from_full_qpos(q))
        np.testing.assert_allclose(got, want, atol=1e-9)
        back = model.kin.to_full_qpos(model.kin.from_full_qpos(q))
        got2 = model.kin.joint_centres(model.kin.from_full_qpos(back))
        np.testing.assert_allclose(got2, want, atol=1e-9)


def test_rendered_patches_agree_with_the_bench_renderer(model):
    """The pipeline's id map of the true pose against the GL renderer's: 97 % of the shirt pixels agree."""
    sc = load_scenario("scenarios/shirt_office.toml", overrides={"duration_s": 1 / 30, "motion.start_s": 1.8, "sensor.motion_blur": False,
                                                                 "sensor.antialias": 1})
    seq = render_frames(build_stage(sc), keep_frames=False, keep_ids=True)
    gt = seq.ground_truth
    q = model.kin.from_full_qpos(gt.qpos[0])
    for cam in gt.calibration():
        truth = idc.shirt_patch(gt.id_maps[cam.name][0])
        W, H = cam.size
        mine = model.render_camera(q, Camera(cam.name, cam.size, cam.K, cam.dist, cam.R, cam.t), CropView(0.0, 0.0, 1.0, max(W, H))).patch[:H, :W]
        shirt = truth >= 0
        assert shirt.sum() > 3000
        assert np.mean(mine[shirt] == truth[shirt]) > 0.97
        assert np.mean(truth[mine >= 0] == mine[mine >= 0]) > 0.95


def test_arm_variants_render_the_pixels_of_whole_renders(model):
    """ShirtModel.render_variants (the still bodies drawn once, each arm over them) gives every variant's
    id maps exactly as a render of the whole varied pose."""
    rng = np.random.default_rng(7)
    K = np.array([[600.0, 0.0, 319.5], [0.0, 600.0, 239.5], [0.0, 0.0, 1.0]])
    shots = [(Camera(n, (640, 480), K, np.zeros(5), *look_at(np.asarray(c, float), np.zeros(3))), CropView(170.0, 90.0, 300 / 96, 96))
             for n, c in (("front", (0.2, -2.2, 0.3)), ("side", (1.9, -1.1, 0.1)))]
    lo, hi = model.kin.lower, model.kin.upper
    differs = 0
    for trial in range(6):
        q = model.kin.neutral()
        q[7:] = lo + (hi - lo) * rng.random(len(lo))
        side = "lr"[trial % 2]
        sl = ARMS[side]
        arms = (lo + (hi - lo) * rng.random((3, len(lo))))[:, sl.start - 7: sl.stop - 7]
        variants = model.render_variants(q, sl, arms, shots)
        assert len(variants) == 3 and all(len(v) == 2 for v in variants)
        for arm, got in zip(arms, variants):
            qv = q.copy()
            qv[sl] = arm
            for want, mine in zip(model.render_cameras(qv, shots), got):
                assert (want.colour >= 0).sum() > 200
                assert np.array_equal(want.face, mine.face)
                assert np.array_equal(want.patch, mine.patch) and np.array_equal(want.colour, mine.colour)
        differs += not np.array_equal(variants[0][0].face, variants[1][0].face)
    assert differs >= 5  # the arms are seen: the variants are not all one picture


def test_shirt_image_box_is_the_pinhole_box_of_the_shirt_vertices_in_front(model):
    """ShirtModel.shirt_image_box: the extremes of ``x / z * f + c`` over the shirt's vertices more than 5 cm in
    front of the camera, to the bit (numpy's form below); None when fewer than 3 are."""
    rng = np.random.default_rng(11)
    K = np.array([[610.0, 0.0, 322.5], [0.0, 590.0, 236.5], [0.0, 0.0, 1.0]])
    lo, hi = model.kin.lower, model.kin.upper
    for trial, centre in enumerate(((0.2, -2.2, 0.3), (1.9, -1.1, 0.1), (0.0, -0.15, 0.25))):  # the last one inside the body
        cam = Camera("c", (640, 480), K, np.zeros(5), *look_at(np.asarray(centre, float), np.zeros(3)))
        q = model.kin.neutral()
        q[7:] = lo + (hi - lo) * rng.random(len(lo))
        P = model.world_vertices(q)[model.shirt_vertex_index]
        Xc = P @ cam.R.T + cam.t
        ok = Xc[:, 2] > 0.05
        uv = Xc[ok, :2] / Xc[ok, 2:3] * [K[0, 0], K[1, 1]] + K[:2, 2]
        box = model.shirt_image_box(P, cam)
        assert 3 <= ok.sum() and np.array_equal(box[0], uv.min(axis=0)) and np.array_equal(box[1], uv.max(axis=0))
        if trial == 2:
            assert ok.sum() < len(P)  # some vertices behind this camera
    behind = Camera("b", (640, 480), K, np.zeros(5), *look_at(np.array([0.0, -2.5, 0.3]), np.array([0.0, -5.0, 0.3])))
    assert model.shirt_image_box(model.world_vertices(model.kin.neutral())[model.shirt_vertex_index], behind) is None
