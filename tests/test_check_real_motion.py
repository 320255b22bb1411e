"""The real_motion suite gates real captures the way the ci suite gates the bench's own motions:
a CMU BVH clip and a real C3D capture (BTS walk), each against the committed baseline
(`scenarios/baselines/real_motion.json`; `simbench baseline update --suite real_motion` after a
change that moves them). The whole suite (18 scenarios) runs with `simbench check --suite
real_motion`; CI runs these two for time."""

from __future__ import annotations

import pytest
from typer.testing import CliRunner

from simbench.cli.app import app


@pytest.mark.slow
def test_real_motion_scenarios_pass_their_baseline(tmp_path) -> None:
    # simbench check's typer app in this process; its two runs go to one spawned worker process
    args = ["check", "--suite", "real_motion", "--baseline", "scenarios/baselines/real_motion.json",
            "--only", "bvh_jumping_jacks", "--only", "c3d_bts_walk", "-j", "1"]
    r = CliRunner().invoke(app, args, catch_exceptions=True)
    assert r.exception is None or isinstance(r.exception, SystemExit), repr(r.exception)
    assert r.exit_code == 0, r.stdout + r.stderr
    assert "PASS suite real_motion" in r.stdout and "0 regressed" in r.stdout
