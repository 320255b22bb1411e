"""The hands as centroid targets of the colour shirt's step 4 (mocap/shirt/hands.py)."""

from __future__ import annotations

from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest

from mocap.calib.synthetic import look_at
from mocap.calibration import Calibration, Camera
from mocap.errors import MocapInputError
from mocap.shirt.classify import Classification, distance_to_patches
from mocap.shirt.colour_model import ColourModel
from mocap.shirt.hands import HandTargets, _centre_of_mass, find_hands, fit_skin_colour, skin_pieces, widened_skin
from mocap.shirt.ik import IKPriors
from mocap.shirt.pipeline import ShirtPipelineParams, ShirtTracker
from mocap.shirt.settings import CameraObservation
from mocap.shirt.shirt_model import CropView
from simbench.pipelines.shirt_database import PoseSampling, build_database
from simbench.scenes.anthropometry import BodyParams

SKIN = np.array([0.40, 0.28, 0.22])


@pytest.fixture(scope="module")
def rig():
    db = build_database(BodyParams(), PoseSampling(n_poses=60, seed=3))
    K = np.array([[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]])
    R, t = look_at(np.array([3.0, 0.4, 1.3]), np.array([0.0, 0.0, 1.2]))
    cam = Camera("front", (640, 480), K, np.zeros(5), R, t)
    k, p = db.n_colours, db.geometry.n_patches
    colours = ColourModel(np.random.default_rng(0).random((k, 3)), np.repeat(np.eye(3)[None] * 1e-3, k, axis=0),
                          tuple(db.geometry.colour_names))
    priors = IKPriors(np.repeat(np.eye(2)[None] * 1e-4, p, axis=0), np.ones(17), np.ones(17))
    tracker = ShirtTracker(db, colours, priors, Calibration((cam,)), [np.eye(3)], replace(ShirtPipelineParams(), arm_search=False))
    return tracker, cam


def _pose(tracker: ShirtTracker) -> np.ndarray:
    kin = tracker.kin
    q = kin.make_q(np.eye(3), np.array([0.0, 0.0, 0.93]), np.zeros(len(kin.lower)))
    q[7 + 3: 7 + 7] = [0.0, 0.0, -0.6, 0.9]     # left arm out and down, elbow bent
    q[7 + 7: 7 + 11] = [0.0, 0.0, 0.6, -0.9]    # the right mirrored
    return q


def test_the_hand_centres_lie_inside_the_hands_beyond_the_wrists(rig):
    """The anchors (each hand's centre of mass from the MJCF, on its hand body) posed by the model's kinematics:
    on the forearm's line beyond the wrist (the wrists are locked), 5-15 cm out, within the hand's mesh along that
    line; the head's inside its mesh's box, 10 cm or more above the neck joint."""
    tracker, _ = rig
    q = _pose(tracker)
    hands, head = tracker.hands.world_points(tracker.model, q)
    world = tracker.model.world_vertices(q)
    g = tracker.model.geometry
    joints = tracker.kin.joint_centres(q)
    for s, (elbow, wrist, name) in enumerate(((4, 5, "hand_l"), (7, 8, "hand_r"))):
        axis = joints[wrist] - joints[elbow]
        out = hands[s] - joints[wrist]
        assert 0.05 < np.linalg.norm(out) < 0.15
        assert np.degrees(np.arccos(out @ axis / np.linalg.norm(out) / np.linalg.norm(axis))) < 2.0
        mesh = world[g.vertex_body == g.body_names.index(name)]
        along = (mesh - joints[wrist]) @ axis / np.linalg.norm(axis)
        assert along.min() < np.linalg.norm(out) < along.max()  # within the hand's length
    assert hands[0][1] > 0 > hands[1][1]
    head_mesh = world[g.vertex_body == g.body_names.index("head")]
    assert np.all(head_mesh.min(axis=0) < head) and np.all(head < head_mesh.max(axis=0)) and head[2] > joints[2][2] + 0.1


def test_a_humanoid_without_a_hands_centre_of_mass_is_refused_with_the_body(rig):
    tracker, _ = rig
    text = tracker.model.mjcf_text
    start = text.index('<body name="hand_l"')
    inert = text.index("<inertial", start)
    end = text.index("/>", inert) + 2
    with pytest.raises(MocapInputError, match="hand_l"):
        _centre_of_mass(text[:inert] + text[end:], "hand_l")


