"""Fuzzing the bench's inputs: bad scenario files for ``simbench run`` and bad inputs for
``mocap markers``, each of which must be refused with exit code 2 and exactly one line on
stderr naming the file and the field (or option), with no traceback, no hang, and nothing
written at ``--out``.

Scenario cases are seeded mutations (an explicit ``np.random.Generator``) of the shipped
``scenarios/*.toml``, each resolved first (every field with its default, relative paths made
absolute) so that every field can be hit: NaN, inf, 1e300, booleans and strings for numbers,
zero or negative for quantities that are positive by nature, unknown names where a name is
looked up in a registry, names that cannot be a file name, missing files, unknown and missing
fields, wrong table types, non-UTF-8 bytes, duplicated keys, broken TOML, and degenerate
geometry (cameras inside the body or looking away, a zero light direction, a singular K, one
frame, one camera, a 2 m ball). Which values are bad is written here, independently of the
schema (the lists below), so a bound missing from the schema shows as an accepted bad value.

Each case runs in-process through the same code path as the command line (``simbench run``
invoked through ``typer.testing.CliRunner``) with the run itself replaced by a sentinel: a case
that reaches it was accepted, and nothing ever renders. ``mocap markers`` cases run its typer
app the same way on a small synthetic take (three 64x48 cameras seeing three markers) whose
unmutated version succeeds. A few cases of each also run as real subprocesses
(:func:`check_in_subprocess`).

Full run (prints the counts)::

    .venv/bin/python tests/fuzz_inputs.py --scenarios 300 --mocap 40

``tests/test_fuzz_inputs.py`` runs a reduced version in the normal suite.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import re
import signal
import subprocess
import sys
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from typer.testing import CliRunner

from fuzz_cases import (  # noqa: F401  (SCENARIOS, resolved_bases, _toml: used by tests/test_fuzz_inputs.py)
    REPO,
    SCENARIOS,
    Case,
    _synthetic_take,
    _toml,
    _value_text,
    mocap_cases,
    resolved_bases,
    scenario_cases,
)


@dataclass
class Outcome:
    label: str
    kind: str
    verdict: str  # "ok", "accepted", "traceback", "hang", "unclear", "half-written"
    exit_code: int | None
    stderr: str
    seconds: float


@dataclass
class Tally:
    outcomes: list[Outcome] = field(default_factory=list)

    def counts(self) -> Counter:
        return Counter(o.verdict for o in self.outcomes)

    def bad(self) -> list[Outcome]:
        return [o for o in self.outcomes if o.verdict != "ok"]


# ------------------------------------------------------------------------------ running
class _Accepted(Exception):
    """The sentinel that replaces a run: the scenario was accepted."""


class _Hang(Exception):
    pass


@contextlib.contextmanager
def _time_limit(seconds: float):
    def on_alarm(signum, frame):
        raise _Hang()

    old = signal.signal(signal.SIGALRM, on_alarm)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


@contextlib.contextmanager
def _runs_replaced():
    """``simbench run`` with the run itself (render and pipelines) replaced by the sentinel."""
    from simbench.pipelines import run as run_module
    from simbench.sweeps import seeds as seeds_module

    def accepted(*a, **k):
        raise _Accepted()

    saved = run_module.run_scenario, getattr(seeds_module, "run_seeds", None)
    run_module.run_scenario = accepted
    seeds_module.run_seeds = accepted
    try:
        yield
    finally:
        run_module.run_scenario = saved[0]
        if saved[1] is not None:
            seeds_module.run_seeds = saved[1]


def _judge(case: Case, exit_code: int | None, stderr: str, exc: BaseException | None, written: list[str],
           file_names: tuple[str, ...], seconds: float, accepted: bool, hang: bool) -> Outcome:
    lines = [ln for ln in stderr.splitlines() if ln.strip()]
    if hang:
        verdict = "hang"
    elif accepted:
        verdict = "accepted"
    elif "Traceback" in stderr or (exc is not None and not isinstance(exc, SystemExit)) or exit_code not in (2,):
        verdict = "traceback"
    elif written:
        verdict = "half-written"
    elif len(lines) != 1 or not lines[0].startswith("error:") or not any(n in lines[0] for n in file_names) or ".partial-" in lines[0]:  # names a folder the user never sees
        verdict = "unclear"
    elif not _names_a_field(lines[0], case):
        verdict = "unclear"
    elif case.kind != "mocap" and _value_text(case.value) is not None and _value_text(case.value) not in lines[0]:
        verdict = "unclear"  # the line does not show the value
    else:
        verdict = "ok"
    return Outcome(case.label, case.kind, verdict, exit_code, stderr.strip() + (f" [{written}]" if written else "")
                   + (f" [{type(exc).__name__}: {exc}]" if exc is not None and verdict == "traceback" else ""), seconds)


def _names_a_field(line: str, case: Case) -> bool:
    """The line names one of the case's fields: ``field 'X'`` with X the field, one of its
    parents, or a part of it; or, for options and files, the name itself."""
    named = re.findall(r"field '([^']*)'", line)
    if case.kind == "mocap":  # files and options: named in the line
        return any(want in line for want in case.fields)
    for want in case.fields:
        if any(x == want or want.startswith(x + ".") or x.startswith(want + ".") for x in named):
            return True
        if not named and want in line:
            return True
    return False


def check_scenario_case(case: Case, root: Path, timeout_s: float = 30.0) -> Outcome:
    """``simbench run FILE --out OUT`` on the case in-process (``--out`` left out for the
    scenario-name cases, then the default ``out/<name>`` is under the case's folder)."""
    from simbench.cli.app import app

    d = root / case.label.split()[0]
    d.mkdir(parents=True)
    path = d / "scenario.toml"
    path.write_bytes(case.text)
    args = ["run", str(path), *case.args] + (["--out", str(d / "out")] if case.use_out else [])
    cwd = os.getcwd()
    t0 = time.perf_counter()
    accepted = hang = False
    result = None
    try:
        os.chdir(d)
        with _runs_replaced(), _time_limit(timeout_s):
            result = CliRunner().invoke(app, args, catch_exceptions=True)
        accepted = isinstance(result.exception, _Accepted)
    except _Hang:
        hang = True
    finally:
        os.chdir(cwd)
    written = sorted(str(p.relative_to(d)) for p in d.rglob("*") if p != path)
    stderr = result.stderr if result is not None else ""
    return _judge(case, result.exit_code if result else None, stderr, result.exception if result else None, written,
                  (str(path),), time.perf_counter() - t0, accepted, hang)


def check_mocap_case(case: Case, root: Path, timeout_s: float = 60.0) -> Outcome:
    """``mocap markers ARGS`` on the case in-process, in a folder holding a good take that the
    case then spoils (``prepare``)."""
    from mocap.cli.app import app

    d = root / case.label.split()[0]
    d.mkdir(parents=True)
    _synthetic_take(d)
    if case.prepare is not None:
        case.prepare(d)
    before = {p for p in d.rglob("*")}
    snapshot = {p: p.read_bytes() for p in before if p.is_file()}
    args = ["markers", *(a.replace("{d}", str(d)) for a in case.args)]
    t0 = time.perf_counter()
    hang = False
    result = None
    try:
        with (case.patch() if case.patch else contextlib.nullcontext()), _time_limit(timeout_s):
            result = CliRunner().invoke(app, args, catch_exceptions=True)
    except _Hang:
        hang = True
    written = sorted(str(p.relative_to(d)) for p in set(d.rglob("*")) - before)
    written += [str(p.relative_to(d)) + " (changed)" for p, b in snapshot.items() if not p.is_file() or p.read_bytes() != b]
    stderr = result.stderr if result is not None else ""
    names = tuple(f for f in case.fields) + ("--out", "cap")
    return _judge(case, result.exit_code if result else None, stderr, result.exception if result else None, written,
                  names, time.perf_counter() - t0, result is not None and result.exit_code == 0, hang)


def check_good_mocap_take(root: Path) -> tuple[int, str]:
    """The unmutated synthetic take: ``mocap markers`` must succeed on it (exit code, output)."""
    from mocap.cli.app import app

    d = root / "good"
    d.mkdir(parents=True)
    videos, cal, tmpl = _synthetic_take(d)
    r = CliRunner().invoke(app, ["markers", *map(str, videos), "--calibration", str(cal), "--template", str(tmpl),
                                 "--out", str(d / "cap")])
    return r.exit_code, r.stdout + r.stderr


def check_in_subprocess(case: Case, root: Path, timeout_s: float = 120.0) -> Outcome:
    """The case through the real command line (``simbench run`` or ``mocap markers`` in a new
    Python process); a scenario case must be one the in-process check refused (else it would run)."""
    d = root / ("sub-" + case.label.split()[0])
    d.mkdir(parents=True)
    if case.kind == "mocap":
        _synthetic_take(d)
        if case.prepare is not None:
            case.prepare(d)
        cmd = [sys.executable, "-m", "mocap.cli", "markers", *(a.replace("{d}", str(d)) for a in case.args)]
        names = tuple(case.fields) + ("--out", "cap")
        path = None
    else:
        path = d / "scenario.toml"
        path.write_bytes(case.text)
        cmd = [sys.executable, "-c", "from simbench.cli.app import main; main()", "run", str(path), *case.args] + (["--out", str(d / "out")] if case.use_out else [])
        names = (str(path),)
    before = {p for p in d.rglob("*")}
    t0 = time.perf_counter()
    try:
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s, cwd=d, env={**os.environ, "COLUMNS": "80"})
        code, stderr, hang = r.returncode, r.stderr, False
    except subprocess.TimeoutExpired:
        code, stderr, hang = None, "", True
    written = sorted(str(p.relative_to(d)) for p in set(d.rglob("*")) - before)
    return _judge(case, code, stderr, None, written, names, time.perf_counter() - t0, False, hang)


