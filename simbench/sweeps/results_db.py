"""Sweep results that are never lost: result files, Parquet per-frame tables, DuckDB.

Layout next to the database file ``DB`` (e.g. ``out/sweeps/NAME/results.duckdb``)::

    results/<run_id>.json      one finished run (ok or failed): the commit marker
    frames/<run_id>.parquet    per-frame table of that run (marker error per frame)
    runs/<run_id>/             the run's outputs (videos, report.md, contact sheet)
    claims/<run_id>.json       a run being computed, and by which process (RunClaims)
    results.duckdb             tables ``sweeps``, ``runs`` and ``metrics`` (long form)

Writes are atomic per run, so a sweep killed with SIGKILL never leaves a half-recorded
run: the Parquet file and then the JSON are written to temporary names and renamed
into place (``os.replace``); only then is the run ingested into DuckDB in one
transaction (delete + insert by ``run_id``, so ingesting twice changes nothing). The
JSON files are the source of truth: :meth:`ResultsDB.reconcile` ingests any the
database does not hold yet, which is what a resumed sweep does first.

Only one process (the sweep's parent) writes; it opens DuckDB for each ingest and
closes it again, so ``simbench report`` can read the database between runs.
"""

from __future__ import annotations

import json
import math
import os
import socket
import time
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import TYPE_CHECKING, Iterable, Iterator

import duckdb
import pyarrow as pa
import pyarrow.parquet as pq

from mocap.atomic_files import atomic_write_bytes
from simbench.errors import SimbenchInputError
from simbench.output_dir import pid_alive, remove_stale_partials

if TYPE_CHECKING:  # pragma: no cover - typing only
    # pandas is imported where a table is built (duckdb's .df() imports it itself): a sweep's or a
    # check's worker processes import this module for RunRecord and never build one (pandas is
    # about 0.7 CPU-s of their start-up on a busy 2-core machine)
    import pandas as pd

STATUS_OK = "ok"
STATUS_FAILED = "failed"

SCHEMA = """
CREATE TABLE IF NOT EXISTS sweeps (
    sweep VARCHAR PRIMARY KEY,
    sweep_file VARCHAR,
    spec JSON,              -- the validated sweep file
    factor_levels JSON,     -- {factor: [level, ...]} in file order (report axes)
    n_runs INTEGER,
    updated_at TIMESTAMP
);
CREATE TABLE IF NOT EXISTS runs (
    run_id VARCHAR PRIMARY KEY,   -- hash of the scenario content hash + overrides
    sweep VARCHAR,
    run_index INTEGER,            -- position in the sweep's expansion
    scenario VARCHAR,             -- scenario name
    scenario_hash VARCHAR,        -- content hash of the resolved scenario
    factors JSON,                 -- {factor: level}
    parameters JSON,              -- {dotted field: value}: every override of the run
    status VARCHAR,               -- 'ok' | 'failed'
    error VARCHAR,
    started_at TIMESTAMP,
    ended_at TIMESTAMP,
    duration_s DOUBLE,
    timings JSON,                 -- {phase: seconds}
    versions JSON,                -- {package: version}
    worker VARCHAR,               -- host:pid that ran it
    out_dir VARCHAR,              -- run outputs, relative to the database's folder
    frames_file VARCHAR,          -- per-frame Parquet, relative to the database's folder
    warnings JSON                 -- distinct warnings the run raised (file:line: category: message)
);
ALTER TABLE runs ADD COLUMN IF NOT EXISTS warnings JSON;  -- databases written before the column existed
CREATE TABLE IF NOT EXISTS metrics (
    run_id VARCHAR,
    metric VARCHAR,
    value DOUBLE,
    PRIMARY KEY (run_id, metric)
);
"""


@dataclass
class RunRecord:
    """One finished run (``status`` ok or failed), as a worker returns it.

    ``per_frame`` (not part of the JSON; stored as Parquet) is a long table with
    columns ``frame, time_s, marker, error_mm, views_visible, reconstructed, filled``.
    """

    run_id: str
    sweep: str
    run_index: int
    scenario: str
    scenario_hash: str
    factors: dict[str, object]
    parameters: dict[str, object]
    status: str
    error: str = ""
    started_at: float = 0.0
    ended_at: float = 0.0
    timings: dict[str, float] = field(default_factory=dict)
    versions: dict[str, str] = field(default_factory=dict)
    worker: str = ""
    out_dir: str = ""
    frames_file: str = ""
    warnings: list[str] = field(default_factory=list)
    metrics: dict[str, float] = field(default_factory=dict)
    per_frame: pa.Table | None = None

    @property
    def duration_s(self) -> float:
        return self.ended_at - self.started_at

    def to_json_dict(self) -> dict:
        d = asdict(self)
        d.pop("per_frame")
        d["metrics"] = {k: _json_float(v) for k, v in self.metrics.items()}
        return d

    @classmethod
    def from_json_dict(cls, d: dict) -> "RunRecord":
        d = dict(d)
        d["metrics"] = {k: (math.nan if v is None else float(v)) for k, v in d.get("metrics", {}).items()}
        return cls(**d)