def test_skin_colour_fit_keeps_the_skin_and_leaves_out_hair():
    rng = np.random.default_rng(4)
    skin = SKIN + rng.normal(0, 0.01, (400, 3))
    hair = np.array([0.05, 0.04, 0.03]) + rng.normal(0, 0.005, (120, 3))
    fit = fit_skin_colour(np.vstack([skin, hair]))
    assert fit.names == ("skin",) and np.allclose(fit.means[0], SKIN, atol=0.004)
    d = fit.distances(np.vstack([SKIN, hair[:1]]), np.eye(3))[:, 0]
    assert d[0] < 1.0 and d[1] > 10.0
    assert fit_skin_colour(skin[:10]) is None


def _pieces(blobs: list[tuple[int, int]], size: int = 64) -> HandTargets:
    """Skin pieces of 3 x 3 pixels centred on ``blobs`` (x, y), all of skin colour, nothing else classified."""
    colour = -np.ones((size, size), np.int16)
    x = np.zeros((size * size, 3), np.float32)
    for bx, by in blobs:
        for yy in range(by - 1, by + 2):
            x[yy * size + bx - 1: yy * size + bx + 2] = SKIN
    skin = ColourModel(SKIN[None], (np.eye(3) * 0.01 ** 2)[None], ("skin",))
    return skin_pieces(np.arange(size * size), x, colour, np.eye(3), skin, 3.0)


def _sleeve(x0: int, x1: int, y: int, size: int = 64) -> np.ndarray:
    return np.array([y * size + x for x in range(x0, x1)])


def test_the_widened_skin_takes_in_shaded_skin_and_keeps_its_mean():
    """widened_skin: a colour scaled by shading (0.5 to 1.5 of the skin's mean) is within 1 unit of the widened skin,
    where the fitted one puts it 6-13 units away; another hue is still far; the mean stays; every direction's SD is
    at least the floor; with no widening the covariance is the fitted one."""
    rng = np.random.default_rng(3)
    mu = np.array([0.198, 0.122, 0.102])  # shirt_walk_lamp seed 1's skin, white-balanced linear RGB
    fitted = fit_skin_colour(mu + rng.normal(0.0, 0.01, (400, 3)))
    wide = widened_skin(fitted, 0.5, 0.05)
    np.testing.assert_array_equal(wide.means, fitted.means)
    eye = np.eye(3)
    for scale in (0.5, 0.75, 1.5):
        d_fit = fitted.distances((scale * fitted.means[0])[None], eye)[0, 0]
        d_wide = wide.distances((scale * fitted.means[0])[None], eye)[0, 0]
        assert d_fit > 5.0
        assert d_wide == pytest.approx(abs(scale - 1.0) / 0.5, abs=0.05)  # 1 SD of shading per 0.5 of the mean
    other_hue = np.array([[0.10, 0.12, 0.20]])  # bluish, about as bright
    assert wide.distances(other_hue, eye)[0, 0] > 3.0
    sd_least = np.sqrt(np.linalg.eigvalsh(wide.covariances[0]).min())
    assert sd_least >= 0.05 * np.linalg.norm(mu) * (1 - 1e-9)
    np.testing.assert_allclose(widened_skin(fitted, 0.0, 0.0).covariances, fitted.covariances, atol=1e-15)


def test_the_sleeve_a_piece_borders_tells_the_hands_apart_where_the_pose_has_them_crossed():
    found = _pieces([(20, 30), (40, 30)])
    assert len(found.counts) == 3 and set(found.counts[1:]) == {9}
    left_sleeve, right_sleeve = _sleeve(10, 19, 30), _sleeve(42, 52, 30)   # left sleeve ends at the piece at x 20
    head = np.array([30.0, 5.0])
    # the pose puts the left hand near the right piece and the right hand near the left one
    crossed = np.array([[38.0, 30.0], [22.0, 30.0]])
    got = find_hands(found, (left_sleeve, right_sleeve), crossed, head, gate_px=25.0, min_pixels=4)
    assert np.allclose(got, [[20, 30], [40, 30]])
    # without sleeves bordering any piece, no hand is found (nearness alone took the wrong one)
    none = find_hands(found, (np.array([], int), np.array([], int)), crossed, head, gate_px=25.0, min_pixels=4)
    assert np.isnan(none).all()
    # beyond the gate, or too small, or the piece under the head: none
    far = find_hands(found, (left_sleeve, right_sleeve), crossed, head, gate_px=5.0, min_pixels=4)
    assert np.isnan(far).all()
    small = find_hands(found, (left_sleeve, right_sleeve), crossed, head, gate_px=25.0, min_pixels=10)
    assert np.isnan(small).all()
    under_head = find_hands(found, (left_sleeve, right_sleeve), crossed, np.array([20.0, 30.0]), gate_px=25.0, min_pixels=4)
    assert np.isnan(under_head[0]).all() and np.allclose(under_head[1], [40, 30])


