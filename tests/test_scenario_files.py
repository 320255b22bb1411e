"""Scenario files: every shipped one validates; bad input names file, field, value; exit 2."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from simbench.errors import ScenarioError
from simbench.scenario import load_scenario

# scenarios/suites.toml lists suites of scenarios (simbench check); it is not one.
SCENARIOS = sorted(p for p in Path("scenarios").glob("*.toml") if p.name != "suites.toml")


@pytest.mark.parametrize("path", SCENARIOS, ids=[p.stem for p in SCENARIOS])
def test_shipped_scenarios_validate(path):
    sc = load_scenario(path)
    assert sc.n_frames >= 1
    assert sc.content_hash() == load_scenario(path).content_hash()


def test_enough_scenarios_cover_the_axes():
    scs = [load_scenario(p) for p in SCENARIOS]
    assert len(scs) >= 7
    assert {s.sensor.mode for s in scs} == {"ir", "visible"}
    assert any(s.props for s in scs) and any(s.sensor.motion_blur and s.sensor.exposure_ms >= 20 for s in scs)
    assert len({s.lighting.preset for s in scs}) >= 4
    assert any(s.subject.shirt for s in scs) and any(s.motion.clip == "bvh" for s in scs)


def _write(tmp_path, text: str) -> Path:
    p = tmp_path / "bad.toml"
    p.write_text(text)
    return p


@pytest.mark.parametrize("text, field, value", [
    ('name = "x"\n[sensor]\nexposure_ms = -3\n', "sensor.exposure_ms", "-3"),
    ('name = "x"\n[rig]\nhfov_deg = 200\n', "rig.hfov_deg", "200"),
    ('name = "x"\n[lighting]\npreset = "disco"\n', "lighting.preset", "disco"),
    ('name = "x"\n[sensor]\nexposur_ms = 3\n', "sensor.exposur_ms", "3"),
    ('name = "x"\n[[props]]\nkind = "ball"\nradius_m = 0\n', "props.0.radius_m", "0"),
    ('name = "x"\n[sensor]\nexposure_ms = 50\n', "<root>", "exceeds the frame interval"),
    # names checked against their registries when the scenario loads (not after the render)
    ('name = "x"\n[markers_pipeline]\ntracker = "kalmann"\n', "markers_pipeline.tracker", "kalmann"),
    ('name = "x"\n[motion]\nclip = "wave_slw"\n', "motion.clip", "wave_slw"),
    ('name = "x"\n[subject]\nmarkers = "plugin_gait"\n', "subject.markers", "plugin_gait"),
    ('name = "x"\n[body.proportions]\nshank_fraction = 0.3\n', "body", "shank_fraction"),
    ('name = "x"\n[body.proportions]\nthorax_frac = 0.5\n', "body", "head"),
    ('name = "x"\n[calibration_scene]\nboard = "charuco"\ndictionary = "DICT_4X4_5O"\n', "calibration_scene.dictionary",
     "DICT_4X4_5O"),
    ('name = "x"\n[[lighting.events]]\nt_s = 1.0\nlight = "lamp9"\nintensity = 0\n', "lighting.events", "lamp9"),
])
def test_bad_fields_name_file_field_and_value(tmp_path, text, field, value):
    p = _write(tmp_path, text)
    with pytest.raises(ScenarioError) as info:
        load_scenario(p)
    msg = str(info.value)
    assert str(p) in msg and field in msg and value in msg


def test_an_event_may_switch_a_light_of_the_preset_or_an_added_one(tmp_path):
    p = _write(tmp_path, 'name = "x"\n[lighting]\npreset = "mixed"\n[[lighting.lights]]\nname = "lamp9"\nposition = [1, 1, 2]\n'
                         '[[lighting.events]]\nt_s = 1.0\nlight = "lamp9"\nintensity = 0\n'
                         '[[lighting.events]]\nt_s = 1.5\nlight = "tungsten"\nintensity = 0\n')
    assert [e.light for e in load_scenario(p).lighting.events] == ["lamp9", "tungsten"]
    bad = _write(tmp_path, 'name = "y"\n[[lighting.events]]\nt_s = 1.0\nlight = "tungsten"\nintensity = 0\n')
    with pytest.raises(ScenarioError, match="lighting.events.*'tungsten'.*ceiling_0"):
        load_scenario(bad)  # office light has no tungsten lamp


def test_cli_exits_2_with_one_line_and_writes_nothing(tmp_path):
    p = _write(tmp_path, 'name = "x"\n[rig]\ncount = 0\n')
    out = tmp_path / "out"
    env = dict(os.environ, COLUMNS="300")
    r = subprocess.run([sys.executable, "-m", "simbench.cli", "render", str(p), "--out", str(out)],
                       capture_output=True, text=True, env=env)
    assert r.returncode == 2
    assert "rig.count" in r.stderr and str(p) in r.stderr.replace("\n", "")
    assert "Traceback" not in r.stderr
    assert not out.exists()
    assert not any(tmp_path.glob(".out.partial-*"))


def test_interrupted_render_leaves_nothing_half_written(tmp_path, monkeypatch):
    """A failure mid-render removes the partial directory and keeps an older output intact."""
    from simbench.stage import rendering

    from simbench.output_dir import MARKER, OutputMarker

    out = tmp_path / "render"
    out.mkdir()
    (out / MARKER).write_text(OutputMarker.for_this_process("quickstart", "render").to_json())  # an earlier bench output
    (out / "keep.txt").write_text("previous run")
    sc = load_scenario("scenarios/quickstart.toml", overrides={"duration_s": 0.2, "rig.count": 1})
    calls = {"n": 0}
    real = rendering.render_frames

    def failing(bench, on_frame=None, **kw):
        def boom(fo):
            calls["n"] += 1
            if on_frame:
                on_frame(fo)
            if calls["n"] == 2:
                raise KeyboardInterrupt
        return real(bench, on_frame=boom, **kw)

    monkeypatch.setattr(rendering, "render_frames", failing)
    with pytest.raises(KeyboardInterrupt):
        rendering.render_scenario(sc, out)
    assert (out / "keep.txt").read_text() == "previous run"
    assert not any(tmp_path.glob(".render.partial-*"))


def test_missing_gl_platform_error_names_the_variables():
    env = dict(os.environ, PYOPENGL_PLATFORM="bogus", MUJOCO_GL="bogus")
    r = subprocess.run([sys.executable, "-m", "simbench.gl_check"], capture_output=True, text=True, env=env)
    assert r.returncode == 2
    assert "PYOPENGL_PLATFORM" in r.stderr and "MUJOCO_GL" in r.stderr and "libosmesa6" in r.stderr
