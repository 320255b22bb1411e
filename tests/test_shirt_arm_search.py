"""The arm search of the colour-shirt pipeline: arms scored against a classification by projected sample points."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from mocap.calib.synthetic import look_at
from mocap.calibration import Camera
from mocap.shirt.arm_search import ArmSearch, colour_distance_maps
from mocap.shirt.hypotheses import ARMS, RankedArms, TrackerHypotheses
from mocap.shirt.pipeline import ShirtTracker
from mocap.shirt.settings import ShirtPipelineParams
from mocap.shirt.shirt_model import CropView
from simbench.pipelines.shirt_database import shirt_model
from simbench.scenes.anthropometry import BodyParams


@pytest.fixture(scope="module")
def model():
    return shirt_model(BodyParams())


def _cameras():
    K = np.array([[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]])
    cams = []
    for name, y in (("left", 1.0), ("right", -1.0)):
        R, t = look_at(np.array([2.3, y, 1.5]), np.array([0.0, 0.0, 1.2]))
        cams.append(Camera(name, (640, 480), K, np.zeros(5), R, t))
    return cams


def test_the_true_arm_scores_best_and_a_wrong_arm_is_told_apart(model):
    """Classification = the true pose's rendered colours: the true arm costs ~0, a swung arm much more,
    and among hundreds of database arms the search ranks one near the true arm first."""
    rng = np.random.default_rng(5)
    kin = model.kin
    hinges = kin.lower + (kin.upper - kin.lower) * rng.random((2000, len(kin.lower)))
    search = ArmSearch(model, hinges, n_arms=300, points_per_part=6, rng=np.random.default_rng(0))
    q_true = kin.make_q(np.eye(3), np.array([0.0, 0.0, 0.93]), np.zeros(len(kin.lower)))
    q_true[7 + 3: 7 + 7] = [0.3, -0.4, 0.2, 0.9]            # left arm: shoulder x y z, elbow
    view = CropView(120.0, 40.0, 400.0 / 144, 144)
    shots = []
    for cam in _cameras():
        colour = model.render_camera(q_true, cam, view).colour
        assert (colour >= 0).sum() > 1000
        shots.append((cam, view, colour_distance_maps(colour, search.colours["l"]), 60.0))
    truth = search.score(q_true, "l", shots)
    assert truth.current < 0.02  # points on hidden faces (behind the torso) cost up to the truncation
    q_wrong = q_true.copy()
    q_wrong[7 + 3: 7 + 7] = [-0.6, 0.6, -0.5, 0.1]
    wrong = search.score(q_wrong, "l", shots, extra_arms=q_true[None, 10:14])
    assert wrong.current > 0.05
    # the true arm (given as an extra candidate) is the best candidate, far below the wrong arm
    best = int(np.argmin(wrong.scores))
    np.testing.assert_allclose(wrong.arms[best], q_true[10:14])
    assert wrong.scores[best] < 0.02
    # without it, the best of the database's arms is still well below the wrong arm
    alone = search.score(q_wrong, "l", shots)
    assert alone.scores.min() < 0.5 * wrong.current
    assert len(alone.scores) == len(search.fixed["l"]) and len(search.fixed["l"]) > 250


def test_arm_points_are_right_when_the_cache_overflows_mid_call(model, monkeypatch):
    """A long take fills the per-arm cache; a call that overflows it, with some of its arms cached before,
    returns every arm's points as computed afresh (it raised KeyError: the cache was emptied under them)."""
    import mocap.shirt.arm_search as arm_search

    rng = np.random.default_rng(2)
    kin = model.kin
    hinges = kin.lower + (kin.upper - kin.lower) * rng.random((500, len(kin.lower)))
    search = ArmSearch(model, hinges, n_arms=20, points_per_part=4, rng=np.random.default_rng(0))
    monkeypatch.setattr(arm_search, "_CACHE_ARMS", 8)
    arms = search.fixed["l"][:10]
    search._in_thorax("l", arms[:6])          # 6 of 8 cached
    got = search._in_thorax("l", arms[3:10])  # 3 cached, 4 new: over the limit
    np.testing.assert_array_equal(got, search._compute_in_thorax("l", arms[3:10]))
    np.testing.assert_array_equal(search._in_thorax("l", arms[3:10]), got)  # and read back from the cache


def test_a_colour_with_no_pixel_is_far_everywhere():
    colour = -np.ones((20, 30), np.int16)
    colour[5, 7] = 2
    d = colour_distance_maps(colour, np.array([1, 2]))
    assert d.shape == (2, 20, 30) and np.all(d[0] == 50)
    assert d[1, 5, 7] == 0 and d[1, 5, 10] == pytest.approx(3.0, abs=0.2)  # the 3x3 chamfer metric


class _Verifier:
    """The tracker's arm verification (:class:`mocap.shirt.hypotheses.TrackerHypotheses`) with the renders
    stubbed (whole poses and arm variants alike): a pose agrees with step 1 by 0.5, plus 0.1 when its left arm is ``good``; the loose solve
    returns its start and records it."""

    def __init__(self, good):
        self.params = ShirtPipelineParams()
        self.q_prev = None
        self.good = np.asarray(good, float)
        self.solved = []

    def _step1_cells(self, obs, seen):
        return {}, np.zeros(9, int)

    def _agreement(self, poses, obs, seen, cells=None):
        return [0.5 + 0.1 * float(np.allclose(q[10:14], self.good)) for q in poses], [{} for _ in poses]

    def _arm_agreement(self, q, side, arms, obs, seen, cells=None):
        sl = ARMS[side]
        return self._agreement([np.concatenate([q[:sl.start], a, q[sl.stop:]]) for a in arms], obs, seen)[0]

    def _loose_priors(self, q_blend, previous=True):
        return []

    def _loose_solve(self, q, est, lin, sil, loose, passes):
        self.solved.append(np.array(q))
        return np.array(q)


