"""Results store and database without rendering: atomic files, idempotent ingest,
reconcile after a crash, per-frame Parquet, and the report built from a synthetic grid."""

from __future__ import annotations

import json
import math
import os
import time

import numpy as np
import pyarrow as pa
import pytest

from simbench.errors import SimbenchInputError
from simbench.sweeps.results_db import ResultsDB, RunRecord
from simbench.sweeps.report import write_sweep_report

LIGHT = ["office_fluorescent", "dim_gym"]
BLUR = ["off", "long"]
TRACKERS = ["alpha_beta", "kalman", "condensation"]


def _rmse(light: str, blur: str, tracker: str) -> float:
    """A made-up but structured response: dim light and blur hurt, trackers differ a little."""
    return 2.0 + 3.0 * (light == "dim_gym") + 5.0 * (blur == "long") + 0.5 * TRACKERS.index(tracker)


def _records() -> list[RunRecord]:
    out = []
    i = 0
    for light in LIGHT:
        for blur in BLUR:
            for tr in TRACKERS:
                rid = f"{i:016x}"
                failed = (light, blur, tr) == ("dim_gym", "long", "condensation")
                per_frame = pa.table({
                    "frame": np.repeat(np.arange(3, dtype=np.int32), 2), "time_s": np.repeat([0.0, 0.1, 0.2], 2),
                    "marker": ["A", "B"] * 3, "error_mm": np.full(6, _rmse(light, blur, tr)),
                    "views_visible": np.full(6, 2, np.int16), "reconstructed": np.ones(6, bool), "filled": np.zeros(6, bool)})
                out.append(RunRecord(
                    run_id=rid, sweep="synthetic", run_index=i, scenario="base", scenario_hash="h" * 16,
                    factors={"lighting.preset": light, "blur": blur, "markers_pipeline.tracker": tr},
                    parameters={"lighting.preset": light}, status="failed" if failed else "ok",
                    error="RuntimeError: synthetic failure\nTraceback ..." if failed else "",
                    started_at=1.7e9 + 10 * i, ended_at=1.7e9 + 10 * i + 4.0, timings={"render_s": 3.0},
                    versions={"numpy": np.__version__}, worker="host:1",
                    metrics={} if failed else {"markers.rmse_mm": _rmse(light, blur, tr),
                                               "markers.reconstructed_fraction": 1.0 - 0.1 * (blur == "long"),
                                               "markers.losses_2d": float(TRACKERS.index(tr)),
                                               "markers.label_swaps": 0.0, "markers.max_error_mm": math.nan},
                    per_frame=None if failed else per_frame))
                i += 1
    return out


@pytest.fixture()
def db(tmp_path) -> ResultsDB:
    db = ResultsDB(tmp_path / "sweep" / "results.duckdb")
    recs = _records()
    for r in recs:
        db.store.write(r)
    db.ingest(recs)
    db.record_sweep("synthetic", "synthetic.toml", {"description": "synthetic grid"},
                    {"lighting.preset": LIGHT, "blur": BLUR, "markers_pipeline.tracker": TRACKERS}, len(recs))
    return db


def test_store_writes_atomically_and_round_trips(db):
    files = sorted(p.name for p in db.store.results_dir.iterdir())
    assert len(files) == 12 and all(f.endswith(".json") for f in files)  # no temporaries left
    back = db.store.read(f"{0:016x}")
    assert back.metrics["markers.rmse_mm"] == 2.0 and math.isnan(back.metrics["markers.max_error_mm"])
    assert back.frames_file == f"frames/{0:016x}.parquet"
    assert json.loads(db.store.result_path(f"{0:016x}").read_text())["metrics"]["markers.max_error_mm"] is None


def test_ingest_is_idempotent_and_metrics_are_long(db):
    db.ingest(_records())
    runs = db.runs()
    assert len(runs) == 12 and runs["run_id"].is_unique
    long = db.metrics_long()
    assert len(long) == 11 * 5 and not long.duplicated(["run_id", "metric"]).any()
    wide = db.metrics_wide()
    row = wide[(wide["lighting.preset"] == "dim_gym") & (wide["blur"] == "off") & (wide["markers_pipeline.tracker"] == "kalman")]
    assert row["markers.rmse_mm"].item() == 5.5
    assert runs.loc[runs["status"] == "failed", "error"].item().startswith("RuntimeError: synthetic failure")