def report(title: str, tally: Tally) -> str:
    c = tally.counts()
    n = len(tally.outcomes)
    return (f"{title}: {n} cases; exit 2 with one line naming file and field: {c['ok']}; tracebacks: {c['traceback']}; "
            f"hangs: {c['hang']}; half-written outputs: {c['half-written']}; accepted bad values: {c['accepted']}; "
            f"unclear messages: {c['unclear']}; slowest {max((o.seconds for o in tally.outcomes), default=0):.1f} s")


def run_fuzz(n_scenarios: int, n_mocap: int, seed: int, root: Path, n_subprocess: int = 3, log=print) -> tuple[Tally, Tally, Tally]:
    """Generate and check the cases; returns the scenario, mocap and subprocess tallies."""
    rng = np.random.default_rng(seed)
    bases = resolved_bases()
    scen, moc, sub = Tally(), Tally(), Tally()
    scenario_list = scenario_cases(n_scenarios, rng, bases)
    for case in scenario_list:
        scen.outcomes.append(check_scenario_case(case, root / "scenarios"))
    mocap_list = mocap_cases(n_mocap, rng)
    for case in mocap_list:
        moc.outcomes.append(check_mocap_case(case, root / "mocap"))
    refused = [c for c, o in zip(scenario_list, scen.outcomes) if o.verdict == "ok"]
    picks = [refused[i] for i in rng.choice(len(refused), min(n_subprocess, len(refused)), replace=False)] if refused else []
    picks += [mocap_list[i] for i in rng.choice(len(mocap_list), min(n_subprocess, len(mocap_list)), replace=False)]
    for case in picks:
        sub.outcomes.append(check_in_subprocess(case, root / "subprocess"))
    return scen, moc, sub


