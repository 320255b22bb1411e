"""The colour shirt's cached pose database and training: several processes at once, and unreadable files
(simbench/pipelines/shirt_database.py, shirt_training.py; mocap/shirt/pose_database.py)."""

from __future__ import annotations

import logging
import threading
from pathlib import Path

import numpy as np
import pytest

from mocap.errors import InputFileError
from mocap.shirt.colour_model import ColourModel
from mocap.shirt.ik import IKPriors
from mocap.shirt.pose_database import PoseDatabase
from simbench.pipelines import shirt_database, shirt_training
from simbench.pipelines.shirt_database import PoseSampling, build_database, cache_lock, default_database_path, ensure_database
from simbench.pipelines.shirt_training import ShirtTraining, ensure_training
from simbench.scenario.loading import load_scenario
from simbench.scenes.anthropometry import BodyParams


SAMPLING = PoseSampling(n_poses=60, seed=3)
REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def tiny_db() -> PoseDatabase:
    return build_database(BodyParams(), SAMPLING)


def _no_build(*args, **kwargs):
    raise AssertionError("built the database again")


def _truncated_copy(db: PoseDatabase, path) -> bytes:
    """Write ``db`` at ``path`` cut to half its bytes (what a killed or interleaved write leaves); the bytes."""
    db.save(path)
    data = path.read_bytes()[: path.stat().st_size // 2]
    path.write_bytes(data)
    return data


def test_a_builder_that_finds_the_lock_held_waits_and_loads_the_file_written_meanwhile(tmp_path, monkeypatch, tiny_db):
    monkeypatch.setenv("SIMBENCH_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr(shirt_database, "build_database", _no_build)
    path = default_database_path(BodyParams(), SAMPLING)
    got: dict[str, object] = {}

    def second_process():
        try:
            got["db"] = ensure_database(BodyParams(), SAMPLING)
        except BaseException as exc:  # reported by the asserts below
            got["error"] = exc

    with cache_lock(path):  # the first builder is at work
        waiting = threading.Thread(target=second_process)
        waiting.start()
        waiting.join(timeout=1.0)
        assert waiting.is_alive(), f"did not wait for the lock: {got}"
        tiny_db.save(path)  # the first builder writes its file and lets go
    waiting.join(timeout=60)
    assert "error" not in got, got.get("error")
    assert np.array_equal(got["db"].hinges, tiny_db.hinges)


def test_a_cached_database_is_read_without_waiting_for_a_lock_another_process_holds(tmp_path, monkeypatch, tiny_db, caplog):
    monkeypatch.setenv("SIMBENCH_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr(shirt_database, "build_database", _no_build)
    path = default_database_path(BodyParams(), SAMPLING)
    tiny_db.save(path)
    got: dict[str, object] = {}
    with caplog.at_level(logging.WARNING, logger=shirt_database.__name__), cache_lock(path):  # another process reads or builds
        reader = threading.Thread(target=lambda: got.setdefault("db", ensure_database(BodyParams(), SAMPLING)))
        reader.start()
        reader.join(timeout=60)
        assert not reader.is_alive(), "waited for the lock to read a whole file"
    assert np.array_equal(got["db"].hinges, tiny_db.hinges) and "waiting" not in caplog.text


def test_a_corrupt_cached_database_is_built_again(tmp_path, monkeypatch, tiny_db, caplog):
    monkeypatch.setenv("SIMBENCH_CACHE_DIR", str(tmp_path))
    path = default_database_path(BodyParams(), SAMPLING)
    _truncated_copy(tiny_db, path)
    monkeypatch.setattr(shirt_database, "build_database", lambda *a, **k: tiny_db)
    with caplog.at_level(logging.WARNING, logger=shirt_database.__name__):
        db = ensure_database(BodyParams(), SAMPLING)
    assert caplog.text.count("cannot be read") == 1 and str(path) in caplog.text
    assert np.array_equal(db.hinges, tiny_db.hinges)
    assert np.array_equal(PoseDatabase.load(path).hinges, tiny_db.hinges)  # the cache is whole again
    assert [p.name for p in path.parent.iterdir() if "partial" in p.name] == []


def test_an_unreadable_database_the_user_named_is_one_clear_error_and_is_left_as_it_was(tmp_path, monkeypatch, tiny_db):
    monkeypatch.setenv("SIMBENCH_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setattr(shirt_database, "build_database", _no_build)
    named = tmp_path / "my_db.npz"
    data = _truncated_copy(tiny_db, named)
    with pytest.raises(InputFileError) as err:
        ensure_database(BodyParams(), SAMPLING, path=named)
    message = str(err.value)
    assert str(named) in message and "not a readable pose database" in message and "\n" not in message
    assert named.read_bytes() == data
    assert [p.name for p in tmp_path.iterdir() if p.name != "cache"] == ["my_db.npz"]  # no lock or temporary file beside it


def test_a_corrupt_cached_training_is_trained_again(tmp_path, monkeypatch, tiny_db, caplog):
    monkeypatch.setenv("SIMBENCH_CACHE_DIR", str(tmp_path))
    scenario = load_scenario(REPO / "scenarios" / "shirt_office.toml")
    k, p = tiny_db.n_colours, tiny_db.geometry.n_patches
    trained = ShirtTraining(ColourModel(np.full((k, 3), 0.5), np.repeat(np.eye(3)[None] * 1e-3, k, axis=0), tuple(tiny_db.geometry.colour_names)),
                            IKPriors(np.repeat(np.eye(2)[None] * 1e-4, p, axis=0), np.ones(17), np.ones(17), 7), {"frames": 7})
    calls = []
    monkeypatch.setattr(shirt_training, "train_shirt_pipeline", lambda *a: calls.append(1) or trained)
    ensure_training(scenario, tiny_db, 10)
    (path,) = [q for q in tmp_path.glob("shirt_training_*.npz")]
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    with caplog.at_level(logging.WARNING, logger=shirt_training.__name__):
        again = ensure_training(scenario, tiny_db, 10)
    assert calls == [1, 1] and caplog.text.count("cannot be read") == 1
    assert again.info == {"frames": 7} and np.array_equal(again.colour_model.means, trained.colour_model.means)
    assert ensure_training(scenario, tiny_db, 10).priors.n_frames == 7 and calls == [1, 1]  # read from the cache now


def test_build_db_out_replaces_a_pose_database_but_never_a_file_of_the_users(tmp_path, tiny_db, monkeypatch):
    from typer.testing import CliRunner

    from simbench.cli.app import app

    monkeypatch.setenv("SIMBENCH_CACHE_DIR", str(tmp_path / "cache"))
    mine = tmp_path / "poses.npz"
    np.savez(mine, x=np.arange(3))  # an .npz of the user's, not a database
    data = mine.read_bytes()
    monkeypatch.setattr(shirt_database, "build_database", _no_build)
    res = CliRunner().invoke(app, ["shirt", "build-db", "--out", str(mine), "--poses", "60", "--seed", "3"])
    assert res.exit_code == 2 and mine.read_bytes() == data, res.output
    assert f"{mine}: exists and is not a pose database written by simbench" in " ".join(res.output.split())
    ours = tmp_path / "db.npz"
    _truncated_copy(tiny_db, ours)  # a database cut short is not recognised either: it is not replaced
    res = CliRunner().invoke(app, ["shirt", "build-db", "--out", str(ours), "--poses", "60", "--seed", "3"])
    assert res.exit_code == 2
    tiny_db.save(ours)
    monkeypatch.setattr(shirt_database, "build_database", lambda *a, **k: tiny_db)
    res = CliRunner().invoke(app, ["shirt", "build-db", "--out", str(ours), "--poses", "60", "--seed", "3"])
    assert res.exit_code == 0, res.output
    assert np.array_equal(PoseDatabase.load(ours).hinges, tiny_db.hinges)


def test_a_long_build_says_once_how_long_it_will_take_where_warnings_show(caplog):
    estimate = shirt_database._BuildEstimate(100, after_s=0.0)
    with caplog.at_level(logging.WARNING, logger=shirt_database.__name__):
        estimate.advance(10)
        estimate.advance(10)
    assert caplog.text.count("min to go") == 1 and "10 of 100 poses" in caplog.text


def test_a_cache_folder_that_cannot_be_written_still_lets_a_named_database_be_built(tmp_path, monkeypatch, tiny_db, caplog):
    blocked = tmp_path / "cache"
    blocked.write_text("a file where the cache folder would be")  # so cache/locks cannot be made
    monkeypatch.setenv("SIMBENCH_CACHE_DIR", str(blocked))
    monkeypatch.setattr(shirt_database, "build_database", lambda *a, **k: tiny_db)
    named = tmp_path / "db.npz"
    with caplog.at_level(logging.WARNING, logger=shirt_database.__name__):
        db = ensure_database(BodyParams(), SAMPLING, path=named)
    assert np.array_equal(db.hinges, tiny_db.hinges) and PoseDatabase.is_database(named)
    assert "building without a lock" in caplog.text


def test_prepare_builds_each_distinct_shirt_scenario_once_with_the_progress_bar(monkeypatch):
    from simbench.pipelines import shirt as shirt_pipeline

    calls = []
    monkeypatch.setattr(shirt_pipeline, "build_stage", lambda sc: sc)
    monkeypatch.setattr(shirt_pipeline, "_database_and_training", lambda stage, factory: calls.append((stage.name, factory)))
    office = load_scenario(REPO / "scenarios" / "shirt_office.toml")
    outdoor = load_scenario(REPO / "scenarios" / "shirt_outdoor.toml")
    markers = load_scenario(REPO / "scenarios" / "quickstart.toml")
    seeds = [office.model_copy(update={"seed": s}) for s in (1, 2, 3)]
    factory = object()
    assert shirt_pipeline.prepare_shirt_caches([*seeds, markers, outdoor], factory) == 2
    assert calls == [("shirt_office", factory), ("shirt_outdoor", factory)]


class _Prepared(Exception):
    pass


class _RanWithoutPreparing(Exception):
    pass


def _no_runs(monkeypatch):
    """Every pool of runs raises at once: a command that skipped the preparation fails fast instead of running."""
    import simbench.sweeps.regression
    import simbench.sweeps.seeds
    import simbench.sweeps.sweep

    def refuse(*args, **kwargs):
        raise _RanWithoutPreparing

    for module in (simbench.sweeps.sweep, simbench.sweeps.seeds, simbench.sweeps.regression):
        monkeypatch.setattr(module, "iter_records", refuse)


@pytest.mark.parametrize("args", [
    ["run", "scenarios/shirt_office.toml", "--seeds", "2", "--out", "{tmp}/seeds"],
    ["sweep", "scenarios/sweeps/shirt_seeds_office.toml", "--db", "{tmp}/db/results.duckdb", "--no-outputs"],
    ["compare", "scenarios/shirt_office.toml", "--b", "shirt_pipeline.settings.pose_prior=false", "--seeds", "2"],
])
def test_commands_with_local_workers_prepare_the_shirt_caches_first_with_a_progress_bar(tmp_path, monkeypatch, args):
    from typer.testing import CliRunner

    from simbench.cli.app import app
    from simbench.cli.common import progress_bar
    from simbench.pipelines import shirt as shirt_pipeline

    seen = []

    def prepare(scenarios, factory):
        seen.append(([sc.name for sc in scenarios], factory))
        raise _Prepared  # nothing after it runs

    monkeypatch.setattr(shirt_pipeline, "prepare_shirt_caches", prepare)
    _no_runs(monkeypatch)
    monkeypatch.chdir(REPO)
    res = CliRunner().invoke(app, [a.replace("{tmp}", str(tmp_path)) for a in args])
    assert isinstance(res.exception, _Prepared), res.output
    (names, factory), = seen
    assert set(names) == {"shirt_office"} and factory is progress_bar


def test_check_prepares_the_shirt_caches_of_its_suite_first(tmp_path, monkeypatch):
    from typer.testing import CliRunner

    from simbench.cli.app import app
    from simbench.cli.common import progress_bar
    from simbench.pipelines import shirt as shirt_pipeline

    (tmp_path / "suites.toml").write_text(
        '[tolerances]\n"*" = { worse = "either", rel = 0.05 }\n[suites.t]\n'
        f'[[suites.t.scenarios]]\nname = "office"\nfile = "{REPO / "scenarios" / "shirt_office.toml"}"\n'
        f'[[suites.t.scenarios]]\nname = "quick"\nfile = "{REPO / "scenarios" / "quickstart.toml"}"\n')
    (tmp_path / "base.json").write_text('{"suite": "t", "scenarios": {}}')
    seen = []

    def prepare(scenarios, factory):
        seen.append(([sc.name for sc in scenarios], factory))
        raise _Prepared

    monkeypatch.setattr(shirt_pipeline, "prepare_shirt_caches", prepare)
    _no_runs(monkeypatch)
    res = CliRunner().invoke(app, ["check", "--suite", "t", "--suites", str(tmp_path / "suites.toml"),
                                   "--baseline", str(tmp_path / "base.json"), "--out", str(tmp_path / "out")])
    assert isinstance(res.exception, _Prepared), res.output
    assert seen == [(["shirt_office", "quickstart"], progress_bar)]
