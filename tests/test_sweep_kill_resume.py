"""A sweep killed with SIGKILL mid-way and resumed ends with every run present exactly once,
and the runs finished before the kill keep their metrics (they are not run again)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import duckdb

from helpers import TINY_RUN_SET

QUICKSTART = Path("scenarios/quickstart.toml").resolve()

SWEEP = f"""
name = "kill_me"
scenario = "{QUICKSTART}"
{TINY_RUN_SET}
[[factors]]
field = "markers_pipeline.tracker"
values = ["alpha_beta", "kalman", "imm"]
"""


def _cmd(sweep: Path, db: Path, *extra: str) -> list[str]:
    return [sys.executable, "-m", "simbench.cli", "sweep", str(sweep), "--db", str(db), "-j", "1", "--no-outputs", *extra]


def test_sigkill_mid_sweep_then_resume(tmp_path):
    sweep = tmp_path / "kill_me.toml"
    sweep.write_text(SWEEP)
    db = tmp_path / "db" / "results.duckdb"
    results = db.parent / "results"
    proc = subprocess.Popen(_cmd(sweep, db), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        deadline = time.monotonic() + 400
        while time.monotonic() < deadline and proc.poll() is None:
            if results.is_dir() and any(results.glob("*.json")):
                break
            time.sleep(0.05)
        assert proc.poll() is None, "the sweep ended before it could be killed"
        # SIGKILL the whole process group: the sweep's parent and its pool worker.
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(timeout=30)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == -signal.SIGKILL
    before = {p.stem: json.loads(p.read_text()) for p in results.glob("*.json")}
    assert before, "no run had finished when the sweep was killed"
    assert all(d["status"] == "ok" for d in before.values())

    r = subprocess.run(_cmd(sweep, db, "--resume"), capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    said = " ".join(r.stderr.split())
    assert f"{3 - len(before)} runs in" in said and f"{len(before)} already done" in said

    con = duckdb.connect(str(db), read_only=True)
    try:
        assert con.execute("SELECT count(*), count(DISTINCT run_id) FROM runs").fetchone() == (3, 3)
        assert con.execute("SELECT count(*) FROM runs WHERE status = 'ok' AND sweep = 'kill_me'").fetchone()[0] == 3
        dup = con.execute("SELECT run_id, metric, count(*) c FROM metrics GROUP BY ALL HAVING c > 1").fetchall()
        assert dup == []
        n_metrics = con.execute("SELECT run_id, count(*) FROM metrics GROUP BY run_id").fetchall()
        assert len(n_metrics) == 3 and len({n for _, n in n_metrics}) == 1
        for rid, rec in before.items():
            got = dict(con.execute("SELECT metric, value FROM metrics WHERE run_id = ?", [rid]).fetchall())
            assert got == {k: v for k, v in rec["metrics"].items() if v is not None}
            started = con.execute("SELECT epoch_ms(started_at) FROM runs WHERE run_id = ?", [rid]).fetchone()[0]
            assert abs(started / 1000.0 - rec["started_at"]) < 2e-3  # not run again
    finally:
        con.close()
    after = {p.stem: json.loads(p.read_text()) for p in results.glob("*.json")}
    assert len(after) == 3 and all(after[k] == v for k, v in before.items())
    # the kill landed mid-sweep: the runs done before it are a proper part of the sweep's
    assert set(before) < set(after), f"all {len(after)} runs had finished before the kill"
    assert sorted(p.stem for p in (db.parent / "frames").glob("*.parquet")) == sorted(after)


def test_two_identical_sweeps_on_one_database_split_the_runs(tmp_path):
    """Started together on one database, two sweeps compute each run once between them."""
    sweep = tmp_path / "kill_me.toml"
    sweep.write_text(SWEEP)
    db = tmp_path / "db" / "results.duckdb"
    procs = [subprocess.Popen(_cmd(sweep, db, "--resume"), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
             for _ in range(2)]
    errs = [p.communicate(timeout=600)[1] for p in procs]
    assert [p.returncode for p in procs] == [0, 0], errs
    ran = [int(" ".join(e.split()).split(" runs in ")[0].split()[-1]) for e in errs]
    assert sum(ran) == 3, errs  # not 6: no run computed twice
    results = [json.loads(p.read_text()) for p in (db.parent / "results").glob("*.json")]
    assert len(results) == 3 and all(r["status"] == "ok" for r in results)
    assert not any((db.parent / "claims").glob("*.json"))  # every claim released
    con = duckdb.connect(str(db), read_only=True)
    try:
        assert con.execute("SELECT count(*), count(DISTINCT run_id) FROM runs").fetchone() == (3, 3)
    finally:
        con.close()
