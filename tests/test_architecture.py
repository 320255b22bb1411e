"""The import contracts of ``.importlinter`` hold (README, "Architecture"), and they are not
vacuous: the same contracts fail on a copy of the code with one import added."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ("simbench", "mocap", "eval")

LINT = "import sys; from importlinter.cli import lint_imports_command; sys.exit(lint_imports_command())"


def lint_imports(root: Path) -> subprocess.CompletedProcess:
    """``lint-imports`` on the packages under ``root`` with ``root/.importlinter`` (no cache)."""
    env = {"PYTHONPATH": str(root), "PATH": "/usr/bin:/bin", "LANG": "C.UTF-8", "COLUMNS": "200"}
    return subprocess.run([sys.executable, "-c", LINT, "--no-cache"], cwd=root, env=env, capture_output=True,
                          text=True, timeout=300)


def test_the_import_contracts_hold():
    r = lint_imports(REPO)
    assert r.returncode == 0, r.stdout[-4000:] + r.stderr[-2000:]
    assert "0 broken" in r.stdout


@pytest.fixture(scope="module")
def code_copy(tmp_path_factory) -> Path:
    """The three packages and the contracts, copied (a change made here cannot touch the repository)."""
    root = tmp_path_factory.mktemp("code")
    for pkg in PACKAGES:
        shutil.copytree(REPO / pkg, root / pkg, ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copy(REPO / ".importlinter", root / ".importlinter")
    return root


@pytest.mark.parametrize(
    "module, added, contract",
    [
        # a cycle between two sibling modules of simbench.scenes
        ("simbench/scenes/props.py", "import simbench.scenes.scene", "No import cycles"),
        # library code that uses the command line
        ("simbench/pipelines/report.py", "import simbench.cli.common", "Nothing outside the command-line packages"),
        # a lower package that reaches up
        ("simbench/render/camera.py", "import simbench.stage.stage", "simbench: each package uses only"),
        # the capture product that needs the simulator
        ("mocap/triangulation.py", "import mujoco", "never import the simulator"),
    ],
)
def test_the_contracts_fail_on_an_added_import(code_copy, module, added, contract):
    path = code_copy / module
    original = path.read_text()
    path.write_text(original + f"\n{added}  # added by the test\n")
    try:
        r = lint_imports(code_copy)
    finally:
        path.write_text(original)
    assert r.returncode == 1, r.stdout[-3000:] + r.stderr[-2000:]
    broken = [ln for ln in r.stdout.splitlines() if " BROKEN" in ln]
    assert any(contract in ln for ln in broken), r.stdout[-3000:]
