"""Regression comparison without running anything: tolerances, directions, missing and
new metrics, failed runs, JUnit XML, baseline round trip, suites file validation."""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest
from rich.console import Console

from simbench.sweeps import regression as rg
from simbench.errors import ScenarioError, SimbenchInputError
from simbench.sweeps.results_db import RunRecord

PATTERNS = [
    ("markers.rmse_mm", rg.Tolerance(worse="higher", abs=0.25, rel=0.10)),
    ("markers.reconstructed_fraction", rg.Tolerance(worse="lower", abs=0.02)),
    ("markers.label_swaps", rg.Tolerance(worse="higher")),
    ("run.*", rg.Tolerance(worse="either")),
]


def _rec(name: str, metrics: dict[str, float], status: str = "ok", error: str = "", h: str = "abc") -> RunRecord:
    return RunRecord(run_id=name, sweep="check:t", run_index=0, scenario=name, scenario_hash=h, factors={"scenario": name},
                     parameters={}, status=status, error=error, metrics=metrics)


BASE = {"markers.rmse_mm": 2.0, "markers.reconstructed_fraction": 0.95, "markers.label_swaps": 0.0, "run.frames": 15.0}


@pytest.fixture()
def baseline(tmp_path) -> rg.Baseline:
    path = rg.write_baseline(tmp_path / "b.json", "t", {"a": _rec("a", BASE), "b": _rec("b", BASE, h="bbb")})
    return rg.load_baseline(path)


@pytest.mark.parametrize("base, cur, tol, expect", [
    (2.0, 2.25, rg.Tolerance(worse="higher", abs=0.25, rel=0.10), "ok"),        # abs 0.25 > rel 0.2: at the limit
    (2.0, 2.26, rg.Tolerance(worse="higher", abs=0.25, rel=0.10), "regressed"),
    (10.0, 10.9, rg.Tolerance(worse="higher", abs=0.25, rel=0.10), "ok"),       # rel 1.0 > abs
    (10.0, 11.1, rg.Tolerance(worse="higher", abs=0.25, rel=0.10), "regressed"),
    (10.0, 8.0, rg.Tolerance(worse="higher", abs=0.25, rel=0.10), "improved"),
    (0.95, 0.92, rg.Tolerance(worse="lower", abs=0.02), "regressed"),
    (0.95, 0.99, rg.Tolerance(worse="lower", abs=0.02), "improved"),
    (0.0, 1.0, rg.Tolerance(worse="higher"), "regressed"),                      # exact: one swap fails
    (15.0, 14.0, rg.Tolerance(worse="either"), "regressed"),
    (2.0, math.nan, rg.Tolerance(worse="higher", abs=1.0), "regressed"),       # could not be computed any more
    (math.nan, math.nan, rg.Tolerance(worse="higher"), "ok"),
    (math.nan, 3.0, rg.Tolerance(worse="higher"), "improved"),
])
def test_judge_directions_and_tolerances(base, cur, tol, expect):
    assert rg.judge(base, cur, tol) == expect


def test_first_matching_pattern_wins():
    pats = [("markers.rmse_mm", rg.Tolerance(worse="higher", abs=1)), ("markers.*", rg.Tolerance(worse="either")),
            ("*", rg.Tolerance(worse="lower"))]
    assert rg.tolerance_for("markers.rmse_mm", pats).abs == 1
    assert rg.tolerance_for("markers.losses_2d", pats).worse == "either"
    assert rg.tolerance_for("shirt.pose_mm", pats).worse == "lower"
    assert rg.tolerance_for("x", pats[:2]) is None


def test_compare_classifies_every_case(baseline):
    worse = dict(BASE, **{"markers.rmse_mm": 3.0, "markers.label_swaps": 2.0})
    del worse["markers.reconstructed_fraction"]
    worse["markers.new_metric"] = 1.0
    records = {"a": _rec("a", worse, h="changed"),
               "b": _rec("b", {}, status="failed", error="RuntimeError: boom\ntraceback"),
               "c": _rec("c", {"run.frames": 15.0})}
    checks = rg.compare(records, baseline, PATTERNS)
    by = {(c.scenario, c.metric): c for c in checks}
    assert by[("a", "markers.rmse_mm")].status == "regressed"
    assert by[("a", "markers.label_swaps")].status == "regressed"
    assert by[("a", "markers.reconstructed_fraction")].status == "missing"
    assert by[("a", "markers.new_metric")].status == "new"
    assert by[("a", "run.frames")].status == "ok"
    assert by[("a", "markers.rmse_mm")].note == "scenario differs from the baseline's"
    assert by[("b", "(run)")].status == "error" and by[("b", "(run)")].note == "RuntimeError: boom"
    assert by[("c", "run.frames")].status == "new"  # scenario not in the baseline: reported, not failing
    assert rg.failed(checks)
    assert not rg.failed([c for c in checks if c.scenario == "c"])


