"""The ``mocap`` command line (typer commands only; nothing else imports this package):
:mod:`mocap.cli.app` (``markers``, ``calibrate``), :mod:`mocap.cli.shirt` (``shirt``),
:mod:`mocap.cli.common` (errors, video order)."""

from mocap.cli.app import app, main

__all__ = ["app", "main"]