def _json_float(v) -> float | None:
    v = float(v)
    return v if math.isfinite(v) else None


class ResultStore:
    """The per-run files next to the database (``results/``, ``frames/``, ``runs/``)."""

    def __init__(self, root: str | Path) -> None:
        self.root = Path(root)
        self.results_dir = self.root / "results"
        self.frames_dir = self.root / "frames"
        self.runs_dir = self.root / "runs"

    def result_path(self, run_id: str) -> Path:
        return self.results_dir / f"{run_id}.json"

    def frames_path(self, run_id: str) -> Path:
        return self.frames_dir / f"{run_id}.parquet"

    def run_dir(self, run_id: str) -> Path:
        return self.runs_dir / run_id

    def write(self, record: RunRecord) -> None:
        """Store one run atomically: Parquet first, then the JSON that commits it."""
        if record.per_frame is not None and record.per_frame.num_rows:
            sink = pa.BufferOutputStream()
            pq.write_table(record.per_frame, sink)
            self.frames_dir.mkdir(parents=True, exist_ok=True)
            atomic_write_bytes(self.frames_path(record.run_id), sink.getvalue().to_pybytes(), fsync=True)
            record.frames_file = str(self.frames_path(record.run_id).relative_to(self.root))
        self.results_dir.mkdir(parents=True, exist_ok=True)
        atomic_write_bytes(self.result_path(record.run_id),
                           json.dumps(record.to_json_dict(), indent=1, sort_keys=True).encode(), fsync=True)

    def read(self, run_id: str) -> RunRecord | None:
        p = self.result_path(run_id)
        return RunRecord.from_json_dict(json.loads(p.read_text())) if p.is_file() else None

    def read_all(self) -> list[RunRecord]:
        if not self.results_dir.is_dir():
            return []
        return [RunRecord.from_json_dict(json.loads(p.read_text())) for p in sorted(self.results_dir.glob("*.json"))]

    def remove_temporaries(self) -> int:
        """Delete half-written files and run folders a killed sweep left behind; return how many."""
        n = 0
        # A temporary file is written and renamed within milliseconds: one older than a
        # minute was left by a killed process; a younger one may be another sweep's (on
        # the same database) being written right now.
        cutoff = time.time() - 60.0
        for d in (self.results_dir, self.frames_dir):
            if d.is_dir():
                for p in d.glob(".*.tmp"):
                    try:
                        if p.stat().st_mtime < cutoff:
                            p.unlink()
                            n += 1
                    except FileNotFoundError:
                        pass
        # Partial run folders only when their writer is gone (another sweep on the same
        # database may be writing its own right now): simbench.output_dir's rule.
        n += len(remove_stale_partials(self.runs_dir))
        return n

    def statuses(self) -> dict[str, str]:
        """``{run_id: status}`` of every stored run."""
        return {r.run_id: r.status for r in self.read_all()}


