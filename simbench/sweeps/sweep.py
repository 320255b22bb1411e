"""Scenario sweeps: a grid or a seeded random sample over any scenario fields.

The sweep file (its format, with an example), its loading and its expansion into runs are in
:mod:`simbench.sweeps.sweep_file` (importable from here too). Every run is validated
before anything renders: a bad field names the sweep file, the factor, the value and
what the scenario schema allows. Each run has a stable id: a hash
of the resolved scenario's content hash and its overrides, so ``--resume`` knows what is
done.

Runs execute in worker processes (``spawn``: each makes its own off-screen GL
context) on a local process pool, or on a Dask distributed cluster
(``scheduler="tcp://HOST:PORT"``; workers should run one thread each, e.g.
``dask worker tcp://HOST:PORT --nthreads 1``, and see the same file system for run
outputs). A run that raises is recorded as failed with its error and the sweep goes
on. Results are stored by :mod:`simbench.sweeps.results_db`.
"""

from __future__ import annotations

import concurrent.futures as cf
import concurrent.futures.process as cf_process
import ctypes
import multiprocessing
import os
import platform
import signal
import socket
import sys
import threading
import time
import traceback
import warnings
from dataclasses import dataclass, field
from importlib import metadata
from pathlib import Path
from typing import Callable, Iterator, Literal

import duckdb
import numpy as np
import pyarrow as pa

from eval.marker_metrics import per_marker_error_mm
from simbench import interrupts
from simbench.errors import SimbenchInputError
from simbench.sweeps.results_db import STATUS_FAILED, STATUS_OK, ResultsDB, RunClaims, RunRecord
# the sweep file (schema, loading, expansion into runs), importable from here too
from simbench.sweeps.sweep_file import Factor, RunSpec, Sweep, SweepSpec, display_value, expand, flatten_dotted, load_sweep, run_id_for  # noqa: F401

VERSION_PACKAGES = ("simbench", "numpy", "scipy", "mujoco", "opencv-python-headless", "pydantic", "filterpy",
                    "pin", "pyrender2", "PyOpenGL", "duckdb", "dask", "distributed")


# ---------------------------------------------------------------------------- one run (worker side)
@dataclass(frozen=True)
class RunTask:
    """What a worker needs: the run and where its outputs go (None: no outputs written)."""

    spec: RunSpec
    out_dir: str | None = None
    #: Gaussian noise (px, SD per axis) added to every 2D detection before the pipeline: an injected
    #: regression of `simbench check --calibrate`, not a scenario field (0: the run as the scenario says).
    detection_noise_px: float = 0.0


# One GL-rendering run at a time per process: Dask workers may run tasks on several
# threads, and the off-screen GL context must not be shared between concurrent runs.
_RUN_LOCK = threading.Lock()


def package_versions() -> dict[str, str]:
    out = {"python": platform.python_version()}
    for name in VERSION_PACKAGES:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            pass
    return out


def per_frame_table(result):
    """Long per-frame marker table of a run (``None`` without markers)."""
    cap = result.capture
    if cap is None:
        return None
    gt = result.sequence.ground_truth
    traj = cap.trajectories
    idx = [traj.labels.index(n) for n in gt.marker_names]
    err = per_marker_error_mm(traj.xyz[:, idx], gt.markers_3d)  # (F, M)
    F, M = err.shape
    filled = traj.filled[:, idx] if traj.filled is not None else np.zeros((F, M), bool)
    return pa.table({
        "frame": np.repeat(np.arange(F, dtype=np.int32), M),
        "time_s": np.repeat(np.asarray(gt.times, float), M),
        "marker": np.tile(np.asarray(gt.marker_names, dtype=object), F),
        "error_mm": err.reshape(-1),
        "views_visible": np.asarray(gt.marker_visible).sum(axis=1).astype(np.int16).reshape(-1),
        "reconstructed": np.isfinite(err).reshape(-1),
        "filled": np.asarray(filled, bool).reshape(-1),
    })


def _record(spec: RunSpec, status: str, **kw) -> RunRecord:
    return RunRecord(run_id=spec.run_id, sweep=spec.sweep, run_index=spec.index, scenario=spec.scenario.name,
                     scenario_hash=spec.scenario.content_hash(), factors=dict(spec.factors),
                     parameters={k: v for k, v in spec.overrides.items()}, status=status, **kw)


