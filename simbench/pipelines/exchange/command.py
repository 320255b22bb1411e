"""A user's capture system as a scenario's pipeline (``[pipeline] kind = "command"``).

``simbench run`` renders the take, writes the inputs folder (:mod:`simbench.pipelines.exchange.inputs`,
in the ``[pipeline]``'s ``format``) into the run folder's ``inputs/``, runs the command with
``{inputs}`` and ``{output}`` filled in (``{python}``: this interpreter; ``{scenario_dir}``),
in the scenario's folder, with a timeout, its stdout and stderr in ``command.log``; then it
reads ``output/<result>`` (C3D, TRC or CSV) and scores it (:mod:`simbench.pipelines.exchange.results`).
A command that fails, times out or writes nothing raises :class:`CommandPipelineError`: one
line naming the command, what happened and the log (the run records it as a failed stage).
"""

from __future__ import annotations

import os
import shlex
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from simbench.errors import SimbenchInputError
from simbench.scenario import PipelineConfig

__all__ = ["CommandPipelineError", "CommandRun", "run_command"]


class CommandPipelineError(SimbenchInputError):
    """The scenario's command failed, timed out or wrote no result (the message names it and its log)."""


@dataclass(frozen=True)
class CommandRun:
    argv: list[str]
    result: Path
    log: Path
    seconds: float


def _last_line(log: Path) -> str:
    try:
        lines = [ln.strip() for ln in log.read_text(errors="replace").splitlines()[1:] if ln.strip()]  # [0]: the command
    except OSError:
        return ""
    return f" (its last line: {lines[-1][:200]!r})" if lines else " (it printed nothing)"


def run_command(cfg: PipelineConfig, inputs: Path, output: Path, log: Path, scenario_dir: Path) -> CommandRun:
    """Run ``cfg.command`` on ``inputs``; returns where its result is. ``output`` is made empty first."""
    output.mkdir(parents=True, exist_ok=True)
    fill = {"inputs": shlex.quote(str(inputs)), "output": shlex.quote(str(output)), "python": shlex.quote(sys.executable),
            "scenario_dir": shlex.quote(str(scenario_dir))}
    argv = shlex.split(cfg.command.format(**fill))
    shown = cfg.command
    t0 = time.perf_counter()
    with log.open("w") as fh:
        fh.write(f"$ {shlex.join(argv)}\n")
        fh.flush()
        try:
            proc = subprocess.run(argv, cwd=scenario_dir, stdout=fh, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                  timeout=cfg.timeout_s, env={**os.environ, "PYTHONUNBUFFERED": "1"})
        except FileNotFoundError:
            raise CommandPipelineError(f"pipeline command {shown!r}: program {argv[0]!r} not found (run in {scenario_dir}); log: {log}") from None
        except subprocess.TimeoutExpired:
            raise CommandPipelineError(f"pipeline command {shown!r} did not finish in timeout_s = {cfg.timeout_s:g} s; "
                                       f"log: {log}{_last_line(log)}") from None
    seconds = time.perf_counter() - t0
    if proc.returncode != 0:
        raise CommandPipelineError(f"pipeline command {shown!r} exited with code {proc.returncode}; log: {log}{_last_line(log)}")
    result = output / cfg.result
    if not result.is_file():
        raise CommandPipelineError(f"pipeline command {shown!r} exited 0 but wrote no {cfg.result} in its output folder; "
                                   f"log: {log}{_last_line(log)}")
    return CommandRun(argv, result, log, seconds)