def test_unmatched_metric_is_an_error_not_a_silent_pass(baseline):
    checks = rg.compare({"a": _rec("a", BASE)}, baseline, PATTERNS[:3])
    assert [c.status for c in checks if c.metric == "run.frames"] == ["error"]


def test_unchanged_run_passes(baseline):
    checks = rg.compare({"a": _rec("a", BASE), "b": _rec("b", BASE, h="bbb")}, baseline, PATTERNS)
    assert len(checks) == 8 and all(c.status == "ok" for c in checks) and not rg.failed(checks)


def test_table_and_junit_name_the_regressions(baseline, tmp_path):
    worse = dict(BASE, **{"markers.rmse_mm": 3.0})
    checks = rg.compare({"a": _rec("a", worse), "b": _rec("b", {}, status="failed", error="ValueError: x")}, baseline, PATTERNS)
    con = Console(record=True, width=160)
    rg.print_checks(checks, con, suite="t", baseline=Path("b.json"))
    text = con.export_text()
    row = next(ln for ln in text.splitlines() if "markers.rmse_mm" in ln)
    for part in ("a", "2", "3", "+1 (+50%)", "higher worse, ±max(0.25, 10%)", "REGRESSED"):
        assert part in row
    assert "ValueError: x" in text and "FAIL suite t" in text and "1 regressed" in text and "1 errors" in text
    path = rg.write_junit(checks, tmp_path / "junit.xml", suite="t", wall_s=1.5)
    root = ET.parse(path).getroot()
    suite = root.find("testsuite")
    assert suite.get("tests") == str(len(checks)) and suite.get("failures") == "1" and suite.get("errors") == "1"
    failure = root.find(".//testcase[@name='markers.rmse_mm']/failure")
    assert failure is not None and "baseline 2, current 3" in failure.get("message")
    assert root.find(".//testcase[@classname='t.b']/error") is not None


def test_baseline_round_trip_and_refusal(tmp_path):
    recs = {"a": _rec("a", dict(BASE, **{"markers.max_error_mm": math.nan}))}
    b = rg.load_baseline(rg.write_baseline(tmp_path / "b.json", "t", recs))
    assert b.suite == "t" and b.scenarios["a"]["scenario_hash"] == "abc"
    assert math.isnan(b.scenarios["a"]["metrics"]["markers.max_error_mm"])
    assert b.scenarios["a"]["metrics"]["markers.rmse_mm"] == 2.0
    with pytest.raises(SimbenchInputError, match="boom"):
        rg.write_baseline(tmp_path / "c.json", "t", {"a": _rec("a", {}, status="failed", error="boom")})
    assert not (tmp_path / "c.json").exists()
    with pytest.raises(ScenarioError, match="baseline update"):
        rg.load_baseline(tmp_path / "missing.json")


def test_shipped_suites_resolve_and_baseline_covers_them():
    suites = rg.load_suites("scenarios/suites.toml")
    runs = suites.runs("ci")
    assert 2 <= len(runs) <= 4
    for r in runs:  # CI-sized: two cameras, no supersampling, at most 1.5 s a scenario and 3 s in all
        assert r.scenario.rig.count == 2 and r.scenario.duration_s <= 1.5 and r.scenario.sensor.antialias == 1
    assert sum(r.scenario.duration_s for r in runs) <= 3.0
    base = rg.load_baseline("scenarios/baselines/ci.json")
    assert set(base.scenarios) == {r.factors["scenario"] for r in runs}
    for r in runs:  # every baseline metric has a tolerance (else the check reports an error)
        assert base.scenarios[r.factors["scenario"]]["parameters"] == r.overrides
        for m in base.scenarios[r.factors["scenario"]]["metrics"]:
            assert rg.tolerance_for(m, suites.tolerances_for("ci")) is not None


@pytest.mark.parametrize("text, field", [
    ('[suites.x]\nscenarios = []\n', "suites.x.scenarios"),
    ('[suites.x]\n[[suites.x.scenarios]]\nname = "a"\nfile = "q.toml"\n[tolerances]\n"m" = { worse = "up" }\n', "tolerances.m.worse"),
    ('[suites.x]\n[[suites.x.scenarios]]\nname = "a"\nfile = "q.toml"\nsett = {}\n', "suites.x.scenarios.0.sett"),
])
def test_bad_suites_files_name_the_field(tmp_path, text, field):
    p = tmp_path / "suites.toml"
    p.write_text(text)
    with pytest.raises(ScenarioError) as info:
        rg.load_suites(p)
    assert info.value.field == field and info.value.path == p


