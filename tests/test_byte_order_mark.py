"""Files users edit may start with a UTF-8 byte-order mark (Windows editors write one): a scenario, a sweep, a
subject and an anipose/Pose2Sim calibration TOML, an OpenCV calibration YAML and a BVH clip load as without it.
tomllib refuses the mark at "line 1, column 1" without saying why, OpenCV's FileStorage refuses it, and the BVH
reader saw "HIERARCHY" with the mark unseen; the subject file's reader also let a non-UTF-8 byte out as a traceback."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from mocap.calibration import Calibration
from mocap.errors import InputFileError
from mocap.subject import SubjectModel
from simbench.render.camera import VirtualCamera
from simbench.scenario import load_scenario
from simbench.scenes.bvh_file import load_bvh
from simbench.scenes.humanoid import BodyParams, humanoid_mjcf
from simbench.sweeps.sweep_file import load_sweep

BOM = b"\xef\xbb\xbf"
SCENARIOS = Path(__file__).resolve().parents[1] / "scenarios"


def _with_bom(src, dst):
    dst.write_bytes(BOM + src.read_bytes())
    return dst


def test_a_scenario_and_a_sweep_with_a_byte_order_mark_load_as_without(tmp_path):
    plain = load_scenario(SCENARIOS / "quickstart.toml")
    # quickstart.toml names no file of its own, so a copy elsewhere is the same scenario
    marked = load_scenario(_with_bom(SCENARIOS / "quickstart.toml", tmp_path / "quickstart.toml"))
    assert marked.content_hash() == plain.content_hash()
    sweep = SCENARIOS / "sweeps" / "lighting_blur_tracker.toml"
    marked_sweep = tmp_path / "sweeps" / sweep.name
    marked_sweep.parent.mkdir()
    text = sweep.read_text().replace('scenario = "../visible_office.toml"', f'scenario = "{SCENARIOS / "visible_office.toml"}"')
    marked_sweep.write_bytes(BOM + text.encode())
    assert [r.run_id for r in load_sweep(marked_sweep).runs] == [r.run_id for r in load_sweep(sweep).runs]


def test_a_calibration_toml_or_opencv_yaml_with_a_byte_order_mark_loads_as_without(tmp_path):
    rig = load_scenario(SCENARIOS / "quickstart.toml").rig
    cal = Calibration(tuple(VirtualCamera.from_config(c).calibration_camera() for c in rig.camera_configs()))
    cal.save_toml(tmp_path / "calibration.toml")
    cal.save_opencv_yaml(tmp_path / "calibration.yml")
    for back in (Calibration.load_toml(_with_bom(tmp_path / "calibration.toml", tmp_path / "marked.toml")),
                 Calibration.load_opencv_yaml(_with_bom(tmp_path / "calibration.yml", tmp_path / "marked.yml"))):
        assert [c.name for c in back.cameras] == [c.name for c in cal.cameras]
        for a, b in zip(back.cameras, cal.cameras):
            np.testing.assert_allclose(a.K, b.K)
            np.testing.assert_allclose(a.R, b.R, atol=1e-12)


def test_a_subject_toml_with_a_byte_order_mark_loads_and_a_non_utf8_one_is_refused(tmp_path):
    xml = humanoid_mjcf(BodyParams(height_m=1.72), marker_set="plugin_gait_full")
    subject = SubjectModel.from_mjcf_text(xml, name="s")
    toml = subject.save_toml(tmp_path / "s.toml")
    marked = _with_bom(toml, tmp_path / "marked.toml")  # beside s.xml, which it names
    assert SubjectModel.load(marked).marker_names == subject.marker_names
    bad = tmp_path / "bad.toml"
    bad.write_bytes(toml.read_bytes().replace(b"[subject]", b"# caf\xe9\n[subject]"))
    with pytest.raises(InputFileError, match=r"byte \d+ is not UTF-8"):
        SubjectModel.load(bad)


def test_a_bvh_clip_with_a_byte_order_mark_loads_as_without(tmp_path):
    clip = SCENARIOS / "data" / "bvh" / "01_01_frames120-900.bvh"
    plain, marked = load_bvh(clip), load_bvh(_with_bom(clip, tmp_path / "marked.bvh"))
    assert marked.joint_names == plain.joint_names
    np.testing.assert_array_equal(marked.offsets, plain.offsets)
    np.testing.assert_array_equal(marked.frames, plain.frames)
