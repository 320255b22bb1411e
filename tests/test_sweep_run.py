"""A real small sweep: local process pool vs a distributed.LocalCluster (identical metrics),
a failing run recorded while the sweep goes on, the DuckDB/Parquet records, the report."""

from __future__ import annotations

import json
from pathlib import Path

import duckdb
import numpy as np
import pytest

from simbench.errors import SimbenchInputError
from simbench.sweeps.results_db import ResultsDB
from simbench.sweeps.sweep import load_sweep, run_sweep
from simbench.sweeps.report import write_sweep_report

from helpers import TINY_RUN_SET

QUICKSTART = Path("scenarios/quickstart.toml").resolve()
# A run that passes the sweep's validation and fails when it runs: a window past the clip's end.
WALK_BVH = Path("scenarios/data/bvh/131_01.bvh").resolve()

# Tiny runs (helpers.TINY_RUN_SET): 2 cameras at 320x240, 0.3 s (9 frames), no supersampling, no skeleton.
SWEEP = f"""
name = "tiny_trackers"
scenario = "{QUICKSTART}"
""" + TINY_RUN_SET + """
[[factors]]
name = "variant"
[factors.levels]
alpha_beta = { "markers_pipeline.tracker" = "alpha_beta" }
kalman_blur = { "markers_pipeline.tracker" = "kalman", "sensor.exposure_ms" = 25.0, "sensor.motion_blur" = true }
broken = { "motion.clip" = "bvh", "motion.bvh" = "WALK_BVH", "motion.start_s" = 600.0 }
""".replace("WALK_BVH", str(WALK_BVH))


@pytest.fixture(scope="module")
def local(tmp_path_factory):
    d = tmp_path_factory.mktemp("sweep")
    (d / "tiny.toml").write_text(SWEEP)
    sw = load_sweep(d / "tiny.toml")
    # one spawned worker: a second would only add its start-up (imports, GL context), about 5 CPU-s
    summary = run_sweep(sw, d / "local" / "results.duckdb", workers=1, outputs=True)
    return sw, summary, ResultsDB(d / "local" / "results.duckdb")


def _metrics(db: ResultsDB) -> dict[str, dict[str, float]]:
    long = db.metrics_long()
    return {rid: dict(zip(g["metric"], g["value"])) for rid, g in long.groupby("run_id")}


def test_failing_run_is_recorded_and_the_sweep_goes_on(local):
    sw, summary, db = local
    assert (summary.total, summary.ran, summary.failed, summary.skipped) == (3, 3, 1, 0)
    runs = db.runs().set_index("run_id")
    assert sorted(runs.index) == sorted(r.run_id for r in sw.runs)
    bad = runs[runs["status"] == "failed"]
    assert len(bad) == 1
    assert bad.iloc[0]["factors"] == {"variant": "broken"}
    assert "the BVH clip" in bad.iloc[0]["error"] and "Traceback" in bad.iloc[0]["error"]
    ok = runs[runs["status"] == "ok"]
    assert len(ok) == 2 and (ok["error"] == "").all()
    for _, r in ok.iterrows():
        assert r["versions"]["numpy"] == np.__version__ and "mujoco" in r["versions"]
        assert r["parameters"]["rig.count"] == 2 and r["duration_s"] > 0 and r["timings"]["render_s"] > 0
        assert (db.store.root / r["out_dir"] / "report.md").is_file()
    m = _metrics(db)
    assert set(m) == set(ok.index)  # a failed run has no metrics
    for vals in m.values():
        assert vals["run.frames"] == 9 and vals["run.cameras"] == 2
        assert np.isfinite(vals["markers.rmse_mm"]) and 0 < vals["markers.reconstructed_fraction"] <= 1


def test_per_frame_parquet_agrees_with_the_metrics(local):
    _, _, db = local
    m = _metrics(db)
    frames = db.per_frame()
    assert set(frames["run_id"]) == set(m)
    for rid, f in frames.groupby("run_id"):
        assert f["frame"].nunique() == 9 and len(f) == 9 * f["marker"].nunique()
        e = f["error_mm"].to_numpy()
        fin = e[np.isfinite(e)]
        assert np.sqrt(np.mean(fin**2)) == pytest.approx(m[rid]["markers.rmse_mm"], rel=1e-9)
        assert (f["reconstructed"] == np.isfinite(e)).all()
        # reconstructed fraction is over marker-frames seen by two or more cameras
        seen = f[f["views_visible"] >= 2]
        assert seen["reconstructed"].mean() == pytest.approx(m[rid]["markers.reconstructed_fraction"], rel=1e-9)


def test_local_cluster_gives_identical_metrics(local, tmp_path):
    from distributed import LocalCluster

    sw, _, db = local
    # one worker process: the runs still go to the cluster's process (checked below); a second one
    # would only add its start-up
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        summary = run_sweep(sw, tmp_path / "results.duckdb", scheduler=cluster.scheduler_address, outputs=False)
    assert (summary.ran, summary.failed) == (3, 1)
    dask_db = ResultsDB(tmp_path / "results.duckdb")
    a, b = _metrics(db), _metrics(dask_db)
    assert a.keys() == b.keys() and len(a) == 2
    for rid in a:
        assert a[rid] == b[rid]  # exactly equal, not approximately
    sa = dict(zip(db.runs()["run_id"], db.runs()["status"]))
    sb = dict(zip(dask_db.runs()["run_id"], dask_db.runs()["status"]))
    assert sa == sb
    # the workers that ran them were the cluster's, not this process
    assert all(not w.endswith(f":{__import__('os').getpid()}") for w in dask_db.runs()["worker"])


def test_without_resume_an_existing_sweep_is_refused(local):
    sw, _, db = local
    with pytest.raises(SimbenchInputError, match="--resume"):
        run_sweep(sw, db.path, workers=1)


def test_report_of_the_sweep_links_outputs(local, tmp_path):
    sw, _, db = local
    md = write_sweep_report(db.path, tmp_path / "report")
    text = md.read_text()
    html = (tmp_path / "report" / "report.html").read_text()
    assert "Failed runs (1)" in text and "the BVH clip" in text
    assert (tmp_path / "report" / "plots" / "metrics_vs_variant.png").is_file()
    assert "![metrics vs variant](plots/metrics_vs_variant.png)" in text
    # worst runs link to each run's report and contact sheet, and the links resolve
    links = [ln.split("](")[1].split(")")[0] for ln in text.splitlines() if "[report](" in ln]
    assert len(links) == 2
    for link in links:
        assert (tmp_path / "report" / link).resolve().is_file()
    assert html.count("<table>") == sum(ln.startswith("|---") for ln in text.splitlines()) >= 4
    assert html.count("<img") == text.count("![")
    summary = json.loads((tmp_path / "report" / "summary.json").read_text())
    assert summary["runs"] == 3 and summary["failed"] == 1
    con = duckdb.connect(str(db.path), read_only=True)
    try:
        assert con.execute("SELECT count(*), count(DISTINCT run_id) FROM runs").fetchone() == (3, 3)
    finally:
        con.close()
