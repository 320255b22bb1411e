"""``simbench bench ...``: speed figures (:mod:`simbench.benchmarks`), each with a reference
measured in the same run."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path
from typing import Optional

import typer

from simbench.cli.common import user_errors

bench_app = typer.Typer(no_args_is_help=True, help="Benchmarks that print figures with a reference measured in the same run.")

#: BLAS, OpenMP and llvmpipe read their thread counts when they load: a one-core measurement
#: needs them in the environment of a fresh process.
ONE_CORE_ENV = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "LP_NUM_THREADS": "1"}


@bench_app.command("render")
@user_errors
def bench_render(frames: int = typer.Option(60, help="frames per measurement")) -> None:
    """Frames per second of the renderer, with mujoco.Renderer on the same scene as reference."""
    from simbench.benchmarks.render import run_render_benchmark  # the GL stack loads only for this command

    run_render_benchmark(n_frames=frames)


@bench_app.command("trackers")
def bench_trackers(frames: int = typer.Option(200, help="frames per measurement"),
                   seed: int = typer.Option(0, help="seed of the synthetic trajectories")) -> None:
    """Per-frame tracking cost of every tracker for 1..30 markers (seed 000 Tables V-VII),
    with a plain per-marker filterpy KalmanFilter loop as the reference."""
    from simbench.benchmarks.trackers import format_benchmark_table, run_tracker_benchmark  # numba, filterpy: on use

    print(format_benchmark_table(run_tracker_benchmark(n_frames=frames, seed=seed)))


@bench_app.command("pipeline")
@user_errors
def bench_pipeline(frames: int = typer.Option(30, help="frames of the scenario rendered and timed"),
                   scenario: Path = typer.Option(Path("scenarios/quickstart.toml"), help="scenario whose frames are timed"),
                   passes: int = typer.Option(3, help="passes per measurement (the fastest is kept)")) -> None:
    """Marker pipeline cost per stage per multi-camera frame on one core, with a threshold +
    cv2.connectedComponentsWithStats pass on the same images as reference."""
    from simbench.benchmarks.pipeline import run_pipeline_benchmark  # MuJoCo, GL: on use

    print(run_pipeline_benchmark(n_frames=frames, scenario_path=str(scenario), passes=passes).table())


@bench_app.command("shirt")
@user_errors
def bench_shirt(
    frames: int = typer.Option(20, "--frames", help="frames timed (after 3 warm-up frames)"),
    scenario: Optional[Path] = typer.Option(None, "--scenario", help="shirt scenario (default scenarios/shirt_office.toml)"),
    passes: int = typer.Option(3, "--passes", min=1, help="passes of the full method over the same frames (all are averaged; each pass's mean is printed)"),
) -> None:
    """ms per 2-camera frame of the colour-shirt pipeline per stage, one core, with references."""
    if any(os.environ.get(k) != v for k, v in ONE_CORE_ENV.items()):
        args = [sys.executable, "-m", "simbench.cli", "bench", "shirt", "--frames", str(frames), "--passes", str(passes)]
        if scenario is not None:
            args += ["--scenario", str(scenario)]
        raise typer.Exit(subprocess.run(args, env={**os.environ, **ONE_CORE_ENV}).returncode)
    from simbench.benchmarks.shirt import run_shirt_benchmark  # faiss, Pinocchio, GL: on use

    run_shirt_benchmark(n_frames=frames, scenario_path=str(scenario) if scenario else None, passes=passes)


@bench_app.command("memory")
@user_errors
def bench_memory(
    duration: float = typer.Option(60.0, "--duration", help="length of the take (s), overrides the scenario's duration_s"),
    scenario: Path = typer.Option(Path("scenarios/quickstart.toml"), "--scenario", help="scenario TOML (default: the quickstart, 4 cameras)"),
    set_: list[str] = typer.Option([], "--set", help="override a field, e.g. --set rig.count=6"),
    every: int = typer.Option(100, "--every", min=1, help="print a row every this many frames"),
    out: Optional[Path] = typer.Option(None, "--out", help="keep the run's outputs here (default: a temporary folder, removed)"),
) -> None:
    """RSS against frames rendered for a long take run as `simbench run` runs it; peak RSS and the
    growth from frame 300 to the end, beside the RSS before the run and the size of one camera-frame."""
    from simbench.benchmarks.memory import run_memory_benchmark  # MuJoCo, GL: on use
    from simbench.output_dir import replaceable_state
    from simbench.scenario import load_scenario, parse_overrides

    sc = load_scenario(scenario, overrides={**parse_overrides(set_), "duration_s": duration})
    if out is not None:
        replaceable_state(out)  # refuse a path that is not the bench's before anything renders

    def row(s) -> None:
        if s.frames % every == 0:
            print(f"  frame {s.frames:>6}/{sc.n_frames}  {s.elapsed_s:>7.1f} s  RSS {s.rss_bytes / 2 ** 20:8.1f} MiB", flush=True)

    print(run_memory_benchmark(sc, out=out, on_sample=row).table(every))
