"""Label initialisation: template IO and recovery of a subject's placement and labels."""

from __future__ import annotations

from pathlib import Path

import ezc3d
import numpy as np
import pytest

from mocap.calibration import Calibration, Camera
from mocap.errors import InputFileError
from mocap.labelling import (
    LabelInitParams,
    LabelTemplate,
    Placement,
    initial_labels,
    load_template,
    save_template,
)
from mocap.types import Detections
from mocap.calib.synthetic import look_at



def room_rig() -> Calibration:
    """Four 640x480 webcams in the corners of a 6 m x 6 m room, 2.3 m up."""
    cams = []
    for i, (ex, ey) in enumerate([(3.0, 3.0), (-3.0, 3.0), (-3.0, -3.0), (3.0, -3.0)]):
        R, t = look_at([ex, ey, 2.3], [0.0, 0.0, 0.9])
        cams.append(Camera(f"cam{i}", (640, 480), [[420, 0, 322], [0, 421, 239], [0, 0, 1]], [-0.08, 0.01, 0.0, 0.0, 0.0], R, t))
    return Calibration(tuple(cams))


@pytest.fixture(scope="module")
def static_c3d(shared_data) -> Path:
    return shared_data / "c3d" / "Sample_Static.c3d"


def plug_in_gait_template(static_c3d: Path) -> LabelTemplate:
    """The 35 Plug-in Gait markers of a real static trial (Vicon, pyCGM sample data),
    moved to the subject-local frame: facing +X, Z up, origin between the ankles on the
    floor. The subject stands with the arms out (not a strict T-pose): fine for a template."""
    c3d = ezc3d.c3d(str(static_c3d))
    labels = c3d["parameters"]["POINT"]["LABELS"]["value"][:35]
    p = c3d["data"]["points"][:3, :35, 0].T / 1000.0
    idx = {n: i for i, n in enumerate(labels)}
    forward = (p[idx["LASI"]] + p[idx["RASI"]] - p[idx["LPSI"]] - p[idx["RPSI"]])[:2]
    yaw = np.arctan2(forward[1], forward[0])
    c, s = np.cos(-yaw), np.sin(-yaw)
    origin = 0.5 * (p[idx["LANK"]] + p[idx["RANK"]])
    origin[2] = 0.0
    local = (p - origin) @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]).T
    local[:, 2] -= local[:, 2].min() - 0.04  # lowest marker (toe/heel) 4 cm above the floor
    return LabelTemplate(tuple(labels), local)


def test_template_is_facing_plus_x(static_c3d) -> None:
    t = plug_in_gait_template(static_c3d)
    i = {n: k for k, n in enumerate(t.names)}
    assert t.positions[i["STRN"], 0] > t.positions[i["T10"], 0]        # chest in front
    assert t.positions[i["LASI"], 1] > t.positions[i["RASI"], 1]       # left is +Y
    # the move to the local frame is rigid (a turn about Z and a shift): the heights of the
    # real trial's markers keep their spread, and the lowest ends 4 cm above the floor
    raw_z = ezc3d.c3d(str(static_c3d))["data"]["points"][2, :35, 0] / 1000.0
    np.testing.assert_allclose(t.positions[:, 2] - t.positions[:, 2].min(), raw_z - raw_z.min(), atol=1e-12)
    assert t.positions[:, 2].min() == pytest.approx(0.04, abs=1e-12)