def main(argv: list[str] | None = None) -> int:
    import tempfile

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenarios", type=int, default=300, help="bad scenario files to generate")
    ap.add_argument("--mocap", type=int, default=40, help="bad `mocap markers` inputs")
    ap.add_argument("--subprocess", type=int, default=3, help="cases of each kind also run as real subprocesses")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--show", type=int, default=20, help="print this many failing cases")
    a = ap.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="simbench-fuzz-") as tmp:
        root = Path(tmp)
        code, text = check_good_mocap_take(root)
        print(f"control: mocap markers on the unspoilt synthetic take: exit {code}: {' '.join(text.split()).split('; wrote')[0]}")
        scen, moc, sub = run_fuzz(a.scenarios, a.mocap, a.seed, root, a.subprocess)
    print(report("simbench run, bad scenarios (in-process)", scen))
    print("  by kind: " + ", ".join(f"{k} {v}" for k, v in sorted(Counter(o.kind for o in scen.outcomes).items())))
    print(report("mocap markers, bad inputs (in-process)", moc))
    print(report("real subprocesses", sub))
    bad = scen.bad() + moc.bad() + sub.bad()
    for o in bad[:a.show]:
        print(f"  {o.verdict}: {o.label} (exit {o.exit_code}): {o.stderr[:400]}")
    return 0 if not bad and code == 0 else 1


if __name__ == "__main__":
    sys.path.insert(0, str(REPO))
    sys.exit(main())
