"""What every ``simbench`` sub-command shares: the error policy, progress bars, ``--set``."""

from __future__ import annotations

import tomllib

from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

from mocap.cli import exit_on_user_errors
from mocap.errors import MocapInputError
from simbench.errors import SimbenchInputError

console = Console(stderr=True)


#: User-caused errors of the bench or the pipeline: one line on stderr, exit code 2.
user_errors = exit_on_user_errors(SimbenchInputError, MocapInputError, console=console)


def progress_bar(description: str, total: int):
    """A rich progress bar on stderr; returns ``(progress, advance)``."""
    prog = Progress(TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
                    TimeElapsedColumn(), TextColumn("eta"), TimeRemainingColumn(), console=console)
    task = prog.add_task(description, total=total)
    return prog, lambda n=1: prog.advance(task, n)


def parse_overrides(items: list[str]) -> dict[str, object]:
    """``FIELD=VALUE`` strings to a dict; values parsed as TOML (numbers, strings, booleans, arrays)."""
    out: dict[str, object] = {}
    for item in items:
        if "=" not in item:
            raise SimbenchInputError(f"--set {item!r}: expected FIELD=VALUE, e.g. sensor.exposure_ms=20")
        key, value = item.split("=", 1)
        try:
            out[key.strip()] = tomllib.loads(f"v = {value}")["v"]
        except tomllib.TOMLDecodeError:
            out[key.strip()] = value
    return out