def scene(rng: np.random.Generator, template: LabelTemplate, truth: Placement, cal: Calibration, noise_px: float, slack_m: float):
    """Shuffled detections of every camera and the true label -> detection index (-1:
    hidden). Markers whose projections come within 3 px of a nearer marker's merge into
    that blob in a real image: they are hidden here, and that blob is theirs as well
    (``merged``: index of the blob hiding each label, -1 if none)."""
    world = truth.apply(template.positions) + rng.normal(0, slack_m, template.positions.shape)
    p2ds = cal.project(world) + rng.normal(0, noise_px, (len(cal), len(template), 2))
    M = len(template)
    dets, expected, merged = [], np.full((len(cal), M), -1), np.full((len(cal), M), -1)
    for c, cam in enumerate(cal):
        depth = cam.to_camera(world)[:, 2]
        dist = np.linalg.norm(p2ds[c][:, None] - p2ds[c][None], axis=2)
        hides = (dist < 3.0) & (depth[None, :] < depth[:, None])     # [m, k]: k hides m
        hidden = hides.any(axis=1)
        vis = np.flatnonzero(~hidden)
        perm = rng.permutation(vis)
        dets.append(Detections.from_points(p2ds[c, perm]))
        expected[c, perm] = np.arange(len(perm))
        for m in np.flatnonzero(hidden):
            front = np.flatnonzero(hides[m] & ~hidden)
            if front.size:
                merged[c, m] = expected[c, front[0]]
    return world, dets, expected, merged


def check_labels(found: np.ndarray, expected: np.ndarray, merged: np.ndarray, projections: np.ndarray, max_unlabelled: int) -> None:
    """No wrong label anywhere (a hidden marker may take the blob it merged into); a
    visible marker may stay unlabelled only if another marker projects within a few
    pixels of it (ambiguous: with 35 markers on a body of ~200 px, wrist, head and
    pelvis markers often nearly overlap), and not too many."""
    wrong = (found >= 0) & (found != expected) & (found != merged)
    assert not wrong.any(), np.argwhere(wrong)
    missed = (found == -1) & (expected >= 0)
    for c, m in np.argwhere(missed):
        d = np.linalg.norm(projections[c] - projections[c, m], axis=1)
        d[m] = np.inf
        assert d.min() < 6.0, (c, m, d.min())
    assert missed.sum() <= max_unlabelled


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_recovers_placement_and_labels(seed: int, static_c3d) -> None:
    rng = np.random.default_rng(seed)
    template = plug_in_gait_template(static_c3d)
    cal = room_rig()
    truth = Placement(rng.uniform(-1.0, 1.0), rng.uniform(-1.0, 1.0), rng.uniform(-np.pi, np.pi), rng.uniform(0.95, 1.05))
    world, dets, expected, merged = scene(rng, template, truth, cal, noise_px=0.3, slack_m=0.01)
    # Camera 1 misses two more markers; camera 3 sees two spurious reflections.
    miss = rng.choice(np.flatnonzero(expected[1] >= 0), 2, replace=False)
    keep = np.setdiff1d(np.arange(len(dets[1])), expected[1, miss])
    remap = np.full(len(dets[1]), -1)
    remap[keep] = np.arange(len(keep))
    dets[1] = Detections.from_points(dets[1].xy[keep])
    expected[1] = np.where(expected[1] >= 0, remap[expected[1]], -1)
    spurious = np.column_stack([rng.uniform(0, 640, 2), rng.uniform(0, 480, 2)])
    dets[3] = Detections.from_points(np.vstack([dets[3].xy, spurious]))

    result = initial_labels(dets, cal, template)
    p = result.placement
    assert np.hypot(p.x - truth.x, p.y - truth.y) < 0.03
    assert abs((p.heading - truth.heading + np.pi) % (2 * np.pi) - np.pi) < np.deg2rad(3.0)
    assert abs(p.scale - truth.scale) < 0.03
    assert result.labels == list(template.names)
    # Labels found where visible (bar a few overlapping ones), none where missing, no swap.
    check_labels(result.detection_index, expected, merged, cal.project(world), max_unlabelled=int(0.12 * (expected >= 0).sum()))
    assert np.isnan(result.xy[1, miss]).all()
    err = np.linalg.norm(result.points - world, axis=1)
    views = (result.detection_index >= 0).sum(axis=0)
    assert err[views >= 3].max() < 0.01     # triangulated from the labelled views
    assert err[views == 2].max(initial=0) < 0.03   # two views can be nearly opposite
    assert err.max() < 0.05                 # else the placed template (1 cm slack per axis)


