"""Errors a user can cause: each names the file, the field, the value and the fix.

The CLIs turn any :class:`MocapInputError` into one line on stderr and exit code 2.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path


class MocapInputError(Exception):
    """Base class for errors caused by the user's input (files, fields, values)."""


class CalibrationFileError(MocapInputError):
    def __init__(self, path: Path | str, field: str, problem: str, fix: str) -> None:
        self.path, self.field, self.problem, self.fix = Path(path), field, problem, fix
        where = f"{self.path}" + (f": field '{field}'" if field else "")
        super().__init__(f"{where}: {problem}; {fix}")


class InputFileError(MocapInputError):
    """A video, image, template or data file that cannot be used."""

    def __init__(self, path: Path | str, problem: str, fix: str, field: str = "") -> None:
        self.path, self.problem, self.fix, self.field = Path(path), problem, fix, field
        where = f"{self.path}" + (f": field '{field}'" if field else "")
        super().__init__(f"{where}: {problem}; {fix}")


_OWN_VALUE = object()


def require(ok: bool, owner: object, field: str, fix: str, *, value: object = _OWN_VALUE,
            error: type[Exception] = ValueError) -> None:
    """The check of every settings dataclass's fields: unless ``ok``, raise ``error`` with
    ``"<Class>.<field>=<value>: <fix>"`` (the value as ``repr``; by default the owner's
    attribute ``field``)."""
    if not ok:
        shown = getattr(owner, field) if value is _OWN_VALUE else value
        raise error(f"{type(owner).__name__}.{field}={shown!r}: {fix}")


def require_one_of(owner: object, field: str, choices: tuple[str, ...] | Mapping[str, str], *,
                   error: type[Exception] = ValueError) -> None:
    """:func:`require` the attribute ``field`` to be one of ``choices``; the fix names them all
    (``"use 'a', 'b' or 'c'"``), each followed by its note in brackets where ``choices`` maps
    the choices to notes."""
    if getattr(owner, field) in tuple(choices):
        return
    notes = choices if isinstance(choices, Mapping) else dict.fromkeys(choices, "")
    named = [repr(c) + (f" ({note})" if note else "") for c, note in notes.items()]
    listed = named[0] if len(named) == 1 else ", ".join(named[:-1]) + " or " + named[-1]
    require(False, owner, field, f"use {listed}", error=error)


def require_finite(owner: object, fields: tuple[str, ...], *, positive: bool = True,
                   error: type[Exception] = ValueError) -> None:
    """:func:`require` each of ``fields`` to be a finite number, ``> 0`` (``positive``) or ``>= 0``."""
    for name in fields:
        v = float(getattr(owner, name))
        ok = math.isfinite(v) and (v > 0 if positive else v >= 0)
        require(ok, owner, name, "must be a finite number > 0" if positive else "must be a finite number >= 0",
                value=v, error=error)
