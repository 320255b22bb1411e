"""[pipeline] kind = "command" (issue 14, part 2): a user's system run by `simbench run`, scored
like the project's; a failing or silent command is one clear error naming it and its log; and
`simbench check` catches a deliberately worse version of the stand-in system."""

from __future__ import annotations

import json
import re

import pytest
from typer.testing import CliRunner

from simbench.cli.app import app
from simbench.pipelines.run import run_scenario
from simbench.scenario import load_scenario

TINY = {"duration_s": 0.2, "rig.count": 2, "rig.start_deg": -40.0, "rig.span_deg": 80.0, "sensor.antialias": 1}


def test_command_pipeline_is_scored_against_the_truth(tmp_path):
    res = run_scenario(load_scenario("scenarios/external_command.toml", TINY), tmp_path / "run")
    assert res.ok, res.failures
    # plain DLT on blob centroids: sub-millimetre, every marker seen twice reconstructed
    assert 0.05 < res.metrics["markers.rmse_mm"] < 2.0
    assert res.metrics["markers.reconstructed_fraction"] > 0.95
    assert res.metrics["markers.label_swaps"] == 0
    log = (tmp_path / "run" / "command.log").read_text()
    assert "external_pipeline.py" in log and "triangulated" in log
    assert (tmp_path / "run" / "inputs" / "calibration" / "calibration.yml").is_file()
    assert not (tmp_path / "run" / "inputs" / "ground_truth").exists()


@pytest.mark.parametrize("command, expected", [
    ("{python} -c \"import sys; print('cannot open camera 3'); sys.exit(4)\"", r"exited with code 4; log: .*command\.log \(its last line: 'cannot open camera 3'\)"),
    ("{python} -c pass", r"exited 0 but wrote no markers\.trc in its output folder; log: .*command\.log \(it printed nothing\)"),
    ("{python} -c \"import time; time.sleep(30)\"", r"did not finish in timeout_s = 1 s"),
    ("no-such-program-xyz {inputs}", r"program 'no-such-program-xyz' not found"),
])
def test_failing_or_silent_command_is_one_clear_error(tmp_path, command, expected):
    sc = load_scenario("scenarios/external_command.toml", {**TINY, "pipeline.command": command, "pipeline.timeout_s": 1.0})
    res = run_scenario(sc, tmp_path / "run")
    assert [f.stage for f in res.failures] == ["command pipeline"]
    cause = res.failures[0].cause
    assert "\n" not in cause and "pipeline command" in cause and re.search(expected, cause), cause
    assert ".partial-" not in cause  # names the final run folder
    failed = json.loads((tmp_path / "run" / "metrics.json").read_text())["failed_stages"]
    assert failed[0]["cause"] == cause


def test_bad_pipeline_section_is_refused(tmp_path):
    p = tmp_path / "s.toml"
    p.write_text('name = "s"\n[pipeline]\nkind = "command"\n')
    from simbench.errors import ScenarioError

    with pytest.raises(ScenarioError, match=r"pipeline.*needs command"):
        load_scenario(p)


@pytest.mark.slow  # a rendered take end to end: seconds
def test_check_catches_the_worse_external_system(tmp_path):
    """The suite passes against its committed baseline with the stand-in system and fails (exit 1)
    with its noisier version."""
    base = ["check", "--suite", "external", "--out", str(tmp_path / "check"), "-j", "1"]
    ok = CliRunner().invoke(app, base)
    assert ok.exit_code == 0, ok.output
    worse = 'pipeline.command="{python} ../examples/external_pipeline.py {inputs} {output} --noise-px 1.5"'
    bad = CliRunner().invoke(app, base + ["--set", worse])
    assert bad.exit_code == 1, bad.output
    assert re.search(r"markers\.rmse_mm.*REGRESSED", bad.output)