class RunClaims:
    """Which process computes which run, when several sweeps share one database folder.

    ``claims/<run_id>.json`` (host and pid) is created with ``O_CREAT | O_EXCL``: exactly
    one process gets it. A claim whose process is gone (same host, pid no longer exists)
    is taken over; a claim from another host is respected. Claims are released when the
    run's result is stored, and all at once when the sweep ends (also when interrupted).
    Taking over a stale claim is not strictly exclusive (two processes may both see it
    stale at the same instant); the cost is one run computed twice, which ingesting by
    ``run_id`` makes harmless.
    """

    def __init__(self, root: str | Path) -> None:
        self.dir = Path(root) / "claims"
        self.held: set[str] = set()
        self._me = {"host": socket.gethostname(), "pid": os.getpid()}

    def _path(self, run_id: str) -> Path:
        return self.dir / f"{run_id}.json"

    def _stale(self, path: Path) -> bool:
        try:
            owner = json.loads(path.read_text())
            host, pid = owner["host"], int(owner["pid"])
        except (OSError, ValueError, KeyError, TypeError):
            return False  # being written right now, or unreadable: respect it
        return host == self._me["host"] and not pid_alive(pid)

    def claim(self, run_id: str) -> bool:
        """Take ``run_id`` for this process; False when another live process holds it."""
        self.dir.mkdir(parents=True, exist_ok=True)
        path = self._path(run_id)
        for _ in range(2):
            try:
                fd = os.open(path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
            except FileExistsError:
                if not self._stale(path):
                    return False
                path.unlink(missing_ok=True)
                continue
            with os.fdopen(fd, "w") as fh:
                json.dump(self._me, fh)
            self.held.add(run_id)
            return True
        return False

    def release(self, run_id: str) -> None:
        if run_id in self.held:
            self._path(run_id).unlink(missing_ok=True)
            self.held.discard(run_id)

    def release_all(self) -> None:
        for run_id in list(self.held):
            self.release(run_id)


def _ts(epoch: float) -> datetime | None:
    return datetime.fromtimestamp(epoch, tz=timezone.utc).replace(tzinfo=None) if epoch else None


def _require_own_folder(path: Path) -> None:
    """Refuse a database whose folder holds another one (:class:`SimbenchInputError` naming the fix).

    The per-run files (``results/``, ``frames/``, ``runs/``) belong to the folder, not to a
    database, and every sweep first ingests the result files its folder holds: two databases
    in one folder each take in the other's runs. Three shirt seed sweeps given databases in one
    folder made each database hold all three sweeps, and a seed table over them counted every
    seed three times."""
    if not path.parent.is_dir():
        return
    others = sorted(p.name for p in path.parent.glob("*.duckdb") if p.name != path.name)
    if others:
        raise SimbenchInputError(
            f"{path}: this folder also holds the results database {', '.join(others)}, and the result files next to "
            f"a database (results/, frames/, runs/) belong to its folder, so each would take in the other's runs; "
            f"give each database its own folder, e.g. --db {path.parent / path.stem / 'results.duckdb'}")


class ResultsDB:
    """The DuckDB database of a sweep folder, plus its :class:`ResultStore` (one database a folder)."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        _require_own_folder(self.path)
        self.store = ResultStore(self.path.parent)

    @contextmanager
    def connect(self, read_only: bool = False, retries: int = 20) -> Iterator[duckdb.DuckDBPyConnection]:
        """Open the database (retrying while another process holds its lock); close it after."""
        if not read_only:
            self.path.parent.mkdir(parents=True, exist_ok=True)
        delay = 0.05
        for attempt in range(retries + 1):
            try:
                con = duckdb.connect(str(self.path), read_only=read_only)
                break
            except duckdb.IOException:
                if attempt == retries:
                    raise
                time.sleep(delay)
                delay = min(1.0, delay * 2)
        try:
            if not read_only:
                con.execute(SCHEMA)
            yield con
        finally:
            con.close()

    # ------------------------------------------------------------------ writes
    def record_sweep(self, sweep: str, sweep_file: str, spec: dict, factor_levels: dict[str, list], n_runs: int) -> None:
        with self.connect() as con:
            con.execute("BEGIN TRANSACTION")
            con.execute("DELETE FROM sweeps WHERE sweep = ?", [sweep])
            con.execute("INSERT INTO sweeps VALUES (?, ?, ?, ?, ?, ?)",
                        [sweep, sweep_file, json.dumps(spec, default=str), json.dumps(factor_levels, default=str),
                         n_runs, datetime.now(timezone.utc).replace(tzinfo=None)])
            con.execute("COMMIT")

    def ingest(self, records: Iterable[RunRecord]) -> int:
        """Insert or replace runs, each in its own transaction; return how many."""
        n = 0
        with self.connect() as con:
            for r in records:
                con.execute("BEGIN TRANSACTION")
                try:
                    con.execute("DELETE FROM metrics WHERE run_id = ?", [r.run_id])
                    con.execute("DELETE FROM runs WHERE run_id = ?", [r.run_id])
                    con.execute(
                        "INSERT INTO runs VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                        [r.run_id, r.sweep, r.run_index, r.scenario, r.scenario_hash,
                         json.dumps(r.factors, default=str), json.dumps(r.parameters, default=str),
                         r.status, r.error, _ts(r.started_at), _ts(r.ended_at), r.duration_s,
                         json.dumps(r.timings), json.dumps(r.versions), r.worker, r.out_dir, r.frames_file,
                         json.dumps(r.warnings)])
                    rows = [(r.run_id, k, float(v)) for k, v in sorted(r.metrics.items())]
                    if rows:
                        con.executemany("INSERT INTO metrics VALUES (?, ?, ?)", rows)
                    con.execute("COMMIT")
                except BaseException:
                    con.execute("ROLLBACK")
                    raise
                n += 1
        return n

    def reconcile(self) -> int:
        """Ingest every result file the database lacks or holds differently; return how many."""
        records = self.store.read_all()
        if not records:
            return 0
        have = self.run_states()

        def stale(r: RunRecord) -> bool:
            st = have.get(r.run_id)
            return st is None or st[0] != r.status or abs(st[1] - r.ended_at) > 2e-3

        todo = [r for r in records if stale(r)]
        return self.ingest(todo) if todo else 0

    # ------------------------------------------------------------------ reads
    def run_states(self) -> dict[str, tuple[str, float]]:
        """``{run_id: (status, ended_at as epoch seconds)}`` of the runs in the database."""
        if not self.path.exists():
            return {}
        with self.connect(read_only=True) as con:
            if not _has_table(con, "runs"):
                return {}
            rows = con.execute("SELECT run_id, status, epoch_ms(ended_at) FROM runs").fetchall()
        return {rid: (st, (ms / 1000.0 if ms is not None else 0.0)) for rid, st, ms in rows}

    def runs(self, sweep: str | None = None) -> pd.DataFrame:
        """One row per run; ``factors``, ``parameters``, ``timings``, ``versions`` parsed from JSON."""
        with self.connect(read_only=True) as con:
            q = "SELECT * FROM runs" + (" WHERE sweep = ?" if sweep else "") + " ORDER BY sweep, run_index"
            df = con.execute(q, [sweep] if sweep else []).df()
        for col, empty in (("factors", dict), ("parameters", dict), ("timings", dict), ("versions", dict), ("warnings", list)):
            if col not in df:  # a database written before the column existed, opened read-only
                df[col] = [empty() for _ in range(len(df))]
            else:
                df[col] = df[col].map(lambda s, empty=empty: json.loads(s) if isinstance(s, str) else empty())
        return df

    def metrics_long(self, sweep: str | None = None) -> pd.DataFrame:
        with self.connect(read_only=True) as con:
            q = ("SELECT m.run_id, m.metric, m.value FROM metrics m JOIN runs r USING (run_id)"
                 + (" WHERE r.sweep = ?" if sweep else "") + " ORDER BY r.run_index, m.metric")
            return con.execute(q, [sweep] if sweep else []).df()

    def metrics_wide(self, sweep: str | None = None) -> pd.DataFrame:
        """One row per run: run columns, one column per factor, one per metric."""
        runs = self.runs(sweep)
        long = self.metrics_long(sweep)
        import pandas as pd

        wide = long.pivot(index="run_id", columns="metric", values="value") if len(long) else pd.DataFrame(index=pd.Index([], name="run_id"))
        factors = pd.DataFrame([dict(f) for f in runs["factors"]], index=runs["run_id"])
        base = runs.set_index("run_id")[["sweep", "run_index", "scenario", "status", "error", "duration_s", "out_dir"]]
        return base.join(factors).join(wide).reset_index()

    def sweeps(self) -> pd.DataFrame:
        with self.connect(read_only=True) as con:
            df = con.execute("SELECT * FROM sweeps ORDER BY sweep").df()
        df["factor_levels"] = df["factor_levels"].map(json.loads)
        df["spec"] = df["spec"].map(json.loads)
        return df

    def per_frame(self, run_ids: Iterable[str] | None = None) -> pd.DataFrame:
        """The per-frame tables of the given runs (all when None) with a ``run_id`` column."""
        ids = set(run_ids) if run_ids is not None else None
        files = sorted(self.store.frames_dir.glob("*.parquet")) if self.store.frames_dir.is_dir() else []
        files = [f for f in files if ids is None or f.stem in ids]
        if not files:
            import pandas as pd

            return pd.DataFrame(columns=["run_id", "frame", "time_s", "marker", "error_mm", "views_visible", "reconstructed", "filled"])
        con = duckdb.connect()
        try:
            return con.execute("SELECT * FROM read_parquet(?, filename = true)", [[str(f) for f in files]]).df() \
                .assign(run_id=lambda d: d["filename"].map(lambda s: Path(s).stem)).drop(columns="filename")
        finally:
            con.close()


def _has_table(con: duckdb.DuckDBPyConnection, name: str) -> bool:
    return bool(con.execute("SELECT count(*) FROM information_schema.tables WHERE table_name = ?", [name]).fetchone()[0])
