"""Every bad input a user can give ``simbench run`` or ``mocap markers`` is refused with exit
code 2 and one line on stderr naming the file and the field (or option), with no traceback, no
hang and nothing written; every shipped scenario is still accepted.

A reduced version of the fuzzing in ``tests/fuzz_inputs.py`` (the full one:
``.venv/bin/python tests/fuzz_inputs.py --scenarios 300 --mocap 40``).
"""

from __future__ import annotations

import ctypes.util
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

sys.path.insert(0, str(Path(__file__).parent))
import fuzz_inputs as fz  # noqa: E402

from simbench.cli.app import app  # noqa: E402

SHIPPED = sorted(p for p in fz.SCENARIOS.glob("*.toml") if p.name != "suites.toml")


def _explain(outcomes) -> str:
    return "\n".join(f"{o.verdict}: {o.label} (exit {o.exit_code}): {o.stderr[:300]}" for o in outcomes if o.verdict != "ok")


@pytest.mark.parametrize("path", SHIPPED, ids=[p.stem for p in SHIPPED])
def test_every_shipped_scenario_is_accepted(path: Path) -> None:
    """The bounds refuse nothing real: `simbench info` on each shipped scenario."""
    r = CliRunner().invoke(app, ["info", str(path)])
    assert r.exit_code == 0, r.stderr
    assert r.stderr == ""


def test_the_harness_sees_an_accepted_scenario(tmp_path) -> None:
    """The check can fail: an unspoilt scenario reaches the (replaced) run and is reported as accepted."""
    bases = fz.resolved_bases(["quickstart"])
    case = fz.Case("000 quickstart unspoilt", "control", ("name",), fz._toml(bases["quickstart"]))
    out = fz.check_scenario_case(case, tmp_path)
    assert out.verdict == "accepted", out


def test_fuzzed_scenarios_are_refused_with_one_line(tmp_path) -> None:
    rng = np.random.default_rng(17)
    cases = fz.scenario_cases(60, rng, fz.resolved_bases())
    assert len(cases) == 60
    assert len({c.kind for c in cases}) >= 8  # the draw covers most kinds
    tally = fz.Tally([fz.check_scenario_case(c, tmp_path) for c in cases])
    assert tally.counts()["ok"] == len(cases), _explain(tally.outcomes)


def test_the_synthetic_take_is_captured(tmp_path) -> None:
    """The take the mocap cases spoil is a good one: `mocap markers` reconstructs all of it."""
    code, text = fz.check_good_mocap_take(tmp_path)
    assert code == 0, text
    assert "3 labels, reconstructed 1.000" in text


def test_fuzzed_mocap_markers_inputs_are_refused_with_one_line(tmp_path) -> None:
    cases = fz.mocap_cases(0, np.random.default_rng(0))  # every kind once
    picked = [c for i, c in enumerate(cases) if i % 3 == 0 or "after the export" in c.label or "rotation" in c.label]
    tally = fz.Tally([fz.check_mocap_case(c, tmp_path) for c in picked])
    assert tally.counts()["ok"] == len(picked), _explain(tally.outcomes)


def test_a_failure_after_the_export_began_leaves_nothing(tmp_path) -> None:
    case = next(c for c in fz.mocap_cases(0, np.random.default_rng(0)) if "after the export" in c.label)
    out = fz.check_mocap_case(case, tmp_path)
    assert out.verdict == "ok", out
    assert "No space left on device" in out.stderr and ".partial-" not in out.stderr  # names --out, not the temporary folder
    assert not list((tmp_path / case.label.split()[0]).glob(".cap.*"))


def test_real_subprocesses(tmp_path) -> None:
    """Through the real command lines (rich console, run_app): one scenario and one mocap case."""
    bases = fz.resolved_bases(["quickstart"])
    data = bases["quickstart"]
    data["rig"]["height_m"] = float("nan")
    scen = fz.Case("000 quickstart rig.height_m = nan", "bad number", ("rig.height_m",), fz._toml(data), value=float("nan"))
    moc = next(c for c in fz.mocap_cases(0, np.random.default_rng(0)) if "NaN in a calibration's K" in c.label)
    for case in (scen, moc):
        out = fz.check_in_subprocess(case, tmp_path)
        assert out.verdict == "ok", out


