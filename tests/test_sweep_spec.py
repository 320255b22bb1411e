"""Sweep files: validation names file/factor/field, grid and seeded random expansion, stable run ids."""

from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import CliRunner

from simbench.cli import app
from simbench.errors import ScenarioError
from simbench.sweeps.sweep import load_sweep, run_id_for

QUICKSTART = Path("scenarios/quickstart.toml").resolve()
SHIPPED = sorted(Path("scenarios/sweeps").glob("*.toml"))


def _sweep(tmp_path: Path, body: str, name: str = "s.toml") -> Path:
    p = tmp_path / name
    p.write_text(f'name = "t"\nscenario = "{QUICKSTART}"\n' + body)
    return p


@pytest.mark.parametrize("path", SHIPPED, ids=[p.stem for p in SHIPPED])
def test_shipped_sweeps_expand(path):
    sw = load_sweep(path)
    assert len(sw.runs) == len({r.run_id for r in sw.runs}) >= 2
    assert [r.index for r in sw.runs] == list(range(len(sw.runs)))


def test_lighting_blur_tracker_is_a_24_run_grid_over_three_factors():
    sw = load_sweep("scenarios/sweeps/lighting_blur_tracker.toml")
    levels = sw.factor_levels()
    assert set(levels) == {"lighting.preset", "blur", "markers_pipeline.tracker"}
    assert len(sw.runs) == 24 == len(levels["lighting.preset"]) * len(levels["blur"]) * len(levels["markers_pipeline.tracker"])
    combos = {tuple(r.factors.values()) for r in sw.runs}
    assert len(combos) == 24
    long = [r for r in sw.runs if r.factors["blur"] == "shutter"]
    assert all(r.scenario.sensor.exposure_ms == 25.0 and r.scenario.sensor.motion_blur for r in long)
    assert all(r.scenario.sensor.exposure_ms == 25.0 and not r.scenario.sensor.motion_blur for r in sw.runs if r not in long)
    assert all(r.scenario.rig.count == 2 and r.scenario.duration_s == 0.5 for r in sw.runs)


def test_grid_levels_set_several_fields_and_unquoted_dotted_keys(tmp_path):
    p = _sweep(tmp_path, """
[set]
rig.count = 2
duration_s = 0.3
[[factors]]
name = "blur"
[factors.levels]
off = { sensor.exposure_ms = 4.0, sensor.motion_blur = false }
long = { "sensor.exposure_ms" = 30.0 }
[[factors]]
field = "seed"
values = [0, 1, 2]
""")
    sw = load_sweep(p)
    assert len(sw.runs) == 6
    first = sw.runs[0]
    assert first.factors == {"blur": "off", "seed": 0}
    assert first.overrides == {"rig.count": 2, "duration_s": 0.3, "sensor.exposure_ms": 4.0, "sensor.motion_blur": False, "seed": 0}
    assert first.scenario.rig.count == 2 and not first.scenario.sensor.motion_blur
    assert sw.runs[-1].scenario.sensor.exposure_ms == 30.0 and sw.runs[-1].scenario.seed == 2


def test_run_ids_are_stable_and_follow_content(tmp_path):
    body = '[[factors]]\nfield = "sensor.exposure_ms"\nvalues = [4.0, 8.0]\n'
    a = load_sweep(_sweep(tmp_path, body, "a.toml"))
    b = load_sweep(_sweep(tmp_path, body, "b.toml"))
    assert [r.run_id for r in a.runs] == [r.run_id for r in b.runs]
    assert a.runs[0].run_id != a.runs[1].run_id
    # The id is the hash of the resolved scenario and the overrides: any change moves it.
    sc = a.runs[0].scenario
    assert run_id_for(sc, a.runs[0].overrides) == a.runs[0].run_id
    assert run_id_for(sc.with_overrides({"seed": 9}), a.runs[0].overrides) != a.runs[0].run_id
    c = load_sweep(_sweep(tmp_path, '[set]\nduration_s = 1.0\n' + body, "c.toml"))
    assert {r.run_id for r in c.runs}.isdisjoint({r.run_id for r in a.runs})


def test_random_sample_is_seeded_and_within_ranges(tmp_path):
    body = """mode = "random"
samples = 12
seed = 5
[[factors]]
field = "sensor.read_noise_e"
range = [1.0, 20.0]
log = true
[[factors]]
field = "rig.count"
range = [2, 6]
integer = true
[[factors]]
field = "lighting.preset"
values = ["office_fluorescent", "dim_gym"]
"""
    a = load_sweep(_sweep(tmp_path, body, "a.toml"))
    b = load_sweep(_sweep(tmp_path, body, "b.toml"))
    assert [r.overrides for r in a.runs] == [r.overrides for r in b.runs]
    assert len(a.runs) + a.duplicates == 12
    noise = [r.scenario.sensor.read_noise_e for r in a.runs]
    assert all(1.0 <= v <= 20.0 for v in noise) and len(set(noise)) == len(noise)
    assert {r.scenario.rig.count for r in a.runs} <= {2, 3, 4, 5, 6}
    other = load_sweep(_sweep(tmp_path, body.replace("seed = 5", "seed = 6"), "c.toml"))
    assert [r.overrides for r in other.runs] != [r.overrides for r in a.runs]


