"""What the shirt tracker's lock-on does on the first frame of a take, stage by stage (issue 18's 100 ms point).

In: a shirt scenario and seeds. Out: per seed, the first frame's joint RMSE (cm, upper-body joint centres
against the simulator's) and agreement with step 1 after each stage of the full method's lock-on, then a
summary of how many seeds each stage leaves more than ``--far`` cm off.

The stages (:class:`mocap.shirt.pipeline.ShirtTracker`, :mod:`mocap.shirt.hypotheses`):

* ``step3``: step 4 solved from step 3's classification (with a lost frame's recovery passes), before the headings;
* ``step3+h``: the same after the upright headings (``_root_hypotheses``);
* ``step1`` and ``step1+h``: the same from step 1's classification (``_lock_on_step_1``);
* ``pass1``: the first pass's pose (the better-agreeing of the two, after the arm hypotheses);
* ``frame0``: the frame's output, after the second pass.

Per seed it renders the take's first three frames, starts the shirt session as ``simbench run`` does (the
database and training from their caches) and tracks that frame with the tracker's own steps, recording the pose
each stage hands on. Why a script: the stages are the tracker's private steps, which no user-facing output has.

Example::

    .venv/bin/python scripts/shirt_lock_on.py scenarios/shirt_outdoor.toml --seeds 20 --seed-start 1
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from _one_line_errors import run_main  # noqa: E402
from mocap.shirt.kinematics import UPPER_BODY_JOINTS  # noqa: E402
from mocap.shirt.pipeline import ShirtTracker  # noqa: E402
from simbench.errors import SimbenchInputError  # noqa: E402
from simbench.pipelines.shirt import start_session, tracker_params  # noqa: E402
from simbench.render.gl_context import configure_gl_environment  # noqa: E402
from simbench.scenario.loading import load_scenario, parse_overrides  # noqa: E402
from simbench.stage.build import build_stage  # noqa: E402
from simbench.stage.rendering import render_frames  # noqa: E402

STAGES = ("step3", "step3+h", "step1", "step1+h", "pass1", "frame0")


def record_lock_on(tracker: ShirtTracker, images: list[np.ndarray]) -> dict[str, np.ndarray]:
    """Track the first frame ``images`` with ``tracker`` (fresh, full method) and return the pose ``(18,)`` each of
    :data:`STAGES` handed on, with ``"agreement:" + stage`` its agreement with step 1 (a 0-d array; NaN for
    ``frame0``)."""
    out: dict[str, np.ndarray] = {}
    root, step_1 = tracker._root_hypotheses, tracker._lock_on_step_1

    def keep(name: str, q: np.ndarray, est) -> None:
        # scored while the frame's classification is at hand (the tracker drops it when the frame ends)
        seen = [ci for ci, o in enumerate(est.cameras) if o.step1 is not None and o.pixels is not None]
        out[name] = np.array(q)
        out["agreement:" + name] = np.array(tracker._agreement([q], est.cameras, seen)[0][0])

    def _root(q, est, lin, sil):
        result = root(q, est, lin, sil)
        # the first call is step 3's, the second (inside _lock_on_step_1) step 1's
        name = "step3" if "step3" not in out else "step1"
        keep(name, q, est)
        keep(name + "+h", result, est)
        return result

    def _step_1(q, est, lin):
        result = step_1(q, est, lin)
        keep("pass1", result, est)
        return result

    tracker._root_hypotheses, tracker._lock_on_step_1 = _root, _step_1
    try:
        est0 = tracker.process(images)
    finally:
        del tracker._root_hypotheses, tracker._lock_on_step_1  # the class's methods again
    out["frame0"] = np.array(est0.q)
    out["agreement:frame0"] = np.array(np.nan)  # (its classification is dropped with the frame)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("scenario")
    ap.add_argument("--seeds", type=int, required=True, help="how many seeds")
    ap.add_argument("--seed-start", type=int, default=1, help="the first seed")
    ap.add_argument("--far", type=float, default=10.0, help="cm: a stage's pose this far off counts as lost")
    ap.add_argument("--set", action="append", default=[], metavar="FIELD=VALUE", help="override a scenario field (TOML value)")
    a = ap.parse_args()
    if a.seeds < 1:
        raise SimbenchInputError(f"--seeds: got {a.seeds}; give how many seeds to run, 1 or more")
    overrides = parse_overrides(a.set)
    # every seed's scenario checked before any work (a bad field or a scenario without the shirt: one line, exit 2)
    scenarios = [load_scenario(a.scenario, {**overrides, "seed": seed}) for seed in range(a.seed_start, a.seed_start + a.seeds)]
    if not scenarios[0].subject.shirt:
        raise SimbenchInputError(f"{a.scenario}: field 'subject.shirt': got false; the lock-on is the colour shirt's, "
                                 "give a shirt scenario (scenarios/shirt_*.toml)")
    configure_gl_environment()
    print(f"{'seed':>4} " + " ".join(f"{s:>15}" for s in STAGES) + "   (joint RMSE cm / agreement with step 1)")
    errors = []
    for sc in scenarios:
        # the first three frames only: the session's empty-scene frames are rendered at the take's first three
        # frame times (simbench.pipelines.shirt_inputs.render_empty_frames), so a shorter take would change them
        stage = build_stage(sc.with_overrides({"duration_s": 3.0 / sc.fps}))
        seq = render_frames(stage, keep_frames=True, keep_ids=True)
        gt = seq.ground_truth
        session = start_session(stage, seq.frames, gt)
        tracker = session.tracker(tracker_params(stage.scenario))  # the full method as `simbench run` sets it
        rec = record_lock_on(tracker, list(seq.frames[0]))
        truth = gt.joint_centres[0, [gt.joint_names.index(b) for b in UPPER_BODY_JOINTS]]
        err = {s: float(np.sqrt(np.mean(np.sum((tracker.kin.joint_centres(rec[s][None])[0] - truth) ** 2, axis=1)))) * 100
               for s in STAGES}
        errors.append([err[s] for s in STAGES])
        print(f"{sc.seed:>4} " + " ".join(f"{err[s]:>7.1f} / {float(rec['agreement:' + s]):.3f}" for s in STAGES), flush=True)
    e = np.array(errors)
    either = np.minimum(e[:, STAGES.index("step3")], e[:, STAGES.index("step1")])  # the better of the two solves before the headings
    print(f"over {a.far:g} cm: " + ", ".join(f"{s} {int((e[:, i] > a.far).sum())} of {len(e)}" for i, s in enumerate(STAGES))
          + f"; the better of step3 and step1 {int((either > a.far).sum())}")
    print("median cm: " + ", ".join(f"{s} {np.median(e[:, i]):.1f}" for i, s in enumerate(STAGES)))


if __name__ == "__main__":
    run_main(main)