def test_arm_verification_takes_a_better_agreeing_candidate_and_skips_the_loose_solve_when_none_wins():
    """``arm_search_verify_all`` (issue 18, shirt_jumping_jacks under a 20 ms blur): every frame the arm
    search's best arms are verified by render even when none passed its screen; a candidate that agrees
    better is solved from and kept, and on a frame the screen did not flag, no candidate winning leaves
    the pose as it was, without a loose solve (the frames of the fixed-light scenarios)."""
    class V(_Verifier, TrackerHypotheses):
        pass

    good = [0.3, -0.4, 0.2, 0.9]
    q = np.zeros(18)
    q[3] = 1.0
    est = SimpleNamespace(cameras=[], q_blend=q.copy())
    v = V(good)
    others = np.array([[0.0, 0.0, 0.0, 0.1], [-0.5, 0.2, 0.1, 1.2]])
    out = v._arm_hypotheses(q, est, [], {}, {"l": others}, neighbours=False, solve_unchanged=False)
    assert out is q and v.solved == []
    out = v._arm_hypotheses(q, est, [], {}, {"l": others}, neighbours=False, solve_unchanged=True)
    assert len(v.solved) == 1 and np.array_equal(out, q)  # solved from q, not better: q kept
    v.solved = []
    out = v._arm_hypotheses(q, est, [], {}, {"l": np.vstack([others, good])}, neighbours=False, solve_unchanged=False)
    assert len(v.solved) == 1
    np.testing.assert_allclose(out[10:14], good)
    np.testing.assert_array_equal(np.delete(out, range(10, 14)), np.delete(q, range(10, 14)))


class _ArmChecks:
    """What :meth:`ShirtTracker._check_arms` asks of the tracker, stubbed: the screen gives each arm the gap
    of ``gaps`` and records which arms it scored; the verification records what it was given."""

    def __init__(self, gaps, frame, **params):
        self.params = ShirtPipelineParams(**params)
        self._frames = frame
        self.gaps = gaps
        self.screened, self.verified = [], []

    def _ranked_arms(self, q, est, sides=tuple(ARMS)):
        self.screened.append(tuple(sides))
        return {s: RankedArms(np.full((3, 4), 0.1 * i), self.gaps[s]) for i, s in enumerate(sides)}

    def _arm_hypotheses(self, q, est, lin, sil, ranked, neighbours=True, solve_unchanged=True):
        self.verified.append((sorted(ranked), neighbours, solve_unchanged))
        return q


def test_the_arm_checks_render_only_the_doubted_arms():
    """Issue 18's 33 ms: an arm is verified by render only where a candidate screens better than it
    (arm_search_verify_gap); past arm_search_margin it is also solved again.  With arm_search_alternate
    the screen scores one arm a frame, in turn.  The first frame and lost frames check both arms."""
    q = np.zeros(18)

    def run(t: _ArmChecks, lost: bool = False) -> _ArmChecks:
        ShirtTracker._check_arms(t, q, None, [], {}, lost)
        return t

    t = run(_ArmChecks({"l": -0.01, "r": -0.01}, frame=0))
    assert t.screened == [("l", "r")] and t.verified == [(["l", "r"], True, True)]
    t = run(_ArmChecks({"l": -0.01, "r": -0.01}, frame=7), lost=True)
    assert t.screened == [("l", "r")] and t.verified == [(["l", "r"], True, True)]
    t = run(_ArmChecks({"l": 0.01, "r": 0.0}, frame=4))
    assert t.screened == [("l", "r")] and t.verified == [(["l"], False, False)]   # r: no candidate screens better
    t = run(_ArmChecks({"l": -0.01, "r": -0.02}, frame=5))
    assert t.verified == []
    t = run(_ArmChecks({"l": 0.05, "r": 0.02}, frame=6))
    assert t.verified == [(["l", "r"], False, True)]                # l past the margin: solved again too
    t = run(_ArmChecks({"l": -0.01, "r": 0.0}, frame=6, arm_search_verify_gap=-np.inf))
    assert t.verified == [(["l", "r"], False, False)]              # session 17's every-frame verification
    t = run(_ArmChecks({"l": 0.01, "r": 0.01}, frame=4, arm_search_alternate=True))
    assert t.screened == [("l",)] and t.verified == [(["l"], False, False)]
    t = run(_ArmChecks({"l": 0.01, "r": 0.01}, frame=5, arm_search_alternate=True))
    assert t.screened == [("r",)] and t.verified == [(["r"], False, False)]


def test_distance_maps_within_reach_are_the_whole_maps():
    """colour_distance_maps with ``reach`` (each colour's transform over its box grown by the reach): every
    distance below the reach is the whole map's (to float32 rounding), none of the others reads below it."""
    rng = np.random.default_rng(11)
    for _ in range(40):
        colour = -np.ones((144, 144), np.int16)
        for k in range(6):
            for _ in range(rng.integers(0, 3)):
                y, x = rng.integers(0, 144, 2)
                h, w = rng.integers(1, 25, 2)
                colour[y:y + h, x:x + w] = k
        reach = float(rng.uniform(4.0, 40.0))
        whole = colour_distance_maps(colour, np.arange(6))
        near = colour_distance_maps(colour, np.arange(6), reach=reach)
        inside = whole < reach
        np.testing.assert_allclose(near[inside], whole[inside], rtol=1e-6, atol=1e-5)
        assert np.all(near[~inside] >= reach)
        assert inside.sum() > 100
