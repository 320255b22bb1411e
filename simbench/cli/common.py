"""What every ``simbench`` sub-command shares: the error policy, exit codes, signals,
progress bars, where library messages (``logging``) are shown.

Exit codes of the ``simbench`` command line:

* 0: done;
* 1: ``simbench check``: a metric regressed; ``simbench sweep``: some runs failed;
* 2: an error you can cause (bad scenario field, missing file, no GL, an ``--out`` that
  is not the bench's to replace): one line naming the file, the field, the value and the
  fix; nothing written;
* 3: ``simbench run``: the run finished but a stage failed (its metrics.json and
  report.md are written and name the stage); ``simbench check``: a scenario could not
  run (its row says ``error: ...``);
* 130 / 143: interrupted by SIGINT / SIGTERM; unfinished outputs are removed.
"""

from __future__ import annotations

import functools
import logging
import signal
import sys
from typing import Callable

import typer
from rich.console import Console
from rich.markup import escape
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn
from rich.text import Text

from mocap.errors import MocapInputError
from simbench import interrupts
from simbench.errors import GLUnavailableError, SimbenchInputError
from simbench.render.gl_context import check_requested_platform

console = Console(stderr=True)

EXIT_USER_ERROR = 2
EXIT_STAGE_FAILED = 3  # simbench run: a stage failed after rendering; simbench check: a scenario could not run


def print_error(message: str, prefix: str = "error:") -> None:
    """One ``error: MESSAGE`` line on stderr; MESSAGE is printed literally (no rich markup,
    so ``[[lighting.lights]]`` in a message stays as written)."""
    console.print(Text.assemble((prefix, "bold red"), " ", message), soft_wrap=True, highlight=False)


def user_errors(fn: Callable) -> Callable:
    """The user-caused errors of a command (bench or pipeline) become one line on stderr
    and exit code 2, no traceback (the message names the file, the field and the fix)."""

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        try:
            return fn(*args, **kwargs)
        except (SimbenchInputError, MocapInputError) as exc:
            print_error(str(exc))
            raise typer.Exit(EXIT_USER_ERROR)

    return wrapper


class _ConsoleHandler(logging.Handler):
    """A log record as one plain line on the console the progress bars use (a line printed
    while a bar is live goes above it instead of breaking it)."""

    def emit(self, record: logging.LogRecord) -> None:
        prefix = f"{record.levelname.lower()}: " if record.levelno >= logging.WARNING else ""
        console.print(prefix + self.format(record), markup=False, highlight=False, soft_wrap=True)


class _StdoutHandler(logging.Handler):
    """A log record as a plain line on standard output (``sys.stdout`` as it is at the time)."""

    def emit(self, record: logging.LogRecord) -> None:
        print(self.format(record), flush=True)


#: Loggers whose records are a command's results (benchmark figures): printed on stdout.
RESULT_LOGGERS = ("simbench.benchmarks",)


def configure_logging() -> None:
    """Show the library's messages (``logging``, INFO and up, of ``simbench`` and ``mocap``)
    on stderr, and the benchmarks' figures on stdout; once per process."""
    for name in ("simbench", "mocap"):
        logger = logging.getLogger(name)
        if not any(isinstance(h, _ConsoleHandler) for h in logger.handlers):
            logger.addHandler(_ConsoleHandler())
        logger.setLevel(logging.INFO)
        logger.propagate = False
    for name in RESULT_LOGGERS:
        logger = logging.getLogger(name)
        if not any(isinstance(h, _StdoutHandler) for h in logger.handlers):
            logger.addHandler(_StdoutHandler())
        logger.propagate = False


def run_app(app: typer.Typer) -> None:
    """Run the command line with library messages shown (:func:`configure_logging`) and
    SIGINT and SIGTERM turned into :class:`simbench.interrupts.Interrupted`: one line on
    stderr, unfinished outputs removed, exit 128 + the signal's number. An exception that a
    signal turned into something else on its way out (see :mod:`simbench.interrupts`)
    counts as that signal."""
    configure_logging()
    interrupts.install()
    try:
        check_requested_platform()
    except GLUnavailableError as exc:
        print_error(str(exc))
        sys.exit(EXIT_USER_ERROR)
    try:
        app()
        interrupts.raise_if_pending()
    except BaseException as exc:  # click ends even a successful command with SystemExit
        signum = exc.signum if isinstance(exc, interrupts.Interrupted) else interrupts.pending()
        if signum is None:
            raise
        console.print(f"interrupted by {signal.Signals(signum).name}: stopped; unfinished outputs removed, "
                      f"earlier outputs left as they were", markup=False, highlight=False, soft_wrap=True)
        sys.exit(128 + signum)


def progress_bar(description: str, total: int):
    """A rich progress bar on stderr; returns ``(progress, advance)``."""
    prog = Progress(TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
                    TimeElapsedColumn(), TextColumn("eta"), TimeRemainingColumn(), console=console)
    task = prog.add_task(escape(description), total=total)  # a scenario name is shown as written
    return prog, lambda n=1: prog.advance(task, n)


def prepare_shirt_caches_here(scenarios, scheduler: str | None) -> None:
    """Before local workers start (``scheduler`` None): build a missing colour-shirt database and training in this
    process, with a progress bar (:func:`simbench.pipelines.shirt.prepare_shirt_caches`). The shirt pipeline, and faiss
    and numba with it, is imported only when a scenario wears the shirt: a marker sweep's process stays as light as
    before."""
    scenarios = list(scenarios)
    if scheduler is not None or not any(sc.subject.shirt for sc in scenarios):
        return
    from simbench.pipelines.shirt import prepare_shirt_caches

    prepare_shirt_caches(scenarios, progress_bar)
