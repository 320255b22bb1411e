"""The scripts' entry point: a user's error (a bad scenario, a bad ``--set``) as one line on stderr and exit 2,
as the ``simbench`` command prints them (its own wrapper, ``simbench.cli.common.user_errors``, ends in typer's exit,
which needs typer's app around it)."""

from __future__ import annotations

import sys
from collections.abc import Callable

from mocap.errors import MocapInputError
from simbench.errors import SimbenchInputError


def run_main(main: Callable[[], None]) -> None:
    """Call ``main()``; a :class:`SimbenchInputError` or :class:`MocapInputError` becomes ``error: MESSAGE`` and exit 2."""
    try:
        main()
    except (SimbenchInputError, MocapInputError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        sys.exit(2)
