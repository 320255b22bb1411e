"""`simbench check` end to end: the ci suite (8 seeds per scenario against the baseline's 32) passes on
the committed baseline; a scenario made worse (a longer, more blurred shutter on the fast zigzag) fails
with a readable table (its one-sided, Holm-corrected p-values) and JUnit.

The committed baseline must match the committed pipeline: a change that moves the ci metrics
comes with `simbench baseline update --suite ci` (that is the gate doing its job)."""

from __future__ import annotations

import subprocess
import xml.etree.ElementTree as ET

from typer.testing import CliRunner

from simbench.cli.app import app


def _check(tmp_path, *extra: str) -> subprocess.CompletedProcess:
    """``simbench check --suite ci`` through the command's typer app in this process (its runs go to
    one spawned worker process, as from the command line with ``-j 1``; a new interpreter for the
    command itself would only add its imports, about 5 CPU-s, and a second worker its start-up)."""
    args = ["check", "--suite", "ci", "--baseline", "scenarios/baselines/ci.json", "--junit", str(tmp_path / "junit.xml"),
            "-j", "1", *extra]
    r = CliRunner().invoke(app, args, catch_exceptions=True)
    assert r.exception is None or isinstance(r.exception, SystemExit), repr(r.exception)
    return subprocess.CompletedProcess(args, r.exit_code, r.stdout, r.stderr)


def test_ci_suite_passes_on_the_committed_baseline(tmp_path):
    r = _check(tmp_path)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "PASS suite ci" in r.stdout and "0 regressed" in r.stdout
    assert "4 scenarios (8 seeds each against 32 baseline seeds)" in r.stdout
    suite = ET.parse(tmp_path / "junit.xml").getroot().find("testsuite")
    assert suite.get("failures") == "0" and suite.get("errors") == "0" and int(suite.get("tests")) >= 4 * 8


def test_check_fails_with_a_table_when_a_scenario_gets_worse(tmp_path):
    # 3 seeds against the baseline's 32: the smallest one-sided p is 1/C(35, 3) = 1.5e-4, below alpha / 9 metrics
    # (1.1e-3) by 7x (4 seeds, 1.7e-5, took a quarter longer)
    r = _check(tmp_path, "--only", "blur_zigzag", "--set", "sensor.exposure_ms=33", "--seeds", "3")
    assert r.returncode == 1, r.stdout + r.stderr
    out = r.stdout
    assert "FAIL suite ci" in out
    # Which marker metric gives way first depends on the pipeline (more blur: fewer markers
    # reconstructed, or larger errors); at least one must be flagged, with its numbers.
    rows = [ln.split("│") for ln in out.splitlines() if "REGRESSED" in ln]
    flagged = {cells[2].strip(): cells for cells in rows if len(cells) > 7 and cells[1].strip() == "blur_zigzag"}
    markers = {m for m in flagged if m.startswith("markers.")}
    assert markers, out
    for m in markers:
        baseline, current, change, tolerance, p = (flagged[m][i].strip() for i in (3, 4, 5, 6, 7))
        assert float(baseline) != float(current) and change and " worse, ±" in tolerance
        assert float(p) < 0.01  # the one-sided test, Holm-corrected over the check, at the suite's alpha
    assert "note: blur_zigzag: scenario differs from the baseline's" in out
    root = ET.parse(tmp_path / "junit.xml").getroot()
    failed = {tc.get("name") for tc in root.iter("testcase") if tc.find("failure") is not None}
    assert markers <= failed
    assert {tc.get("classname") for tc in root.iter("testcase")} == {"ci.blur_zigzag"}  # --only: the others not run
