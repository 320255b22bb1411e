"""`simbench check` end to end: the ci suite passes on the committed baseline; a scenario made
worse (a much longer, blurred shutter on the fast zigzag) fails with a readable table and JUnit."""

from __future__ import annotations

import subprocess
import sys
import xml.etree.ElementTree as ET


def _check(tmp_path, *extra: str) -> subprocess.CompletedProcess:
    cmd = [sys.executable, "-m", "simbench.cli", "check", "--suite", "ci", "--baseline", "scenarios/baselines/ci.json",
           "--junit", str(tmp_path / "junit.xml"), "-j", "2", *extra]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=900)


def test_ci_suite_passes_on_the_committed_baseline(tmp_path):
    r = _check(tmp_path)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "PASS suite ci" in r.stdout and "0 regressed" in r.stdout
    suite = ET.parse(tmp_path / "junit.xml").getroot().find("testsuite")
    assert suite.get("failures") == "0" and suite.get("errors") == "0" and int(suite.get("tests")) >= 3 * 8


def test_check_fails_with_a_table_when_a_scenario_gets_worse(tmp_path):
    r = _check(tmp_path, "--only", "blur_zigzag", "--set", "sensor.exposure_ms=33")
    assert r.returncode == 1, r.stdout + r.stderr
    out = r.stdout
    assert "FAIL suite ci" in out
    rows = [ln for ln in out.splitlines() if "REGRESSED" in ln]
    assert any("blur_zigzag" in ln and "markers.rmse_mm" in ln and "higher worse" in ln for ln in rows), out
    assert "note: blur_zigzag: scenario differs from the baseline's" in out
    root = ET.parse(tmp_path / "junit.xml").getroot()
    failed = {tc.get("name") for tc in root.iter("testcase") if tc.find("failure") is not None}
    assert "markers.rmse_mm" in failed
    assert {tc.get("classname") for tc in root.iter("testcase")} == {"ci.blur_zigzag"}  # --only: the others not run
