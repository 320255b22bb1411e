"""``simbench`` command line: the root app (``info``, ``render``, ``run``, ``list``) and the
command groups of the other modules of this package.

Every error a user can cause (a bad scenario field, a missing file, no GL, an
``--out`` that is not the bench's to replace) prints one line naming the file, the
field, the value and the fix, and exits with code 2. Exit codes: :mod:`simbench.cli.common`.

Commands import the library when they run: ``simbench --help``, ``list`` and ``info``
take about 0.2 s instead of the 3 s of importing MuJoCo, the GL stack, DuckDB and faiss.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Optional

import typer

from simbench.cli import bench, exchange, shirt, study, sweep
from simbench.cli.common import EXIT_STAGE_FAILED, console, prepare_shirt_caches_here, print_error, progress_bar, run_app, user_errors

app = typer.Typer(add_completion=False, no_args_is_help=True, help="Simulation-validated test bench for optical motion capture.")
OUT_HELP = ("output folder; an earlier simbench output (a folder holding .simbench-output.json) or an empty "
            "folder is replaced when the run completes, any other existing path is refused")


@app.command()
@user_errors
def info(scenario: Path = typer.Argument(..., help="scenario TOML"),
         schema: bool = typer.Option(False, "--schema", help="print the JSON schema of scenario files")) -> None:
    """Print the resolved scenario (every field, defaults filled in)."""
    from simbench.scenario import Scenario, load_scenario

    if schema:
        print(json.dumps(Scenario.model_json_schema(), indent=2))
        return
    sc = load_scenario(scenario)
    data = sc.model_dump(mode="json")
    data["_resolved"] = {"n_frames": sc.n_frames, "hash": sc.content_hash()}
    from simbench.render.camera import cameras_from_scenario

    data["_resolved"]["cameras"] = [
        {"name": c.name, "position_m": [round(v, 4) for v in c.center.tolist()], "fx_px": round(float(c.K[0, 0]), 3)}
        for c in cameras_from_scenario(sc)
    ]
    print(json.dumps(data, indent=2))


@app.command()
@user_errors
def render(scenario: Path = typer.Argument(..., help="scenario TOML"),
           out: Path = typer.Option(..., "--out", help=OUT_HELP),
           png: bool = typer.Option(False, "--png", help="also write every frame as PNG")) -> None:
    """Render a scenario: per-camera MP4, ground truth, calibration, contact sheet."""
    from simbench.output_dir import replaceable_state
    from simbench.stage.rendering import render_scenario
    from simbench.scenario import load_scenario

    sc = load_scenario(scenario)
    replaceable_state(out)  # refuse a path that is not the bench's before anything renders
    prog, advance = progress_bar(f"render {sc.name}", sc.n_frames)
    with prog:
        seq = render_scenario(sc, out, png=png, progress=advance)
    gt = seq.ground_truth
    console.print(f"wrote {out}/ : {len(gt.camera_names)} cameras x {gt.n_frames} frames, "
                  f"{len(gt.marker_names)} markers, mean shutter sub-frames {gt.n_subframes.mean():.1f}",
                  markup=False, highlight=False)


@app.command()
@user_errors
def run(scenario: Path = typer.Argument(..., help="scenario TOML"),
        out: Path = typer.Option(None, "--out", help=OUT_HELP + " (default: out/<scenario name>)"),
        set_: list[str] = typer.Option([], "--set", help="override a field, e.g. --set sensor.exposure_ms=20"),
        seeds: Optional[int] = typer.Option(None, "--seeds", min=1, max=1000,
                                            help="run N seeds (seed, seed+1, ...; default: the scenario's `seeds`, 1) and "
                                                 "summarise each metric across them"),
        seed_start: Optional[int] = typer.Option(None, "--seed-start", min=0, help="first seed of --seeds (default: the scenario's seed)"),
        workers: Optional[int] = typer.Option(None, "--workers", "-j", min=1, help="--seeds: local worker processes (default: all cores)"),
        scheduler: Optional[str] = typer.Option(None, "--scheduler", help="--seeds: run on a Dask cluster: tcp://HOST:PORT")) -> None:
    """Render, run the capture pipeline, score against ground truth; write metrics.json and report.md.

    With --seeds N (or a scenario's `seeds = N`): N runs in OUT/seeds/seed-NNNN/, and OUT/metrics.json holds each metric's per-seed values, mean, median, SD and 95 % bootstrap CI; OUT/report.md shows their spread.

    Exit code 3: the run finished but a stage after rendering failed (e.g. an export); metrics.json and report.md are written and name the stage.
    """
    from simbench.output_dir import default_run_dir, replaceable_state
    from simbench.pipelines.run import run_scenario
    from simbench.scenario import load_scenario, parse_overrides

    overrides = parse_overrides(set_)
    sc = load_scenario(scenario, overrides=overrides)
    sc.check_runnable(scenario)
    out = out if out is not None else default_run_dir(sc.name, scenario)
    replaceable_state(out)  # refuse a path that is not the bench's before anything renders
    n_seeds = seeds if seeds is not None else sc.seeds
    if n_seeds > 1 or seeds is not None or seed_start is not None:
        _run_seeds(sc, out, n_seeds, seed_start, overrides, workers, scheduler)
        return
    prog, advance = progress_bar(f"run {sc.name}", sc.n_frames)
    with prog:
        result = run_scenario(sc, out, progress=advance, progress_factory=progress_bar)
    console.print(f"wrote {out}/metrics.json and {out}/report.md", markup=False, highlight=False)
    width = max(len(k) for k in result.metrics)
    for k, v in sorted(result.metrics.items()):
        print(f"{k:<{width}}  {v:.4g}" if isinstance(v, float) else f"{k:<{width}}  {v}")
    for f in result.failures:
        print_error(f"{out}: {f.line()} (the run's other outputs, metrics.json and report.md are written)")
    if result.failures:
        raise typer.Exit(EXIT_STAGE_FAILED)


def _run_seeds(sc, out: Path, n: int, start, overrides, workers, scheduler) -> None:
    """``simbench run --seeds N``: the replicate runs, then each metric's mean, CI and spread."""
    from simbench.cli.sweep import counting_progress
    from simbench.sweeps.seeds import run_seeds

    prepare_shirt_caches_here([sc], scheduler)
    prog, on_record = counting_progress(f"run {sc.name}, {n} seeds", n)
    with prog:
        result = run_seeds(sc, out, n, start, overrides, workers, scheduler, on_record)
    console.print(f"wrote {out}/metrics.json and {out}/report.md (seeds {result.seeds[0]}..{result.seeds[-1]} in "
                  f"{out}/seeds/)", markup=False, highlight=False)
    width = max((len(k) for k in result.summaries), default=6)
    print(f"{'metric':<{width}}  {'mean':>10}  {'95% CI':>21}  {'median':>10}  {'sd':>9}")
    for k, s in sorted(result.summaries.items()):
        ci = f"{s.ci_low:.4g} .. {s.ci_high:.4g}"
        print(f"{k:<{width}}  {s.mean:>10.4g}  {ci:>21}  {s.median:>10.4g}  {s.sd:>9.3g}")
    for seed, cause in result.failures:
        print_error(f"{out}: seed {seed}: {cause}")
    if result.failures:
        raise typer.Exit(EXIT_STAGE_FAILED)


@app.command("list")
def list_things() -> None:
    """List motions, lighting presets, marker sets and trackers (the names a scenario may use)."""
    from mocap.trackers import available_trackers
    from simbench.scenario import LIGHTING_PRESETS
    from simbench.scenes.markers import MARKER_SETS
    from simbench.scenes.motions import MOTIONS

    print("motions:", ", ".join(MOTIONS), "+ bvh")
    print("lighting presets:", ", ".join(LIGHTING_PRESETS))
    print("marker sets:", ", ".join([*MARKER_SETS, "none"]))
    print("trackers:", ", ".join(available_trackers()))


app.add_typer(bench.bench_app, name="bench")
sweep.register(app)
exchange.register(app)
app.add_typer(shirt.shirt_app, name="shirt")
app.add_typer(study.study_app, name="study")


def main() -> None:
    run_app(app)


if __name__ == "__main__":
    main()
