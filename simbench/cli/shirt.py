"""``simbench shirt build-db``: the colour-shirt pipeline's pose database
(:mod:`simbench.pipelines.shirt_database`)."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Optional

import typer

from simbench.cli.common import console, progress_bar, user_errors

shirt_app = typer.Typer(no_args_is_help=True, help="The colour-shirt pipeline's pose database.")


@shirt_app.command("build-db")
@user_errors
def build_db_command(
    out: Optional[Path] = typer.Option(None, "--out", help="database file (default: the cache, shirt_db_<hash>.npz)"),
    n_poses: int = typer.Option(80_000, "--poses", help="number of poses"),
    height_m: float = typer.Option(1.75, "--height", help="subject height (m)"),
    yaw_deg: float = typer.Option(80.0, "--yaw", help="root yaw range +- (deg) around facing the camera"),
    pitch_deg: float = typer.Option(25.0, "--pitch", help="root pitch range +- (deg)"),
    roll_deg: float = typer.Option(20.0, "--roll", help="root roll range +- (deg)"),
    seed: int = typer.Option(0, "--seed"),
) -> None:
    """Sample, rasterise and index upper-body poses of the humanoid (40x40 id maps)."""
    from mocap.atomic_files import check_output_file
    from mocap.shirt.pose_database import PoseDatabase  # faiss: on use
    from simbench.output_dir import OutputPathError
    from simbench.pipelines.shirt_database import PoseSampling, build_database, default_database_path
    from simbench.scenes.anthropometry import BodyParams

    sampling = PoseSampling(n_poses, yaw_deg, pitch_deg, roll_deg, seed)
    params = BodyParams(height_m=height_m)
    path = out or default_database_path(params, sampling)
    if out is not None:  # before the build: a file of the user's is not replaced
        check_output_file(out, PoseDatabase.is_database, "a pose database written by simbench", error=OutputPathError)
    prog, advance = progress_bar(f"shirt database ({n_poses} poses)", n_poses)
    t0 = time.perf_counter()
    with prog:
        db = build_database(params, sampling, progress=advance)
    db.save(path)
    console.print(f"wrote {path}: {len(db)} poses in {time.perf_counter() - t0:.0f} s")


@shirt_app.command("seed-table")
@user_errors
def seed_table_command(
    databases: list[Path] = typer.Argument(..., help="results databases of seed sweeps (scenarios/sweeps/shirt_seeds_*.toml)"),
    out: Optional[Path] = typer.Option(None, "--out", help="also write the table (Markdown) to this file"),
) -> None:
    """Full method against baseline, seed by seed: joint RMSE (cm), median, share <= 4 cm, share >= 20 % better."""
    from mocap.atomic_files import atomic_write_text, check_output_file
    from simbench.output_dir import OutputPathError
    from simbench.sweeps.shirt_table import is_seed_table, read_seed_rows, seed_table_markdown, summarise

    if out is not None:
        check_output_file(out, is_seed_table, "a seed table written by simbench", error=OutputPathError)
    rows = read_seed_rows(databases)
    text = seed_table_markdown(rows, summarise(rows))
    typer.echo(text, nl=False)
    if out is not None:
        atomic_write_text(out, text)
        console.print(f"wrote {out}")
