"""Third-party capture tools on the bench, each in its own virtual environment (issue 14, part 3).

aniposelib and Pose2Sim pin other OpenCV builds, so they never enter the main environment:
``scripts/setup_adapters.sh`` installs each into ``.venv-<name>/`` at the repository root (or
under ``$SIMBENCH_ADAPTER_VENVS``), and the bench talks to them only through files: it writes
the inputs (:mod:`simbench.pipelines.exchange.inputs`, in the tool's calibration format), runs
the tool's adapter script (``adapter_scripts/<name>_adapter.py``, which calls the tool's own
functions) with that environment's Python, and reads back its CSV results, calibration and
``timings.json``. An adapter whose environment is absent is simply not installed
(:func:`installed_adapters`).
"""

from __future__ import annotations

import json
import os
import subprocess
from dataclasses import dataclass
from pathlib import Path

from simbench.errors import SimbenchInputError

__all__ = ["Adapter", "ADAPTERS", "AdapterError", "adapter_python", "installed_adapters", "adapter_version", "run_adapter"]

SCRIPTS = Path(__file__).parent / "adapter_scripts"


class AdapterError(SimbenchInputError):
    """An adapter failed (the message names the tool, the task and its log)."""


@dataclass(frozen=True)
class Adapter:
    name: str  # also the venv's suffix and the package installed in it
    package: str  # the distribution name (its version is reported)
    fmt: str  # the calibration format its inputs are written in
    variants: tuple[str, ...]  # result files the triangulate task writes (<variant>.csv)
    calibrates: bool  # has a calibrate task (board videos -> calibration.toml)
    settings: str  # what the variants are, for the report


ADAPTERS: dict[str, Adapter] = {
    "aniposelib": Adapter("aniposelib", "aniposelib", "anipose", ("triangulate", "triangulate_ransac", "triangulate_optim"), True,
                          "CameraGroup.triangulate / triangulate_ransac(min_cams=2) / triangulate_optim, each with its "
                          "defaults (undistort=True); calibration: CameraGroup.calibrate_videos with Checkerboard(inner corners)"),
    "pose2sim": Adapter("pose2sim", "pose2sim", "pose2sim", ("pose2sim", "pose2sim_gaps_nan"), False,
                        "triangulation_from_best_cameras (15 px, likelihood 0.3, 2 cameras, undistort_points = false), "
                        "linear interpolation of gaps < 20 frames, larger gaps filled with the last value (default) or "
                        "left empty (fill_large_gaps_with = 'nan'), Butterworth 4th order 6 Hz: the demo Config.toml"),
}


def venv_root() -> Path:
    """Where the adapters' environments live: ``$SIMBENCH_ADAPTER_VENVS`` or the repository root."""
    env = os.environ.get("SIMBENCH_ADAPTER_VENVS")
    return Path(env) if env else Path(__file__).resolve().parents[3]


def adapter_python(name: str) -> Path | None:
    """The Python of ``.venv-<name>`` when set up by ``scripts/setup_adapters.sh``, else None."""
    py = venv_root() / f".venv-{name}" / "bin" / "python"
    return py if py.is_file() and (py.parent.parent / ".simbench-adapter").is_file() else None


def installed_adapters() -> list[str]:
    return [n for n in ADAPTERS if adapter_python(n) is not None]


def adapter_version(name: str) -> str:
    """The installed version, from the environment's stamp (``<package>==<version>``)."""
    py = adapter_python(name)
    if py is None:
        return "not installed"
    stamp = (py.parent.parent / ".simbench-adapter").read_text().strip()
    return stamp.split("==", 1)[-1]


def run_adapter(name: str, task: str, inputs: Path, out: Path, timeout_s: float = 3600.0) -> dict:
    """Run ``<name>_adapter.py TASK INPUTS OUT`` in the tool's environment; returns its ``timings.json``.
    Output in ``OUT/adapter.log``."""
    py = adapter_python(name)
    if py is None:
        raise AdapterError(f"adapter {name!r} is not installed: run scripts/setup_adapters.sh {name}")
    out.mkdir(parents=True, exist_ok=True)
    log = out / "adapter.log"
    argv = [str(py), str(SCRIPTS / f"{name}_adapter.py"), task, str(inputs), str(out)]
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME")}
    env.update({"MPLBACKEND": "Agg", "PYTHONUNBUFFERED": "1", "JAX_PLATFORMS": "cpu"})
    with log.open("w") as fh:
        try:
            proc = subprocess.run(argv, stdout=fh, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, timeout=timeout_s, env=env)
        except subprocess.TimeoutExpired:
            raise AdapterError(f"adapter {name} {task} did not finish in {timeout_s:g} s; log: {log}") from None
    if proc.returncode != 0:
        tail = [ln for ln in log.read_text(errors="replace").splitlines() if ln.strip()][-1:] or [""]
        raise AdapterError(f"adapter {name} {task} exited with code {proc.returncode}; log: {log} (last line: {tail[0][:200]!r})")
    return json.loads((out / "timings.json").read_text())
