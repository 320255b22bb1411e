"""`simbench run --seeds` and `simbench compare` end to end on a tiny scenario (2 cameras, 6 frames):
per-seed values and their summary, the same numbers whichever command ran a seed, the folder
and database forms of compare, and bad input as one line with exit 2."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from simbench.sweeps.results_db import ResultsDB, RunRecord

TINY = ["--set", "rig.count=2", "--set", "rig.start_deg=-40", "--set", "rig.span_deg=80", "--set", "duration_s=0.2",
        "--set", "sensor.antialias=1", "--set", "markers_pipeline.solve_skeleton=false"]


def _cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "simbench.cli", *args], capture_output=True, text=True, timeout=900)


def _cli_here(*args: str) -> subprocess.CompletedProcess:
    """The command's typer app in this process (``typer.testing.CliRunner``, as tests/fuzz_inputs.py
    does): for commands that only read stored results or refuse their input, the same code path
    without a new interpreter's imports (about 5 CPU-s a command)."""
    from typer.testing import CliRunner

    from simbench.cli.app import app

    r = CliRunner().invoke(app, list(args), catch_exceptions=True)
    assert r.exception is None or isinstance(r.exception, SystemExit), repr(r.exception)
    return subprocess.CompletedProcess(args, r.exit_code, r.stdout, r.stderr)


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("seeds")
    # in this process (each command's seeds on one spawned worker process): a new interpreter for
    # each command and a second worker each would add only their imports (about 20 CPU-s)
    cmp = _cli_here("compare", "scenarios/quickstart.toml", "--a", "markers_pipeline.tracker=kalman",
                    "--b", "markers_pipeline.tracker=alpha_beta", *TINY, "--seeds", "2", "--out", str(tmp / "cmp"), "-j", "1")
    run = _cli_here("run", "scenarios/quickstart.toml", *TINY, "--set", "markers_pipeline.tracker=kalman", "--seeds", "2",
                    "--out", str(tmp / "run"), "-j", "1")
    return tmp, cmp, run


def test_run_seeds_writes_per_seed_values_and_their_summary(runs):
    tmp, _, run = runs
    assert run.returncode == 0, run.stdout + run.stderr
    data = json.loads((tmp / "run" / "metrics.json").read_text())
    assert data["seeds"] == [0, 1] and data["failed_seeds"] == []
    for seed in (0, 1):  # each seed's own run folder, with the single run's metrics.json
        own = json.loads((tmp / "run" / "seeds" / f"seed-{seed:04d}" / "metrics.json").read_text())
        for m, s in data["metrics"].items():
            assert s["values"][seed] == own[m]
    rmse = data["metrics"]["markers.rmse_mm"]
    v = np.array(rmse["values"])
    assert rmse["mean"] == pytest.approx(v.mean()) and rmse["median"] == pytest.approx(np.median(v))
    assert rmse["sd"] == pytest.approx(v.std(ddof=1))
    assert len(rmse["ci95"]) == 2 and rmse["n"] == 2
    assert data["metrics"]["run.frames"]["ci95"] == [6.0, 6.0] and data["metrics"]["run.frames"]["ci_method"] == "constant"
    report = (tmp / "run" / "report.md").read_text()
    assert "| `markers.rmse_mm` |" in report and "plots/seed_spread.png" in report
    assert (tmp / "run" / "plots" / "seed_spread.png").stat().st_size > 10_000
    assert "markers.rmse_mm" in run.stdout and "95% CI" in run.stdout


def test_the_same_scenario_and_seed_give_the_same_numbers_through_run_and_compare(runs):
    tmp, cmp, run = runs
    assert cmp.returncode == 0, cmp.stdout + cmp.stderr
    a = json.loads((tmp / "cmp" / "a" / "metrics.json").read_text())["metrics"]
    r = json.loads((tmp / "run" / "metrics.json").read_text())["metrics"]
    assert {m: s["values"] for m, s in a.items()} == {m: s["values"] for m, s in r.items()}


