"""The ``simbench`` command line (typer commands only; nothing else imports this package).

:mod:`simbench.cli.app` is the root app; :mod:`simbench.cli.common` the error policy,
exit codes, signals and progress bars every command shares; the command groups are
:mod:`simbench.cli.bench`, :mod:`simbench.cli.shirt`, :mod:`simbench.cli.study` and
:mod:`simbench.cli.sweep`.
"""

from simbench.cli.app import app, main

__all__ = ["app", "main"]