@pytest.mark.parametrize("body, field, value", [
    # an unknown scenario field in a factor names the factor and the scenario field
    ('[[factors]]\nfield = "sensor.exposur_ms"\nvalues = [4.0]\n', "factors[0] (sensor.exposur_ms = 4.0) -> scenario field 'sensor.exposur_ms'", 4.0),
    # a value the scenario schema refuses
    ('[[factors]]\nfield = "lighting.preset"\nvalues = ["office_fluorescent", "disco"]\n', "factors[0] (lighting.preset = 'disco') -> scenario field 'lighting.preset'", "disco"),
    # a bad override in [set]
    ('[set]\n"rig.count" = 0\n[[factors]]\nfield = "seed"\nvalues = [0, 1]\n', "set -> scenario field 'rig.count'", 0),
    # sweep-file level mistakes
    ('mode = "grid"\n[[factors]]\nfield = "sensor.gain"\nrange = [1.0, 4.0]\n', "<root>", "{...}"),
    ('[[factors]]\nfield = "seed"\nvalues = [0]\nlevels = { a = { seed = 1 } }\n', "factors.0", "{...}"),
    ('mode = "sobol"\n[[factors]]\nfield = "seed"\nvalues = [0]\n', "mode", "sobol"),
    ('[[factors]]\nfield = "seed"\nvalues = [0]\nlabels = ["a", "b"]\n', "factors.0", "{...}"),
])
def test_bad_sweep_files_name_file_field_and_value(tmp_path, body, field, value):
    p = _sweep(tmp_path, body)
    with pytest.raises(ScenarioError) as info:
        load_sweep(p)
    err = info.value
    assert err.path == p
    assert err.field == field
    assert err.value == value
    assert str(p) in str(err) and err.allowed


def test_combination_errors_name_the_run(tmp_path):
    # 25 ms is a valid exposure at 30 fps, but not at 60 fps: only the combination fails.
    p = _sweep(tmp_path, '[[factors]]\nfield = "fps"\nvalues = [30.0, 60.0]\n[[factors]]\nfield = "sensor.exposure_ms"\nvalues = [4.0, 25.0]\n')
    with pytest.raises(ScenarioError) as info:
        load_sweep(p)
    assert info.value.field.startswith("run fps=60.0, sensor.exposure_ms=25.0")
    assert "frame interval" in info.value.allowed


def test_cli_sweep_bad_file_is_one_line_exit_2(tmp_path):
    p = _sweep(tmp_path, '[[factors]]\nfield = "markers_pipeline.trackr"\nvalues = ["kalman"]\n')
    r = CliRunner().invoke(app, ["sweep", str(p), "--db", str(tmp_path / "db.duckdb")])
    assert r.exit_code == 2
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "markers_pipeline.trackr" in lines[0] and str(p.name) in lines[0]


def test_cli_dry_run_lists_every_run(tmp_path):
    r = CliRunner().invoke(app, ["sweep", "scenarios/sweeps/lighting_blur_tracker.toml", "--dry-run",
                                 "--db", str(tmp_path / "db.duckdb")])
    assert r.exit_code == 0, r.stderr
    lines = r.stdout.splitlines()
    assert len(lines) == 24 and all(len(ln.split()[0]) == 16 for ln in lines)
    assert not (tmp_path / "db.duckdb").exists()


def test_cli_sweep_refuses_a_database_folder_that_holds_another_database(tmp_path):
    # The result files next to a database belong to its folder: a second database there would
    # take in the first one's runs (and it in the second's). One line, exit 2, nothing written.
    folder = tmp_path / "sweeps"
    folder.mkdir()
    first = folder / "office.duckdb"
    first.write_bytes(b"")  # stands for a database an earlier sweep left there
    p = _sweep(tmp_path, '[[factors]]\nfield = "seed"\nvalues = [0, 1]\n')
    r = CliRunner().invoke(app, ["sweep", str(p), "--db", str(folder / "outdoor.duckdb")])
    assert r.exit_code == 2, r.output
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1
    assert "outdoor.duckdb" in lines[0] and "office.duckdb" in lines[0] and "its own folder" in lines[0]
    assert sorted(q.name for q in folder.iterdir()) == ["office.duckdb"]


def test_a_stopped_pools_manager_thread_that_outlives_the_wait_leaves_the_exit_hooks_list():
    """Python 3.11's exit hook writes to each listed pool's wake-up pipe without the lock its manager thread closes
    it under: a thread still alive after the wait is taken out of that list (simbench.sweeps.sweep)."""
    import concurrent.futures.process as cf_process
    import threading
    import types

    from simbench.sweeps.sweep import _join_manager_thread

    release = threading.Event()
    thread = threading.Thread(target=release.wait, daemon=True)  # a manager thread still closing its pipe
    thread.start()
    finished = threading.Thread(target=lambda: None)  # a manager thread that has ended
    cf_process._threads_wakeups[thread] = object()
    try:
        _join_manager_thread(types.SimpleNamespace(_executor_manager_thread=thread), timeout_s=0.05)
        assert thread not in cf_process._threads_wakeups
        finished.start()
        cf_process._threads_wakeups[finished] = object()
        _join_manager_thread(types.SimpleNamespace(_executor_manager_thread=finished), timeout_s=5.0)
        assert finished in cf_process._threads_wakeups  # one that ended is left to the hook, which skips its closed pipe
    finally:
        release.set()
        cf_process._threads_wakeups.pop(thread, None)
        cf_process._threads_wakeups.pop(finished, None)