def test_a_piece_both_sleeves_border_goes_to_neither_hand():
    found = _pieces([(30, 30)])                          # clasped hands: one piece
    both = find_hands(found, (_sleeve(20, 29, 30), _sleeve(32, 40, 30)), np.array([[28.0, 30.0], [32.0, 30.0]]),
                      np.array([30.0, 5.0]), gate_px=25.0, min_pixels=4)
    assert np.isnan(both).all()


def test_hand_constraints_target_the_hands_skin_in_a_rendered_frame(rig):
    """A frame drawn from the model itself (shirt colours where the render shows them, skin on the hands'
    faces): two hand constraints, each at the centroid of its hand's skin pixels, anchored on the hands'
    bodies; the patches' targets are unchanged by them; a pose whose render hides a hand gives it none."""
    tracker, cam = rig
    q = _pose(tracker)
    model = tracker.model
    uv = cam.project(model.world_vertices(q))
    lo, hi = uv.min(axis=0), uv.max(axis=0)
    side = 1.2 * float(np.max(hi - lo))
    view = CropView(*(0.5 * (lo + hi) - side / 2), side / 144, 144)    # the whole body, 144 working pixels
    rend = model.render_camera(q, cam, view)
    g = model.geometry
    x = np.zeros((144 * 144, 3), np.float32)
    blobs = []
    for name in ("hand_l", "hand_r"):
        px = (rend.face >= 0) & (model.face_body[np.maximum(rend.face, 0)] == g.body_names.index(name))
        assert px.sum() > 10
        x[px.ravel()] = SKIN
        ys, xs = np.nonzero(px)
        blobs.append(view.to_image(np.array([xs.mean(), ys.mean()])))
    idx = np.arange(144 * 144)
    colour = rend.colour.astype(np.int16)
    cls = Classification(colour, np.zeros(colour.shape, np.float32), colour, 1.0)
    o = CameraObservation(view=view, tiny=SimpleNamespace(side=40.0), step1=cls, final=cls, pixels=(idx, x))
    pdist = distance_to_patches(rend.patch, model.n_patches, idx, view.size, 1)
    tracker.skin = None
    without = tracker._camera_constraints(0, o, colour, idx, pdist, rend, q)
    tracker.skin = ColourModel(SKIN[None], (np.eye(3) * 0.02 ** 2)[None], ("skin",))
    tracker._pieces.clear()
    try:
        cons = tracker._camera_constraints(0, o, colour, idx, pdist, rend, q)
        # the same frame, but a render that shows no hand: no hand constraint
        hidden = replace(rend, face=np.where(np.isin(model.face_body[np.maximum(rend.face, 0)], tracker.hands.hand_body), -1, rend.face))
        none = tracker._camera_constraints(0, o, colour, idx, pdist, hidden, q)
    finally:
        tracker.skin = None
    extra = cons.patch >= model.n_patches
    assert extra.sum() == 2 and len(cons) == len(without) + 2
    assert np.array_equal(cons.target_px[~extra], without.target_px)
    got = cons.target_px[extra][np.argsort(cons.patch[extra])]
    assert np.allclose(got, np.array(blobs), atol=1e-6)
    anchored = cons.anchor_body[np.isin(cons.anchor_of, np.flatnonzero(extra))]
    assert sorted(g.body_names[b] for b in anchored) == ["hand_l", "hand_r"]
    assert not np.any(none.patch >= model.n_patches)


def test_the_scenario_switch_turns_the_hands_off_and_keeps_older_scenarios_hashes():
    """``[shirt_pipeline] hands``: on by default and then left out of the serialised scenario (the hash of a
    scenario written before the hands is unchanged); ``false`` reaches the tracker's settings and changes the
    hash; a non-boolean is refused naming the field."""
    from simbench.errors import SimbenchInputError
    from simbench.pipelines.shirt import tracker_params
    from simbench.scenario import load_scenario

    default = load_scenario("scenarios/shirt_office.toml")
    on = default.with_overrides({"shirt_pipeline.hands": True})
    off = default.with_overrides({"shirt_pipeline.hands": False})
    assert "hands" not in default.model_dump()["shirt_pipeline"]
    assert on.content_hash() == default.content_hash() != off.content_hash()
    assert tracker_params(default).hand_constraints and not tracker_params(off).hand_constraints
    assert tracker_params(off).keep_classification
    with pytest.raises(SimbenchInputError, match="shirt_office.toml: field 'shirt_pipeline.hands': got 'no'"):
        load_scenario("scenarios/shirt_office.toml", overrides={"shirt_pipeline.hands": "no"})
