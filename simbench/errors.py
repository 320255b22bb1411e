"""Errors users can cause, each with a message that names the fix.

The CLI prints any :class:`SimbenchInputError` (and ``mocap.errors.MocapInputError``)
as one line and exits with code 2.
"""

from __future__ import annotations

from pathlib import Path


class SimbenchInputError(Exception):
    """Base class for errors caused by user input or the machine's set-up."""


class ScenarioError(SimbenchInputError):
    """A scenario or sweep file that does not validate."""

    def __init__(self, path: Path | str, field: str, value: object, allowed: str) -> None:
        self.path, self.field, self.value, self.allowed = Path(path), field, value, allowed
        super().__init__(f"{self.path}: field '{field}': got {value!r}; {allowed}")


class GLUnavailableError(SimbenchInputError):
    """No off-screen OpenGL context could be made."""