def execute_run(task: RunTask) -> RunRecord:
    """Run one scenario in this (worker) process; never raises for a failing run."""
    worker = f"{socket.gethostname()}:{os.getpid()}"
    versions = package_versions()
    # One run at a time per process (lock); warnings are kept with the run, not printed
    # over the sweep's progress bar.
    with _RUN_LOCK, warnings.catch_warnings(record=True) as caught:
        started = time.time()
        warnings.simplefilter("always")
        try:
            from simbench.pipelines.run import run_scenario  # MuJoCo and GL load in the workers only

            result = run_scenario(task.spec.scenario, task.out_dir, write_outputs=task.out_dir is not None,
                                  detection_noise_px=task.detection_noise_px)
            metrics = {k: float(v) for k, v in result.metrics.items()}
            # A stage that failed after rendering (e.g. an export) fails the run; its
            # metrics are kept with it (simbench.pipelines.run: a run never loses its metrics).
            status, error = STATUS_OK, ""
            if not result.ok:
                status = STATUS_FAILED
                error = "; ".join(f.line() for f in result.failures) + "\n" + "\n".join(f.detail for f in result.failures)
            return _record(task.spec, status, error=error, started_at=started, ended_at=time.time(),
                           timings=dict(result.timings_s), versions=versions, worker=worker, out_dir=task.out_dir or "",
                           metrics=metrics, per_frame=per_frame_table(result), warnings=_distinct(caught))
        except Exception as exc:  # a failing run is recorded, the sweep goes on
            interrupts.raise_if_pending(exc)
            tb = traceback.format_exc(limit=-6)
            return _record(task.spec, STATUS_FAILED, error=f"{type(exc).__name__}: {exc}\n{tb}", started_at=started,
                           ended_at=time.time(), versions=versions, worker=worker, warnings=_distinct(caught))


def _distinct(caught: list[warnings.WarningMessage], limit: int = 20) -> list[str]:
    out: list[str] = []
    for w in caught:
        s = f"{Path(w.filename).name}:{w.lineno}: {w.category.__name__}: {w.message}"
        if s not in out:
            out.append(s)
    return out[:limit]


# ---------------------------------------------------------------------------- executors
def default_workers() -> int:
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not Linux
        return max(1, os.cpu_count() or 1)


# Seconds a pool worker has, after SIGTERM, to remove its partial output folder and exit
# before SIGALRM (default action: end the process) does it.
WORKER_EXIT_S = 10


def _pool_execute(task: RunTask) -> RunRecord:
    """:func:`execute_run` in a local pool worker. A worker stopped by SIGTERM exits once
    the run has unwound (its partial output folder removed), rather than take the next
    run from the pool's queue; SIGALRM ends it after ``WORKER_EXIT_S`` whatever happens."""
    try:
        record = execute_run(task)
    except interrupts.Interrupted:
        os._exit(128 + signal.SIGTERM)
    if interrupts.pending() is not None:  # the signal was caught as a failure on its way out
        os._exit(128 + signal.SIGTERM)
    return record


def _worker_sigterm(signum, frame) -> None:
    signal.alarm(WORKER_EXIT_S)
    f = frame
    while f is not None and f.f_code is not _pool_execute.__code__:
        f = f.f_back
    if f is None:  # idle between runs: nothing to clean up
        os._exit(128 + signal.SIGTERM)
    interrupts.stop(signum)  # records it, ignores later SIGTERMs, raises Interrupted


def _worker_init(parent_pid: int) -> None:
    """Start-up of a local pool worker: it never outlives the sweep's parent process.

    Ctrl-C in a terminal reaches the whole process group; the parent decides (it stops
    the workers with SIGTERM), so workers ignore SIGINT. SIGTERM unwinds the run in
    progress (partial outputs removed) and ends the worker within ``WORKER_EXIT_S``. On
    Linux the kernel sends SIGTERM when the parent dies, even by SIGKILL
    (``prctl(PR_SET_PDEATHSIG)``, via ctypes: the standard library has no binding);
    elsewhere a watchdog thread polls the parent's pid.
    """
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, _worker_sigterm)
    interrupts.quiet_unraisable()
    armed = False
    if sys.platform.startswith("linux"):
        try:
            pr_set_pdeathsig = 1
            armed = ctypes.CDLL(None, use_errno=True).prctl(pr_set_pdeathsig, int(signal.SIGTERM), 0, 0, 0) == 0
        except (OSError, AttributeError):
            armed = False
    if os.getppid() != parent_pid:  # the parent died before the line above took effect
        os._exit(1)
    if not armed:
        def watchdog() -> None:
            while os.getppid() == parent_pid:
                time.sleep(1.0)
            os.kill(os.getpid(), signal.SIGTERM)

        threading.Thread(target=watchdog, name="simbench-parent-watchdog", daemon=True).start()


