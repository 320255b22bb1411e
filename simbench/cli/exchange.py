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


def scoreboard(suite: str = typer.Argument(..., help="suite name in the suites file, e.g. scoreboard"),
               suites_file: Path = typer.Option(Path("scenarios/suites.toml"), "--suites", help="suites file"),
               out: Path = typer.Option(None, "--out", help="report folder (default out/scoreboard/<suite>)"),
               systems: list[str] = typer.Option([], "--system", help="only these adapters (default: every installed one); 'project' alone: no adapter"),
               seeds: int = typer.Option(1, "--seeds", min=1, max=100,
                                         help="each scenario on N seeds; figures become means with 95 %% bootstrap CIs")) -> None:
    """The project's pipeline and every installed third-party adapter (scripts/setup_adapters.sh) on the same
    frames of each scenario of SUITE: one table, and a Markdown report with plots."""
    from simbench.sweeps.scoreboard import run_scoreboard, table_lines, write_report
    from simbench.errors import SimbenchInputError
    from simbench.output_dir import AtomicOutputDir, replaceable_state
    from simbench.pipelines.exchange.adapters import ADAPTERS, installed_adapters
    from simbench.sweeps.regression import load_suites

    unknown = [s for s in systems if s not in ADAPTERS and s != "project"]
    if unknown:
        raise SimbenchInputError(f"--system {unknown[0]!r}: use an adapter ({', '.join(ADAPTERS)}) or 'project' (the project's rows only)")
    n = len(load_suites(suites_file).get(suite).scenarios)
    out = out if out is not None else Path("out") / "scoreboard" / suite
    replaceable_state(out)
    missing = [a for a in ADAPTERS if a not in installed_adapters() and (not systems or a in systems)]  # asked for, absent
    for a in missing:
        console.print(f"note: adapter {a} is not installed (scripts/setup_adapters.sh {a}); its rows are left out",
                      markup=False, highlight=False)
    prog, advance = progress_bar(f"scoreboard {suite}", n * seeds)
    with AtomicOutputDir(out, scenario=suite, kind="run") as tmp:
        with prog:
            sb = run_scoreboard(suites_file, suite, tmp, systems or None, progress=advance, seeds=seeds)
        sb.failures = [f.replace(str(tmp), str(out)) for f in sb.failures]  # name the final folder
        write_report(sb, tmp)
    print("\n".join(table_lines(sb)))
    for f in sb.failures:
        console.print(f"failed: {f}", markup=False, highlight=False)
    console.print(f"wrote {out}/scoreboard.md (plots in {out}/plots/) and {out}/scoreboard.json", markup=False, highlight=False)


def register(app: typer.Typer) -> None:
    """Add ``export-inputs`` and ``scoreboard`` to the ``simbench`` app."""
    app.command("export-inputs")(user_errors(export_inputs))
    app.command("scoreboard")(user_errors(scoreboard))