def test_non_utf8_scenario_is_one_line(tmp_path) -> None:
    bad = tmp_path / "latin1.toml"
    bad.write_bytes(b'name = "caf\xe9"\n')
    r = CliRunner().invoke(app, ["info", str(bad)])
    assert r.exit_code == 2
    assert r.stderr.count("\n") == 1 and "'<encoding>'" in r.stderr and "got 'name = \"caf\ufffd\"'; line 1 (byte 11 of the file) is not UTF-8" in r.stderr, r.stderr


@pytest.mark.skipif(ctypes.util.find_library("OSMesa") is not None, reason="libOSMesa is installed here")
def test_osmesa_requested_without_libosmesa_is_one_line(tmp_path) -> None:
    r = subprocess.run([sys.executable, "-c", "from simbench.cli.app import main; main()", "info", str(SHIPPED[0])],
                       capture_output=True, text=True, timeout=120, cwd=tmp_path,
                       env={**{k: v for k, v in os.environ.items() if k != "PYOPENGL_PLATFORM"}, "MUJOCO_GL": "osmesa"})
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "MUJOCO_GL=osmesa but libOSMesa.so is not installed" in lines[0], r.stderr


def test_one_camera_or_one_frame_is_a_valid_render_but_not_a_run(tmp_path) -> None:
    from simbench.errors import ScenarioError
    from simbench.scenario import load_scenario

    sc = load_scenario(fz.SCENARIOS / "quickstart.toml", overrides={"rig.count": 1})  # a render of one camera is fine
    with pytest.raises(ScenarioError, match="field 'rig.count': got 1; the marker pipeline triangulates"):
        sc.check_runnable("quickstart.toml")
    load_scenario(fz.SCENARIOS / "quickstart.toml", overrides={"rig.count": 1, "subject.markers": "none"}).check_runnable("x")
    one_frame = load_scenario(fz.SCENARIOS / "quickstart.toml", overrides={"duration_s": 1 / 30})  # renders one frame
    with pytest.raises(ScenarioError, match="field 'duration_s': got 0.0333.*gives 1 frame; a run needs 2 frames"):
        one_frame.check_runnable("quickstart.toml")


@pytest.mark.parametrize("overrides, field, words", [
    ({"rig.radius_m": 0.35}, "rig", "inside the body"),
    ({"rig.look_at": [40.0, 0.0, 1.0]}, "rig", "does not see the subject"),
    ({"duration_s": 0.01}, "duration_s", "gives no frame"),
    ({"rig.width": 5000}, "rig.width", "less than or equal to 4096"),
    ({"fps": True}, "fps", "expected a number, got bool"),
    ({"lighting.scale": 1e300}, "lighting.scale", "less than or equal to 1000"),
    ({"rig.distortion": [float("inf"), 0, 0, 0, 0]}, "rig.distortion.0", "finite"),
])
def test_schema_refusals_name_the_field(overrides, field, words) -> None:
    from simbench.errors import ScenarioError
    from simbench.scenario import load_scenario

    with pytest.raises(ScenarioError) as err:
        load_scenario(fz.SCENARIOS / "quickstart.toml", overrides=overrides)
    assert err.value.field == field and words in str(err.value), str(err.value)


@pytest.mark.parametrize("name, overrides, field, words", [
    ("shirt_office", {"cameras.5.hfov_deg": 50}, "cameras.5", "cameras has 2 entries (indices 0-1)"),
    ("shirt_office", {"cameras.x.hfov_deg": 50}, "cameras.x", "cameras is a list: index it with a number (indices 0-1)"),
    ("shirt_office", {"seed.x": 1}, "seed.x", "seed is a value (10), not a table: set seed itself"),
    ("quickstart", {"cameras.0.hfov_deg": 50}, "cameras.0", "no cameras list to index; write [[cameras]] tables"),
    ("quickstart", {"lighting.lights.0.intensity": 2}, "lighting.lights.0", "write [[lighting.lights]] tables"),
])
def test_override_paths_that_lead_nowhere_name_the_part_that_fails(name, overrides, field, words) -> None:
    """A list index out of range or not a number, or a field inside a value, was a traceback (IndexError,
    ValueError, TypeError) from `--set`, or 'Input should be a valid tuple' where the scenario has no such list."""
    from simbench.errors import ScenarioError
    from simbench.scenario import load_scenario

    with pytest.raises(ScenarioError) as err:
        load_scenario(fz.SCENARIOS / f"{name}.toml", overrides=overrides)
    assert err.value.field == field and words in str(err.value), str(err.value)
    assert err.value.value == next(iter(overrides.values()))


