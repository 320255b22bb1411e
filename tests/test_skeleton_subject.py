"""Subject model: markers read from the MJCF's sites, TOML round trip, errors that name the fix."""

from __future__ import annotations

import numpy as np
import pytest

from mocap.errors import InputFileError
from mocap.subject import MarkerPlacement, SubjectModel
from simbench.scenes.humanoid import BODY_NAMES, HINGE_NAMES, BodyParams, humanoid_mjcf
from simbench.scenes.markers import marker_set


@pytest.fixture(scope="module")
def xml():
    return humanoid_mjcf(BodyParams(height_m=1.72), marker_set="plugin_gait_full")


def test_markers_from_mjcf_sites_match_the_marker_set(xml, tmp_path):
    path = tmp_path / "humanoid.xml"
    path.write_text(xml)
    subject = SubjectModel.from_mjcf(path)
    specs = marker_set("plugin_gait_full", BodyParams(height_m=1.72))
    assert subject.name == "humanoid" and subject.mjcf_path == path
    assert subject.body_names == list(BODY_NAMES)
    assert subject.hinge_names == list(HINGE_NAMES)
    by_name = {s.name: s for s in specs}
    assert set(subject.marker_names) == set(by_name) and len(subject.markers) == 39
    for m in subject.markers:
        assert m.body == by_name[m.name].body
        np.testing.assert_allclose(m.offset_m, by_name[m.name].offset_m, atol=1e-8)  # MJCF text has 9 digits


def test_site_prefix_and_no_sites(xml):
    sub = SubjectModel.from_mjcf_text(xml, site_prefix="L")
    assert all(not n.startswith("L") for n in sub.marker_names)  # prefix stripped
    assert "ASI" in sub.marker_names and "RASI" not in [m.name for m in sub.markers]
    with pytest.raises(InputFileError, match="no <site>"):
        SubjectModel.from_mjcf_text(humanoid_mjcf(BodyParams()))


def test_toml_round_trip(xml, tmp_path):
    mjcf = tmp_path / "model" / "humanoid.xml"
    mjcf.parent.mkdir()
    mjcf.write_text(xml)
    subject = SubjectModel.from_mjcf(mjcf).with_markers(["LASI", "RASI", "LKNE", "RFIN"])
    subject.markers[0] = MarkerPlacement("LASI", "pelvis", [0.1, 0.2, 0.3])  # a measured placement
    toml = subject.save_toml(tmp_path / "subject.toml")
    assert 'mjcf = "model/humanoid.xml"' in toml.read_text()
    back = SubjectModel.load(toml)
    assert back.marker_names == ["LASI", "RASI", "LKNE", "RFIN"]
    assert [m.body for m in back.markers] == [m.body for m in subject.markers]
    np.testing.assert_allclose([m.offset_m for m in back.markers], [m.offset_m for m in subject.markers])
    assert back.mjcf_text == xml and back.mjcf_path == mjcf.resolve()
    # A subject built from text writes its MJCF next to the TOML.
    text_only = SubjectModel.from_mjcf_text(xml, name="s2")
    toml2 = text_only.save_toml(tmp_path / "s2.toml")
    assert (tmp_path / "s2.xml").read_text() == xml
    assert SubjectModel.load(toml2).marker_names == text_only.marker_names


@pytest.mark.parametrize(
    "toml_text, field, fragment",
    [
        ('[subject]\nname = "x"\n', "subject.mjcf", "missing the MJCF path"),
        ('[subject]\nmjcf = "nothere.xml"\n', "subject.mjcf", "cannot read the MJCF"),
        ('[subject]\nmjcf = "h.xml"\n', "markers", "no markers"),
        ('[subject]\nmjcf = "h.xml"\n[[markers]]\nname = "A"\nbody = "pelvis"\n', "markers[0].offset_m", "has no 'offset_m'"),
        ('[subject]\nmjcf = "h.xml"\n[[markers]]\nname = "A"\nbody = "pelvis"\noffset_m = [1, 2]\n', "markers[0].offset_m", "not 3 numbers"),
        ('[subject]\nmjcf = "h.xml"\n[[markers]]\nname = "A"\nbody = "tail"\noffset_m = [0, 0, 0]\n', "markers.body", "'tail'"),
        ('[subject]\nmjcf = "h.xml"\n[[markers]]\nname = "A"\nbody = "pelvis"\noffset_m = [0, 0, 0]\n'
         '[[markers]]\nname = "A"\nbody = "head"\noffset_m = [0, 0, 0]\n', "markers.name", "appears twice"),
        ("[subject\n", "", "not valid TOML"),
    ],
)
def test_toml_errors_name_file_and_field(xml, tmp_path, toml_text, field, fragment):
    (tmp_path / "h.xml").write_text(xml)
    path = tmp_path / "bad.toml"
    path.write_text(toml_text)
    with pytest.raises(InputFileError) as info:
        SubjectModel.load(path)
    assert info.value.path == path and info.value.field == field
    assert fragment in str(info.value) and str(path) in str(info.value)


def test_bad_mjcf_errors(tmp_path):
    with pytest.raises(InputFileError, match="not valid XML"):
        SubjectModel.from_mjcf_text("<mujoco><worldbody>")
    with pytest.raises(InputFileError, match="not <mujoco>"):
        SubjectModel.from_mjcf_text("<robot/>")
    with pytest.raises(InputFileError, match="cannot read"):
        SubjectModel.from_mjcf(tmp_path / "missing.xml")
    with pytest.raises(ValueError, match="offset_m"):
        MarkerPlacement("A", "pelvis", [0.0, np.nan, 0.0])
