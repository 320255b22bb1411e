"""SIGINT / SIGTERM as an exception that unwinds a run, and the record that one arrived.

:func:`install` makes SIGINT and SIGTERM raise :class:`Interrupted` in the main thread,
so every ``with`` and ``finally`` on the way out runs (partial output folders are
removed). A handler's exception can be caught and re-wrapped by code it lands in
(ctypes turns it into ``ctypes.ArgumentError`` when it arrives while PyOpenGL converts
call arguments, and drops it altogether, printing it, when it arrives in a Python
callback called from C, as numba's JIT compiler makes; an ``except Exception`` may record
it as a failure), so the signal is also recorded: :func:`pending` and
:func:`raise_if_pending` let code that catches broad exceptions (the run's stages, the
sweep worker, the CLI) and code at safe points (every rendered frame, every stage,
before an output is moved into place) stop rather than go on. The record is
process-wide state on purpose: so are signals.
"""

from __future__ import annotations

import signal
import sys
from typing import NoReturn

_received: list[int] = []  # signal numbers received by this process, in order


class Interrupted(BaseException):
    """SIGINT or SIGTERM arrived. A ``BaseException`` like ``KeyboardInterrupt``: no
    ``except Exception`` swallows it."""

    def __init__(self, signum: int) -> None:
        self.signum = signum
        super().__init__(signal.Signals(signum).name)


def stop(signum: int) -> NoReturn:
    """Record ``signum`` and raise :class:`Interrupted`; later SIGTERMs are ignored during
    the clean-up (a dying multi-threaded parent may even send a worker its death signal
    twice: it hands the worker to another of its threads first)."""
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    _received.append(signum)
    raise Interrupted(signum)


def _on_signal(signum: int, frame) -> None:
    # A second Ctrl-C is the usual KeyboardInterrupt, for the impatient (what is left
    # half-written is removed by the next run into the same folder, simbench.output_dir).
    signal.signal(signal.SIGINT, signal.default_int_handler)
    stop(signum)


def _unraisable(hook):
    def quiet(unraisable) -> None:
        # ctypes prints an exception raised in a callback (numba's JIT compiler calls
        # Python back from C) and drops it: the signal is recorded, the next check stops
        # the run, and no traceback is printed.
        if isinstance(unraisable.exc_value, Interrupted):
            return
        hook(unraisable)

    return quiet


def install(signals: tuple[int, ...] = (signal.SIGINT, signal.SIGTERM)) -> None:
    """Turn ``signals`` into :class:`Interrupted` (main thread only)."""
    for s in signals:
        signal.signal(s, _on_signal)
    quiet_unraisable()


def quiet_unraisable() -> None:
    """Do not print an :class:`Interrupted` that a C callback could not raise (see :func:`pending`)."""
    if getattr(sys.unraisablehook, "__name__", "") != "quiet":
        sys.unraisablehook = _unraisable(sys.unraisablehook)


def pending() -> int | None:
    """The first signal received since :func:`install`, or None."""
    return _received[0] if _received else None


def raise_if_pending(cause: BaseException | None = None) -> None:
    """Raise :class:`Interrupted` if a signal arrived (``cause``: the exception it was
    wrapped into, kept as ``__cause__``)."""
    signum = pending()
    if signum is not None:
        raise Interrupted(signum) from cause