def _stop_workers(pool: cf.ProcessPoolExecutor) -> None:
    """Stop a pool now (interrupted sweep): no further runs start; each worker gets SIGTERM
    (it removes its partial output and exits), SIGKILL if still alive after ``WORKER_EXIT_S``."""
    procs = list((getattr(pool, "_processes", None) or {}).values())  # no public API before Python 3.14
    pool.shutdown(wait=False, cancel_futures=True)
    for p in procs:
        if p.is_alive():
            p.terminate()
    deadline = time.monotonic() + WORKER_EXIT_S
    for p in procs:
        p.join(max(0.0, deadline - time.monotonic()))
        if p.is_alive():
            p.kill()
            p.join(1.0)


def _join_manager_thread(pool: cf.ProcessPoolExecutor, timeout_s: float = 30.0) -> None:
    """Wait for a stopped pool's manager thread to finish closing its wake-up pipe.

    Python 3.11's exit hook (``concurrent.futures.process._python_exit``) writes to every
    live pool's wake-up pipe without the lock the manager thread closes it under; if the
    interpreter exits while that thread is still closing it, the hook prints an
    ``OSError: [Errno 9] Bad file descriptor`` traceback after the interrupt line (seen in
    CI in session 15, and again in session 27's fresh-clone run, when a 5 s wait was not
    enough on a loaded machine). Once the thread has ended the pipe is marked closed and
    the hook skips it; the workers are dead by now, so it ends as soon as it runs. A thread
    still alive after ``timeout_s`` is taken out of the hook's list, so that the hook does
    not write to the pipe it may be closing (the interpreter still joins it at exit).
    """
    thread = getattr(pool, "_executor_manager_thread", None)  # no public API
    if thread is not None and thread.is_alive():
        thread.join(timeout_s)
        if thread.is_alive():
            cf_process._threads_wakeups.pop(thread, None)  # no public API either


def iter_local(tasks: list[RunTask], workers: int, claim: Callable[[RunTask], bool] | None = None) -> Iterator[RunRecord]:
    """Run tasks on a spawn process pool, ``workers`` at a time; yield records as they finish.

    If a worker process dies (e.g. a crash in the GL driver), the runs it had in flight
    are recorded as failed and the pool is restarted for the rest. Workers die with the
    parent (:func:`_worker_init`); an interrupted sweep stops them (:func:`_stop_workers`).
    ``claim(task)`` is asked just before a task is submitted; False skips it (another
    process is computing it).
    """
    pending = list(reversed(tasks))
    ctx = multiprocessing.get_context("spawn")
    while pending:
        pool = cf.ProcessPoolExecutor(max_workers=workers, mp_context=ctx, initializer=_worker_init,
                                      initargs=(os.getpid(),))
        inflight: dict[cf.Future, RunTask] = {}
        broken = False
        finished = False
        try:
            while pending or inflight:
                while pending and len(inflight) < workers and not broken:
                    t = pending.pop()
                    if claim is not None and not claim(t):
                        continue
                    inflight[pool.submit(_pool_execute, t)] = t
                if not inflight:
                    break
                done, _ = cf.wait(inflight, return_when=cf.FIRST_COMPLETED)
                interrupts.raise_if_pending()
                for fut in done:
                    t = inflight.pop(fut)
                    try:
                        yield fut.result()
                    except cf.process.BrokenProcessPool as exc:
                        broken = True
                        yield _record(t.spec, STATUS_FAILED, error=f"worker process died: {exc}",
                                      started_at=time.time(), ended_at=time.time())
                if broken and not inflight:
                    break
            finished = True
        finally:
            # Interrupted (Ctrl-C, SIGTERM, consumer stopped): stop the runs in flight.
            if not finished:
                _stop_workers(pool)
            pool.shutdown(wait=finished, cancel_futures=True)
            if not finished:
                _join_manager_thread(pool)


def iter_dask(tasks: list[RunTask], scheduler: str) -> Iterator[RunRecord]:
    """Run tasks on a Dask distributed cluster; yield records as they finish."""
    from distributed import Client, as_completed  # a Dask cluster only when --scheduler asks for one

    try:
        client = Client(scheduler, timeout="20s")
    except (OSError, TimeoutError) as exc:
        raise SimbenchInputError(f"--scheduler {scheduler}: cannot connect ({exc}); start one with "
                                 f"`dask scheduler` and `dask worker {scheduler} --nthreads 1`") from None
    try:
        futures = {client.submit(execute_run, t, pure=False, key=f"simbench-run-{t.spec.run_id}-{time.time_ns()}"): t
                   for t in tasks}
        for fut in as_completed(list(futures)):
            t = futures[fut]
            try:
                yield fut.result()
            except Exception as exc:  # e.g. KilledWorker: the worker died running it
                yield _record(t.spec, STATUS_FAILED, error=f"{type(exc).__name__}: {exc}",
                              started_at=time.time(), ended_at=time.time())
    finally:
        client.close()


