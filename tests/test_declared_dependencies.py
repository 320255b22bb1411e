"""Every third-party module the project imports comes from a distribution pyproject.toml declares.

A module installed by hand in a developer's environment passes every test there and fails on a
fresh setup: `hypothesis` did, and the project's CI failed on it (tests/test_shirt_metrics.py
could not be imported). This test reads the imports of the packages, the tests and the scripts
and checks each against the declared dependencies (the main list and the `test` extra).
"""

from __future__ import annotations

import ast
import importlib.metadata as md
import re
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SCANNED = ("mocap", "eval", "simbench", "tests", "scripts")
# run inside the third-party tools' own environments (scripts/setup_adapters.sh), never in the main one
ADAPTER_SCRIPTS = ROOT / "simbench" / "pipelines" / "exchange" / "adapter_scripts"
# import names whose distribution's metadata does not list them
IMPORT_ALIASES = {"pinocchio": "pin"}


def _normalise(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def _declared() -> set[str]:
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    specs = list(project["dependencies"]) + list(project.get("optional-dependencies", {}).get("test", []))
    return {_normalise(re.split(r"[<>=!~\[; ]", s, maxsplit=1)[0]) for s in specs}


def _imports(path: Path) -> set[str]:
    names = set()
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            names |= {a.name.split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module.split(".")[0])
    return names


def _local_modules() -> set[str]:
    """The project's own packages and the modules that sit beside the importing files (tests' helpers)."""
    local = {"mocap", "eval", "simbench", "tests", "conftest"}
    for d in SCANNED:
        local |= {p.stem for p in (ROOT / d).rglob("*.py")}
    return local


def _undeclared(paths: list[Path], declared: set[str], local: set[str]) -> list[str]:
    """One line per (file, third-party module) whose providing distribution is not in ``declared``."""
    providers = md.packages_distributions()
    out = []
    for path in paths:
        for name in sorted(_imports(path) - local):
            if name in sys.stdlib_module_names or name == "__future__":
                continue
            dists = {_normalise(x) for x in providers.get(name, [])} | {_normalise(IMPORT_ALIASES.get(name, name))}
            if not dists & declared:
                out.append(f"{path.name} imports {name} (from {sorted(dists)}), not in pyproject.toml")
    return out


def test_every_imported_third_party_module_is_declared_in_pyproject():
    paths = [p for d in SCANNED for p in sorted((ROOT / d).rglob("*.py")) if ADAPTER_SCRIPTS not in p.parents]
    assert len(paths) > 100
    undeclared = _undeclared(paths, _declared(), _local_modules())
    assert not undeclared, "\n".join(undeclared)


def test_a_module_installed_but_not_declared_is_reported(tmp_path):
    # pip is in every virtual environment and never among the project's dependencies
    f = tmp_path / "uses_pip.py"
    f.write_text("import os\nimport numpy as np\nfrom pip._internal import main\nimport pinocchio\nfrom mocap import types\n")
    assert _undeclared([f], _declared(), _local_modules()) == ["uses_pip.py imports pip (from ['pip']), not in pyproject.toml"]