def test_reconcile_ingests_results_the_database_missed(tmp_path):
    db = ResultsDB(tmp_path / "results.duckdb")
    recs = _records()
    for r in recs:
        db.store.write(r)  # written, then the process died before ingesting
    db.ingest(recs[:3])
    half = db.store.results_dir / ".half.json.abc.tmp"
    half.write_text("{")  # a write cut short two minutes ago
    os.utime(half, (time.time() - 120, time.time() - 120))
    busy = db.store.results_dir / ".busy.json.def.tmp"
    busy.write_text("{")  # another sweep on this database writing right now
    assert db.store.remove_temporaries() == 1
    assert not half.exists() and busy.exists()
    assert db.reconcile() == 9
    assert db.reconcile() == 0
    assert len(db.runs()) == 12


def test_per_frame_tables_come_back_with_run_ids(db):
    f = db.per_frame([f"{0:016x}", f"{5:016x}"])
    assert sorted(f["run_id"].unique()) == [f"{0:016x}", f"{5:016x}"]
    assert len(f) == 12 and set(f.columns) >= {"frame", "time_s", "marker", "error_mm", "views_visible", "reconstructed", "filled"}


def test_report_plots_every_factor_heatmaps_trackers_and_worst_runs(db, tmp_path):
    md = write_sweep_report(db.path, tmp_path / "rep", n_worst=3)
    text = md.read_text()
    plots = {p.name for p in (tmp_path / "rep" / "plots").glob("*.png")}
    assert {"metrics_vs_lighting_preset.png", "metrics_vs_blur.png", "metrics_vs_markers_pipeline_tracker.png",
            "heatmap_blur__lighting_preset.png", "heatmap_markers_pipeline_tracker__lighting_preset.png",
            "heatmap_markers_pipeline_tracker__blur.png", "trackers.png", "worst_runs_per_frame.png"} <= plots
    for p in plots:
        assert (tmp_path / "rep" / "plots" / p).stat().st_size > 5000
        assert f"(plots/{p})" in text
    # trackers side by side: mean rmse per tracker over the runs that finished
    ok = [(li, b, t) for li in LIGHT for b in BLUR for t in TRACKERS if (li, b, t) != ("dim_gym", "long", "condensation")]
    for t in TRACKERS:
        mean = np.mean([_rmse(*k) for k in ok if k[2] == t])
        assert f"| {t} | {sum(k[2] == t for k in ok)} | {mean:.4g} |" in text
    # the worst run by rmse is dim light + long blur with the highest-cost tracker that finished
    worst = text.split("## Worst 3 runs")[1].splitlines()[4]
    assert "dim_gym" in worst and "long" in worst and "kalman" in worst and "| 10.5 |" in worst
    assert "## Failed runs (1)" in text and "synthetic failure" in text
    assert "(outputs not kept)" in text
    assert (tmp_path / "rep" / "report.html").read_text().count("<img") == len(plots)


def test_report_errors_name_the_fix(tmp_path, db):
    with pytest.raises(SimbenchInputError, match="simbench sweep"):
        write_sweep_report(tmp_path / "nope.duckdb", tmp_path / "r")
    with pytest.raises(SimbenchInputError, match="holds: synthetic"):
        write_sweep_report(db.path, tmp_path / "r", sweep="other")


def test_report_command_replaces_its_own_report_and_never_a_folder_of_the_users(db, tmp_path):
    from typer.testing import CliRunner

    from simbench.cli.app import app

    rep = tmp_path / "rep"
    for _ in range(2):  # written, then replaced by the rerun
        res = CliRunner().invoke(app, ["report", str(db.path), "--out", str(rep), "--worst", "2"])
        assert res.exit_code == 0, res.output
        assert (rep / "report.md").is_file() and (rep / "plots" / "trackers.png").is_file()
    assert not [p for p in tmp_path.iterdir() if ".partial-" in p.name]
    mine = tmp_path / "documents"
    mine.mkdir()
    (mine / "report.md").write_text("my own report\n")
    res = CliRunner().invoke(app, ["report", str(db.path), "--out", str(mine)])
    assert res.exit_code == 2 and "exists and was not written by simbench" in " ".join(res.output.split())
    assert [p.name for p in mine.iterdir()] == ["report.md"] and (mine / "report.md").read_text() == "my own report\n"
