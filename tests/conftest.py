"""What the tests share: where the project's real data is, and the fast subset.

The real captures, BVH clips and calibration pictures live in ``shared/data`` beside the
repository (``../shared/data``; its README describes every file). Tests that need them
take the :func:`shared_data` fixture, which skips them, naming the path it looked at, when
the folder is not there.

``pytest -m "not slow"`` runs the fast subset for the inner loop (under a minute on two
cores); CI runs everything. A test is marked ``slow`` when it takes more than a few
seconds (an end-to-end render and run, a real capture through the whole pipeline).

Under ``pytest -n 2`` (pytest-xdist) a module's tests go to one worker together
(``--dist loadfile`` in pyproject.toml), so a module-scoped fixture (one render or run that
several tests check) is computed once, not once on each worker; and the slow modules are
collected first, so that the workers start on them and the fast modules fill in at the end.
"""

from __future__ import annotations

import importlib.util
import os
from pathlib import Path
from types import ModuleType

import pytest

# OpenBLAS on one thread in the test processes and everything they start (spawned workers,
# subprocesses and Dask workers inherit the variable); set before numpy loads here. Under
# ``-n 2`` both cores already run a test process each, and each process's OpenBLAS threads then
# wait for a core, spinning: tests/test_shirt_search.py and five other BLAS-heavy modules took 41.9
# CPU-s with OpenBLAS's default threads on the shared 2-core machine and 28.4 with one (the shirt
# pose database's randomised SVD: 3 QR factorisations, 4.7 CPU-s on two threads, 0.7 on one;
# simbench.pipelines.calibration.single_threaded_blas is the same finding in the bundle
# adjustment). A value the caller set is kept.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

#: ``../shared/data`` relative to the repository.
SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


def load_script(name: str) -> ModuleType:
    """The repository's ``scripts/NAME.py`` as a module (its ``main`` called in-process: no new interpreter)."""
    spec = importlib.util.spec_from_file_location(name, Path(__file__).resolve().parents[1] / "scripts" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """The shared real-data folder (the test is skipped when it is missing)."""
    if not SHARED_DATA.is_dir():
        pytest.skip(f"shared real data not found at {SHARED_DATA} (put shared/ beside the repository)")
    return SHARED_DATA


#: Whole modules that run the bench end to end (``simbench run``, sweeps, suites, the CLIs on
#: rendered videos, signals sent to running processes, real captures through the labelling) or
#: render many GL frames (sensor backends, rolling shutters, calibration boards, visible-light
#: detection on renders): seconds to tens of seconds each, so they are ``slow``. Single slow
#: tests elsewhere carry ``@pytest.mark.slow`` themselves.
SLOW_MODULES = frozenset({
    "test_calibrate_rig.py",
    "test_calibration_scene_render.py",
    "test_calibration_scene_run.py",
    "test_capture_scenario.py",
    "test_detection_visible.py",
    "test_render_sensor.py",
    "test_webcam_sensor.py",
    "test_check_real_motion.py",
    "test_check_suite.py",
    "test_exchange_adapters.py",
    "test_mocap_markers_inputs.py",
    "test_model_labelling.py",
    "test_run_interrupts.py",
    "test_run_markers.py",
    "test_run_real_motion.py",
    "test_run_seeds.py",
    "test_run_webcams.py",
    "test_scoreboard.py",
    "test_shirt_pipeline_run.py",
    "test_study_trackers.py",
    "test_sweep_kill_resume.py",
    "test_sweep_run.py",
})


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    for item in items:
        if item.path.name in SLOW_MODULES:
            item.add_marker(pytest.mark.slow)
    # The slow modules first; a stable sort, so each module's tests stay together and in order.
    items.sort(key=lambda item: item.path.name not in SLOW_MODULES)