def test_unknown_suite_and_only_name_the_choices(tmp_path):
    suites = rg.load_suites("scenarios/suites.toml")
    with pytest.raises(ScenarioError, match="defined: ci"):
        suites.get("nightly_typo")
    with pytest.raises(ScenarioError, match="quickstart"):
        suites.runs("ci", only=["nope"])


def test_exit_codes_tell_a_regression_from_a_scenario_that_could_not_run(baseline):
    worse = dict(BASE, **{"markers.rmse_mm": 3.0})
    regressed = rg.compare({"a": _rec("a", worse)}, baseline, PATTERNS)
    assert rg.exit_code(regressed) == 1
    crashed = rg.compare({"a": _rec("a", worse), "b": _rec("b", {}, status="failed", error="exports failed: x")},
                         baseline, PATTERNS)
    assert rg.exit_code(crashed) == 3 and [c.scenario for c in rg.could_not_run(crashed)] == ["b"]
    assert rg.exit_code(rg.compare({"a": _rec("a", BASE)}, baseline, PATTERNS[:3])) == 1  # no tolerance: not a crash
    assert rg.exit_code(rg.compare({"a": _rec("a", BASE), "b": _rec("b", BASE, h="bbb")}, baseline, PATTERNS)) == 0


@pytest.fixture
def short_tmp():
    import shutil
    import tempfile
    from pathlib import Path

    d = Path(tempfile.mkdtemp(prefix="chk", dir="/tmp"))
    yield d
    shutil.rmtree(d, ignore_errors=True)


def test_check_shows_unrunnable_scenarios_as_error_rows_and_exits_3(short_tmp):
    """A suite entry whose file is missing or has a bad field is its own row, not an exit-2 abort."""
    from typer.testing import CliRunner

    from simbench.cli import app

    tmp_path = short_tmp  # the table is 160 columns wide off a terminal: pytest-xdist's long tmp paths wrapped the row

    (tmp_path / "bad.toml").write_text('name = "bad"\n[lighting]\npreset = "custom"\n')
    (tmp_path / "suites.toml").write_text(
        '[tolerances]\n"*" = { worse = "either", rel = 0.05 }\n[suites.t]\n'
        '[[suites.t.scenarios]]\nname = "badfield"\nfile = "bad.toml"\n'
        '[[suites.t.scenarios]]\nname = "nofile"\nfile = "nope.toml"\n')
    (tmp_path / "base.json").write_text('{"suite": "t", "scenarios": {}}')
    r = CliRunner().invoke(app, ["check", "--suite", "t", "--suites", str(tmp_path / "suites.toml"),
                                 "--baseline", str(tmp_path / "base.json"), "--junit", str(tmp_path / "j.xml")],
                           env={"COLUMNS": "400"})
    assert r.exit_code == 3, r.output
    rows = {ln.split("│")[1].strip(): ln for ln in r.stdout.splitlines() if "│" in ln and "ERROR" in ln}
    assert set(rows) == {"badfield", "nofile"}
    assert f"error: {tmp_path / 'bad.toml'}: field" in rows["badfield"]
    assert f"error: {tmp_path / 'suites.toml'}:" in rows["nofile"]
    notes = " ".join(ln.split("│")[-2].strip() for ln in r.stdout.splitlines() if ln.count("│") > 8)
    assert "[[lighting.lights]] entry" in notes  # no markup ate the brackets
    assert "field 'suites.t.scenarios[1].file'" in notes
    assert "2 scenarios could not run" in r.stdout
    errors = {e.get("message") for e in ET.parse(tmp_path / "j.xml").getroot().iter("error")}
    assert len(errors) == 2 and any("[[lighting.lights]]" in e for e in errors)
    # a rerun replaces its own JUnit file; a file of the user's at --junit is refused before anything runs
    again = CliRunner().invoke(app, ["check", "--suite", "t", "--suites", str(tmp_path / "suites.toml"),
                                     "--baseline", str(tmp_path / "base.json"), "--junit", str(tmp_path / "j.xml")])
    assert again.exit_code == 3, again.output
    (tmp_path / "mine.xml").write_text("<notes/>")
    refused = CliRunner().invoke(app, ["check", "--suite", "t", "--suites", str(tmp_path / "suites.toml"),
                                       "--baseline", str(tmp_path / "base.json"), "--junit", str(tmp_path / "mine.xml")])
    assert refused.exit_code == 2 and (tmp_path / "mine.xml").read_text() == "<notes/>"
    assert "is not a JUnit file written by simbench check; it will not be replaced" in " ".join(refused.output.split())
    assert "ERROR" not in refused.output


def test_a_bad_set_on_the_command_line_is_still_exit_2(tmp_path):
    suites = rg.load_suites("scenarios/suites.toml")
    with pytest.raises(ScenarioError) as info:
        suites.resolve("ci", extra_set={"sensor.exposure_ms": -1})
    assert info.value.field.startswith("--set sensor.exposure_ms")
