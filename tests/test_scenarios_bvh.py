"""Real-motion scenarios (scenarios/bvh_*.toml) and the scenario fields of a BVH motion:
the window against the clip's length (``motion.end``), ``motion.name_map``, the shipped copies
of the clips, the ``real_motion`` suite."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from mocap.errors import InputFileError
from simbench.stage.stage import body_params, make_scenario_motion
from simbench.errors import ScenarioError
from simbench.sweeps.regression import load_suites
from simbench.render.camera import cameras_from_scenario
from simbench.scenario import load_scenario
from simbench.scenes.bvh import retarget_bvh, retarget_bvh_keys
from simbench.scenes.bvh_file import load_bvh
from simbench.scenes.motions import HumanoidKinematics

REPO = Path(__file__).resolve().parents[1]
SCENARIOS = REPO / "scenarios"
SHARED_BVH = REPO.parent / "shared" / "data" / "bvh"
REAL_MOTION = sorted(SCENARIOS.glob("bvh_*.toml"))
JACKS = SCENARIOS / "bvh_jumping_jacks.toml"
RNG = np.random.default_rng(0)  # make_scenario_motion's signature; BVH motions draw nothing


def _motion(path: Path, **overrides):
    sc = load_scenario(path, overrides=overrides)
    return sc, make_scenario_motion(sc, body_params(sc), RNG)


# ----------------------------------------------------------------------------- shipped scenarios


def test_six_real_motion_scenarios_one_per_clip():
    clips = {load_scenario(p).motion.bvh for p in REAL_MOTION}
    assert [p.stem for p in REAL_MOTION] == ["bvh_hops", "bvh_indian_dance", "bvh_jumping_jacks", "bvh_kick", "bvh_salsa", "bvh_walk"]
    assert len(clips) == 6


@pytest.mark.parametrize("path", REAL_MOTION, ids=[p.stem for p in REAL_MOTION])
def test_real_motion_scenario_window(path):
    sc, motion = _motion(path)
    bvh = sc.resolve_path(sc.motion.bvh).resolve()
    assert bvh.is_relative_to(SCENARIOS / "data" / "bvh") and bvh.is_file()  # ships with the repository
    assert 4.0 <= sc.duration_s <= 8.0 and sc.motion.end == "error"
    assert sc.rig.count == 6 and sc.sensor.mode == "ir" and sc.subject.markers == "plugin_gait_full"

    params = body_params(sc)
    kin = HumanoidKinematics(params)
    times = np.arange(sc.n_frames) / sc.fps
    qpos = motion.qpos(times)
    # not the converter's T-pose (nor standing still in one): the limbs are bent somewhere
    assert np.abs(qpos[0, 7:]).max() > np.deg2rad(20.0)

    # the subject (joint centres, soles, top of the head) in view of every camera, every frame
    pos, rot = kin.forward(qpos)
    sole = kin.sole_points(qpos)
    head_top = pos[:, 3] + 0.25 * rot[:, 3, :, 2]
    points = np.concatenate([pos, sole, head_top[:, None]], axis=1)
    half_room = 0.5 * sc.set.room_size_m
    for cam in cameras_from_scenario(sc):
        assert np.all(np.abs(cam.center[:2]) < half_room - 0.2), f"{cam.name} outside the room"
        uv = cam.project(points.reshape(-1, 3)).reshape(len(times), -1, 2)
        margin = np.minimum.reduce([uv[..., 0], cam.width - uv[..., 0], uv[..., 1], cam.height - uv[..., 1]])
        print(f"{sc.name} {cam.name}: smallest margin {margin.min():.0f} px")
        assert margin.min() > 10.0

    # floor contact at shutter sub-frame instants: never below the floor, never more than 10 mm
    # below the source's lowest foot point (interpolated between its frames)
    keys = retarget_bvh_keys(load_bvh(sc.resolve_path(sc.motion.bvh)), params)
    fine = np.arange(0.0, sc.duration_s, 1.0 / 240.0)
    ours = kin.sole_points(motion.qpos(fine))[:, :, 2].min(axis=1)
    source = np.interp(sc.motion.start_s + sc.motion.speed * fine, keys.times_s, keys.source_foot_height_m)
    print(f"{sc.name}: lowest sole >= {ours.min() * 1000:.1f} mm, ours - source >= {(ours - source).min() * 1000:.1f} mm")
    assert ours.min() > -0.002
    assert (ours - source).min() > -0.010


def _rows(data: bytes) -> tuple[list[bytes], list[bytes]]:
    """(header lines up to Frame Time, motion rows) of a BVH, lines with their endings."""
    lines = data.splitlines(keepends=True)
    start = next(i for i, line in enumerate(lines) if line.lstrip().lower().startswith(b"frame time")) + 1
    return lines[:start], [line for line in lines[start:] if line.strip()]


@pytest.mark.parametrize("copy", sorted((SCENARIOS / "data" / "bvh").glob("*_frames*-*.bvh")), ids=lambda p: p.stem)
def test_trimmed_copies_are_rows_of_the_shared_files(copy):
    if copy.name == "13_29_jumping_jacks_frames0-599.bvh":
        source = SHARED_BVH / copy.name  # shipped whole (the shared file is the trimmed one)
        assert copy.read_bytes() == source.read_bytes()
        return
    first, last = (int(v) for v in re.search(r"_frames(\d+)-(\d+)\.bvh$", copy.name).groups())
    source = SHARED_BVH / (copy.name[: copy.name.index("_frames")] + ".bvh")
    src_header, src_rows = _rows(source.read_bytes())
    header, rows = _rows(copy.read_bytes())
    assert rows == src_rows[first:last + 1]
    frames_line = next(i for i, line in enumerate(src_header) if line.lstrip().lower().startswith(b"frames:"))
    assert header[:frames_line] == src_header[:frames_line] and header[frames_line + 1:] == src_header[frames_line + 1:]
    assert header[frames_line] == re.sub(rb"\d+", str(last - first + 1).encode(), src_header[frames_line], count=1)


def test_real_motion_suite_lists_the_bvh_scenarios_ci_sized():
    suites = load_suites(SCENARIOS / "suites.toml")
    runs = suites.runs("real_motion")
    names = {r.factors["scenario"] for r in runs}
    assert {p.stem for p in REAL_MOTION} <= names  # every BVH scenario, beside the C3D and TRC captures
    assert {p.stem for p in SCENARIOS.glob("c3d_*.toml")} | {p.stem for p in SCENARIOS.glob("trc_*.toml")} <= names
    for r in runs:
        assert (r.scenario.duration_s, r.scenario.sensor.antialias) == (0.9, 1)


# ----------------------------------------------------------------------------- motion.end


def test_a_window_past_the_clip_is_an_error_naming_file_and_lengths():
    # 13_29: 600 frames at 120 Hz, frame 0 the converter's T-pose -> 598 / 120 = 4.983 s of motion
    with pytest.raises(ScenarioError) as info:
        _motion(JACKS, duration_s=6.0)
    message = str(info.value)
    print(message)
    assert "13_29_jumping_jacks_frames0-599.bvh" in message
    assert "lasts 4.983 s" in message and "= 6.200 s" in message and "motion.end" in message


def test_hold_and_loop_are_explicit_choices():
    sc, exact = _motion(JACKS)
    clip = retarget_bvh(load_bvh(sc.resolve_path(sc.motion.bvh)), body_params(sc))  # clip time from frame 1
    length = 598 * 0.0083333  # 598 frame steps of the file's Frame Time
    assert clip.duration_s == pytest.approx(length, abs=1e-9)
    start = sc.motion.start_s
    _, hold = _motion(JACKS, duration_s=6.0, **{"motion.end": "hold"})
    _, loop = _motion(JACKS, duration_s=6.0, **{"motion.end": "loop"})
    inside = np.linspace(0.0, 4.5, 19)
    np.testing.assert_allclose(hold.qpos(inside), exact.qpos(inside), atol=1e-12)
    np.testing.assert_allclose(loop.qpos(inside), exact.qpos(inside), atol=1e-12)
    after = np.array([5.0, 5.5, 5.99])  # clip times 5.2 .. 6.19 s: past its last frame
    last = clip.qpos(length)
    np.testing.assert_allclose(hold.qpos(after), np.broadcast_to(last, (3, last.shape[-1])), atol=1e-12)
    np.testing.assert_allclose(loop.qpos(after), clip.qpos(start + after - length), atol=1e-12)
    assert np.abs(loop.qpos(after) - hold.qpos(after)).max() > 0.1


def test_hold_refuses_a_window_that_starts_after_the_clip():
    with pytest.raises(ScenarioError, match=r"motion\.start_s.*lasts 4\.983 s"):
        _motion(JACKS, **{"motion.end": "hold", "motion.start_s": 5.5})


def test_end_is_validated():
    with pytest.raises(ScenarioError, match=r"motion\.end.*'forever'"):
        load_scenario(JACKS, overrides={"motion.end": "forever"})


# ----------------------------------------------------------------------------- motion.name_map


@pytest.fixture()
def skull_scenario(tmp_path):
    """The jumping-jacks scenario on a copy of its clip whose Head joint is called Skull."""
    clip = SCENARIOS / "data" / "bvh" / "13_29_jumping_jacks_frames0-599.bvh"
    (tmp_path / "skull.bvh").write_bytes(clip.read_bytes().replace(b"JOINT Head\n", b"JOINT Skull\n", 1))
    text = JACKS.read_text().replace('bvh = "data/bvh/13_29_jumping_jacks_frames0-599.bvh"', 'bvh = "skull.bvh"')
    assert 'bvh = "skull.bvh"' in text
    path = tmp_path / "skull.toml"
    path.write_text(text)
    return path


def test_loader_hint_names_the_scenario_field_that_fixes_it(skull_scenario):
    with pytest.raises(InputFileError) as info:
        _motion(skull_scenario)
    message = str(info.value)
    assert "['head']" in message and "[motion.name_map] head" in message
    # ... and that field exists: the renamed joint maps, and the motion is the original's
    _, fixed = _motion(skull_scenario, **{"motion.name_map": {"head": "Skull"}})
    _, original = _motion(JACKS)
    t = np.linspace(0.0, 4.4, 12)
    np.testing.assert_allclose(fixed.qpos(t), original.qpos(t), atol=1e-12)


def test_name_map_is_validated(skull_scenario):
    with pytest.raises(ScenarioError, match=r"motion\.name_map\.head.*'Skul'.*no such joint.*Skull") as err:
        _motion(skull_scenario, **{"motion.name_map": {"head": "Skul"}})
    assert err.value.path == skull_scenario  # the file, not its folder (errors found after loading named the folder)
    with pytest.raises(ScenarioError, match=r"motion\.name_map.*\['skull'\] are not humanoid bodies"):
        load_scenario(skull_scenario, overrides={"motion.name_map": {"skull": "Skull"}})
    with pytest.raises(ScenarioError, match=r"name_map applies to a BVH clip only"):
        load_scenario(SCENARIOS / "quickstart.toml", overrides={"motion.name_map": {"head": "Skull"}})
