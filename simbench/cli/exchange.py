"""``simbench export-inputs`` and ``simbench scoreboard`` (issue 14: any capture system on the bench).

Registered on the main app by :func:`register` (see the end of :mod:`simbench.cli.app`).
"""

from __future__ import annotations

from pathlib import Path

import typer

from simbench.cli.common import console, progress_bar, user_errors

FORMAT_HELP = "calibration file format and convention: opencv, anipose, pose2sim or easymocap"


def export_inputs(scenario: Path = typer.Argument(..., help="scenario TOML"),
                  out: Path = typer.Option(..., "--out", help="inputs folder (an earlier bench output or an empty folder is replaced)"),
                  fmt: str = typer.Option("opencv", "--format", help=FORMAT_HELP),
                  set_: list[str] = typer.Option([], "--set", help="override a field, e.g. --set duration_s=0.5")) -> None:
    """Write what another capture system needs: videos, calibration in its format, 2D detections
    (OpenPose JSON and CSV), label template, board pictures (scenarios with a calibration scene)."""
    from mocap.calibration_formats import CALIBRATION_FORMATS
    from simbench.errors import SimbenchInputError
    from simbench.pipelines.exchange.inputs import export_inputs as export
    from simbench.output_dir import replaceable_state
    from simbench.scenario import load_scenario, parse_overrides

    if fmt not in CALIBRATION_FORMATS:
        raise SimbenchInputError(f"--format {fmt!r}: use one of {', '.join(CALIBRATION_FORMATS)}")
    sc = load_scenario(scenario, overrides=parse_overrides(set_))
    replaceable_state(out)
    prog, advance = progress_bar(f"export {sc.name}", sc.n_frames)
    with prog:
        ex = export(sc, out, fmt, progress=advance)
    seen = int((ex.confidence > 0).sum())
    console.print(f"wrote {out}/ ({fmt}): {len(ex.calibration)} cameras x {len(ex.times)} frames, {len(ex.marker_names)} markers, "
                  f"{seen} labelled 2D detections; manifest {out}/inputs.json", markup=False, highlight=False)


def register(app: typer.Typer) -> None:
    """Add ``export-inputs`` (and ``scoreboard``) to the ``simbench`` app."""
    app.command("export-inputs")(user_errors(export_inputs))
