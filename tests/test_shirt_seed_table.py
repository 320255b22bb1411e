"""`simbench shirt seed-table`: the colour shirt's seed table read from sweep results databases."""

from __future__ import annotations

import math

import pytest
from typer.testing import CliRunner

from simbench.cli.app import app
from simbench.errors import SimbenchInputError
from simbench.sweeps.results_db import STATUS_FAILED, STATUS_OK, ResultsDB, RunRecord
from simbench.sweeps.shirt_table import read_seed_rows, seed_table_markdown, summarise

# (seed, full cm, baseline cm) per scenario; seed 4 of the office failed and must be left out
_OFFICE = [(1, 1.5, 2.0), (2, 2.0, 2.4), (3, 8.0, 9.0), (4, math.nan, math.nan)]
_OUTDOOR = [(1, 1.0, 20.0), (2, 3.0, 2.0)]


def _db(path, scenario: str, runs) -> None:
    db = ResultsDB(path)
    records = []
    for i, (seed, full, base) in enumerate(runs):
        status = STATUS_FAILED if math.isnan(full) else STATUS_OK
        metrics = {} if math.isnan(full) else {"shirt.joint_rmse_cm": full, "shirt.baseline_joint_rmse_cm": base, "shirt.ms_per_frame": 30.0}
        records.append(RunRecord(f"{scenario}{seed}", f"seeds_{scenario}", i, scenario, "h", {"seed": seed}, {"seed": seed}, status,
                                 metrics=metrics))
    db.ingest(records)


@pytest.fixture
def dbs(tmp_path):
    a, b = tmp_path / "office" / "results.duckdb", tmp_path / "outdoor" / "results.duckdb"  # one database a folder
    _db(a, "shirt_office", _OFFICE)
    _db(b, "shirt_outdoor", _OUTDOOR)
    return a, b


def test_summary_counts_seeds_medians_and_shares(dbs):
    rows = read_seed_rows(list(dbs))
    assert [(r.scenario, r.seed) for r in rows] == [("shirt_office", 1), ("shirt_office", 2), ("shirt_office", 3),
                                                    ("shirt_outdoor", 1), ("shirt_outdoor", 2)]
    office, outdoor = summarise(rows)
    assert office.n_seeds == 3 and office.median_full_cm == 2.0 and office.median_baseline_cm == 2.4
    # <= 4 cm: seeds 1 and 2; >= 20 % better (full <= 0.8 baseline): only seed 1 (1.5 <= 1.6; 2.0 > 1.92; 8.0 > 7.2)
    assert office.share_good == pytest.approx(2 / 3) and office.share_better == pytest.approx(1 / 3)
    assert (office.worst_seed, office.worst_full_cm) == (3, 8.0)
    assert outdoor.share_good == 1.0 and outdoor.share_better == 0.5 and outdoor.median_full_cm == 2.0
    # The paired comparison `simbench compare` makes, baseline (A) against full (B): differences
    # full - baseline per seed -0.5, -0.4, -1.0 on the office (mean -0.6333), 3 pairs only.
    c = office.comparison
    assert c.n_pairs == 3 and c.diff_mean == pytest.approx(-1.9 / 3) and c.better == "lower"
    assert c.diffs == pytest.approx((-0.5, -0.4, -1.0))
    assert c.p_value == pytest.approx(0.25)  # exact two-sided Wilcoxon, all three of one sign: 2 / 2**3
    assert c.verdict == "no detectable difference at this N"


def test_table_carries_the_paired_comparison_and_its_verdict(tmp_path):
    # 12 seeds where the full method is 1 cm better every time, within noise
    runs = [(s, 2.0 + 0.05 * s, 3.0 + 0.05 * s + 0.01 * (s % 3)) for s in range(1, 13)]
    _db(tmp_path / "o.duckdb", "shirt_office", runs)
    rows = read_seed_rows([tmp_path / "o.duckdb"])
    (office,) = summarise(rows)
    assert office.comparison.verdict == "B better" and office.comparison.ci_high < 0
    text = seed_table_markdown(rows)
    assert "| Wilcoxon p, verdict | " in text and "full better" in text
    assert "| full - baseline, mean (95 % CI) | -1.0" in text


def test_markdown_has_a_row_per_seed_bold_failures_and_blank_missing_cells(dbs):
    text = seed_table_markdown(read_seed_rows(list(dbs)))
    lines = text.splitlines()
    assert lines[0] == "| seed | shirt_office | shirt_outdoor |"
    assert "| 3 | **8.00** / 9.00 |  |" in lines
    assert "| 1 | 1.50 / 2.00 | 1.00 / 20.00 |" in lines
    assert "| full >= 20 % better | 33 % | 50 % |" in lines


def test_cli_prints_and_writes_the_table_and_refuses_a_missing_database(dbs, tmp_path):
    out = tmp_path / "table.md"
    res = CliRunner().invoke(app, ["shirt", "seed-table", str(dbs[0]), str(dbs[1]), "--out", str(out)])
    assert res.exit_code == 0, res.output
    assert out.read_text() in res.output and "| median | 2.00 / 2.40 | 2.00 / 11.00 |" in out.read_text()
    res = CliRunner().invoke(app, ["shirt", "seed-table", str(tmp_path / "nope.duckdb")])
    assert res.exit_code == 2 and "nope.duckdb: no results database there" in res.output


def test_a_database_without_shirt_runs_is_refused(tmp_path):
    db = ResultsDB(tmp_path / "m.duckdb")
    db.ingest([RunRecord("x", "s", 0, "quickstart", "h", {"seed": 1}, {}, STATUS_OK, metrics={"marker.rmse_mm": 1.0})])
    with pytest.raises(SimbenchInputError, match="no colour-shirt seed runs"):
        read_seed_rows([tmp_path / "m.duckdb"])


def test_out_replaces_a_seed_table_but_never_a_file_of_the_users(dbs, tmp_path):
    out = tmp_path / "table.md"
    out.write_text("| seed | an older table |\n")
    res = CliRunner().invoke(app, ["shirt", "seed-table", str(dbs[0]), "--out", str(out)])
    assert res.exit_code == 0, res.output
    assert "| median |" in out.read_text()
    notes = tmp_path / "notes.md"
    notes.write_text("my notes\n")
    res = CliRunner().invoke(app, ["shirt", "seed-table", str(dbs[0]), "--out", str(notes)])
    assert res.exit_code == 2 and notes.read_text() == "my notes\n"
    assert f"{notes}: exists and is not a seed table written by simbench; it will not be replaced" in res.output
    assert len(res.output.strip().splitlines()) == 1 and "| seed |" not in res.output  # refused before anything ran
