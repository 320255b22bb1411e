"""simbench scoreboard (issue 14, part 4): one table of every system on the same frames, a report with plots."""

from __future__ import annotations

import json
from pathlib import Path

from typer.testing import CliRunner

from simbench.cli.app import app
from simbench.pipelines.exchange.adapters import adapter_python


def test_scoreboard_tiny_suite(tmp_path):
    (tmp_path / "suites.toml").write_text(
        '[suites.tiny]\ndescription = "tiny"\nset = { duration_s = 0.3, "rig.count" = 3, "rig.start_deg" = -60.0, '
        '"rig.span_deg" = 120.0, "sensor.antialias" = 1, "markers_pipeline.solve_skeleton" = false }\n'
        f'[[suites.tiny.scenarios]]\nname = "quickstart"\nfile = "{Path("scenarios/quickstart.toml").resolve()}"\n')
    systems = ["pose2sim"] if adapter_python("pose2sim") is not None else []
    args = ["scoreboard", "tiny", "--suites", str(tmp_path / "suites.toml"), "--out", str(tmp_path / "sb")]
    args += [a for s in systems for a in ("--system", s)] or ["--system", "project"]
    r = CliRunner().invoke(app, args)
    assert r.exit_code == 0, r.output
    data = json.loads((tmp_path / "sb" / "scoreboard.json").read_text())
    rows = {(x["system"], x["variant"]): x["metrics"] for x in data["rows"]}
    project = rows[("project", "mocap pipeline (scenario settings)")]
    dlt = rows[("project", "triangulate_dlt (labelled 2D)")]
    assert 0.05 < dlt["markers.rmse_mm"] < 2.0 and project["markers.rmse_mm"] > 0.05 and project["markers.reconstructed_fraction"] > 0.5
    assert all(v["ms_per_frame"] > 0 for v in rows.values() if "ms_per_frame" in v)
    if systems:
        assert rows[("pose2sim", "pose2sim_gaps_nan")]["markers.rmse_mm"] < 2.0
    md = (tmp_path / "sb" / "scoreboard.md").read_text()
    assert "| quickstart | project | triangulate_dlt (labelled 2D) |" in md and "plots/errors_quickstart.png" in md
    assert (tmp_path / "sb" / "plots" / "errors_quickstart.png").stat().st_size > 10_000
    assert "RMSE mm" in r.output and "triangulate_dlt" in r.output


def test_scoreboard_seeds_give_confidence_intervals(tmp_path):
    """--seeds 2: every system runs on each seed's frames; each figure is the seeds' mean with a 95 % CI
    that contains it, and the per-seed rows differ (different frames). (Two seeds are enough for a
    mean and a t interval; 3 took a third longer.)"""
    (tmp_path / "suites.toml").write_text(
        '[suites.tiny]\ndescription = "tiny"\nset = { duration_s = 0.2, "rig.count" = 2, "rig.start_deg" = -40.0, '
        '"rig.span_deg" = 80.0, "sensor.antialias" = 1, "markers_pipeline.solve_skeleton" = false }\n'
        f'[[suites.tiny.scenarios]]\nname = "quickstart"\nfile = "{Path("scenarios/quickstart.toml").resolve()}"\n')
    args = ["scoreboard", "tiny", "--suites", str(tmp_path / "suites.toml"), "--out", str(tmp_path / "sb"), "--seeds", "2"]
    args += ["--system", "pose2sim" if adapter_python("pose2sim") is not None else "project"]  # the fast adapter, or none
    r = CliRunner().invoke(app, args)
    assert r.exit_code == 0, r.output
    data = json.loads((tmp_path / "sb" / "scoreboard.json").read_text())
    dlt = [x for x in data["rows"] if x["variant"] == "triangulate_dlt (labelled 2D)"]
    assert sorted(x["seed"] for x in dlt) == [0, 1]
    values = [x["metrics"]["markers.rmse_mm"] for x in dlt]
    assert len(set(values)) == 2
    s = next(x for x in data["summary"] if x["variant"] == "triangulate_dlt (labelled 2D)")["metrics"]["markers.rmse_mm"]
    assert s["n"] == 2 and abs(s["mean"] - sum(values) / 2) < 1e-9 and s["ci_low"] < s["mean"] < s["ci_high"]
    assert "mean over 2 seeds" in (tmp_path / "sb" / "scoreboard.md").read_text()
    assert "[" in r.output  # the table's CI brackets