def test_compare_prints_differences_test_verdict_and_detectable_effect(runs):
    tmp, cmp, _ = runs
    out = cmp.stdout
    assert "markers_pipeline.tracker=kalman" in out and "markers_pipeline.tracker=alpha_beta" in out
    for col in ("B - A", "95% CI", "verdict", "detectable"):
        assert col in out
    data = json.loads((tmp / "cmp" / "compare.json").read_text())
    assert data["pairs"] == ["seed 0", "seed 1"]
    a = json.loads((tmp / "cmp" / "a" / "metrics.json").read_text())["metrics"]
    b = json.loads((tmp / "cmp" / "b" / "metrics.json").read_text())["metrics"]
    row = data["metrics"]["markers.losses_2d"]
    diffs = [vb - va for va, vb in zip(a["markers.losses_2d"]["values"], b["markers.losses_2d"]["values"])]
    assert row["diffs"] == pytest.approx(diffs) and row["better"] == "lower"
    assert row["verdict"] == "no detectable difference at this N"  # two pairs can never reach p < 0.05
    # the stored folders compare to the same figures
    again = _cli_here("compare", str(tmp / "cmp" / "a"), str(tmp / "cmp" / "b"))
    assert again.returncode == 0, again.stderr
    assert [ln for ln in again.stdout.splitlines() if "markers.rmse_mm" in ln] == \
        [ln for ln in out.splitlines() if "markers.rmse_mm" in ln]


def test_compare_of_two_databases_pairs_runs_by_their_factors(tmp_path):
    def db(path, shift):
        recs = [RunRecord(run_id=f"r{s}{shift}", sweep="sw", run_index=s, scenario="q", scenario_hash="h",
                          factors={"seed": s}, parameters={}, status="ok",
                          metrics={"markers.rmse_mm": 1.0 + 0.1 * s + shift, "markers.reconstructed_fraction": 0.9})
                for s in range(12)]
        ResultsDB(path).ingest(recs)
        return path

    a, b = db(tmp_path / "a" / "results.duckdb", 0.0), db(tmp_path / "b" / "results.duckdb", 0.05)
    r = _cli_here("compare", str(a), str(b))
    assert r.returncode == 0, r.stdout + r.stderr
    row = next(ln for ln in r.stdout.splitlines() if "markers.rmse_mm" in ln)
    assert "A better" in row and "+0.05" in row  # B's rmse 0.05 higher on every run: lower is better
    frac = next(ln for ln in r.stdout.splitlines() if "reconstructed_fraction" in ln)
    assert "no detectable difference" in frac


@pytest.mark.parametrize("args, says, cli", [
    (["compare", "scenarios/quickstart.toml"], "needs --a FIELD=VALUE", _cli),  # the real command line once
    (["compare", "scenarios/quickstart.toml", "--a", "seed=0", "--b", "seed=0"], "the same configuration", _cli_here),
    (["compare", "scenarios/quickstart.toml", "scenarios/nope.duckdb"], "compare two of the same kind", _cli_here),
    (["compare", "scenarios/quickstart.toml", "--a", "sensor.exposure_ms=-1"], "sensor.exposure_ms", _cli_here),
], ids=["no-overrides-process", "same-configuration", "mixed-kinds", "bad-field"])
def test_bad_compare_input_is_one_line_and_exit_2(args, says, cli):
    r = cli(*args)
    assert r.returncode == 2, r.stdout + r.stderr
    assert says in r.stderr and "Traceback" not in r.stderr


def test_run_seeds_refuses_a_folder_it_did_not_write(tmp_path):
    (tmp_path / "mine.txt").write_text("keep")
    r = _cli_here("run", "scenarios/quickstart.toml", "--seeds", "2", "--out", str(tmp_path))
    assert r.returncode == 2 and "was not written by simbench" in r.stderr
    assert (tmp_path / "mine.txt").read_text() == "keep" and sorted(p.name for p in tmp_path.iterdir()) == ["mine.txt"]