def test_overrides_index_a_scenario_s_lists_from_the_file_and_from_a_loaded_scenario() -> None:
    from simbench.errors import ScenarioError
    from simbench.scenario import load_scenario
    from simbench.sweeps.sweep_file import _with

    sc = load_scenario(fz.SCENARIOS / "shirt_office.toml", overrides={"cameras.1.hfov_deg": 50, "cameras.0.position.2": 1.7})
    assert sc.cameras[1].hfov_deg == 50 and sc.cameras[0].position[2] == 1.7
    # a loaded scenario's dump holds its lists as tuples (a sweep's factors go this way)
    again = sc.with_overrides({"cameras.0.hfov_deg": 40, "cameras.0.position.2": 1.6})
    assert again.cameras[0].hfov_deg == 40 and again.cameras[0].position[2] == 1.6 and again.cameras[1].hfov_deg == 50
    with pytest.raises(ScenarioError) as err:
        _with(sc, {"cameras.2.hfov_deg": 40}, fz.SCENARIOS / "sweep.toml", "factors[0] (hfov = 40)")
    assert err.value.field == "factors[0] (hfov = 40) -> scenario field 'cameras.2'" and err.value.value == 40
    assert "cameras has 2 entries" in str(err.value)


@pytest.mark.parametrize("line, field", [
    ('samples = true', "samples"),
    ('seed = nan', "seed"),
    ('factors = [{ field = "sensor.gain", range = [nan, 2.0] }]', "factors.0.range.0"),
    ('factors = [{ field = "sensor.gain", range = [1.0, inf] }]', "factors.0.range.1"),
    ('factors = [{ field = "sensor.gain", range = [1.0, 2.0], log = 1 }]', "factors.0.log"),
])
def test_sweep_files_refuse_bad_numbers(tmp_path, line: str, field: str) -> None:
    """The sweep schema uses the same finite, bounded, non-boolean numbers as the scenario schema."""
    from simbench.errors import ScenarioError
    from simbench.sweeps.sweep import load_sweep

    text = f'name = "s"\nscenario = "{fz.SCENARIOS / "quickstart.toml"}"\nmode = "random"\n'
    text += line + "\n" if line.startswith("factors") else f'{line}\nfactors = [{{ field = "sensor.gain", range = [1.0, 2.0] }}]\n'
    if not line.startswith("samples"):
        text += "samples = 4\n"
    path = tmp_path / "sweep.toml"
    path.write_text(text)
    with pytest.raises(ScenarioError) as err:
        load_sweep(path)
    assert err.value.field == field, str(err.value)


@pytest.mark.parametrize("tolerance, field", [("rel = inf", "rel"), ("abs = nan", "abs"), ("abs = true", "abs")])
def test_suite_tolerances_are_finite_numbers(tmp_path, tolerance: str, field: str) -> None:
    """A tolerance of inf would make a check that cannot fail."""
    from simbench.errors import ScenarioError
    from simbench.sweeps.regression import load_suites

    path = tmp_path / "suites.toml"
    path.write_text(f'[suites.ci]\nscenarios = [{{ name = "q", file = "{fz.SCENARIOS / "quickstart.toml"}" }}]\n'
                    f'[suites.ci.tolerances."markers.rmse_mm"]\nworse = "higher"\n{tolerance}\n')
    with pytest.raises(ScenarioError) as err:
        load_suites(path)
    assert err.value.field.endswith(field), str(err.value)