def iter_records(tasks: list[RunTask], workers: int | None = None, scheduler: str | None = None,
                 claim: Callable[[RunTask], bool] | None = None) -> Iterator[RunRecord]:
    """Records of ``tasks`` as they finish (local pool, or Dask with ``scheduler``); tasks
    for which ``claim`` says False are skipped (locally just before each is started, on
    Dask all at the start)."""
    if scheduler and claim is not None:
        tasks = [t for t in tasks if claim(t)]
    if not tasks:
        return iter(())
    if scheduler:
        return iter_dask(tasks, scheduler)
    return iter_local(tasks, min(workers or default_workers(), len(tasks)), claim)


# ---------------------------------------------------------------------------- a whole sweep
@dataclass
class SweepProgress:
    """Counts passed to the progress callback at the start, after each finished run
    (``event`` "run", ``last`` is its record) and after each run another process had
    (``event`` "skip")."""

    total: int
    done: int = 0
    failed: int = 0
    skipped: int = 0
    last: RunRecord | None = None
    event: Literal["start", "run", "skip"] = "start"


@dataclass
class SweepSummary:
    db: Path
    total: int
    ran: int
    failed: int
    skipped: int
    wall_s: float
    records: list[RunRecord] = field(default_factory=list)
    not_ingested: int = 0  # stored in results/ but not in the database (it was locked); ingested next time


def default_db_path(sweep: Sweep) -> Path:
    return Path("out") / "sweeps" / sweep.name / "results.duckdb"


def run_sweep(sweep: Sweep, db_path: str | Path, workers: int | None = None, scheduler: str | None = None,
              resume: bool = False, outputs: bool = True,
              on_progress: Callable[[SweepProgress], None] | None = None) -> SweepSummary:
    """Run every run of ``sweep`` not yet finished; record each in the results database.

    Without ``resume`` the database folder must not hold any run of this sweep yet
    (raises :class:`SimbenchInputError` naming the fix). With ``resume``, runs whose
    result is stored with status ok are skipped; failed runs are run again.

    Several sweeps on one database folder split the work: each run is claimed
    (:class:`~simbench.sweeps.results_db.RunClaims`) just before it starts; a run another live
    process holds, or whose result another process stored since this sweep started, is
    counted as skipped.
    """
    t0 = time.perf_counter()
    db = ResultsDB(db_path)
    store = db.store
    ids = [r.run_id for r in sweep.runs]
    stored = store.statuses()
    mine = {i: stored[i] for i in ids if i in stored}
    if mine and not resume:
        raise SimbenchInputError(
            f"{db.path}: already holds {len(mine)} of the {len(ids)} runs of sweep '{sweep.name}'; "
            f"pass --resume to skip finished runs, or give a new --db")
    store.remove_temporaries()  # half-written files of a killed sweep
    db.reconcile()  # result files a killed sweep wrote but did not ingest
    db.record_sweep(sweep.name, str(sweep.path), sweep.spec.model_dump(mode="json"), sweep.factor_levels(), len(ids))
    todo = [r for r in sweep.runs if mine.get(r.run_id) != STATUS_OK]
    prog = SweepProgress(total=len(ids), skipped=len(ids) - len(todo))
    prog.done = prog.skipped
    if on_progress:
        on_progress(prog)
    tasks = [RunTask(r, str(store.run_dir(r.run_id).resolve()) if outputs else None) for r in todo]
    records: list[RunRecord] = []
    not_ingested: set[str] = set()
    claims = RunClaims(store.root)
    started = time.time()

    def claim(task: RunTask) -> bool:
        rid = task.spec.run_id
        if claims.claim(rid):
            done = store.read(rid)  # finished by another sweep since this one looked?
            if done is None or (done.status != STATUS_OK and done.ended_at < started):
                return True
            claims.release(rid)
        prog.skipped += 1
        prog.done += 1
        prog.event = "skip"
        if on_progress:
            on_progress(prog)
        return False

    try:
        for rec in iter_records(tasks, workers, scheduler, claim=claim):
            if rec.out_dir:
                rec.out_dir = os.path.relpath(rec.out_dir, store.root)
            store.write(rec)
            claims.release(rec.run_id)
            try:
                db.ingest([rec])
            except duckdb.Error:  # e.g. locked by a reader: the result file is safe, reconcile ingests it
                not_ingested.add(rec.run_id)
            rec.per_frame = None
            records.append(rec)
            prog.done += 1
            prog.failed += rec.status != STATUS_OK
            prog.last = rec
            prog.event = "run"
            if on_progress:
                on_progress(prog)
    finally:
        claims.release_all()
    try:
        db.reconcile()
        not_ingested.clear()
    except duckdb.Error:
        pass
    return SweepSummary(db.path, len(ids), len(records), prog.failed, prog.skipped, time.perf_counter() - t0, records,
                        not_ingested=len(not_ingested))