def relaxed_pose(template: LabelTemplate, arm_drop_deg: float) -> LabelTemplate:
    """The template with both arms lowered about the shoulders and the head turned:
    how a subject's first frame differs from the calibration pose."""
    i = {n: k for k, n in enumerate(template.names)}
    p = template.positions.copy()
    for side, sign in (("L", 1.0), ("R", -1.0)):
        pivot = p[i[side + "SHO"]]
        a = np.deg2rad(arm_drop_deg) * sign   # rotation about +X lowers the left arm (+Y side)
        Rx = np.array([[1, 0, 0], [0, np.cos(a), np.sin(a)], [0, -np.sin(a), np.cos(a)]])
        arm = [i[side + n] for n in ("ELB", "WRA", "WRB", "FIN")]
        p[arm] = (p[arm] - pivot) @ Rx.T + pivot
    head = [i[n] for n in ("LFHD", "RFHD", "LBHD", "RBHD")]
    c, s = np.cos(0.15), np.sin(0.15)
    centre = p[head].mean(axis=0)
    p[head] = (p[head] - centre) @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]).T + centre
    return LabelTemplate(template.names, p)


def test_first_frame_off_the_template_pose(static_c3d) -> None:
    """Arms 8 degrees lower than in the template, head turned 9 degrees, 5 mm of
    marker noise and 0.5 px of pixel noise: labels are still right."""
    rng = np.random.default_rng(7)
    template = plug_in_gait_template(static_c3d)
    cal = room_rig()
    truth = Placement(0.6, -0.4, 2.5)
    world, dets, expected, merged = scene(rng, relaxed_pose(template, 8.0), truth, cal, noise_px=0.5, slack_m=0.005)
    moved = np.linalg.norm(relaxed_pose(template, 8.0).positions - template.positions, axis=1)
    assert moved.max() > 0.05   # the fingers move by several centimetres
    result = initial_labels(dets, cal, template, LabelInitParams(scales=(1.0,)))  # scale fixed
    assert result.placement.scale == 1.0
    assert abs((result.placement.heading - truth.heading + np.pi) % (2 * np.pi) - np.pi) < np.deg2rad(3.0)
    check_labels(result.detection_index, expected, merged, cal.project(world), max_unlabelled=int(0.12 * (expected >= 0).sum()))


def test_template_csv_roundtrip_and_errors(tmp_path: Path, static_c3d) -> None:
    t = plug_in_gait_template(static_c3d)
    path = save_template(t, tmp_path / "pig.csv")
    back = load_template(path)
    assert back.names == t.names
    np.testing.assert_allclose(back.positions, t.positions, atol=1e-6)
    assert path.read_text().splitlines()[0] == "name,x,y,z"

    cases = {
        "cols.csv": ("name,x,y,z\nA,0,0,1\nB,0,1\n", "line 3"),
        "nan.csv": ("A,0,0,1\nB,0,zero,1\n", "line 2"),
        "dup.csv": ("A,0,0,1\nB,0,1,1\nA,1,1,1\n", "already defined on line 1"),
        "empty.csv": ("name,x,y,z\n", "no marker rows"),
    }
    for name, (text, msg) in cases.items():
        (tmp_path / name).write_text(text)
        with pytest.raises(InputFileError, match=msg) as err:
            load_template(tmp_path / name)
        assert name in str(err.value)
    with pytest.raises(InputFileError, match="not found"):
        load_template(tmp_path / "missing.csv")


def test_input_errors(static_c3d) -> None:
    template = plug_in_gait_template(static_c3d)
    cal = room_rig()
    with pytest.raises(ValueError, match="4"):
        initial_labels([Detections.empty()] * 3, cal, template)
    with pytest.raises(ValueError, match="two cameras"):
        initial_labels([Detections.from_points([[1.0, 2.0]])] + [Detections.empty()] * 3, cal, template)
    with pytest.raises(ValueError, match="duplicate"):
        LabelTemplate(("A", "A"), np.zeros((2, 3)))
    with pytest.raises(ValueError, match="scales"):
        LabelInitParams(scales=())
