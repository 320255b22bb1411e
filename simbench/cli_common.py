"""Temporary alias of :mod:`simbench.cli.common` for ``simbench/cli_study.py`` until that
module moves into ``simbench/cli/`` (issue 16; it is being edited for issue 19)."""

from simbench.cli.common import console, user_errors

__all__ = ["console", "user_errors"]
